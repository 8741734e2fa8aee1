"""``lpc bench stereo``: what the simulated stereo camera's matching does, and what it costs.

On simple scenes seen square-on (camera at the world origin looking along +z), per matcher
and block size:

- ``plane``: a fronto-parallel wall at 200 mm; disparity bias against the truth, and the
  sub-pixel RMS as the D435 datasheet defines it (the residual of a plane fitted to the
  disparity; the datasheet's figure is about 0.08-0.1 px), valid fraction;
- ``slant``: a wall turned 40 degrees: the sub-pixel staircase, as the share of disparities
  within 1/8 px of a whole pixel (0.25 if the sub-pixel part were uniform);
- ``edge``: a 60 mm plate 200 mm ahead of a wall at 300 mm: how far the plate's depth runs
  past its right edge (edge fattening, px, median and 90th percentile over the rows), and the
  share of holes in the band left of it that the right imager cannot see (occlusion and the
  projector's shadow);
- ``grazing``: a wall seen at 80 degrees incidence: its valid fraction;
- cost: per frame, rendering the IR pair and matching it, wall clock and CPU time of the
  process (OpenCV may use more than one thread), p50.

    lpc bench stereo                     # sgbm and bm, blocks 5, 7, 9
    lpc bench stereo --matcher bm --block-size 7 --frames 5
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass

import numpy as np

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.sim import scene
from lpc_core.sim.stereo import StereoSensor, match
from lpc_core.sim.stereo_settings import MATCHERS, Matcher, StereoRig

INTRINSICS = Intrinsics()
POSE = np.eye(4)
STAIR_TOL_PX = 0.125


def wall(z_m: float, tilt_deg: float = 0.0) -> scene.Scene:
    """A wall ``z_m`` ahead on the optical axis, turned ``tilt_deg`` about the image's y."""
    normal = scene.rotation_about((0.0, 1.0, 0.0), math.radians(tilt_deg)) @ (0.0, 0.0, -1.0)
    return scene.Scene(support=scene.Plane(np.array([0.0, 0.0, z_m]), normal))


def plate_before_wall(plate_m: float = 0.2, wall_m: float = 0.3) -> scene.Scene:
    """A 60 x 60 x 20 mm plate whose front face is ``plate_m`` ahead, before a wall."""
    plate = scene.cuboid_object("plate", (0.0, 0.0, plate_m + 0.01), np.eye(3), (0.06, 0.06, 0.02))
    return scene.Scene(objects=(plate,), support=wall(wall_m).support)


def sphere_before_wall(center_m: float = 0.23, wall_m: float = 0.35) -> scene.Scene:
    """A 60 mm ball before a wall."""
    ball = scene.sphere_object("ball", (0.0, 0.0, center_m), 0.03)
    return scene.Scene(objects=(ball,), support=wall(wall_m).support)


def exact(world: scene.Scene) -> np.ndarray:
    return scene.exact_depth(world, INTRINSICS, POSE)


def _band_cols(intrinsics: Intrinsics, margin: int = 8) -> slice:
    """Columns clear of the device's invalid band on the left (fx B / z px) for z >= 0.15 m."""
    return slice(math.ceil(intrinsics.fx * 0.05 / 0.15) + margin, intrinsics.width - margin)


def plane_disparity(disparity16: np.ndarray, truth_m: np.ndarray) -> dict[str, float]:
    """Valid fraction, bias (px) against the truth and sub-pixel RMS (px) about a fitted plane
    of a matched plane, over the columns clear of the left band."""
    cols = _band_cols(INTRINSICS)
    d = disparity16[:, cols].astype(np.float64) / 16.0
    true_d = INTRINSICS.fx * 0.05 / truth_m[:, cols]
    valid = d > 0
    v, u = np.nonzero(valid)
    if v.size < 3:
        return {"valid": float(valid.mean()), "bias": math.nan, "rms": math.nan}
    a = np.column_stack([u, v, np.ones_like(u)]).astype(np.float64)
    coef, *_ = np.linalg.lstsq(a, d[valid], rcond=None)
    residual = d[valid] - a @ coef
    return {
        "valid": float(valid.mean()),
        "bias": float(np.mean(d[valid] - true_d[valid])),
        "rms": float(np.sqrt(np.mean(residual**2))),
    }


def staircase_share(disparity16: np.ndarray) -> float:
    """Share of valid disparities within ``STAIR_TOL_PX`` of a whole pixel."""
    d = disparity16[:, _band_cols(INTRINSICS)]
    d = d[d > 0].astype(np.float64) / 16.0
    if d.size == 0:
        return math.nan
    frac = d - np.rint(d)
    return float(np.mean(np.abs(frac) <= STAIR_TOL_PX))


@dataclass(frozen=True)
class EdgeFigures:
    fattening_px: np.ndarray  # per row: measured right edge minus true right edge
    left_band_holes: float  # share of holes in the band the right imager cannot see


