"""A scripted simulated session for the live demo: a hand-mounted camera visits objects.

For each stop the camera approaches its object from the side (the optical axis starts left
of the object and sweeps onto it), dwells on target, then moves on; a small tremor is always
present. ``SimTimeline.at(t_s)`` is a pure function of time: the same ``t_s`` always gives
the same scene and pose, and the script repeats forever.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from lpc_core.sim.scene import (
    ObjectTruth,
    Plane,
    Scene,
    SceneObject,
    aim_pose,
    functional_objects,
    make_pose,
    rotation_about,
    table,
)

Phase = Literal["approach", "on_target", "transit"]


@dataclass(frozen=True, kw_only=True)
class TimelineStop:
    """One object visit: where the camera aims from, and how far the pierced surface is."""

    obj: SceneObject
    azimuth_deg: float = 0.0
    elevation_deg: float = 20.0
    roll_deg: float = 0.0
    distance_m: float = 0.19


@dataclass(frozen=True, eq=False)
class TimelineSample:
    """The world at one instant: what to render, from where, and what is being aimed at.

    ``target`` is the visited object's ground truth from ``camera_pose`` during ``approach``
    and ``on_target`` (check ``target.pierced`` for whether the axis is on it yet), and None
    during ``transit``.
    """

    t_s: float
    scene: Scene
    camera_pose: np.ndarray
    target: ObjectTruth | None
    phase: Phase
    stop_index: int


def _min_jerk(x: float) -> float:
    """Minimum-jerk profile 10x³ - 15x⁴ + 6x⁵ on [0, 1] (the shape of a reaching movement)."""
    x = min(max(x, 0.0), 1.0)
    return x * x * x * (10.0 + x * (-15.0 + 6.0 * x))


@dataclass(frozen=True, eq=False)
class SimTimeline:
    """Stops visited in order, each for ``approach_s + dwell_s + transit_s`` seconds.

    The approach starts with the camera displaced by ``approach_offset_m`` (camera frame:
    to the left, and backed off) and ends on the aim pose; the transit moves it off by
    ``leave_offset_m``. Tremor: three sinusoids per axis (1-10 Hz, phases from ``seed``),
    ``tremor_m`` in translation and ``tremor_rad`` in rotation about the image axes.
    """

    stops: tuple[TimelineStop, ...]
    support: Plane | None = field(default_factory=table)
    approach_s: float = 1.5
    dwell_s: float = 2.5
    transit_s: float = 0.6
    approach_offset_m: tuple[float, float, float] = (-0.09, 0.0, -0.03)
    leave_offset_m: tuple[float, float, float] = (0.09, -0.03, -0.03)
    tremor_m: float = 0.0008
    tremor_rad: float = float(np.radians(0.3))
    seed: int = 0
    _aims: tuple[np.ndarray, ...] = field(init=False, repr=False)
    _scenes: tuple[Scene, ...] = field(init=False, repr=False)
    _tremor: tuple[np.ndarray, np.ndarray, np.ndarray] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "stops", tuple(self.stops))
        if not self.stops:
            raise ValueError("stops must not be empty")
        for name in ("approach_s", "dwell_s", "transit_s"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be positive, got {value}")
        for name in ("tremor_m", "tremor_rad"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be non-negative")
        aims = tuple(
            aim_pose(
                s.obj,
                s.distance_m,
                azimuth_rad=np.radians(s.azimuth_deg),
                elevation_rad=np.radians(s.elevation_deg),
                roll_rad=np.radians(s.roll_deg),
            )
            for s in self.stops
        )
        object.__setattr__(self, "_aims", aims)
        object.__setattr__(
            self, "_scenes", tuple(Scene((s.obj,), self.support) for s in self.stops)
        )
        rng = np.random.default_rng(self.seed)
        freqs = rng.uniform(1.0, 10.0, size=(5, 3))  # 5 channels: x, y, z, pitch, yaw
        phases = rng.uniform(0.0, 2.0 * np.pi, size=(5, 3))
        weights = np.array([0.6, 0.3, 0.1])  # slow drift dominates, fast tremor is small
        object.__setattr__(self, "_tremor", (freqs, phases, weights))

    @property
    def stop_s(self) -> float:
        return self.approach_s + self.dwell_s + self.transit_s

    @property
    def period_s(self) -> float:
        """The whole script's length; ``at(t)`` equals ``at(t + period_s)``."""
        return self.stop_s * len(self.stops)

    def _tremor_pose(self, t_s: float) -> np.ndarray:
        freqs, phases, weights = self._tremor
        wave = np.sin(2.0 * np.pi * freqs * t_s + phases) @ weights  # (5,), each within ±1
        shift = self.tremor_m * wave[:3]
        rot = rotation_about((1.0, 0.0, 0.0), self.tremor_rad * wave[3]) @ rotation_about(
            (0.0, 1.0, 0.0), self.tremor_rad * wave[4]
        )
        return make_pose(rot, shift)

    def at(self, t_s: float) -> TimelineSample:
        """The scripted world at ``t_s`` seconds (>= 0) after the session start."""
        t_s = float(t_s)
        if not np.isfinite(t_s) or t_s < 0:
            raise ValueError(f"t_s must be a non-negative finite number, got {t_s}")
        local = t_s % self.period_s
        index = min(int(local // self.stop_s), len(self.stops) - 1)
        tau = local - index * self.stop_s
        phase: Phase
        if tau < self.approach_s:
            phase = "approach"
            offset = (1.0 - _min_jerk(tau / self.approach_s)) * np.asarray(self.approach_offset_m)
        elif tau < self.approach_s + self.dwell_s:
            phase = "on_target"
            offset = np.zeros(3)
        else:
            phase = "transit"
            x = (tau - self.approach_s - self.dwell_s) / self.transit_s
            offset = _min_jerk(x) * np.asarray(self.leave_offset_m)
        pose = self._aims[index] @ make_pose(None, offset) @ self._tremor_pose(local)
        stop = self.stops[index]
        target = None if phase == "transit" else stop.obj.truth(pose)
        return TimelineSample(
            t_s=t_s,
            scene=self._scenes[index],
            camera_pose=pose,
            target=target,
            phase=phase,
            stop_index=index,
        )


DEFAULT_ORDER: tuple[tuple[str, float, float], ...] = (
    # (object, azimuth_deg, elevation_deg): shapes alternate, as in the paper's sequence.
    ("sphere_large", 0.0, 20.0),
    ("cylinder_tilt_left", 0.0, 15.0),
    ("cuboid_upright", 10.0, 20.0),
    ("sphere_small", -10.0, 25.0),
    ("cylinder_lying", 0.0, 30.0),
    ("cuboid_tilt_right", 0.0, 15.0),
    ("cylinder_upright", 15.0, 20.0),
    ("cuboid_lying", 0.0, 25.0),
    ("cylinder_tilt_right", -10.0, 15.0),
    ("cuboid_tilt_left", 0.0, 15.0),
)


def default_timeline(
    seed: int = 0, with_table: bool = True, objects: Sequence[str] | None = None
) -> SimTimeline:
    """The built-in session: the paper's ten functional objects, a sphere, a cylinder and a
    cuboid first, 4.6 s each (1.5 s approach, 2.5 s on target, 0.6 s transit), pierced
    surface 190 mm from the camera. A 10 s run sees two complete visits."""
    catalogue = functional_objects()
    order = DEFAULT_ORDER
    if objects is not None:
        views = {name: (az, el) for name, az, el in DEFAULT_ORDER}
        unknown = [name for name in objects if name not in catalogue]
        if unknown:
            raise ValueError(f"objects: unknown names {unknown}")
        order = tuple((name, *views[name]) for name in objects)
    stops = tuple(
        TimelineStop(obj=catalogue[name], azimuth_deg=az, elevation_deg=el)
        for name, az, el in order
    )
    return SimTimeline(stops=stops, support=table() if with_table else None, seed=seed)
