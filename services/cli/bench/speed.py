"""``lpc bench speed``: where the four-line method spends its time, per stage, on one core.

Frames are rendered first (the functional suite of ``lpc bench accuracy``), then timed:

- ``scan cut``: crop to the capture volume and cut the four scan lines (``cut_scan_lines``);
- ``line models``: segment, fit line, circle and ellipse, choose, per frame (all four lines);
- ``fit line`` / ``fit circle`` / ``fit ellipse``: each fit alone on the frame's four segments
  (the method itself skips a richer fit once a simpler model covers a line);
- ``decision``: the 3-D solids, the shape and its grasp (``decide``);
- ``total``: scan lines to reconstruction (``reconstruct_laser``), and with the cut.

Then a cProfile of ``reconstruct_laser`` over every frame. Figures are this process's CPU time
(``process_time``), so other load on the machine inflates them less than wall time would;
BLAS threads are reported because multi-threaded BLAS adds CPU time to the small solves here
(run with ``OPENBLAS_NUM_THREADS=1`` for one-core figures).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import sys
import time

import numpy as np

from lpc_core.perception import fit
from lpc_core.perception.laser import (
    LaserParams,
    LineModels,
    analyse_lines,
    decide,
    reconstruct_laser,
)
from lpc_core.perception.scans import cut_scan_lines
from services.cli import _laser_views as lv

TARGET = "target: total from scan lines p50 <= 5 ms, p99 <= 11 ms (the paper's C++: 138 ms)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=int, default=3, help="trials per object (default 3)")
    parser.add_argument("--frames", type=int, default=10, help="frames per trial (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of poses and noise")
    parser.add_argument("--repeat", type=int, default=3, help="timed passes over the frames")
    parser.add_argument("--top", type=int, default=15, help="profile lines to print")
    parser.add_argument("--quick", action="store_true", help="1 trial x 5 frames, 1 pass")
    parser.add_argument("--method", choices=("laser", "paper"), default="laser")


def _ms(samples: list[float]) -> str:
    a = np.asarray(samples) * 1000.0
    return f"{np.percentile(a, 50):8.3f} {np.percentile(a, 99):8.3f} {a.mean():8.3f}"


def _time_fits(models: list[LineModels], params: LaserParams, seq: int) -> dict[str, float]:
    """Seconds each fit takes alone on the frame's segments (all three, as the paper fits)."""
    spent = {"line": 0.0, "circle": 0.0, "ellipse": 0.0}
    thr = params.threshold_m
    for m in models:
        if len(m.sz) < params.min_points_per_line:
            continue
        start = time.process_time()
        fit.fit_line(m.sz, thr, seed=seq)
        middle = time.process_time()
        fit.fit_circle(m.sz, thr, radius_limits=params.radius_limits_m, seed=seq)
        end = time.process_time()
        fit.fit_ellipse(m.sz, thr, axis_limits=fit.AXIS_LIMITS_M, seed=seq)
        spent["line"] += middle - start
        spent["circle"] += end - middle
        spent["ellipse"] += time.process_time() - end
    return spent


def run(args: argparse.Namespace) -> int:
    trials, frames, repeat = (1, 5, 1) if args.quick else (args.trials, args.frames, args.repeat)
    if trials < 1 or frames < 1 or repeat < 1:
        print("lpc bench speed: error: --trials, --frames, --repeat must be >= 1", file=sys.stderr)
        return 2
    params = LaserParams(variant="lpc" if args.method == "laser" else "paper")
    total = lv.count("functional", trials, frames)
    print(f"rendering {total} frames...", file=sys.stderr, flush=True)
    depths = [(v.seq, v.depth) for v in lv.views("functional", trials, frames, args.seed)]
    blas = os.environ.get("OPENBLAS_NUM_THREADS") or os.environ.get("OMP_NUM_THREADS") or "unset"
    print(
        f"lpc bench speed: method {args.method}, {len(depths)} frames x {repeat} passes, "
        f"BLAS threads {blas}; {TARGET}"
    )
    for seq, depth in depths[:3]:  # warm caches (scan tables, grids) before timing
        reconstruct_laser(cut_scan_lines(depth, lv.INTRINSICS), params, seed=seq)
    stages: dict[str, list[float]] = {
        k: []
        for k in (
            "scan cut", "line models", "  fit line", "  fit circle", "  fit ellipse",
            "decision", "total from scan lines", "total with the cut",
        )
    }  # fmt: skip
    clock = time.process_time
    points = []
    for _ in range(repeat):
        for seq, depth in depths:
            t0 = clock()
            lines = cut_scan_lines(depth, lv.INTRINSICS)
            t1 = clock()
            models = analyse_lines(lines, params, seq)
            t2 = clock()
            decide(models, params, lines)
            t3 = clock()
            reconstruct_laser(lines, params, seed=seq)
            t4 = clock()
            stages["scan cut"].append(t1 - t0)
            stages["line models"].append(t2 - t1)
            stages["decision"].append(t3 - t2)
            stages["total from scan lines"].append(t4 - t3)
            stages["total with the cut"].append(t1 - t0 + t4 - t3)
            points.append(lines.total_points)
            for name, value in _time_fits(models, params, seq).items():
                stages[f"  fit {name}"].append(value)
    print(f"{'stage (ms per frame)':24} {'p50':>8} {'p99':>8} {'mean':>8}")
    for name, samples in stages.items():
        print(f"{name:24} {_ms(samples)}")
    print(f"points per frame: {np.mean(points):.0f} ± {np.std(points):.0f}")

    profile = cProfile.Profile()
    profile.enable()
    for seq, depth in depths:
        reconstruct_laser(cut_scan_lines(depth, lv.INTRINSICS), params, seed=seq)
    profile.disable()
    out = io.StringIO()
    stats = pstats.Stats(profile, stream=out).strip_dirs()
    stats.sort_stats("tottime").print_stats(args.top)
    stats.sort_stats("cumulative").print_stats(args.top)
    text = [ln for ln in out.getvalue().splitlines() if ln.strip()]
    print(f"\ncProfile of reconstruct_laser over {len(depths)} frames (tottime, then cumulative):")
    print("\n".join(text))
    return 0
