"""The 10-frame window: the grasp target the controller acts on.

The paper takes the median of a 10-frame moving window for the grasp size and the wrist
orientation, and signals "reconstructed" once the window holds a shape (all tactors pulse; the
user may then trigger the preshape). Here the shape is the window's majority; width and angle
are medians over the frames of that shape. Wrist angles are axial (an axis and its reverse are
the same, +90 deg is -90 deg), so their median is taken on the doubled-angle circle.

``window_step`` is pure: the state is an immutable value, nothing reads a clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lpc_core.perception.reconstruction import Reconstruction, Shape, median, wrap_half_turn


@dataclass(frozen=True, kw_only=True)
class WindowParams:
    """``size`` frames (the paper's 10); "reconstructed" needs a full window whose majority
    shape is held by at least ``min_agree`` frames. A pause of more than ``max_gap_ns`` between
    frames, or a sequence number going backwards, starts the window afresh."""

    size: int = 10
    min_agree: int = 7
    max_gap_ns: int = 500_000_000

    def __post_init__(self) -> None:
        if self.size < 1:
            raise ValueError(f"size must be >= 1, got {self.size}")
        if not 1 <= self.min_agree <= self.size:
            raise ValueError(f"min_agree must be in [1, size], got {self.min_agree}")
        if self.max_gap_ns <= 0:
            raise ValueError(f"max_gap_ns must be positive, got {self.max_gap_ns}")


@dataclass(frozen=True)
class WindowEntry:
    seq: int
    t_ns: int
    shape: Shape
    grasp_width_m: float | None
    wrist_angle_rad: float | None


@dataclass(frozen=True)
class WindowState:
    params: WindowParams = field(default_factory=WindowParams)
    entries: tuple[WindowEntry, ...] = ()


@dataclass(frozen=True, kw_only=True)
class WindowResult:
    """The window after one frame: majority ``shape`` and the medians over its frames."""

    seq: int
    t_ns: int
    shape: Shape
    grasp_width_m: float | None
    wrist_angle_rad: float | None
    reconstructed: bool
    frames: int
    agreement: float

    @property
    def grasp_width_mm(self) -> float | None:
        return None if self.grasp_width_m is None else 1000.0 * self.grasp_width_m

    @property
    def wrist_angle_deg(self) -> float | None:
        return None if self.wrist_angle_rad is None else math.degrees(self.wrist_angle_rad)


def axial_median(angles_rad: np.ndarray) -> float:
    """Median of axis angles (period pi), in [-pi/2, pi/2).

    The angles are doubled onto the circle, measured from their mean direction there, and the
    median of those offsets is halved back: 89 and -89 deg give +-90, not 0.
    """
    angles = np.asarray(angles_rad, dtype=np.float64).reshape(-1)
    if len(angles) == 0:
        raise ValueError("angles_rad must not be empty")
    doubled = 2.0 * angles
    reference = math.atan2(float(np.sin(doubled).sum()), float(np.cos(doubled).sum()))
    offsets = (doubled - reference + np.pi) % (2 * np.pi) - np.pi
    return wrap_half_turn((reference + median(offsets.tolist())) / 2.0)


def _majority(entries: tuple[WindowEntry, ...]) -> tuple[Shape, int]:
    # list.count over ten shapes costs less than building a Counter.
    shapes = [e.shape for e in entries]
    top = max(map(shapes.count, set(shapes)))
    # A tie goes to the shape seen most recently.
    for shape in reversed(shapes):
        if shapes.count(shape) == top:
            return shape, top
    raise AssertionError("unreachable: entries is not empty")


def window_step(
    state: WindowState, reconstruction: Reconstruction, seq: int, t_ns: int
) -> tuple[WindowState, WindowResult]:
    """Add one frame's reconstruction and return the window's grasp target."""
    params = state.params
    entries = state.entries
    if entries and (seq <= entries[-1].seq or t_ns - entries[-1].t_ns > params.max_gap_ns):
        entries = ()
    entry = WindowEntry(
        seq=seq,
        t_ns=t_ns,
        shape=reconstruction.shape,
        grasp_width_m=reconstruction.grasp_width_m,
        wrist_angle_rad=reconstruction.wrist_angle_rad,
    )
    entries = (*entries, entry)[-params.size :]
    shape, agree = _majority(entries)
    width = angle = None
    if shape != "none":
        same = [e for e in entries if e.shape == shape]
        widths = [e.grasp_width_m for e in same if e.grasp_width_m is not None]
        angles = [e.wrist_angle_rad for e in same if e.wrist_angle_rad is not None]
        width = median(widths) if widths else None
        if shape != "sphere" and angles:
            angle = axial_median(np.array(angles))
    reconstructed = shape != "none" and len(entries) == params.size and agree >= params.min_agree
    result = WindowResult(
        seq=seq,
        t_ns=t_ns,
        shape=shape,
        grasp_width_m=width,
        wrist_angle_rad=angle,
        reconstructed=reconstructed,
        frames=len(entries),
        agreement=agree / len(entries),
    )
    return WindowState(params=params, entries=entries), result


__all__ = [
    "WindowEntry",
    "WindowParams",
    "WindowResult",
    "WindowState",
    "axial_median",
    "window_step",
]
