"""Simulated views for ``lpc bench accuracy`` and ``lpc bench speed``: the paper's evaluations.

A *trial* is one approach to an object: a base pose (distance of the pierced surface 160-230 mm,
azimuth, elevation, wrist roll, aim offset), then ``frames`` consecutive frames with a steady
hand's jitter (about 1 mm and 1 degree) and fresh D435-like noise each, as the 10-frame window
sees them. Every random draw comes from ``numpy.random.default_rng([seed, suite, object,
trial, frame])``, so a view does not depend on which others were generated.

Suites (reference/paper.tex, "Results" and "Testing of Irregularly Shaped Objects"):

- ``rotation``: a 40 mm prism and 40 and 75 mm cylinders lying on the table, seen from above,
  the wrist rolled to six angles 30 degrees apart;
- ``functional``: the paper's ten objects (upright, lying, tilted left and right);
- ``irregular``: the stress-test objects, the jar cap from the front and from the top;
- ``clutter``: the functional objects seen steeply (the table inside the capture volume) or
  with a neighbouring object 70-85 mm to the side.
"""

from __future__ import annotations

import hashlib
import math
import os
import pickle
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.sim import scene
from lpc_core.sim.stereo import StereoSensor

SUITES = ("rotation", "functional", "irregular", "clutter")
ROTATION_ANGLES_DEG = (0, 30, 60, 90, 120, 150)
INTRINSICS = Intrinsics()
_MM = 0.001


@dataclass(frozen=True)
class Approach:
    """How a view is taken: ranges the base pose is drawn from (degrees, metres)."""

    elevation_deg: tuple[float, float] = (10.0, 35.0)
    azimuth_deg: tuple[float, float] = (-25.0, 25.0)
    roll_deg: tuple[float, float] = (-30.0, 30.0)
    distance_m: tuple[float, float] = (0.16, 0.23)
    aim_offset_m: float = 0.004


@dataclass(frozen=True)
class Subject:
    """An object to approach, the scene around it and how to approach it."""

    name: str
    obj: scene.SceneObject
    world: scene.Scene
    approach: Approach
    detail: str = ""  # e.g. the nominal wrist angle of the rotation test


@dataclass(frozen=True)
class View:
    suite: str
    subject: str
    detail: str
    trial: int
    frame: int
    seq: int
    depth: np.ndarray
    truth: scene.ObjectTruth
    square_face: bool = False  # a box pierced on a square face: its axis is ambiguous by 90 deg


def _table_scene(*objects: scene.SceneObject) -> scene.Scene:
    return scene.Scene(objects=objects, support=scene.table(0.0))


def rotation_subjects() -> list[Subject]:
    along_x = scene.rotation_about((0.0, 1.0, 0.0), math.pi / 2)
    objects = [
        scene.cuboid_object("prism_40", (0, 0, 0), along_x, np.array([40, 40, 150]) * _MM),
        scene.cylinder_object("cylinder_40", (0, 0, 0), (1, 0, 0), 20 * _MM, 150 * _MM),
        scene.cylinder_object("cylinder_75", (0, 0, 0), (1, 0, 0), 37.5 * _MM, 150 * _MM),
    ]
    subjects = []
    for obj in objects:
        obj = obj.resting_on(0.0)
        for angle in ROTATION_ANGLES_DEG:
            approach = Approach(
                elevation_deg=(75.0, 85.0), azimuth_deg=(-5.0, 5.0), roll_deg=(angle, angle)
            )
            subjects.append(
                Subject(obj.name, obj, _table_scene(obj), approach, f"roll {angle:3d} deg")
            )
    return subjects


def functional_subjects() -> list[Subject]:
    return [
        Subject(name, obj, _table_scene(obj), Approach())
        for name, obj in scene.functional_objects().items()
    ]


