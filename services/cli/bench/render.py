"""``lpc bench render``: the simulated camera's speed, and the scan-line cut's.

Per frame, wall-clock (``time.perf_counter``) p50 and p95, and the calling thread's CPU time
(``time.thread_time``) p50, which other processes on a shared machine disturb less:

- ``timeline``: ``SimTimeline.at(t)`` of the default session (pose, tremor, ground truth);
- ``render``: ``render_depth`` of a table and 1, 2 or 3 functional objects with the default
  noise (the camera service's live load at 90 Hz needs well under 11 ms);
- ``exact``: the same geometry without noise (float64, as the tests use it);
- ``cut``: ``cut_scan_lines`` (with the capture-volume count) on the rendered frames;
- ``capture``: ``capture_points`` on the same frames;
- with ``--irregular``: ``render_depth`` of each irregular object on a table.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

import numpy as np

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.scans import capture_points, cut_scan_lines
from lpc_core.sim.scene import (
    Scene,
    aim_pose,
    exact_depth,
    functional_objects,
    irregular_objects,
    render_depth,
    table,
)
from lpc_core.sim.timeline import default_timeline


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=300, metavar="N", help="frames per figure")
    parser.add_argument("--seed", type=int, default=0, help="seed of the noise")
    parser.add_argument(
        "--irregular", action="store_true", help="also time each irregular (stress-test) object"
    )


def _time_ms(fn: Callable[[int], object], frames: int) -> np.ndarray:
    """(frames, 2) wall and thread-CPU milliseconds per call, after one warm-up call."""
    fn(0)  # warm the per-intrinsics caches
    out = np.empty((frames, 2))
    for k in range(frames):
        wall, cpu = time.perf_counter(), time.thread_time()
        fn(k)
        out[k] = time.perf_counter() - wall, time.thread_time() - cpu
    return 1000.0 * out


def _render_timed(
    world: Scene, intr: Intrinsics, pose: np.ndarray, rng: np.random.Generator, frames: int
) -> tuple[np.ndarray, list[np.ndarray]]:
    """(ms per frame, the frames) of ``frames`` renders after one warm-up render."""
    rendered: list[np.ndarray] = []
    ms = _time_ms(lambda k: rendered.append(render_depth(world, intr, pose, rng)), frames)
    return ms, rendered[1:]


def _line(name: str, ms: np.ndarray, note: str = "") -> str:
    p50, p95 = np.percentile(ms[:, 0], [50, 95])
    cpu = np.percentile(ms[:, 1], 50)
    return f"{name:<28s} wall p50 {p50:7.3f} p95 {p95:7.3f}   cpu p50 {cpu:7.3f} ms   {note}"


def run(args: argparse.Namespace) -> int:
    if args.frames < 1:
        print("lpc bench render: --frames must be at least 1", file=sys.stderr)
        return 2
    intr = Intrinsics()
    frames = args.frames
    tl = default_timeline()
    ts = np.linspace(0.0, tl.period_s, frames, endpoint=False)
    print(f"lpc bench render: {intr.width}x{intr.height}, {frames} frames per figure")
    print(_line("timeline.at", _time_ms(lambda k: tl.at(float(ts[k])), frames)))

    cat = functional_objects()
    groups = {
        1: ("cylinder_tilt_left",),
        2: ("cylinder_tilt_left", "sphere_small"),
        3: ("cylinder_tilt_left", "sphere_small", "cuboid_lying"),
    }
    depth_frames: list[np.ndarray] = []
    for count, names in groups.items():
        # Side by side, 120 mm apart, the camera aimed at the first: all in view.
        objs = tuple(cat[n].translated((0.12 * i, 0.0, 0.0)) for i, n in enumerate(names))
        world = Scene(objs, table())
        pose = aim_pose(objs[0], 0.19)
        ms, rendered = _render_timed(world, intr, pose, np.random.default_rng(args.seed), frames)
        print(_line(f"render table+{count} object(s)", ms))
        if count == 1:
            depth_frames = rendered
            exact = _time_ms(lambda k, w=world, p=pose: exact_depth(w, intr, p), frames)
            print(_line("exact table+1 (float64)", exact))

    # Scan cut on timeline frames too (objects at every stage of aiming).
    rng = np.random.default_rng(args.seed)
    for k in range(0, frames, 3):
        sample = tl.at(float(ts[k]))
        depth_frames.append(render_depth(sample.scene, intr, sample.camera_pose, rng))
    n = len(depth_frames)
    points = np.mean([cut_scan_lines(d, intr).total_points for d in depth_frames])
    print(
        _line(
            "cut_scan_lines",
            _time_ms(lambda k: cut_scan_lines(depth_frames[k % n], intr), frames),
            f"({points:.0f} points per frame on average)",
        )
    )
    print(
        _line(
            "capture_points", _time_ms(lambda k: capture_points(depth_frames[k % n], intr), frames)
        )
    )

    if args.irregular:
        for name, obj in irregular_objects().items():
            world = Scene((obj,), table())
            pose = aim_pose(obj, 0.19, elevation_rad=np.radians(30.0))
            few = max(frames // 10, 3)
            ms, _ = _render_timed(world, intr, pose, np.random.default_rng(args.seed), few)
            print(_line(f"render {name}", ms, f"({len(obj.parts)} parts)"))
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="lpc bench render", description=__doc__)
    add_arguments(parser)
    sys.exit(run(parser.parse_args()))
