"""``lpc bench fit``: time the scan-line fits of ``lpc_core.perception.fit`` on typical scan lines.

Scan lines are ray-cast as the D435 sees them at 424x240 (one ray per pixel, fx = 213 px):
the near side of a sphere's circle, of a cylinder's elliptic cross-section and of a cuboid's
face, 150-250 mm away, with z^2-proportional depth noise (0.17-0.47 mm), 1 mm depth
quantisation and a few flying pixels. Each fit runs once per scan line; the figures are the
p50 / p99 over all lines of per-thread CPU time (what the fit costs on one core, steady
while other processes share the machine) and of wall time.
"""

from __future__ import annotations

import argparse
import functools
import math
import time

import numpy as np

from lpc_core.perception import fit

FX = 213.0
# fit_all with the paper's limits (the fits' defaults are unbounded, as PCL's).
fit_all = functools.partial(
    fit.fit_all, radius_limits=fit.RADIUS_LIMITS_M, axis_limits=fit.AXIS_LIMITS_M
)


def _ray_cast(rng: np.random.Generator, shape: str) -> np.ndarray:
    """One scan line ``(N, 2)`` (s, z) in metres through a random object of ``shape``."""
    k = np.arange(-120, 121)
    phi = np.arctan(k / FX)
    d = np.column_stack([np.sin(phi), np.cos(phi)])
    zc = rng.uniform(0.17, 0.23)
    if shape == "line":
        # A cuboid face tilted up to 50 degrees through (0, zc); half the time the line also
        # crosses an edge onto the next face, at 90 degrees.
        tilt = rng.uniform(-0.9, 0.9)
        edge = rng.uniform(0.01, 0.03) if rng.random() < 0.5 else math.inf
        tangent = np.array([math.cos(tilt), math.sin(tilt)])
        normal = np.array([math.sin(tilt), -math.cos(tilt)])
        origin = np.array([0.0, zc])
        t = (normal @ origin) / (d @ normal)
        along = (t[:, None] * d - origin) @ tangent
        if math.isfinite(edge):
            corner = origin + edge * tangent
            t2 = (tangent @ corner) / (d @ tangent)  # the next face, normal = tangent
            beyond = along > edge
            t = np.where(beyond & (t2 > 0), np.minimum(t, t2), t)
        hit = (np.abs(d @ normal) > math.cos(math.radians(75))) & (np.abs(along) < 0.05)
    else:
        if shape == "circle":
            a = b = rng.uniform(0.01, 0.04)
            theta = 0.0
        else:
            b = rng.uniform(0.01, 0.035)
            a = b / rng.uniform(0.35, 0.9)
            theta = rng.uniform(-math.pi / 2, math.pi / 2)
        zc += b
        c, s = math.cos(theta), math.sin(theta)
        o = np.array([-zc * s, -zc * c])
        dl = np.column_stack([d[:, 0] * c + d[:, 1] * s, -d[:, 0] * s + d[:, 1] * c])
        qa = (dl[:, 0] / a) ** 2 + (dl[:, 1] / b) ** 2
        qb = 2 * (o[0] * dl[:, 0] / a**2 + o[1] * dl[:, 1] / b**2)
        qc = (o[0] / a) ** 2 + (o[1] / b) ** 2 - 1
        disc = qb * qb - 4 * qa * qc
        hit = disc > 0
        t = (-qb - np.sqrt(np.where(hit, disc, 0.0))) / (2 * qa)
        q = o + t[:, None] * dl
        n = np.column_stack([q[:, 0] / a**2, q[:, 1] / b**2])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        hit &= -(n * dl).sum(axis=1) > math.cos(math.radians(70))
    z = (t * d[:, 1])[hit]
    z = z + rng.normal(0.0, 1.0, z.shape) * z * z * 0.08 / (FX * 0.05)
    # Flying pixels: a few depths halfway to the background.
    flying = rng.random(z.shape) < 0.03
    z = np.where(flying, z + rng.uniform(0.005, 0.05, z.shape), z)
    z = np.round(z * 1000.0) / 1000.0
    keep = (z > 0.15) & (z < 0.25)
    return np.column_stack([z * np.tan(phi[hit]), z])[keep]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--lines", type=int, default=300, help="scan lines per scene kind")
    parser.add_argument("--seed", type=int, default=0, help="seed of the generated scan lines")
    parser.add_argument("--threshold-mm", type=float, default=1.0, help="inlier distance")
    parser.add_argument(
        "--profile", action="store_true", help="also print a cProfile of fit_all on all lines"
    )