# How a user approaches each irregular object: flat things lying on the table from above.
_FROM_ABOVE = Approach(elevation_deg=(55.0, 75.0))
_IRREGULAR_APPROACH = {
    "tv_remote": _FROM_ABOVE,
    "soap_bar": _FROM_ABOVE,
    "frying_pan_handle": _FROM_ABOVE,
}


def irregular_subjects() -> list[Subject]:
    subjects = []
    for name, obj in scene.irregular_objects().items():
        if name == "jar_cap":
            front = Approach(elevation_deg=(10.0, 25.0))
            # Within 5 degrees of straight down the cap's axis has no wrist angle to judge.
            top = Approach(elevation_deg=(86.0, 89.0), azimuth_deg=(-5.0, 5.0))
            subjects.append(Subject(name, obj, _table_scene(obj), front, "front"))
            subjects.append(Subject(name, obj, _table_scene(obj), top, "top"))
        else:
            approach = _IRREGULAR_APPROACH.get(name, Approach())
            subjects.append(Subject(name, obj, _table_scene(obj), approach))
    return subjects


def clutter_subjects() -> list[Subject]:
    objects = scene.functional_objects()
    names = list(objects)
    subjects = []
    for i, name in enumerate(names):
        obj = objects[name]
        steep = Approach(elevation_deg=(40.0, 55.0))
        subjects.append(Subject(name, obj, _table_scene(obj), steep, "table in view"))
        neighbour = objects[names[(i + 3) % len(names)]]
        _, radius = neighbour.bounds()
        beside = neighbour.translated((0.07 + 0.015 + 0.5 * min(radius, 0.05), 0.0, 0.0))
        subjects.append(
            Subject(name, obj, _table_scene(obj, beside), Approach(), f"beside {neighbour.name}")
        )
    return subjects


SUBJECTS = {
    "rotation": rotation_subjects,
    "functional": functional_subjects,
    "irregular": irregular_subjects,
    "clutter": clutter_subjects,
}


def _back(azimuth: float, elevation: float) -> np.ndarray:
    return np.array(
        [
            math.sin(azimuth) * math.cos(elevation),
            -math.cos(azimuth) * math.cos(elevation),
            math.sin(elevation),
        ]
    )


def aim_target(obj: scene.SceneObject, back: np.ndarray) -> np.ndarray:
    """Where a user aims: a box's face turned most toward them (its centre), else the centre."""
    box = obj.box
    if box is None:
        return obj.center
    normals = np.concatenate([box.rotation.T, -box.rotation.T])
    half = np.concatenate([box.size, box.size]) / 2
    k = int(np.argmax(normals @ back))
    return box.center + normals[k] * half[k]


def _square_face(obj: scene.SceneObject, pose: np.ndarray) -> bool:
    """Whether the optical axis enters ``obj``'s box through a square face (slab test)."""
    if obj.box is None:
        return False
    cam_from_world = scene.invert_pose(pose)
    rotation = cam_from_world[:3, :3] @ obj.box.rotation
    center = cam_from_world[:3, :3] @ obj.box.center + cam_from_world[:3, 3]
    half = np.asarray(obj.box.size) / 2
    origin, direction = rotation.T @ -center, rotation.T @ np.array([0.0, 0.0, 1.0])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - origin) / direction, (half - origin) / direction
    near = np.nan_to_num(np.minimum(t1, t2), nan=-np.inf)
    far = np.nan_to_num(np.maximum(t1, t2), nan=np.inf)
    if near.max() > far.min() or far.min() <= 0:
        return False
    i, j = [a for a in range(3) if a != int(np.argmax(near))]
    return bool(abs(half[i] - half[j]) <= 0.05 * max(half[i], half[j]))


def _uniform(rng: np.random.Generator, limits: tuple[float, float]) -> float:
    return float(rng.uniform(*limits)) if limits[0] != limits[1] else float(limits[0])


