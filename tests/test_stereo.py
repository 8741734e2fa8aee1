"""The simulated stereo camera (``lpc_core.sim.stereo``): its depth shows the artifacts of
matching two IR images, measured on simple scenes seen square-on, across matcher settings.

Scenes and measures are ``lpc bench stereo``'s (``services/cli/bench/stereo.py``): a wall at
200 mm, a wall turned 40 and 80 degrees, a 60 mm plate 200 mm ahead of a wall at 300 mm, a
60 mm ball before a wall at 350 mm.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

pytest.importorskip("cv2", reason="the stereo camera needs OpenCV: pip install 'lpc[stereo]'")

from lpc_core.sim import scene
from lpc_core.sim.simcam import SimCamera
from lpc_core.sim.stereo import StereoSensor, disparity_to_depth, match, render_ir
from lpc_core.sim.stereo_settings import Matcher, StereoRig
from services.cli.bench import stereo as bench

K = bench.INTRINSICS
SCENES = {
    "plane": bench.wall(0.2),
    "slant": bench.wall(0.22, 40.0),
    "grazing": bench.wall(0.25, 80.0),
    "plate": bench.plate_before_wall(0.2, 0.3),
    "ball": bench.sphere_before_wall(0.23, 0.35),
}


@cache
def _truth(name: str) -> np.ndarray:
    return bench.exact(SCENES[name])


@cache
def _frame(name: str, seed: int = 0, **settings: object) -> tuple[np.ndarray, np.ndarray]:
    """(disparity in 1/16 px, depth in mm) of a scene; ``settings`` go to Matcher, or to
    StereoRig when prefixed ``rig_``."""
    rig = {k[4:]: v for k, v in settings.items() if k.startswith("rig_")}
    matcher = {k: v for k, v in settings.items() if not k.startswith("rig_")}
    sensor = StereoSensor(rig=StereoRig(**rig), matcher=Matcher(**matcher))  # type: ignore[arg-type]
    pair = sensor.render_pair(SCENES[name], K, bench.POSE, np.random.default_rng([seed, 15]))
    disparity = match(pair, sensor.matcher)
    return disparity, sensor.depth_from_pair(pair, K)


def _valid(depth: np.ndarray) -> float:
    return float(np.mean(depth[:, bench._band_cols(K)] > 0))


# --------------------------------------------------------------------------- settings and units


def test_matcher_rejects_bad_settings_by_name() -> None:
    with pytest.raises(ValueError, match="block_size"):
        Matcher(block_size=6)
    with pytest.raises(ValueError, match="block_size for bm"):
        Matcher(kind="bm", block_size=3)
    with pytest.raises(ValueError, match="num_disparities"):
        Matcher(num_disparities=100)
    with pytest.raises(ValueError, match="uniqueness"):
        Matcher(uniqueness=120)
    with pytest.raises(ValueError, match="kind"):
        Matcher(kind="census")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="projector_x_m"):
        StereoRig(projector_x_m=0.08)
    with pytest.raises(ValueError, match="dot_density"):
        StereoRig(dot_density=0.0)


def test_disparity_to_depth_converts_through_the_intrinsics_and_drops_the_left_band() -> None:
    disparity = np.zeros((K.height, K.width), dtype=np.int16)
    disparity[:, :] = 16 * 50  # 50 px: z = 213 * 0.05 / 50 = 213 mm
    disparity[10, 300] = 16 * 50 + 8  # 50.5 px: 210.9 mm
    disparity[20, 300] = -16  # no match
    depth = disparity_to_depth(disparity, K, 0.05)
    assert depth.dtype == np.uint16
    assert depth[5, 300] == 213 and depth[10, 300] == 211 and depth[20, 300] == 0
    # A match 50 px to the left of column 49 falls outside the right imager.
    assert np.all(depth[:, :50] == 0) and np.all(depth[:, 50:60] == 213)
    assert np.all(disparity_to_depth(disparity, K, 0.05, left_band=False)[:, :50] == 213)


def test_render_ir_is_a_pure_function_of_the_rng_and_the_pattern_is_fixed() -> None:
    world = SCENES["plate"]
    a = render_ir(world, K, bench.POSE, np.random.default_rng(1))
    b = render_ir(world, K, bench.POSE, np.random.default_rng(1))
    c = render_ir(world, K, bench.POSE, np.random.default_rng(2))
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    assert not np.array_equal(a.left, c.left)
    # Only the sensor noise differs: the dots stay where they were (a few DN apart).
    diff = np.abs(a.left.astype(int) - c.left.astype(int))
    assert np.median(diff) <= 2 and np.percentile(diff, 99) <= 15
    other = render_ir(world, K, bench.POSE, np.random.default_rng(1), StereoRig(pattern_seed=9))
    assert np.percentile(np.abs(a.left.astype(int) - other.left.astype(int)), 99) > 30


# --------------------------------------------------------------------------- the artifacts


@pytest.mark.parametrize("kind", ["sgbm", "bm"])
@pytest.mark.parametrize("block", [5, 7, 9])
def test_fronto_parallel_plane_is_matched_within_a_millimetre(kind: str, block: int) -> None:
    disparity, depth = _frame("plane", kind=kind, block_size=block)
    truth = _truth("plane")
    cols = bench._band_cols(K)
    got = depth[:, cols].astype(float)
    ok = got > 0
    error_mm = got[ok] - 1000 * truth[:, cols][ok]
    figures = bench.plane_disparity(disparity, truth)
    # BM drops the windows whose best match is not unique; SGBM's smoothness fills them.
    assert figures["valid"] >= (0.99 if kind == "sgbm" else 0.85)
    assert np.mean(np.abs(error_mm)) <= 1.0
    # Sub-pixel noise about the fitted plane, beside the datasheet's 0.08-0.1 px: smaller for
    # larger windows, BM noisier than SGBM.
    assert 0.02 <= figures["rms"] <= (0.08 if kind == "sgbm" else 0.15)


def test_subpixel_noise_falls_with_block_size() -> None:
    rms = {
        (kind, block): bench.plane_disparity(
            _frame("plane", kind=kind, block_size=block)[0], _truth("plane")
        )["rms"]
        for kind in ("sgbm", "bm")
        for block in (5, 9)
    }
    assert rms[("sgbm", 9)] < rms[("sgbm", 5)]
    assert rms[("bm", 9)] < rms[("bm", 5)]
    assert rms[("bm", 5)] > rms[("sgbm", 5)]


@pytest.mark.parametrize("kind", ["sgbm", "bm"])
def test_plate_edge_fattens_by_up_to_half_a_block(kind: str) -> None:
    means = {}
    for block in (5, 7, 9):
        shifts = np.concatenate(
            [
                bench.edge_figures(
                    _frame("plate", seed, kind=kind, block_size=block)[1], _truth("plate"), 0.25
                ).fattening_px
                for seed in (0, 1)
            ]
        )
        # The plate's depth runs past its right edge onto the wall behind it: by about a
        # pixel typically, never by much more than half the matching window.
        assert 0 <= np.median(shifts) <= block // 2
        assert np.percentile(shifts, 90) <= block // 2 + 2
        assert np.mean(shifts > 0) >= 0.3
        means[block] = float(np.mean(shifts))
    assert means[9] > means[5]


@pytest.mark.parametrize("kind", ["sgbm", "bm"])
def test_occlusion_shadow_left_of_a_ball_is_holes(kind: str) -> None:
    _, depth = _frame("ball", kind=kind, block_size=7)
    truth = _truth("ball")
    figures = bench.edge_figures(depth, truth, 0.3)
    # The wall the right imager cannot see (about 20 px left of the ball) has no depth...
    assert figures.left_band_holes >= 0.6
    # ...while as wide a band of the same wall right of the ball mostly has.
    fg = truth < 0.3
    rows = np.flatnonzero(fg.sum(axis=1) >= 5)[3:-3]
    ends = [int(np.flatnonzero(fg[r]).max()) for r in rows]
    right = np.concatenate(
        [depth[r, end + 4 : end + 24] for r, end in zip(rows, ends, strict=True)]
    )
    assert np.mean(right > 0) >= 0.7


def test_projector_shadow_has_no_dots() -> None:
    # The projector, 25 mm right of the left imager, casts the plate's shadow on the wall:
    # seen from the left imager, a band about 9 px wide left of the plate that only the dim
    # room light reaches, while the wall further left has dots.
    pair = render_ir(SCENES["plate"], K, bench.POSE, np.random.default_rng(3))
    truth = _truth("plate")
    rows = np.flatnonzero((truth < 0.25).sum(axis=1) >= 5)[3:-3]
    left = int(np.flatnonzero(truth[rows[0]] < 0.25).min())
    image = pair.left[rows].astype(float)
    shadow = image[:, left - 7 : left - 2]
    lit = image[:, left - 40 : left - 25]

    def contrast(band: np.ndarray) -> float:  # dot peaks above the background
        return float(np.percentile(band, 99) - np.median(band))

    assert contrast(shadow) < 0.3 * contrast(lit)
    # Without room light the shadow is black but for the sensor noise.
    dark = render_ir(SCENES["plate"], K, bench.POSE, np.random.default_rng(3), StereoRig(ambient=0))
    assert np.median(dark.left[rows][:, left - 7 : left - 2]) <= 2


def test_sgbm_disparity_steps_between_whole_pixels_on_a_slanted_wall() -> None:
    # The true disparity sweeps evenly through every sub-pixel value across the slanted
    # wall; SGBM's interpolation sticks to whole pixels (pixel locking), a staircase in depth.
    share = bench.staircase_share(_frame("slant", kind="sgbm", block_size=7)[0])
    assert share >= 0.35  # 0.25 if the sub-pixel part were uniform


@pytest.mark.parametrize("kind", ["sgbm", "bm"])
def test_a_wall_seen_nearly_edge_on_vanishes(kind: str) -> None:
    assert _valid(_frame("grazing", kind=kind, block_size=7)[1]) <= 0.2
    assert _valid(_frame("plane", kind=kind, block_size=7)[1]) >= 0.85


# --------------------------------------------------------------------------- thresholds, density


def test_bm_texture_threshold_drops_weakly_textured_windows() -> None:
    valid = [
        _valid(_frame("plate", kind="bm", block_size=7, texture_threshold=t)[1])
        for t in (0, 1000, 2000)
    ]
    # The far wall's dim dots go first, then the plate's.
    assert valid[0] - 0.05 > valid[1] > valid[2] + 0.3


@pytest.mark.parametrize(("kind", "drop"), [("sgbm", 0.005), ("bm", 0.3)])
def test_uniqueness_ratio_drops_ambiguous_matches(kind: str, drop: float) -> None:
    # SGBM's aggregated costs leave few close seconds; BM's raw window costs many.
    loose = _valid(_frame("plate", kind=kind, block_size=7, uniqueness=0)[1])
    strict = _valid(_frame("plate", kind=kind, block_size=7, uniqueness=50)[1])
    assert strict < loose - drop


def test_sparser_dots_leave_more_holes() -> None:
    sparse = _valid(_frame("plane", kind="bm", block_size=7, rig_dot_density=0.02)[1])
    dense = _valid(_frame("plane", kind="bm", block_size=7, rig_dot_density=0.12)[1])
    assert sparse < dense - 0.1


@pytest.mark.parametrize(("kind", "least_valid"), [("sgbm", 0.3), ("bm", 0.1)])
def test_sim_camera_renders_the_same_stereo_frame_for_the_same_seq(
    kind: str, least_valid: float
) -> None:
    # BM also matches the mirrored pair for its left-right check: OpenCV's own check in
    # StereoBM gives a different frame now and then.
    camera = SimCamera(seed=0, sensor=StereoSensor(matcher=Matcher(kind=kind)))
    first, truth = camera.frame(3.0, 17)
    again, _ = camera.frame(3.0, 17)
    assert first.dtype == np.uint16 and first.shape == (K.height, K.width)
    assert np.array_equal(first, again)
    # A ball on a table, the table receding to 2.5 m: the far, dim table has no depth, and
    # BM, whose window assumes a surface square to the view, loses most of the slanted table.
    assert truth is not None and least_valid <= np.mean(first > 0) <= 0.8
    model, _ = SimCamera(seed=0).frame(3.0, 17)
    assert not np.array_equal(first, model)


def test_stereo_depth_tracks_an_object_on_a_table() -> None:
    # A functional object seen as lpc sees it: the depth that is there is right to a few mm.
    obj = scene.functional_objects()["cylinder_upright"]
    world = scene.Scene(objects=(obj,), support=scene.table(0.0))
    pose = scene.aim_pose(obj, 0.2)
    truth = scene.exact_depth(world, K, pose)
    depth = StereoSensor().render_depth(world, K, pose, np.random.default_rng(0))
    near = truth < 0.4  # the object and the table around it
    ok = (depth > 0) & near
    error = depth[ok] - 1000 * truth[ok]
    assert np.sum(ok) >= 0.8 * np.sum(near)
    assert np.median(np.abs(error)) <= 2.0