def _percentiles(ns: list[int]) -> tuple[float, float]:
    ms = np.array(ns, dtype=float) / 1e6
    return float(np.percentile(ms, 50)), float(np.percentile(ms, 99))


def run(args: argparse.Namespace) -> int:
    rng = np.random.default_rng(args.seed)
    threshold = args.threshold_mm / 1000.0
    scenes = {kind: [_ray_cast(rng, kind) for _ in range(args.lines)]
              for kind in ("circle", "ellipse", "line")}  # fmt: skip
    # The paper's radius and axis limits, as the reconstructor fits scan lines.
    r_lim, a_lim = fit.RADIUS_LIMITS_M, fit.AXIS_LIMITS_M
    fits = {
        "line": lambda p, i: fit.fit_line(p, threshold, seed=i),
        "circle": lambda p, i: fit.fit_circle(p, threshold, radius_limits=r_lim, seed=i),
        "ellipse": lambda p, i: fit.fit_ellipse(p, threshold, axis_limits=a_lim, seed=i),
        "ellipse (direct only)": lambda p, i: fit.fit_ellipse(
            p, threshold, axis_limits=a_lim, seed=i, geometric=False
        ),
        "fit_all": lambda p, i: fit_all(p, threshold, seed=i),
    }
    print(f"lpc bench fit: {args.lines} scan lines per scene, threshold {args.threshold_mm} mm, "
          f"seed {args.seed}")  # fmt: skip
    print(f"{'scene':8s} {'points':>6s}  {'fit':22s} {'cpu p50':>8s} {'cpu p99':>8s} "
          f"{'wall p50':>8s} {'wall p99':>8s} {'trials':>6s} {'inliers':>7s}  (ms)")  # fmt: skip
    for kind, lines in scenes.items():
        n_mean = np.mean([len(p) for p in lines])
        for name, call in fits.items():
            for i, p in enumerate(lines[:10]):  # warm-up
                call(p, i)
            cpu, wall, trials, frac = [], [], [], []
            for i, p in enumerate(lines):
                w0, c0 = time.perf_counter_ns(), time.thread_time_ns()
                found = call(p, i)
                c1, w1 = time.thread_time_ns(), time.perf_counter_ns()
                cpu.append(c1 - c0)
                wall.append(w1 - w0)
                for f in found if isinstance(found, tuple) else (found,):
                    trials.append(f.trials)
                    frac.append(f.inlier_fraction)
            (c50, c99), (w50, w99) = _percentiles(cpu), _percentiles(wall)
            print(f"{kind:8s} {n_mean:6.0f}  {name:22s} {c50:8.3f} {c99:8.3f} {w50:8.3f} "
                  f"{w99:8.3f} {np.mean(trials):6.0f} {np.mean(frac):7.3f}")  # fmt: skip
    # A frame: four scan lines of one scene, all three models on each (the reconstructor's
    # fitting load per frame).
    for kind, lines in scenes.items():
        cpu, wall = [], []
        for f0 in range(0, len(lines) - 3, 4):
            w0, c0 = time.perf_counter_ns(), time.thread_time_ns()
            for i in range(f0, f0 + 4):
                fit_all(lines[i], threshold, seed=i)
            c1, w1 = time.thread_time_ns(), time.perf_counter_ns()
            cpu.append(c1 - c0)
            wall.append(w1 - w0)
        (c50, c99), (w50, w99) = _percentiles(cpu), _percentiles(wall)
        print(f"{kind:8s} {'4 lines':>6s}  {'frame: 4 x fit_all':22s} {c50:8.3f} {c99:8.3f} "
              f"{w50:8.3f} {w99:8.3f}")  # fmt: skip
    if args.profile:
        import cProfile
        import pstats

        profile = cProfile.Profile()
        profile.enable()
        for lines in scenes.values():
            for i, p in enumerate(lines):
                fit_all(p, threshold, seed=i)
        profile.disable()
        pstats.Stats(profile).sort_stats("tottime").print_stats(20)
    return 0