def edge_figures(depth: np.ndarray, truth_m: np.ndarray, split_m: float) -> EdgeFigures:
    """Edge fattening at the near object's right edge and holes in its left occlusion band.

    Foreground is depth below ``split_m``. Rows where the object spans less than 5 px in the
    truth, and the object's top and bottom 3 rows, are left out.
    """
    fg_true = truth_m < split_m
    z = depth.astype(np.float64) * INTRINSICS.depth_scale
    fg = (depth > 0) & (z < split_m)
    rows = np.flatnonzero(fg_true.sum(axis=1) >= 5)[3:-3]
    shifts, holes = [], []
    for r in rows:
        true_cols = np.flatnonzero(fg_true[r])
        got = np.flatnonzero(fg[r])
        if got.size:
            shifts.append(int(got.max()) - int(true_cols.max()))
        # The band hidden from the right imager: d_fg - d_bg pixels left of the object.
        left = int(true_cols.min())
        bg = truth_m[r, max(left - 1, 0)]
        width = INTRINSICS.fx * 0.05 * (1.0 / truth_m[r, left] - 1.0 / bg)
        band = depth[r, max(left - int(width), 0) : left]
        if band.size:
            holes.append(float(np.mean(band == 0)))
    return EdgeFigures(np.asarray(shifts), float(np.mean(holes)) if holes else math.nan)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--matcher", choices=MATCHERS, action="append", help="matcher, repeatable (default both)"
    )
    parser.add_argument(
        "--block-size", type=int, action="append", metavar="N", help="repeatable (default 5 7 9)"
    )
    parser.add_argument("--frames", type=int, default=3, metavar="N", help="frames per scene")
    parser.add_argument("--dot-density", type=float, default=StereoRig().dot_density, metavar="D")


def _row(sensor: StereoSensor, frames: int) -> tuple[str, list[float], list[float], list[float]]:
    scenes = {
        "plane": wall(0.2),
        "slant": wall(0.22, 40.0),
        "edge": plate_before_wall(),
        "grazing": wall(0.25, 80.0),
    }
    truths = {name: exact(world) for name, world in scenes.items()}
    plane, stairs, fat, holes, grazing = [], [], [], [], []
    render_ms, match_ms, cpu_ms = [], [], []
    for k in range(frames):
        for name, world in scenes.items():
            rng = np.random.default_rng([k, 0x57E])
            start, cpu = time.perf_counter(), time.process_time()
            pair = sensor.render_pair(world, INTRINSICS, POSE, rng)
            middle = time.perf_counter()
            disparity = match(pair, sensor.matcher)
            end = time.perf_counter()
            render_ms.append(1000 * (middle - start))
            match_ms.append(1000 * (end - middle))
            cpu_ms.append(1000 * (time.process_time() - cpu))
            depth = sensor.depth_from_pair(pair, INTRINSICS)
            if name == "plane":
                plane.append(plane_disparity(disparity, truths[name]))
            elif name == "slant":
                stairs.append(staircase_share(disparity))
            elif name == "edge":
                figures = edge_figures(depth, truths[name], 0.25)
                fat.extend(figures.fattening_px.tolist())
                holes.append(figures.left_band_holes)
            else:
                grazing.append(float(np.mean(depth[:, _band_cols(INTRINSICS)] > 0)))
    m = sensor.matcher
    text = (
        f"{m.kind:5} {m.block_size:5d} {np.mean([p['valid'] for p in plane]):7.3f} "
        f"{np.mean([p['bias'] for p in plane]):+8.3f} {np.mean([p['rms'] for p in plane]):7.3f} "
        f"{np.mean(stairs):7.2f} {np.median(fat):7.1f} {np.percentile(fat, 90):6.1f} "
        f"{np.mean(holes):7.2f} {np.mean(grazing):8.3f}"
    )
    return text, render_ms, match_ms, cpu_ms


def run(args: argparse.Namespace) -> int:
    if args.frames < 1:
        print("lpc bench stereo: --frames must be at least 1")
        return 2
    matchers = args.matcher or list(MATCHERS)
    blocks = args.block_size or [5, 7, 9]
    print(
        f"lpc bench stereo: {args.frames} frame(s) per scene, dots {args.dot_density:g}/px², "
        "424x240, baseline 50 mm; disparity in px (datasheet sub-pixel RMS about 0.08-0.1)"
    )
    print(
        f"{'':5} {'':>5} {'plane at 200 mm':^24} {'slant':>7} {'plate edge':^22} "
        f"{'grazing':>8}\n"
        f"{'kind':5} {'block':>5} {'valid':>7} {'bias':>8} {'RMS':>7} {'stairs':>7} "
        f"{'fat p50':>7} {'p90':>6} {'holes L':>7} {'valid':>8}"
    )
    costs = []
    for kind in matchers:
        for block in blocks:
            try:
                matcher = Matcher(kind=kind, block_size=block)
            except ValueError as exc:
                print(f"{kind:5} {block:5d} skipped: {exc}")
                continue
            sensor = StereoSensor(rig=StereoRig(dot_density=args.dot_density), matcher=matcher)
            text, render_ms, match_ms, cpu_ms = _row(sensor, args.frames)
            print(text, flush=True)
            costs.append(
                (kind, block, np.median(render_ms), np.median(match_ms), np.median(cpu_ms))
            )
    print("cost per frame, p50 (wall clock: render the IR pair, match it; CPU time of both):")
    for kind, block, render, matched, cpu in costs:
        total = render + matched
        print(
            f"  {kind:5} block {block}: render {render:6.1f} ms, match {matched:6.1f} ms, "
            f"total {total:6.1f} ms = {1000 / total:5.1f} frames/s (the camera asks 90); "
            f"CPU {cpu:6.1f} ms"
        )
    print(
        "stairs: share of disparities within 1/8 px of a whole pixel on the slanted wall "
        "(0.25 when the sub-pixel part is uniform); fat: px the plate's depth runs past its "
        "right edge; holes L: share of holes in the band left of it the right imager cannot see"
    )
    return 0
