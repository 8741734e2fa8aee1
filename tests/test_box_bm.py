"""A block matcher's box: its fattened edges keep the face's own depth (no plateau to measure),
its residuals hardly correlate, and it leaves no depth past an edge facing +x, where no
shadow band lies; such a frame takes ``LaserParams.hole_fattening_px`` off each side."""

from __future__ import annotations

import numpy as np
import pytest

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.laser import LaserParams, reconstruct_laser
from lpc_core.perception.scans import cut_scan_lines

INTRINSICS = Intrinsics()
_FACE_Z_M = 0.2
_WIDTH_M = 0.04
_BACKGROUND_Z_M = 0.4


def _square_on_box(fatten_px: int, background: bool, seed: int) -> np.ndarray:
    """Depth (mm) of a box's face 40 mm wide and 150 mm tall, square-on 200 mm ahead, with
    ``fatten_px`` pixels past each side at the face's depth, as a block matcher's window gives
    them. ``background``: a wall 400 mm ahead behind it, seen by both imagers except in the
    shadow band left of the face (the second imager sits along +x); else no depth anywhere
    but the face, as where the matcher finds no match on the far background. Each pixel's
    depth has its own noise (0.4 mm RMS, seeded by ``seed``), uncorrelated like a block
    matcher's, before the 1 mm quantum."""
    xs, ys = INTRINSICS.pixel_rays()
    x, y = xs * _FACE_Z_M, ys * _FACE_Z_M
    inside = (np.abs(x) <= _WIDTH_M / 2) & (np.abs(y) <= 0.075)
    noisy = _FACE_Z_M * 1000 + np.random.default_rng(seed).normal(0.0, 0.4, inside.shape)
    depth = np.where(inside, np.rint(noisy), 0).astype(np.uint16)
    if background:
        # The wall's points the second imager (50 mm along +x) sees past the face's left side.
        left = xs * _BACKGROUND_Z_M
        hidden = (left >= -_WIDTH_M / 2 * _BACKGROUND_Z_M / _FACE_Z_M) & (
            (left - 0.05) * _FACE_Z_M / _BACKGROUND_Z_M + 0.05 <= _WIDTH_M / 2
        )
        wall = np.where(hidden, 0, round(_BACKGROUND_Z_M * 1000)).astype(np.uint16)
        depth = np.where(inside, depth, wall)
    for row in range(INTRINSICS.height):
        cols = np.flatnonzero(inside[row])
        if len(cols) and fatten_px:
            depth[row, cols[-1] + 1 : cols[-1] + 1 + fatten_px] = depth[row, cols[-1]]
            depth[row, max(cols[0] - fatten_px, 0) : cols[0]] = depth[row, cols[0]]
    return depth


def _width_error_px(result: object) -> float:
    """The width's error in pixels at the face's depth, half a pixel a side per sample."""
    return (result.grasp_width_m - _WIDTH_M) * INTRINSICS.fx / _FACE_Z_M  # type: ignore[attr-defined]


@pytest.mark.parametrize("seed", range(3))
def test_a_box_with_no_depth_past_its_right_edge_loses_a_small_window_a_side(seed: int) -> None:
    """2 px a side at 200 mm is 1.9 mm: the face's own depth past its edges shows no plateau
    and the residuals do not correlate, so no fattening was measured and the sides through
    the farthest samples kept it all (3.75 px too wide). The same face with the wall behind
    seen past its right edge (lpc's noise model: only the shadow band left of it has no
    depth) has no block matcher's hole there and keeps its sides."""
    fattened = cut_scan_lines(_square_on_box(2, background=False, seed=seed), INTRINSICS)
    result = reconstruct_laser(fattened, LaserParams(), seed=seed)
    assert result.shape == "cuboid"
    assert abs(_width_error_px(result)) < 1.0
    assert "residual_correlation" not in result.extra
    assert result.extra.get("hole_past_edge") == 1.0
    assert result.extra["fattening_px"] == 2.0
    seen = cut_scan_lines(_square_on_box(0, background=True, seed=seed), INTRINSICS)
    kept = reconstruct_laser(seen, LaserParams(), seed=seed)
    assert kept.shape == "cuboid"
    assert "hole_past_edge" not in kept.extra
    assert kept.extra["fattening_px"] == 0.0
    assert abs(_width_error_px(kept)) < 1.0


def test_hole_fattening_off_keeps_the_fattened_sides() -> None:
    """``hole_fattening_px`` 0 turns the rule off: the sides keep the 2 px a side."""
    fattened = cut_scan_lines(_square_on_box(2, background=False, seed=0), INTRINSICS)
    blind = reconstruct_laser(fattened, LaserParams(hole_fattening_px=0.0), seed=0)
    assert blind.extra["fattening_px"] == 0.0
    assert _width_error_px(blind) > 3.0


def test_a_far_side_compares_its_occluding_seeds_by_their_edges(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """BM (block 5), the upright box, trial 0 frame 0: a side with the room behind it holds a
    seed of a whole window's share 3.7 mm beyond one of 0.38 of it, 2.65 mm between their
    edges (each seed's own trim taken off), 3.2 mm apart allowed. Compared as they lay, the
    farther was dropped, then the nearer, and the side went through a hole's seed 4 mm
    inside: 7.4 mm narrow. Compared by their edges (``laser._beyond_seed``) both stay and
    the side goes through their median: 1.2 mm narrow, the axis as it was."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception import laser
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(kind="bm", block_size=5))
    (view,) = lv.views("functional", 1, 1, 0, names=["cuboid_upright"], sensor=sensor)
    lines = cut_scan_lines(view.depth, lv.INTRINSICS)
    result = reconstruct_laser(lines, seed=view.seq)
    monkeypatch.setattr(laser, "_beyond_seed", lambda seed, inner, far: seed[0] - inner[0])
    before = reconstruct_laser(lines, seed=view.seq)
    assert result.shape == before.shape == "cuboid"
    assert abs(result.wrist_angle_rad - before.wrist_angle_rad) < 1e-9
    truth = view.truth.grasp_width_m
    assert before.grasp_width_m - truth < -0.007
    assert abs(result.grasp_width_m - truth) < 0.0015
