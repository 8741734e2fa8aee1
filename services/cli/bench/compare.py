"""``lpc bench compare``: the four-line method and the full-cloud benchmark on the same frames.

This is the paper's comparison (reference/paper.tex, Results): shape accuracy, size and
orientation errors, points used and computing time per frame, for the laser-scan prototype and
the full-point-cloud benchmark (Castro et al. 2022). Both methods run here, one after the
other, in this one process, on the same simulated D435 frames: each of the paper's ten
functional objects on a table, aimed at from random poses, with the simulator's noise.

CPU time is ``time.process_time`` around each method's call, the least of ``--repeat`` runs
on the frame (both methods are deterministic per frame): on a shared machine a single run
picks up interrupts and other processes' cache traffic, and the laser method's median frame
sits between its fast frames (spheres, boxes) and its slow ones (cylinders), where that noise
alone moved the ratio by a quarter between runs. The laser method is timed twice: from its
scan lines (what a real laser scanner would deliver), and with the cutting of those lines
from the depth frame included (the emulation the paper also ran).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.reconstruction import SHAPES, Reconstruction
from lpc_core.sim.stereo import StereoSensor
from services.drivers.depth_flags import add_sensor_arguments, sensor_label, stereo_sensor

# The paper's figures (Results), for the printout.
PAPER = {
    "accuracy_pct": {"laser": (96.5, 95.3, 89.0), "cloud": (98.0, 93.0, 100.0)},
    "size_error_mm": {"laser": "8 ± 5", "cloud": "4 ± 3"},
    "angle_error_deg": {"laser": "2 ± 3", "cloud": "2 ± 3"},
    "points": {"laser": "700 ± 300", "cloud": "5300 ± 2100"},
    "time_ms": {"laser": "138", "cloud": "75"},
}
QUICK_OBJECTS = ("sphere_small", "cylinder_lying", "cuboid_upright")
METHODS = ("laser", "cloud")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--frames",
        type=int,
        default=None,
        metavar="N",
        help="frames per object (default 20, or 2 with --quick)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the poses and the noise")
    parser.add_argument(
        "--repeat",
        type=int,
        default=3,
        metavar="N",
        help="run each method N times per frame and keep the least CPU time (default 3)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"one object per shape ({', '.join(QUICK_OBJECTS)}) and 2 frames each",
    )
    add_sensor_arguments(parser)


@dataclass(frozen=True)
class View:
    """One simulated frame and what a perfect reconstruction would report."""

    seq: int
    name: str
    depth: np.ndarray
    shape: str
    grasp_width_m: float
    wrist_angle_rad: float | None


def simulated_views(
    names: tuple[str, ...] | None,
    frames: int,
    seed: int,
    sensor: StereoSensor | None = None,
) -> Iterator[View]:
    """``frames`` views of each functional object on a table, through the noise model or,
    given ``sensor``, the simulated stereo camera.

    The surface the optical axis pierces is 160-220 mm ahead (inside the laser method's
    capture volume, 150-250 mm), seen from up to 30 degrees either side, 10-45 degrees above
    the table, rolled by up to 30 degrees, aimed within 5 mm of the object's centre.
    """
    from lpc_core.sim import scene  # the simulator is only needed here

    intrinsics = Intrinsics()
    catalogue = scene.functional_objects()
    chosen = catalogue if names is None else {n: catalogue[n] for n in names}
    seq = 0
    for index, (name, obj) in enumerate(chosen.items()):
        world = scene.Scene(objects=(obj,), support=scene.table(0.0))
        for k in range(frames):
            rng = np.random.default_rng([seed, index, k])
            pose = scene.aim_pose(
                obj,
                distance_m=rng.uniform(0.16, 0.22),
                azimuth_rad=rng.uniform(-1, 1) * math.radians(30),
                elevation_rad=math.radians(rng.uniform(10, 45)),
                roll_rad=rng.uniform(-1, 1) * math.radians(30),
                aim_point=obj.center + rng.uniform(-0.005, 0.005, 3),
            )
            truth = obj.truth(pose)
            if sensor is None:
                depth = scene.render_depth(world, intrinsics, pose, rng)
            else:
                depth = sensor.render_depth(world, intrinsics, pose, rng)
            yield View(seq, name, depth, truth.shape, truth.grasp_width_m, truth.wrist_angle_rad)
            seq += 1


@dataclass
class Tally:
    """What one method did on the frames of one true shape."""

    frames: int = 0
    correct: int = 0
    width_errors_mm: list[float] = field(default_factory=list)
    angle_errors_deg: list[float] = field(default_factory=list)
    points: list[int] = field(default_factory=list)
    cpu_ms: list[float] = field(default_factory=list)

    def add(self, view: View, result: Reconstruction, cpu_s: float) -> None:
        self.frames += 1
        self.points.append(result.points)
        self.cpu_ms.append(1000.0 * cpu_s)
        if result.shape != view.shape:
            return
        self.correct += 1
        if result.grasp_width_m is not None:
            self.width_errors_mm.append(1000.0 * abs(result.grasp_width_m - view.grasp_width_m))
        if view.wrist_angle_rad is not None and result.wrist_angle_rad is not None:
            diff = (result.wrist_angle_rad - view.wrist_angle_rad + math.pi / 2) % math.pi
            self.angle_errors_deg.append(math.degrees(abs(diff - math.pi / 2)))

    def merge(self, other: Tally) -> None:
        self.frames += other.frames
        self.correct += other.correct
        self.width_errors_mm += other.width_errors_mm
        self.angle_errors_deg += other.angle_errors_deg
        self.points += other.points
        self.cpu_ms += other.cpu_ms


def _mean_sd(values: list[float] | list[int], digits: int = 1) -> str:
    if not values:
        return "-"
    return f"{np.mean(values):.{digits}f} ± {np.std(values):.{digits}f}"


def _p50(values: list[float]) -> float:
    return float(np.median(values)) if values else math.nan


def _laser(
    view: View, intrinsics: Intrinsics, repeat: int = 1
) -> tuple[Reconstruction, float, float]:
    """The four-line method: (result, CPU seconds from the lines, CPU seconds with the cut),
    the least of ``repeat`` runs."""
    from lpc_core.perception.laser import reconstruct_laser
    from lpc_core.perception.scans import ScanParams, cut_scan_lines

    best_lines = best_total = math.inf
    for _ in range(repeat):
        start = time.process_time()
        lines = cut_scan_lines(view.depth, intrinsics, ScanParams())
        cut = time.process_time()
        result = reconstruct_laser(lines, seed=view.seq)
        end = time.process_time()
        best_lines, best_total = min(best_lines, end - cut), min(best_total, end - start)
    return result, best_lines, best_total


def _cloud(view: View, intrinsics: Intrinsics, repeat: int = 1) -> tuple[Reconstruction, float]:
    """The full-cloud method: (result, CPU seconds), the least of ``repeat`` runs."""
    from lpc_core.perception.cloud import reconstruct_cloud  # scipy loads only when the bench runs

    best = math.inf
    for _ in range(repeat):
        start = time.process_time()
        result = reconstruct_cloud(view.depth, intrinsics, seed=view.seq)
        best = min(best, time.process_time() - start)
    return result, best


def run(args: argparse.Namespace) -> int:
    if args.frames is not None and args.frames < 1:
        print("lpc bench compare: --frames must be at least 1", file=sys.stderr)
        return 2
    if args.repeat < 1:
        print("lpc bench compare: --repeat must be at least 1", file=sys.stderr)
        return 2
    try:
        sensor = stereo_sensor(args)
    except ValueError as exc:
        print(f"lpc bench compare: {exc}", file=sys.stderr)
        return 2
    frames = args.frames if args.frames is not None else (2 if args.quick else 20)
    names = QUICK_OBJECTS if args.quick else None
    intrinsics = Intrinsics()
    tallies = {m: {s: Tally() for s in SHAPES} for m in METHODS}
    cut_ms: list[float] = []
    cloud_counts: dict[str, list[float]] = {"raw_points": [], "segment_points": []}
    warm = False
    started = time.perf_counter()
    last_name = None
    for view in simulated_views(names, frames, args.seed, sensor):
        if not warm:  # first calls fill caches and import modules: keep them out of the times
            _laser(view, intrinsics)
            _cloud(view, intrinsics)
            warm = True
        laser, laser_s, laser_cut_s = _laser(view, intrinsics, args.repeat)
        cloud, cloud_s = _cloud(view, intrinsics, args.repeat)
        tallies["laser"][view.shape].add(view, laser, laser_s)
        tallies["cloud"][view.shape].add(view, cloud, cloud_s)
        cut_ms.append(1000.0 * laser_cut_s)
        for key, values in cloud_counts.items():
            values.append(cloud.extra.get(key, 0.0))
        if view.name != last_name:
            last_name = view.name
            print(
                f"compare: {view.name} (frame {view.seq + 1}, "
                f"{time.perf_counter() - started:.1f} s)",
                file=sys.stderr,
            )
    label = sensor_label(args)
    print(_report(tallies, cut_ms, cloud_counts, frames, args.seed, args.repeat, label))
    return 0


def _report(
    tallies: dict[str, dict[str, Tally]],
    cut_ms: list[float],
    cloud_counts: dict[str, list[float]],
    frames: int,
    seed: int,
    repeat: int = 1,
    sensor: str = "noise model",
) -> str:
    total = sum(t.frames for t in tallies["laser"].values())
    out = [
        f"lpc bench compare: {total} frames ({frames} per object), seed {seed}, "
        f"simulated D435 424x240 ({sensor}), CPU time on one process (least of {repeat} "
        "per frame)",
        "",
        f"{'shape':<9} {'method':<6} {'frames':>6} {'accuracy':>9} {'paper':>6} "
        f"{'width err mm':>14} {'angle err deg':>14} {'points/frame':>15} {'CPU ms p50':>10}",
    ]
    for i, shape in enumerate((*SHAPES, "all")):
        for method in METHODS:
            if shape == "all":
                tally = Tally()
                for t in tallies[method].values():
                    tally.merge(t)
                paper = ""
            else:
                tally = tallies[method][shape]
                paper = f"{PAPER['accuracy_pct'][method][i]:.1f}%"
            if not tally.frames:
                continue
            accuracy = 100.0 * tally.correct / tally.frames
            out.append(
                f"{shape:<9} {method:<6} {tally.frames:>6} {accuracy:>8.1f}% {paper:>6} "
                f"{_mean_sd(tally.width_errors_mm):>14} {_mean_sd(tally.angle_errors_deg):>14} "
                f"{_mean_sd(tally.points, 0):>15} {_p50(tally.cpu_ms):>10.1f}"
            )
    laser, cloud = Tally(), Tally()
    for t in tallies["laser"].values():
        laser.merge(t)
    for t in tallies["cloud"].values():
        cloud.merge(t)
    points_ratio = np.mean(laser.points) / max(np.mean(cloud.points), 1e-9)
    cpu_ratio = _p50(laser.cpu_ms) / _p50(cloud.cpu_ms)
    cut_ratio = _p50(cut_ms) / _p50(cloud.cpu_ms)
    out += [
        "",
        "laser/cloud ratios (all frames):",
        f"  points per frame   {points_ratio:6.3f}   (paper 700/5300 = {700 / 5300:.3f})",
        f"  CPU time p50       {cpu_ratio:6.3f}   laser from its scan lines: "
        f"{_p50(laser.cpu_ms):.1f} ms vs cloud {_p50(cloud.cpu_ms):.1f} ms "
        f"(cloud/laser {1 / cpu_ratio:.1f}x)",
        f"  CPU time p50       {cut_ratio:6.3f}   laser with the line cut from the frame: "
        f"{_p50(cut_ms):.1f} ms (cloud/laser {1 / cut_ratio:.1f}x)",
        f"  CPU time mean      {np.mean(laser.cpu_ms) / np.mean(cloud.cpu_ms):6.3f}   laser "
        f"{np.mean(laser.cpu_ms):.1f} ms vs cloud {np.mean(cloud.cpu_ms):.1f} ms "
        f"(cloud/laser {np.mean(cloud.cpu_ms) / np.mean(laser.cpu_ms):.1f}x)",
        f"  width error mean   {np.mean(laser.width_errors_mm or [math.nan]):.1f} vs "
        f"{np.mean(cloud.width_errors_mm or [math.nan]):.1f} mm",
        "cloud points per frame: cropped "
        f"{_mean_sd(cloud_counts['raw_points'], 0)}, after the 2 mm voxel grid "
        f"{_mean_sd(cloud.points, 0)} (the 'points/frame' above), in the chosen segment "
        f"{_mean_sd(cloud_counts['segment_points'], 0)}",
        "",
        "paper (laser vs benchmark): points "
        f"{PAPER['points']['laser']} vs {PAPER['points']['cloud']}; "
        f"time {PAPER['time_ms']['laser']} vs {PAPER['time_ms']['cloud']} ms; size error "
        f"{PAPER['size_error_mm']['laser']} vs {PAPER['size_error_mm']['cloud']} mm; "
        f"angle error {PAPER['angle_error_deg']['laser']} deg for both",
        "width and angle errors are over the frames whose shape was right; "
        "angles only where the truth has one (not spheres)",
    ]
    return "\n".join(out)