def views(
    suite: str,
    trials: int,
    frames: int,
    seed: int,
    subjects: list[Subject] | None = None,
    names: Collection[str] | None = None,
    sensor: StereoSensor | None = None,
    cache: Path | None = None,
) -> Iterator[View]:
    """``trials`` approaches of ``frames`` frames to each subject of ``suite`` (or only to
    those called ``names``: the others' views are skipped, not changed), seen through the
    noise model or, given ``sensor``, the simulated stereo camera (same poses either way).

    With ``cache`` (a directory), stereo frames are read from it when rendered before and
    written to it otherwise (``_cached_depth``): a stereo frame costs about 100 ms to render."""
    if suite not in SUBJECTS:
        raise ValueError(f"suite must be one of {SUITES}, got {suite!r}")
    subjects = SUBJECTS[suite]() if subjects is None else subjects
    suite_id = SUITES.index(suite)
    seq = 0
    for s, subject in enumerate(subjects):
        if names is not None and subject.name not in names:
            seq += trials * frames
            continue
        a = subject.approach
        for trial in range(trials):
            base = np.random.default_rng([seed, suite_id, s, trial])
            distance = _uniform(base, a.distance_m)
            azimuth = math.radians(_uniform(base, a.azimuth_deg))
            elevation = math.radians(_uniform(base, a.elevation_deg))
            roll = math.radians(_uniform(base, a.roll_deg))
            offset = base.uniform(-a.aim_offset_m, a.aim_offset_m, 3)
            for frame in range(frames):
                rng = np.random.default_rng([seed, suite_id, s, trial, frame])
                jitter = math.radians(1.0)
                az = azimuth + rng.uniform(-jitter, jitter)
                el = elevation + rng.uniform(-jitter, jitter)
                target = aim_target(subject.obj, _back(az, el))
                pose = scene.aim_pose(
                    subject.obj,
                    distance_m=distance + rng.uniform(-0.002, 0.002),
                    azimuth_rad=az,
                    elevation_rad=el,
                    roll_rad=roll + rng.uniform(-jitter, jitter),
                    aim_point=target + offset + rng.uniform(-0.001, 0.001, 3),
                )
                if sensor is None:
                    depth = scene.render_depth(subject.world, INTRINSICS, pose, rng)
                elif cache is None:
                    depth = sensor.render_depth(subject.world, INTRINSICS, pose, rng)
                else:
                    depth = _cached_depth(cache, sensor, subject.world, pose, rng)
                yield View(
                    suite, subject.name, subject.detail, trial, frame, seq, depth,
                    subject.obj.truth(pose), _square_face(subject.obj, pose),
                )  # fmt: skip
                seq += 1


def _cached_depth(
    cache: Path,
    sensor: StereoSensor,
    world: scene.Scene,
    pose: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """The stereo frame of ``world`` from ``pose``, from ``cache`` if there. The key is the
    sensor's and the scene's full description, the pose's bytes and the noise generator's
    state, so a changed scene, pose, seed or setting is a miss, never a stale frame."""
    key = hashlib.sha256(
        pickle.dumps((sensor, world, INTRINSICS, rng.bit_generator.state), protocol=5)
        + pose.tobytes()
    ).hexdigest()[:32]
    path = cache / f"{key}.npy"
    try:
        return np.load(path)
    except (OSError, ValueError):
        pass
    depth = sensor.render_depth(world, INTRINSICS, pose, rng)
    cache.mkdir(parents=True, exist_ok=True)
    # Each process its own temporary file: two sweeps rendering the same frame at once must
    # not rename each other's away.
    tmp = cache / f"{key}.{os.getpid()}.tmp.npy"
    np.save(tmp, depth)
    tmp.replace(path)
    return depth


def count(suite: str, trials: int, frames: int, names: Collection[str] | None = None) -> int:
    subjects = SUBJECTS[suite]()
    if names is not None:
        subjects = [s for s in subjects if s.name in names]
    return len(subjects) * trials * frames
