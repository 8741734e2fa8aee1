"""The reconstructor's logic: scan lines (or whole depth frames) in, reconstructions and the
grasp target out.

Two methods: ``laser``, the four-line method on ``lpc/scans``, and ``cloud``, the full-point-
cloud benchmark on ``lpc/camera/depth`` (``cloud``). Two ways to run either, with the
same results per frame:

- ``reconstruct_step(state, scans, now_ns)`` / ``reconstruct_cloud_step(state, frame, now_ns)``:
  one frame, in-process (tests, replay). Their ``compute_ms`` is 0: nothing here reads a clock.
- The service (``services/reconstructor.py``) runs ``reconstruct_message`` or
  ``reconstruct_cloud_message`` in a process pool
  and keeps order with ``frame_arrived`` / ``frame_done``: frames go to free workers in
  arrival order (``ahead`` more per worker queue in its pipe); at most ``max_pending`` more
  wait, and when another arrives the oldest
  waiting frame is dropped and counted; results are released in ``seq`` order, each then going
  through the 10-frame window (``release``).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Generic, TypeVar

import numpy as np

from lpc_core.perception.cloud import CloudParams, reconstruct_cloud
from lpc_core.perception.grip import GripRules, choose_grip
from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.laser import LaserParams, reconstruct_laser
from lpc_core.perception.pipeline import depth_image, intrinsics_from_message, intrinsics_to_message
from lpc_core.perception.reconstruction import Reconstruction as CoreReconstruction
from lpc_core.perception.scans import ScanLines as CoreScanLines
from lpc_core.perception.state import evolve
from lpc_core.perception.window import WindowParams, WindowResult, WindowState, window_step
from schemas import (
    DepthFrame,
    GraspTarget,
    LineModel,
    Reconstruction,
    ScanLines,
    from_wire,
    joined_points,
    to_wire,
)

# The topic each method reconstructs from.
INPUT_TOPICS: MappingProxyType[str, str] = MappingProxyType(
    {"laser": "lpc/scans", "cloud": "lpc/camera/depth"}
)

Job = TypeVar("Job")


# Scans messages carry no pixel indices: every line shares this empty, read-only array.
_NO_PIXELS = np.empty(0, dtype=np.int64)
_NO_PIXELS.flags.writeable = False


def _line_points(message: ScanLines) -> list[np.ndarray]:
    """Each scan line's (N, 3) points as float64, with ``from_wire``'s errors."""
    return _lines_and_rows(message)[0]


def _lines_and_rows(message: ScanLines) -> tuple[list[np.ndarray], np.ndarray | None]:
    """``_line_points``, and the float64 rows they are consecutive slices of (finite), or
    None. Where ``joined_points`` takes the lines, as the scans service sends them, all are
    widened at once and each line is a slice of the result (20 -> 12 us a frame on a live
    recording's scans)."""
    wires = [line.points for line in message.lines]
    joined = joined_points(wires)
    if joined is not None:
        rows = joined.astype(np.float64)
        ends = itertools.accumulate(w.shape[0] for w in wires)
        return [rows[end - w.shape[0] : end] for end, w in zip(ends, wires, strict=True)], rows
    points = []
    for wire in wires:
        array = np.asarray(from_wire(wire), dtype=np.float64)
        if array.ndim != 2 or array.shape[1] != 3:
            raise ValueError(f"scan line points must be (N, 3), got {array.shape}")
        points.append(array)
    return points, None


def scan_lines_from_message(message: ScanLines) -> CoreScanLines:
    """The scan lines of a ``lpc/scans`` message; ``ValueError`` if an array is malformed."""
    return _scan_lines(message)[0]


def _scan_lines(message: ScanLines) -> tuple[CoreScanLines, np.ndarray | None]:
    """``scan_lines_from_message``, and its lines' points joined as ``reconstruct_laser``
    takes them (read-only; None where the message's lines came one by one): the float32
    rows were checked finite and widened once, and need no second concatenation and check."""
    points, rows = _lines_and_rows(message)
    if rows is not None:
        # A read-only view: the lines' pierced segments are slices of it, never written.
        rows = rows.view()
        rows.flags.writeable = False
    # math.radians multiplies by the same constant pi / 180 as np.radians, on Python floats
    # (without converting the list for a ufunc).
    angles = np.array([math.radians(line.angle_deg) for line in message.lines])
    past = [line.past_ends_m for line in message.lines]
    if any(p is not None and len(p) != 2 for p in past):
        raise ValueError("a scan line's past_ends_m must hold two depths, one per end")
    far = [line.far_past_m for line in message.lines]
    if any(f is not None and len(f) != 6 for f in far):
        raise ValueError("a scan line's far_past_m must hold two points, one per end")
    edge = [line.edge_past_m for line in message.lines]
    if any(e is not None and len(e) != 6 for e in edge):
        raise ValueError("a scan line's edge_past_m must hold two points, one per end")
    scan_lines = CoreScanLines(
        angles_rad=angles,
        points=tuple(points),
        pixels=(_NO_PIXELS,) * len(points),
        # Scans recorded before the depth past the lines' ends was measured have none.
        past_ends_m=None if any(p is None for p in past) else np.array(past, dtype=np.float64),
        far_past_m=(
            None
            if any(f is None for f in far)
            else np.array(far, dtype=np.float64).reshape(len(far), 2, 3)
        ),
        edge_past_m=(
            None
            if any(e is None for e in edge)
            else np.array(edge, dtype=np.float64).reshape(len(edge), 2, 3)
        ),
    )
    return scan_lines, rows


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def reconstruction_message(
    result: CoreReconstruction, source: ScanLines | DepthFrame, compute_ms: float = 0.0
) -> Reconstruction:
    """The ``lpc/reconstruction`` message of one frame.

    ``seq``, ``t_ns`` and ``truth`` are those of ``source``, the message reconstructed: the
    scans (whose ``frame_seq`` names the depth frame) or the depth frame itself. Its float
    fields hold floats (an int 1 would encode as an int and decode as 1.0): the service
    publishes a worker's encoding as it is, which must be the encoding of what it decodes to.
    """
    frame_seq = source.frame_seq if isinstance(source, ScanLines) else source.seq
    lines = [
        LineModel(
            angle_deg=ln.angle_deg,
            model=ln.model,  # type: ignore[arg-type]
            params=[float(v) for v in ln.params if math.isfinite(v)],
            inlier_fraction=float(min(max(ln.inlier_fraction, 0.0), 1.0)),
            n_points=ln.n_points,
        )
        for ln in result.lines
    ]
    return Reconstruction(
        seq=source.seq,
        t_ns=source.t_ns,
        frame_seq=frame_seq,
        method=result.method,  # type: ignore[arg-type]
        shape=result.shape,
        grasp_width_mm=_finite(result.grasp_width_mm),
        wrist_angle_deg=_finite(result.wrist_angle_deg),
        center_m=None if result.center_m is None else list(result.center_m),
        axis=None if result.axis is None else list(result.axis),
        lines=lines,
        confidence=float(min(max(result.confidence, 0.0), 1.0)),
        reason=result.reason,
        points=result.points,
        compute_ms=float(max(compute_ms, 0.0)),
        truth=source.truth,
    )


_DEFAULT = LaserParams()
_CLOUD = CloudParams()


def reconstruct_message(
    scans: ScanLines, params: LaserParams = _DEFAULT, compute_ms: float = 0.0
) -> Reconstruction:
    """Reconstruct one ``lpc/scans`` message; RANSAC is seeded by the depth frame's ``seq``."""
    lines, joined = _scan_lines(scans)
    result = reconstruct_laser(lines, params, seed=scans.frame_seq, joined=joined)
    return reconstruction_message(result, scans, compute_ms)


def reconstruct_cloud_message(
    frame: DepthFrame, params: CloudParams = _CLOUD, compute_ms: float = 0.0
) -> Reconstruction:
    """Reconstruct one ``lpc/camera/depth`` frame by the cloud method, seeded by its ``seq``.

    ``ValueError`` if the depth array does not match the frame's intrinsics.
    """
    intrinsics = intrinsics_from_message(frame.intrinsics)
    result = reconstruct_cloud(depth_image(frame), intrinsics, params, seed=frame.seq)
    return reconstruction_message(result, frame, compute_ms)


def warmup_frame(intrinsics: Intrinsics | None = None) -> DepthFrame:
    """A 50 mm ball 200 mm ahead of a wall at 240 mm, noise-free.

    The service's workers reconstruct it once at start, so that the first real frame does not
    pay for the imports and first calls (about 0.5-0.8 s) and get the frames behind it dropped.
    """
    intr = intrinsics or Intrinsics()
    rx, ry = intr.pixel_rays()
    # Ray (rx, ry, 1) t meets the sphere |p - c| = r where t^2 |d|^2 - 2 t d.c + |c|^2 - r^2 = 0.
    center_z, radius, wall_z = 0.2, 0.025, 0.24
    a = rx * rx + ry * ry + 1.0
    disc = center_z**2 - a * (center_z**2 - radius**2)
    with np.errstate(invalid="ignore"):
        z = np.where(disc >= 0, (center_z - np.sqrt(disc)) / a, wall_z)
    depth = np.round(z / intr.depth_scale).astype(np.uint16)
    return DepthFrame(seq=0, t_ns=0, intrinsics=intrinsics_to_message(intr), depth=to_wire(depth))


# --------------------------------------------------------------------------- the window


def _core(message: Reconstruction) -> CoreReconstruction:
    return CoreReconstruction(
        shape=message.shape,
        grasp_width_m=None if message.grasp_width_mm is None else message.grasp_width_mm / 1000,
        wrist_angle_rad=(
            None if message.wrist_angle_deg is None else math.radians(message.wrist_angle_deg)
        ),
    )


# The default rules, built and checked once rather than on every frame's grasp target.
_GRIP_RULES = GripRules()


def grasp_target_message(window: WindowResult, message: Reconstruction) -> GraspTarget:
    width_mm, angle_deg = window.grasp_width_mm, window.wrist_angle_deg
    choice = choose_grip(window.shape, width_mm, angle_deg, _GRIP_RULES)
    return GraspTarget(
        seq=message.seq,
        t_ns=message.t_ns,
        frame_seq=message.frame_seq,
        shape=window.shape,
        grasp_width_mm=width_mm,
        wrist_angle_deg=angle_deg,
        reconstructed=window.reconstructed,
        frames=window.frames,
        agreement=window.agreement,
        grip=choice.grip,  # type: ignore[arg-type]
        grip_reason=choice.reason,
    )


def window_message(state: WindowState, message: Reconstruction) -> tuple[WindowState, GraspTarget]:
    """Pass one reconstruction through the 10-frame window."""
    state, window = window_step(state, _core(message), message.seq, message.t_ns)
    return state, grasp_target_message(window, message)


# --------------------------------------------------------------------------- in-process step


@dataclass(frozen=True)
class ReconstructState:
    """Either method's in-process state: its parameters and the 10-frame window."""

    params: LaserParams = field(default_factory=LaserParams)
    window: WindowState = field(default_factory=WindowState)
    cloud: CloudParams = field(default_factory=CloudParams)


def reconstruct_step(
    state: ReconstructState, scans: ScanLines, now_ns: int
) -> tuple[ReconstructState, list[Reconstruction | GraspTarget]]:
    """One frame in-process: its reconstruction, then the window's grasp target."""
    del now_ns  # outputs carry the capture time of their frame
    return release_step(state, reconstruct_message(scans, state.params))


def reconstruct_cloud_step(
    state: ReconstructState, frame: DepthFrame, now_ns: int
) -> tuple[ReconstructState, list[Reconstruction | GraspTarget]]:
    """One depth frame in-process by the cloud method: its reconstruction, then the window's."""
    del now_ns  # outputs carry the capture time of their frame
    return release_step(state, reconstruct_cloud_message(frame, state.cloud))


def release_step(
    state: ReconstructState, message: Reconstruction
) -> tuple[ReconstructState, list[Reconstruction | GraspTarget]]:
    """A frame's reconstruction, made here or by a worker process, through the window."""
    window, target = window_message(state.window, message)
    return evolve(state, window=window), [message, target]


def reconstruct(state: ReconstructState, message: ScanLines | DepthFrame) -> Reconstruction:
    """One frame's reconstruction with the parameters of ``state``: scan lines by the laser
    method, a depth frame by the cloud method, as the in-process steps do. It depends on the
    frame alone, so a replay runs it in worker processes, as the service does."""
    if isinstance(message, ScanLines):
        return reconstruct_message(message, state.params)
    if isinstance(message, DepthFrame):
        return reconstruct_cloud_message(message, state.cloud)
    raise ValueError(f"message must be ScanLines or DepthFrame, got {type(message).__name__}")


# --------------------------------------------------------------------------- pool bookkeeping


@dataclass(frozen=True, kw_only=True)
class PoolParams:
    """``workers`` frames run at once, and ``ahead`` more per worker are handed to it behind
    the one it runs; ``max_pending`` more may wait in the service, where a newer frame can
    still replace them.

    A frame handed ahead sits in the worker's pipe, so the worker starts it the moment it
    finishes the one before, without waiting for the service's loop to read the result and
    send the next job: under a CPU quota that loop is itself late (scans, aim and the recorder
    share it), and each hand-over cost the worker about 0.8 ms of idle time a frame.
    """

    workers: int = 1
    max_pending: int = 2
    ahead: int = 0

    def __post_init__(self) -> None:
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")
        if self.max_pending < 0:
            raise ValueError(f"max_pending must be >= 0, got {self.max_pending}")
        if self.ahead < 0:
            raise ValueError(f"ahead must be >= 0, got {self.ahead}")

    @property
    def in_flight(self) -> int:
        """Frames handed to the workers at most: each one's running frame and those ahead."""
        return self.workers * (1 + self.ahead)


@dataclass(frozen=True)
class Submit(Generic[Job]):
    """Start this frame's job on a worker."""

    seq: int
    job: Job


@dataclass(frozen=True)
class Release:
    """This frame's result is next in ``seq`` order: publish it."""

    seq: int
    result: Any


@dataclass(frozen=True)
class Dropped:
    """This frame was dropped: it waited while a newer one arrived, or it came out of order."""

    seq: int
    reason: str


@dataclass(frozen=True)
class PoolState:
    params: PoolParams = field(default_factory=PoolParams)
    running: frozenset[int] = frozenset()
    pending: tuple[tuple[int, Any], ...] = ()
    waiting: tuple[int, ...] = ()  # frames not yet released, in seq order
    done: MappingProxyType[int, Any] = field(default_factory=lambda: MappingProxyType({}))
    last_seq: int = -1
    dropped: int = 0


Output = Submit[Any] | Release | Dropped


def frame_arrived(state: PoolState, seq: int, job: Any) -> tuple[PoolState, list[Output]]:
    """A frame arrives: run it, let it wait, or drop the oldest waiting frame for it."""
    if seq <= state.last_seq:
        return evolve(state, dropped=state.dropped + 1), [Dropped(seq, "out of order")]
    outputs: list[Output] = []
    if len(state.running) < state.params.in_flight:
        outputs.append(Submit(seq, job))
        return evolve(
            state, running=state.running | {seq}, waiting=(*state.waiting, seq), last_seq=seq
        ), outputs
    pending = (*state.pending, (seq, job))
    if len(pending) <= state.params.max_pending:
        return evolve(state, pending=pending, waiting=(*state.waiting, seq), last_seq=seq), []
    (old, _), pending = pending[0], pending[1:]
    # The oldest waiting frame is this one when none may wait (``max_pending`` 0).
    waiting = tuple(s for s in (*state.waiting, seq) if s != old)
    outputs.append(Dropped(old, "the pool fell behind"))
    # Dropping a waiting frame may unblock results that were held behind it.
    waiting, done = _release(waiting, state.done, outputs)
    return evolve(
        state,
        pending=pending,
        waiting=waiting,
        done=done,
        last_seq=seq,
        dropped=state.dropped + 1,
    ), outputs


def frame_done(state: PoolState, seq: int, result: Any) -> tuple[PoolState, list[Output]]:
    """A worker finished ``seq``: release what is now in order, start a waiting frame."""
    if seq not in state.running:
        return state, []
    running = state.running - {seq}
    outputs: list[Output] = []
    pending = state.pending
    if pending and len(running) < state.params.in_flight:
        (next_seq, job), pending = pending[0], pending[1:]
        running = running | {next_seq}
        outputs.append(Submit(next_seq, job))
    waiting, done = state.waiting, state.done
    if waiting[0] == seq:
        # The frame next in order (as a single worker's always is) goes out at once, without
        # passing through ``done``: a copy of that mapping fewer a frame.
        outputs.append(Release(seq, result))
        waiting, done = _release(waiting[1:], done, outputs)
    else:
        done = MappingProxyType({**done, seq: result})
    return evolve(state, running=running, pending=pending, waiting=waiting, done=done), outputs


def _release(
    waiting: tuple[int, ...], done: MappingProxyType[int, Any], outputs: list[Output]
) -> tuple[tuple[int, ...], MappingProxyType[int, Any]]:
    """The results now in order appended to ``outputs`` as releases; ``waiting`` and ``done``
    without them (the same objects when there are none)."""
    if not waiting or waiting[0] not in done:
        return waiting, done
    rest = dict(done)
    while waiting and waiting[0] in rest:
        seq, waiting = waiting[0], waiting[1:]
        outputs.append(Release(seq, rest.pop(seq)))
    return waiting, MappingProxyType(rest)


__all__ = [
    "INPUT_TOPICS",
    "Dropped",
    "Output",
    "PoolParams",
    "PoolState",
    "ReconstructState",
    "Release",
    "Submit",
    "WindowParams",
    "frame_arrived",
    "frame_done",
    "grasp_target_message",
    "reconstruct",
    "reconstruct_cloud_message",
    "reconstruct_cloud_step",
    "reconstruct_message",
    "reconstruct_step",
    "reconstruction_message",
    "release_step",
    "scan_lines_from_message",
    "warmup_frame",
    "window_message",
]
