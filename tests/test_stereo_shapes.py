"""The four-line method's shape on real frames of the simulated stereo camera (left and right
infrared images matched by OpenCV), where the matcher's artifacts once cost it shapes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lpc_core.perception.laser import reconstruct_laser
from lpc_core.perception.reconstruction import Reconstruction
from lpc_core.perception.scans import cut_scan_lines
from services.cli._laser_views import View


def _bench_frame(
    name: str,
    trial: int,
    frame: int,
    *,
    suite: str = "functional",
    detail: str | None = None,
    **matcher: object,
) -> tuple[View, Reconstruction]:
    """The stereo frame ``(trial, frame)`` of the bench's 2 x 5 views of ``name`` in ``suite``
    (with ``detail``, the view's: a wrist roll of the rotation suite), its seed the frame's seq
    as the bench's, through a matcher of ``matcher``'s settings, and the four-line method's
    result on it."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(**matcher))  # type: ignore[arg-type]
    views = lv.views(suite, 2, 5, 0, names=[name], sensor=sensor)
    view = next(
        v for v in views if (v.trial, v.frame) == (trial, frame) and detail in (None, v.detail)
    )
    return view, reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)


def test_a_small_ball_under_block_matching_is_a_sphere() -> None:
    """Block matching (block 7) loses the 40 mm ball's rim and flattens its cap: each line was
    a flat run with short straight sides, and all five frames of this approach came out a box
    or a disc (laser._straight_pieces)."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(kind="bm", block_size=7))
    views = list(lv.views("functional", 1, 5, 0, names=["sphere_small"], sensor=sensor))
    assert len(views) == 5
    for view in views:
        result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert result.shape == "sphere", (view.frame, result.shape, result.reason)
        assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.008


def test_a_jar_under_semi_global_matching_keeps_its_circles_past_a_bump() -> None:
    """SGBM (block 5) pulls the 75 mm jar's depth 2 mm toward the camera over four samples
    where the axis pierces it: that bump, outside the circle, broke the circle's run on the
    horizontal line, the line model won it and the jar came out a box."""
    view, result = _bench_frame("cylinder_tilt_left", 1, 2, kind="sgbm", block_size=5)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert result.lines[0].model == "circle"
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.008


def test_a_can_under_semi_global_matching_whose_axis_the_coarse_search_misses() -> None:
    """SGBM (block 9), the 60 mm can, trial 0 frame 4: no line gave its axis, the 96-direction
    search's nearest direction held few points, and the cylinder it gave (139 mm) was rejected;
    the frame came out a box. The four times finer search, among in-limit circles, finds it."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(kind="sgbm", block_size=9))
    views = lv.views("functional", 1, 5, 0, names=["cylinder_upright"], sensor=sensor)
    view = next(v for v in views if v.frame == 4)
    result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
    assert result.shape == "cylinder", (result.shape, result.reason)
    # Its width is still 13 mm wide of the truth: the rims SGBM 9 fattens (see the README).
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.015


def test_a_small_ball_whose_diagonal_line_holes_thin_is_still_a_sphere() -> None:
    """Block matching (block 5), the 40 mm ball 225 mm away, trial 0 frames 2 and 4: the 135
    degree line crosses the ball on 25 pixels, of which the matcher left 11-14, and holes of
    6-9 mm split its segment (frame 2: 9 points left on the object) or its circle's run
    (frame 4: 9 inliers). Both frames had no shape ("too few points on line 3"); the holes
    now join the pierced stretch (laser._hole)."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(kind="bm", block_size=5))
    views = lv.views("functional", 1, 5, 0, names=["sphere_small"], sensor=sensor)
    for view in (v for v in views if v.frame in (2, 4)):
        lines = cut_scan_lines(view.depth, lv.INTRINSICS)
        assert len(lines.points[3]) < 16  # the holes: 30 samples on an exact frame
        result = reconstruct_laser(lines, seed=view.seq)
        assert result.shape == "sphere", (view.frame, result.shape, result.reason)
        assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.003


def test_a_fattened_ball_takes_its_width_from_every_inlier_but_the_plateaus() -> None:
    """SGBM (block 7): the 40 mm ball (trial 1 frame 2) and the 70 mm ball (trial 0 frames 0
    and 2), whose lines end in the matcher's plateaus, came out 31.3, 61.4 and 64.9 mm from
    the camera-facing cap (the cap alone trades its radius against its centre's depth under
    the staircase). The fit on every inlier but the plateaus gives 39.3, 68.9 and 70.7 mm.
    The same views through lpc's noise model show no fattening and keep the camera-facing
    fit."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception.laser import _fattened, analyse_lines, decide
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(kind="sgbm", block_size=7))
    names = ["sphere_small", "sphere_large"]
    picked = {("sphere_small", 1, 2), ("sphere_large", 0, 0), ("sphere_large", 0, 2)}
    views = lv.views("functional", 2, 5, 0, names=names, sensor=sensor)
    checked = 0
    for view in (v for v in views if (v.subject, v.trial, v.frame) in picked):
        lines = analyse_lines(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert _fattened(lines), (view.subject, view.trial, view.frame)
        result = decide(lines)
        assert result.shape == "sphere", (view.subject, result.shape, result.reason)
        error = result.grasp_width_m - view.truth.grasp_width_m
        assert abs(error) < 0.0015, (view.subject, view.trial, view.frame, error)
        checked += 1
    assert checked == 3
    for view in lv.views("functional", 2, 5, 0, names=names):
        lines = analyse_lines(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert not _fattened(lines), (view.subject, view.trial, view.frame)


def test_a_rounded_soap_bar_takes_its_axis_from_the_seeds_outline() -> None:
    """SGBM (block 9), the soap bar (a 90 x 60 x 30 mm superellipsoid) from above, trial 0
    frame 1: its lines leave the plane along a rounded outline, no rectangle holds the seeds
    on its sides (one lies 14 mm inside the best), and the direction with most seeds on
    sides was 51 deg off; the minimum-area rectangle around the seeds follows the outline
    (laser._unless_rounded)."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception.reconstruction import wrap_half_turn
    from lpc_core.sim.stereo import Matcher, StereoSensor
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(kind="sgbm", block_size=9))
    views = lv.views("irregular", 1, 2, 0, names=["soap_bar"], sensor=sensor)
    view = next(v for v in views if v.frame == 1)
    result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
    assert result.shape == "cuboid", (result.shape, result.reason)
    assert view.truth.wrist_angle_rad is not None and result.wrist_angle_rad is not None
    error = abs(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
    assert error < 0.1, error  # radians: 51 deg before
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.010  # 74 mm before


def test_an_upright_box_seen_square_on_trims_the_fattening_its_lines_do_not_show() -> None:
    """SGBM (block 7), the upright box, trial 0: seen square-on, the fattened pixels copy
    each row's edge depth and lie on the face's own plane, so no face run shows the
    fattening (laser._fattening) on four frames of five, and the box came out 7.6-10.7 mm
    too wide (7.1 mm on average). The lines' residuals, correlated between neighbours as
    SGBM's are (0.35-0.38), trim its free sides by a 7 x 7 window's fattening; the noise
    model's, from the same poses, are not, and its seeds stay where they are."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    import numpy as np

    from lpc_core.perception.laser import LaserParams
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    gate = LaserParams().window_correlation_gate
    sensor = StereoSensor(matcher=Matcher(kind="sgbm", block_size=7))
    errors = []
    for view in lv.views("functional", 1, 5, 0, names=["cuboid_upright"], sensor=sensor):
        result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert result.shape == "cuboid", (view.frame, result.shape, result.reason)
        errors.append(result.grasp_width_m - view.truth.grasp_width_m)
        if "residual_correlation" in result.extra:
            assert result.extra["residual_correlation"] >= gate
            assert result.extra["fattening_px"] == LaserParams().window_fattening_px
    assert len(errors) == 5
    assert np.mean(np.abs(errors)) < 0.0045, errors  # 7.1 mm before
    for view in lv.views("functional", 1, 5, 0, names=["cuboid_upright"]):
        result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert "residual_correlation" not in result.extra
        assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.001


def test_a_box_side_ignores_a_seed_fattened_far_beyond_the_others() -> None:
    """SGBM (block 7) fattens a box's occluding edges by an amount that varies along them, up
    to 15 mm. The upright box, trial 1 frame 0: one seed of its left side lay 14.8 mm past the
    true edge, the other two 1.7 and 4.7 mm, and the side through it left the width 13.2 mm
    too wide; the tilted box, trial 1 frame 1, 7.6 mm. A seed more than two trims beyond every
    other of its side is no longer the side (laser._consistent_sides): -0.3 and 1.3 mm with
    the whole window's trim on each side (scans without the depth past the lines' ends; with
    it the upright box's far sides take one and a half windows: -3.4 mm)."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(kind="sgbm", block_size=7))
    for name, frame in (("cuboid_upright", 0), ("cuboid_tilt_left", 1)):
        views = lv.views("functional", 2, 5, 0, names=[name], sensor=sensor)
        view = next(v for v in views if (v.trial, v.frame) == (1, frame))
        lines = replace(cut_scan_lines(view.depth, lv.INTRINSICS), past_ends_m=None)
        result = reconstruct_laser(lines, seed=view.seq)
        assert result.shape == "cuboid", (name, result.shape, result.reason)
        assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.002, name


def test_a_box_side_with_one_edge_seed_ignores_a_run_fattened_to_the_capture_volume() -> None:
    """SGBM (block 9), the box tilted left, trial 1 frames 0 and 1: one line's run on the face
    carried the face's depth 21.6 mm past the true side, to the capture volume's edge, while
    the side's one uncut seed, at an occluding edge, lay 6.4 and 7.5 mm out. The cut seed
    bounded the side (laser._consistent_sides) and the box came out 19.2 and 18.2 mm too
    wide; a cut seed lying more than two trims beyond the side's edge seed no longer does.
    Block matching (block 5), the box tilted right, trial 0 frame 2: the side's one uncut
    seed ended at no edge, 35 mm inside the side, and the cut seed still bounds it (44.5 mm
    too narrow had it been dropped)."""
    for name, trial, frame in (("cuboid_tilt_left", 1, 0), ("cuboid_tilt_left", 1, 1)):
        view, result = _bench_frame(name, trial, frame, kind="sgbm", block_size=9)
        assert result.shape == "cuboid", (frame, result.shape, result.reason)
        error = result.grasp_width_m - view.truth.grasp_width_m
        assert abs(error) < 0.005, (frame, error)  # 19.2 and 18.2 mm before
    view, result = _bench_frame("cuboid_tilt_right", 0, 2, kind="bm", block_size=5)
    assert result.shape == "cuboid", (result.shape, result.reason)
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.006


def test_a_box_edge_smeared_down_to_the_table_is_no_bevel() -> None:
    """SGBM (block 7), the box tilted left, trial 0 frame 0: the matcher smeared the step from
    the box's lower edge down to the table over about its window, and the walk past the face's
    edge (laser._beyond_edges) took the smear, which falls away like a bevel, for more of the
    object: a point 8.9 mm past the true side, the box 9.4 mm too wide. A walk no longer than
    the fattening shows no surface."""
    view, result = _bench_frame("cuboid_tilt_left", 0, 0, kind="sgbm", block_size=7)
    assert result.shape == "cuboid", (result.shape, result.reason)
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.002  # 9.4 mm before


def test_a_cylinder_whose_rims_a_matcher_pulls_forward_is_fitted_inside_them() -> None:
    """SGBM (block 7): the 60 mm can upright (trial 1 frames 1 and 2) and the 50 mm bottle
    tilted right (trial 0 frames 0 and 2). The matcher pulls the steep surface near the
    silhouette toward the camera, so the fit on the whole arc came out flat and 5.6-10.9 mm
    too wide; refitted 9 px inside the silhouette the samples show, within 3 mm. The same
    poses through lpc's noise model show no such rim and keep the whole arc's fit."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception.laser import (
        LaserParams,
        _cylinder_candidate,
        _pixel_rad,
        _rim_free,
        analyse_lines,
        decide,
    )
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    names = ["cylinder_upright", "cylinder_tilt_right"]
    picked = {
        ("cylinder_upright", 1, 1),
        ("cylinder_upright", 1, 2),
        ("cylinder_tilt_right", 0, 0),
        ("cylinder_tilt_right", 0, 2),
    }
    whole_arc = LaserParams(rim_bias_px=0.0)
    sensor = StereoSensor(matcher=Matcher(kind="sgbm", block_size=7))
    checked = 0
    for view in lv.views("functional", 2, 5, 0, names=names, sensor=sensor):
        if (view.subject, view.trial, view.frame) not in picked:
            continue
        lines = analyse_lines(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        before = decide(lines, whole_arc)
        after = decide(lines)
        assert after.shape == "cylinder", (view.subject, after.shape, after.reason)
        assert before.grasp_width_m - view.truth.grasp_width_m > 0.005, (view.subject, view.frame)
        error = after.grasp_width_m - view.truth.grasp_width_m
        assert abs(error) < 0.003, (view.subject, view.trial, view.frame, error)
        checked += 1
    assert checked == 4
    params = LaserParams()
    for view in lv.views("functional", 2, 5, 0, names=names):
        lines = analyse_lines(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        clean = np.concatenate([ln.points.take(ln.run, axis=0) for ln in lines])
        full = _cylinder_candidate(lines, clean, params).solid
        assert full is not None
        rim_free = _rim_free(lines, full, clean, params, _pixel_rad(lines, params))
        assert rim_free is None, (view.subject, view.trial, view.frame)


def test_a_lying_cylinder_is_no_narrower_than_its_runs_span() -> None:
    """SGBM (block 7), the 40 mm cylinder lying, trial 0 frames 2 and 4: its runs span it to
    within 2 mm, and the fit on the whole arc is within 2 mm, but the fit on the arc facing
    the camera (laser._camera_facing) traded its radius against its centre's depth under the
    matcher's correlated errors and came out 10-12 mm narrow. It can be no narrower than its
    runs span less the rims a matcher fattens (laser._narrower_than_runs)."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception.laser import (
        LaserParams,
        _camera_facing,
        _cylinder_candidate,
        _fattened,
        _pixel_rad,
        analyse_lines,
        decide,
    )
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    params = LaserParams()
    sensor = StereoSensor(matcher=Matcher(kind="sgbm", block_size=7))
    checked = 0
    for view in lv.views("functional", 2, 5, 0, names=["cylinder_lying"], sensor=sensor):
        if (view.trial, view.frame) not in ((0, 2), (0, 4)):
            continue
        lines = analyse_lines(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert _fattened(lines)
        clean = np.concatenate([ln.points.take(ln.run, axis=0) for ln in lines])
        full = _cylinder_candidate(lines, clean, params).solid
        facing = _camera_facing(full, clean, params, _pixel_rad(lines, params))
        truth = view.truth.grasp_width_m
        assert truth - 2 * facing.radius > 0.009, (view.frame, 2 * facing.radius)
        result = decide(lines)
        assert result.shape == "cylinder", (view.frame, result.shape, result.reason)
        error = result.grasp_width_m - truth
        assert abs(error) < 0.003, (view.frame, error)
        checked += 1
    assert checked == 2


@pytest.mark.parametrize(("block", "uniqueness", "trial", "frame"), [(7, 5, 0, 1), (9, 10, 0, 2)])
def test_an_upright_can_whose_whole_arc_fit_sgbm_flattened_is_bounded_by_its_silhouette(
    block: int, uniqueness: int, trial: int, frame: int
) -> None:
    """SGBM, the 60 mm can before the table 80 mm behind it: the window pulled the can's
    flanks toward the camera, the whole arc's fit came out 80 mm with its silhouette 2-12 px
    beyond the samples on each side and the rims lying on it (no bow for the rim refit); the
    widths were 73.4 mm (block 7, uniqueness 5, trial 0 frame 1) and 79.6 mm (block 9, trial
    0 frame 2). The samples' own silhouette, their rims fattened before a background further
    than the can is wide, bounds them (laser._silhouette_bound)."""
    view, result = _bench_frame(
        "cylinder_upright", trial, frame, kind="sgbm", block_size=block, uniqueness=uniqueness
    )
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert "silhouette_width_mm" in result.extra
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.004


def test_a_can_whose_rims_block_matching_lost_to_holes_keeps_its_fit() -> None:
    """BM (block 5), the same can, trial 0 frame 1: the samples stop 5-14 px inside the
    silhouette where holes took the rims (the last samples before them skip pixels), so their
    extent (50 mm) bounds nothing; the width stays the fit's."""
    view, result = _bench_frame("cylinder_upright", 0, 1, kind="bm", block_size=5)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert "silhouette_width_mm" not in result.extra
    assert result.grasp_width_m > view.truth.grasp_width_m


@pytest.mark.parametrize(
    ("matcher", "main_mm"),
    # BM 9's frame (17.7 mm) now takes its width from the hole on the can's +x side before
    # this bound applies (test_round_window: laser._unoccluded_hole, -1.1 mm).
    [({"kind": "bm", "block_size": 7, "uniqueness": 5, "texture_threshold": 20}, 20.1)],
)
def test_an_upright_can_is_no_wider_than_the_background_seen_past_its_rims(
    matcher: dict[str, object], main_mm: float
) -> None:
    """BM, the 60 mm can, trial 0 frame 1: the window flattened the whole arc's fit (20.1 mm
    wide) and its rims do not bow out of it, and the samples stop short of the silhouette in
    holes, so neither the rim refit nor the samples' silhouette trims it; its silhouette lay
    4-10 px past the first pixel that shows the room beyond the can. The can is no wider than
    that pixel allows (laser._background_bound)."""
    view, result = _bench_frame("cylinder_upright", 0, 1, **matcher)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert "background_width_mm" in result.extra
    wide = 1000 * (result.grasp_width_m - view.truth.grasp_width_m)
    assert 0 < wide < 8.0 < main_mm, wide


@pytest.mark.parametrize(
    ("name", "block", "trial", "frame", "main_mm", "within_mm"),
    [
        ("cylinder_upright", 11, 0, 0, 7.5, 6.5),
        ("cylinder_tilt_right", 7, 0, 0, 2.6, 2.2),
        ("cylinder_tilt_right", 9, 0, 0, 5.8, 5.3),
    ],
)
def test_a_round_is_no_wider_than_the_background_seen_past_any_line_near_its_rims(
    name: str, block: int, trial: int, frame: int, main_mm: float, within_mm: float
) -> None:
    """SGBM, the 60 mm can and the 50 mm bottle tilted right: the outermost sample on a side
    ended its segment in the window's fattening past the silhouette (a plateau, then the
    rim), and the background past it bounded nothing (7.5, 2.6 and 5.8 mm wide); another
    line's end within a few pixels of it showed the background nearer. A cylinder's
    silhouette lies at one view angle across its axis all along it, so that background
    bounds the width too, two pixels past it (laser._near_rim_ends)."""
    view, result = _bench_frame(name, trial, frame, kind="sgbm", block_size=block)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert "background_width_mm" in result.extra
    wide = 1000 * (result.grasp_width_m - view.truth.grasp_width_m)
    assert abs(wide) < within_mm < main_mm, wide


@pytest.mark.parametrize(("frame", "main_mm", "within_mm"), [(1, 9.0, 2.5), (4, 6.0, 3.5)])
def test_a_round_whose_outermost_samples_end_in_a_window_ramp_is_bounded_by_other_lines(
    frame: int, main_mm: float, within_mm: float
) -> None:
    """SGBM (block 11), the 60 mm can, trial 1: a side's outermost sample ended its segment
    in a smear of eight samples or more within a millimetre, where a rim reached at its
    silhouette comes 15-16 mm nearer over the first four pixels: no plateau that the rim then
    follows (laser._fattened_end), so the other lines' ends near that rim bounded nothing and
    the can came out 9.0 and 6.0 mm wide. An end that comes nearer by a third or less of a
    rim's rise is the window's (laser._smoothed_rim), and the background past those ends
    bounds the width, ``_RIM_PX`` past it (laser._near_rim_ends): 2.0 and 3.1 mm wide."""
    view, result = _bench_frame("cylinder_upright", 1, frame, kind="sgbm", block_size=11)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert "background_width_mm" in result.extra
    wide = 1000 * (result.grasp_width_m - view.truth.grasp_width_m)
    assert abs(wide) < within_mm < main_mm, wide


def test_lines_leaving_a_can_over_its_top_rim_bound_no_width() -> None:
    """lpc's noise model, the 60 mm can seen from above: the lines that leave it over its
    top rim end 7-15 px inside the silhouette, and the background past them would cut it to
    44-56 mm where the outermost samples showed a fattening. They end at the can's top
    along its axis (laser._near_rim_ends): the widths stay within 1 mm."""
    from services.cli import _laser_views as lv

    widths = [
        reconstruct_laser(cut_scan_lines(v.depth, lv.INTRINSICS), seed=v.seq).grasp_width_m
        for v in lv.views("functional", 1, 10, 0, names=["cylinder_upright"])
    ]
    assert len(widths) == 10
    assert max(abs(w - 0.060) for w in widths) < 0.001, widths


def test_a_lying_marker_whose_trimmed_fit_floats_off_the_table_keeps_its_whole_arc() -> None:
    """SGBM (block 7), the rotation suite's 40 mm cylinder lying on the table seen from above,
    wrist roll 0, trial 0 frame 4: the whole arc's fit was 39.9 mm and touched the table; the
    camera-facing refit, 31.0 mm, stood 4.7 mm off it, too little for the resting rule to move
    it onto the table, and stood as the width. A trim that lifts the round off the support
    its whole arc lies on took off no fattening (laser._lifted_off)."""
    view, result = _bench_frame(
        "cylinder_40", 0, 4, suite="rotation", detail="roll   0 deg", kind="sgbm", block_size=7
    )
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.002


def test_a_lying_marker_whose_whole_arc_fit_sinks_into_the_table_rests_on_it() -> None:
    """SGBM (block 9), the 40 mm marker lying before the camera, trial 1 frame 2: the whole
    arc's fit, 46.8 mm, sank 5.8 mm into the table; the camera-facing refit, 34.5 mm, touched
    it (within the solids' threshold), so the resting rule left it its own width. Fitted
    again touching the table, as the whole arc's fit says the marker rests, it is 40 mm."""
    view, result = _bench_frame("cylinder_lying", 1, 2, kind="sgbm", block_size=9)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.002


def test_a_jar_cap_seen_from_the_front_is_no_ball() -> None:
    """SGBM (block 7), the jar cap (60 mm across, 15 mm high) from the front, trial 1: the
    lines see a 15-20 mm band of its side, on which a 60 mm ball fits 94-98 % of the samples,
    and all five frames came out a sphere. The band covers 0.38-0.53 of that ball's chord on
    three lines, where a ball's lines cross it whole (laser._short_of_ball): a cylinder."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(kind="sgbm", block_size=7))
    views = lv.views("irregular", 2, 5, 0, names=["jar_cap"], sensor=sensor)
    checked = 0
    for view in (v for v in views if v.detail == "front" and v.trial == 1):
        result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert result.shape == "cylinder", (view.frame, result.shape, result.reason)
        assert result.extra["short_of_ball"] == 1.0
        assert result.extra["f_sphere"] > 0.9  # the ball explained the band as well
        checked += 1
    assert checked == 5


def test_balls_and_the_pear_cover_their_chords() -> None:
    """The same matcher, the 40 and 70 mm balls and the pear (whose upper bulb the lines run
    into): every frame of the bench's 2 x 5 stays a sphere, none short of its ball."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(kind="sgbm", block_size=7))
    views = [
        *lv.views("functional", 2, 5, 0, names=["sphere_small", "sphere_large"], sensor=sensor),
        *lv.views("irregular", 2, 5, 0, names=["pear"], sensor=sensor),
    ]
    assert len(views) == 30
    for view in views:
        result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert result.shape == "sphere", (view.subject, view.trial, view.frame, result.shape)
        assert "short_of_ball" not in result.extra


def test_a_ball_under_semi_global_matching_keeps_the_fit_on_every_inlier() -> None:
    """SGBM (block 5), the 40 mm ball, trial 0 frame 4 and trial 1 frame 2: the lines show no
    plateau, and the fit on the camera-facing cap alone came out 29.3 and 33.1 mm (the cap
    trades its radius against its centre's depth under the matcher's staircase). The scan
    lines' residuals are correlated like SGBM's, and the ball keeps the fit on every inlier:
    40.0 and 40.2 mm."""
    from lpc_core.perception.laser import _fattened, analyse_lines, decide
    from services.cli import _laser_views as lv

    for trial, frame in ((0, 4), (1, 2)):
        view, result = _bench_frame("sphere_small", trial, frame, kind="sgbm", block_size=5)
        scan_lines = cut_scan_lines(view.depth, lv.INTRINSICS)
        assert not _fattened(analyse_lines(scan_lines, seed=view.seq))
        assert result.shape == "sphere", (result.shape, result.reason)
        error = result.grasp_width_m - view.truth.grasp_width_m
        assert abs(error) < 0.001, (trial, frame, error)
        assert decide(analyse_lines(scan_lines, seed=view.seq), scan_lines=scan_lines) == result


def test_a_jar_cap_seen_from_the_front_takes_its_axis_from_its_rims() -> None:
    """BM (block 7), the jar cap from the front, the bench's 2 x 5 frames: the band's own
    cylinder fit turned the cap's axis 59-74 degrees about the view on three frames (the
    wrist-angle errors' spread about their median 38 degrees, the bench's limit 15). The
    lines that cross the band end on its rims, which lie across the axis (laser._rim_axis):
    the spread is 5 degrees (7 with the line along the band, laser._across_band)."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception.reconstruction import wrap_half_turn
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(kind="bm", block_size=7))
    views = lv.views("irregular", 2, 5, 0, names=["jar_cap"], sensor=sensor)
    errors = []
    banded = 0
    for view in (v for v in views if v.detail == "front"):
        result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        banded += "rim_axis" in result.extra
        if result.wrist_angle_rad is not None:
            assert view.truth.wrist_angle_rad is not None
            error = wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad)
            errors.append(np.degrees(error))
    assert banded >= 7
    assert len(errors) >= 9
    median = float(np.median(errors))
    spread = float(np.sqrt(np.mean(np.square(np.array(errors) - median))))
    assert abs(median) < 3.0, errors
    assert spread < 10.0, errors


def test_a_large_ball_sheds_its_plateaus_where_they_widen_it_past_its_own_noise() -> None:
    """BM (block 7), the 70 mm ball, trial 0 frames 2 and 4: some segments end in a plateau
    (background given the edge's depth), too few for the lines to show the matcher's
    fattening. Without the plateaus the ball is 0.9 and 1.1 mm narrower: under the 1.5 mm a
    cylinder's refit must gain, but over twice the ball's own radius SD (0.6 mm in width on
    its 156-170 samples), so the plateaus widened it: 2.5 and 1.3 mm wide before, 1.6 and
    0.2 mm now."""
    for frame, limit in ((2, 0.0020), (4, 0.0005)):
        view, result = _bench_frame("sphere_large", 0, frame, kind="bm", block_size=7)
        assert result.shape == "sphere", (frame, result.shape, result.reason)
        error = result.grasp_width_m - view.truth.grasp_width_m
        assert abs(error) < limit, (frame, error)


def test_a_line_along_the_jar_caps_band_gives_no_rim() -> None:
    """BM (block 7), the jar cap from the front, trial 0 frames 2 and 4: the line that runs
    along the band, 47-49 mm long on the ball fitted to it, ends on the band's sides; the
    ball, wider than the band, faces the camera there at 0.63-0.65, so the rim test took its
    ends for rims too and turned the axis 10-11 degrees off the truth's wrist angle. Along
    the axis the other lines give it spans 2 mm of the band's 14-17 mm (laser._across_band):
    without it the angle is within a degree, or two on frame 2 since its horizontal line
    takes the band's arc (laser._flattened_crests: 1.9 degrees, and 54 mm wide, not 38)."""
    from lpc_core.perception.reconstruction import wrap_half_turn

    for frame in (2, 4):
        view, result = _bench_frame(
            "jar_cap", 0, frame, suite="irregular", detail="front", kind="bm", block_size=7
        )
        assert result.shape == "cylinder", (frame, result.shape, result.reason)
        assert "rim_axis" in result.extra
        assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
        error = wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad)
        assert abs(np.degrees(error)) < 2.0, (frame, np.degrees(error))


def test_a_jar_cap_seen_from_the_front_lies_flat_on_the_table() -> None:
    """The jar cap from the front, trial 0: SGBM 5 frame 0 and SGBM 7 with sparse dots (0.04
    per px²) frame 2. The lines cross a 15 mm band of a 60 mm round and run onto its top face;
    no ball explains them (its centre is not beyond the surface, or the face wins), and the
    cylinder fitted with a free axis lay along the band: 27 and 21 mm wide, 63 and 86 degrees
    off the cap's axis, and the bench's angle spread on those settings 21.9 and 29.1 degrees
    (its limit 15). The band stands 16-17 mm above the table the lines show, under the
    circle's radius across the table's normal: a disc lying flat on it (laser._lying_disc),
    within 2 degrees of the truth's wrist angle."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception.reconstruction import wrap_half_turn
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher, StereoRig
    from services.cli import _laser_views as lv

    sensors = (
        (StereoSensor(matcher=Matcher(kind="sgbm", block_size=5)), 0),
        (StereoSensor(rig=StereoRig(dot_density=0.04), matcher=Matcher(kind="sgbm")), 2),
    )
    for sensor, frame in sensors:
        views = lv.views("irregular", 2, 5, 0, names=["jar_cap"], sensor=sensor)
        view = next(v for v in views if v.detail == "front" and (v.trial, v.frame) == (0, frame))
        result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert result.shape == "cylinder", (frame, result.shape, result.reason)
        assert "disc_axis" in result.extra
        assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
        error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
        assert abs(error) < 2.0, (frame, error)
        assert result.grasp_width_m is not None
        assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.025, result.grasp_width_m


def test_a_jar_cap_no_solid_explained_is_a_disc_on_the_table() -> None:
    """SGBM (block 5), the jar cap from the front, trial 0 frames 1 and 4: the free cylinder
    put its axis in front of the band, the face held 0.48 and 0.54 of the runs, the ball 0.42,
    and the frames were no shape. The disc lying on the table the lines show, its flat top
    with it, holds 0.79 and 0.70 (laser._lying_disc): a cylinder within a degree of the
    truth's wrist angle."""
    from lpc_core.perception.reconstruction import wrap_half_turn

    for frame in (1, 4):
        view, result = _bench_frame(
            "jar_cap", 0, frame, suite="irregular", detail="front", kind="sgbm", block_size=5
        )
        assert result.shape == "cylinder", (frame, result.shape, result.reason)
        assert "disc_axis" in result.extra
        assert result.confidence >= 0.6
        assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
        error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
        assert abs(error) < 1.0, (frame, error)


def test_a_lying_cylinder_short_of_a_ball_keeps_its_own_axis() -> None:
    """SGBM (block 7), the rotation suite's 40 mm cylinder at a 90 degree wrist roll, trial 0
    frame 4: a ball beat it and the lines fall short of that ball, so it is a cylinder (it was
    a sphere); the axis its rims would give leaves 0.57 of the runs on the cylinder (0.98 on
    its own), no solid, and the cylinder keeps its own, within 5 degrees of the truth."""
    from lpc_core.perception.reconstruction import wrap_half_turn

    view, result = _bench_frame(
        "cylinder_40", 0, 4, suite="rotation", detail="roll  90 deg", kind="sgbm", block_size=7
    )
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert result.extra["short_of_ball"] == 1.0
    assert "rim_axis" not in result.extra
    assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
    error = wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad)
    assert abs(np.degrees(error)) < 5.0
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.003


# h23a: a whole-arc fit flattened by the window, whose rims it flattened with it.
@pytest.mark.parametrize(
    ("name", "kind", "block", "trial", "frame", "before_mm"),
    [
        ("cylinder_upright", "sgbm", 7, 0, 3, 13.9),
        ("cylinder_tilt_right", "bm", 9, 0, 1, 11.4),
    ],
)
def test_a_round_whose_whole_arc_fit_lies_beyond_its_rims_is_fitted_inside_them(
    name: str, kind: str, block: int, trial: int, frame: int, before_mm: float
) -> None:
    """A matcher's window pulls both flanks toward the camera, and the whole arc's fit comes out
    so flat that the rims lie on it (no bow: _rim_free's first test) while its silhouette lies
    2 px or more beyond the samples on both sides, each of which ends its segment at an
    occluding edge before a background a diameter or more behind: the samples reach the
    silhouette, and the fit lies beyond them because the window flattened the arc. Without
    that second test the width came out 11-14 mm wide (``before_mm``); refitted inside the
    rims, within 3 mm."""
    view, result = _bench_frame(name, trial, frame, kind=kind, block_size=block)
    assert result.shape == "cylinder"
    error_mm = 1000 * (result.grasp_width_m - view.truth.grasp_width_m)
    assert abs(error_mm) < 3.0, (error_mm, before_mm)


# A crest the matcher flattened (laser._flattened_crests): where every line chose its straight
# run, a line that one convex circle holds, flanks and all, better than the run is an arc.


def test_a_can_whose_crest_block_matching_flattened_is_a_cylinder() -> None:
    """Block matching (block 9), the 60 mm can, trial 1 frame 1: the horizontal line's crest
    comes out a 201-202 mm tread about 14 samples wide, 1-1.5 mm behind the arc through its
    flanks. The tread ended the circle's run (23 samples of 49) and the straight run over
    tread and flank won the line (26); with every line straight the runs lay on one plane and
    the can came out a 37 mm box. One circle holds 41 of the line's 49 samples: an arc."""
    _, result = _bench_frame("cylinder_upright", 1, 1, kind="bm", block_size=9)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert result.lines[0].model == "circle"
    assert result.extra["f_cuboid"] < 0.9  # the circle's run leaves the tread's plane


def test_a_jar_cap_whose_band_block_matching_flattened_keeps_its_arc() -> None:
    """Block matching (block 9), the jar cap from the front, trial 0 frame 2: the horizontal
    line across its 60 mm band is a crest flattened into a tread, whose circle and straight run
    both reach 25 samples of 48 through the axis, and the line won: every line straight, and
    the cylinder fitted on the straight runs came out 37 mm wide. One circle holds 37 of the
    48 samples: the line is the band's arc, and the cap is about its width."""
    view, result = _bench_frame("jar_cap", 0, 2, suite="irregular", detail="front", kind="bm",
                                block_size=9)  # fmt: skip
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert result.lines[0].model == "circle"
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.006


# h24b: a whole-arc fit flattened by an SGBM window, whose fattened rims lie on it.
@pytest.mark.parametrize(
    ("name", "trial", "frame", "before_mm"),
    [
        ("cylinder_upright", 1, 3, 7.6),
        ("cylinder_tilt_right", 1, 3, 6.4),
    ],
)
def test_a_round_under_a_correlated_window_is_fitted_inside_its_rims_without_a_bow(
    name: str, trial: int, frame: int, before_mm: float
) -> None:
    """SGBM (block 9): the window pulls both flanks toward the camera and fattens the rims
    past the silhouette along with them, so the rims lie on the too-flat whole-arc fit (no
    bow: _rim_free's first test) while their background is too near, or a hole too close,
    for the occluding-rim test. The scan lines' residuals are correlated like a window's, and
    that alone says the fit is flattened: refitted inside the rims, within 3 mm; it was
    ``before_mm`` wide."""
    view, result = _bench_frame(name, trial, frame, kind="sgbm", block_size=9)
    assert result.shape == "cylinder"
    error_mm = 1000 * (result.grasp_width_m - view.truth.grasp_width_m)
    assert abs(error_mm) < 3.0, (error_mm, before_mm)


@pytest.mark.parametrize(
    ("detail", "trial", "frame", "before_mm"),
    [("roll   0 deg", 0, 0, 66.1), ("roll  60 deg", 0, 3, 66.4)],
)
def test_a_round_resting_on_a_support_behind_its_rims_keeps_its_fit_under_a_window(
    detail: str, trial: int, frame: int, before_mm: float
) -> None:
    """SGBM (block 7), the rotation suite's 75 mm cylinder lying on the table seen from above:
    it fills most of the lines, too little table shows beside it for a support plane, and the
    refit inside its rims under a correlated window (no bow) traded its radius against its
    centre's depth, ``before_mm`` wide. The table lies right behind both rims, a radius from
    the whole arc's axis (laser._rests_behind_rims): the round rests on it, its samples stop
    short of its rims there, and it keeps its fit, within 3 mm."""
    view, result = _bench_frame(
        "cylinder_75", trial, frame, suite="rotation", detail=detail, kind="sgbm", block_size=7
    )
    assert result.shape == "cylinder"
    error_mm = 1000 * (result.grasp_width_m - view.truth.grasp_width_m)
    assert abs(error_mm) < 3.0, (error_mm, before_mm)


def _disc_angle_error(view: View, result: Reconstruction) -> float:
    """The wrist angle error in degrees of ``result``, which must be a disc lying flat (a
    cylinder along the table's normal)."""
    from lpc_core.perception.reconstruction import wrap_half_turn

    assert result.shape == "cylinder", (result.shape, result.reason)
    assert "disc_axis" in result.extra
    assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
    error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
    return float(error)


def _jar_cap_front_disc(
    trial: int, frame: int, **matcher: object
) -> tuple[View, Reconstruction, float]:
    """The jar cap seen from the front on SGBM 7 (``matcher``: other settings), read as a disc
    lying flat (a cylinder along the table's normal): its view, result and wrist angle error
    in degrees."""
    view, result = _bench_frame(
        "jar_cap", trial, frame, suite="irregular", detail="front", kind="sgbm", block_size=7,
        **matcher,
    )  # fmt: skip
    return view, result, _disc_angle_error(view, result)


def test_a_jar_cap_whose_table_the_matcher_smeared_still_lies_flat_on_it() -> None:
    """SGBM (block 7), the jar cap from the front, trial 0 frame 1: the matcher smeared the
    band's lower rim 4-9 mm down behind the table (2 of the 39 samples beside the runs), and
    the table's 34 samples split 7, 8 and 19 between three lines, so the support search found
    none; the free cylinder lay along the band, 30 mm wide and 53 degrees off the truth's wrist
    angle. The plane most of those samples lie on is the table (laser._DISC_SUPPORT), and the
    cap a disc lying flat on it: within a degree of the truth, 57 mm wide (the truth 60)."""
    view, result, error = _jar_cap_front_disc(trial=0, frame=1)
    assert abs(error) < 2.0, error
    assert result.grasp_width_m is not None
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.005, result.grasp_width_m


def test_a_jar_cap_whose_band_a_face_explains_is_a_disc_on_the_table() -> None:
    """SGBM (block 7), the jar cap from the front, trial 0 frame 0: 20 mm of the 60 mm cap's
    band are flat within the threshold, and a face held 0.82 of the runs against the free
    cylinder's 0.73: a box 18 mm wide, 16 degrees off the truth's wrist angle. The disc lying
    flat on the table the lines show holds 0.70 (laser._lying_disc): within a degree."""
    _, _, error = _jar_cap_front_disc(trial=0, frame=0)
    assert abs(error) < 1.0, error


def test_a_jar_cap_whose_top_chord_makes_a_small_circle_is_a_disc_on_the_table() -> None:
    """SGBM (block 7) in 8-path (HH) mode, the jar cap from the front, trial 0 frame 0: the
    support search found the table, but the circle with most samples on it was 7.8 mm across
    through the top face's chord and a band standing 20 mm tall, no disc's; a face won, a box
    18 mm wide and 81 degrees off the truth's wrist angle (the bench's angle spread 26.0
    degrees, its limit 15). Scored as the disc is judged, its band and its top together, the
    circles through three samples give a disc within a degree (laser._disc_shares)."""
    view, result, error = _jar_cap_front_disc(trial=0, frame=0, sgbm_mode="hh")
    assert abs(error) < 1.0, error
    assert result.grasp_width_m is not None
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.020, result.grasp_width_m


def test_a_box_face_is_no_table_for_a_disc() -> None:
    """SGBM (block 7), the tilted box, trial 1 frame 1: the disc's table search
    (laser._DISC_SUPPORT, the largest plane beside the runs) takes the face the runs lie on,
    all of them within 2.2 mm of it; a circle across it held 0.62 of them and read a disc 19
    mm wider than the box. A disc stands off its table (laser._lying_disc): the box stays."""
    view, result = _bench_frame("cuboid_tilt_left", 1, 1, kind="sgbm", block_size=7)
    assert result.shape == "cuboid", (result.shape, result.reason)
    assert result.grasp_width_m is not None
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.003, result.grasp_width_m


def test_a_jar_cap_whose_lower_rim_the_matcher_smeared_below_the_table_is_a_disc() -> None:
    """SGBM (block 7) with the OpenCV sample's smoothness (P1 and P2 x 3, speckle range 32),
    the jar cap from the front, trial 0 frame 2: the support search found the table, within
    half a degree, but the end of one line crossing the band lay 5.2 mm below it (the band's
    lower rim smeared behind the table), so no disc stood on it and the free cylinder lay 11
    degrees off. A run's last samples below the table are the smear (laser._smeared_below):
    the disc lies on it, within a degree."""
    area = 7 * 7
    _, _, error = _jar_cap_front_disc(0, 2, p1=8 * area * 3, p2=32 * area * 3, speckle_range=32)
    assert abs(error) < 1.0, error


def test_a_jar_cap_whose_table_both_searches_missed_is_a_disc_on_the_plane_beside() -> None:
    """SGBM (block 7, uniqueness 5), the jar cap from the front, trial 0 frame 4: a face
    held 0.65 of the runs over the cylinder, a box 29 mm wide and 46 degrees off; both
    support searches took a plane through the cap's top face and the table behind it (65
    and 27 degrees off the table), on which no disc stood. Of the planes through samples
    beside the runs, the table's holds the disc (laser._disc_on_plane_beside): 0.82 of the
    runs, within a degree of the truth."""
    view, result, error = _jar_cap_front_disc(0, 4, uniqueness=5)
    assert abs(error) < 1.0, error
    assert result.grasp_width_m is not None
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.010, result.grasp_width_m


def _setting_frame(
    setting: str,
    name: str,
    trial: int,
    frame: int,
    detail: str | None = None,
    *,
    suite: str = "irregular",
) -> tuple[View, Reconstruction]:
    """The stereo frame ``(trial, frame)`` of ``name`` in ``suite`` (with ``detail``, seen
    from there) on the bench sweep's ``setting``, and the four-line method's result on it."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from services.cli import _laser_views as lv
    from services.cli.bench.sweep import SETTINGS

    views = lv.views(suite, 2, 5, 0, names=[name], sensor=SETTINGS[setting].sensor())
    view = next(
        v for v in views if (v.trial, v.frame) == (trial, frame) and detail in (None, v.detail)
    )
    return view, reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)


def test_a_box_side_facing_the_occlusion_side_goes_through_its_median_edge() -> None:
    """The band of background past a box's side facing -x that only the left imager sees
    holds the matcher's fill, as far as each row's paths carried the face's disparity. SGBM 7
    in HH mode at P2 x 4 (the sweep's hh7-p2x4) and at four times the room light (light4),
    the upright box, trial 0 frame 3: the left side went through its farthest seed, 10.2 and
    8.8 mm past the true side (the right side 0.3 and 4.9), the box 10.2 and 12.0 mm too wide.
    Through the median of its occluding seeds' edges (laser._occlusion_sides): 2.9 and 5.5."""
    for setting, bound in (("hh7-p2x4", 0.004), ("light4", 0.0065)):
        view, result = _setting_frame(setting, "cuboid_upright", 0, 3, suite="functional")
        assert result.shape == "cuboid", (setting, result.shape, result.reason)
        error = result.grasp_width_m - view.truth.grasp_width_m
        assert abs(error) < bound, (setting, error)  # 10.2 and 12.0 mm before


def test_a_box_side_facing_the_occlusion_side_trims_runs_receding_into_the_band() -> None:
    """The projector at 15 % (the sweep's proj15), the upright box, trial 0 frame 3: its
    side facing -x held no occluding seed, only runs stopping short of their segments' ends
    where the segments fall away toward the room behind (the band's fill and its ramp down):
    that side went through the farthest of them untrimmed, the box 12.8 mm too wide. Taking
    a whole window as occluding seeds do there (laser._Seeds.receding): 4.8 mm."""
    view, result = _setting_frame("proj15", "cuboid_upright", 0, 3, suite="functional")
    assert result.shape == "cuboid", (result.shape, result.reason)
    error = result.grasp_width_m - view.truth.grasp_width_m
    assert abs(error) < 0.007, error  # 12.8 mm before


def test_a_rounded_side_facing_the_occlusion_side_keeps_its_walk() -> None:
    """SGBM 7, the soap bar (rounded on both sides): its walks past the side facing -x, all on
    the bar, fell away as a matcher's fill does, and were dropped where the line's other end
    kept no walk (laser._occlusion_side_fill). There the bar's side facing +x falls away over
    1-4 samples, no longer than the fattening's trim: counted before the trim, it shows the
    object falling away on both sides. Trial 0 frames 1 and 2, trial 1 frame 2: 9.7, 9.5 and
    14.0 mm too narrow before, 7.2, 7.6 and 10.8 so."""
    for trial, frame, bound in ((0, 1, -0.0085), (0, 2, -0.0085), (1, 2, -0.012)):
        view, result = _setting_frame("sgbm7", "soap_bar", trial, frame)
        assert result.shape == "cuboid", (trial, frame, result.shape, result.reason)
        error = result.grasp_width_m - view.truth.grasp_width_m
        assert error > bound, (trial, frame, error)


def test_a_jar_cap_whose_table_holds_runs_past_the_disc_is_scored_as_a_disc() -> None:
    """SGBM 5 in HH mode with a stiffer smoothness (the sweep's hh5), the jar cap from the
    front, trial 0 frame 0: the support search found the table within a degree, but one of
    the four runs lies on the table in front of the cap (16 of 69 samples) and the circle
    with most samples on it held 0.48 of the runs, short of a disc; the circles through three
    samples were tried only where that circle held none, and the free cylinder lay 58 degrees
    off the truth's wrist angle (the bench's angle spread 38.6 degrees, its limit 15). Scored
    as the disc is judged wherever the RANSAC circle makes no disc, a circle through three
    samples holds 0.61: within a degree."""
    view, result = _setting_frame("hh5", "jar_cap", 0, 0, "front")
    error = _disc_angle_error(view, result)
    assert abs(error) < 1.0, error


def test_a_jar_cap_a_cylinder_lies_along_rests_on_the_plane_beside_it() -> None:
    """SGBM 9 with half the smoothness and uniqueness 5 (the sweep's soft9), the jar cap from
    the front, trial 0 frame 0: the support search found no plane, the disc's table search a
    plane 11 degrees off the table on which the band stands 15 mm below it, and the free
    cylinder won, 53 degrees off the truth's wrist angle (the bench's angle spread 20 degrees,
    its limit 15). The planes beside the runs were searched only where no cylinder won; the
    table among them holds the disc (0.78 of the runs): within a degree, 60 mm wide."""
    view, result = _setting_frame("soft9", "jar_cap", 0, 0, "front")
    error = _disc_angle_error(view, result)
    assert abs(error) < 1.0, error
    assert result.grasp_width_m is not None
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.003, result.grasp_width_m


@pytest.mark.parametrize(("setting", "before_deg"), [("bm9", 62.1), ("bm7-u5", 69.6)])
def test_a_jar_cap_whose_hole_the_optical_axis_pierces_is_no_thin_box(
    setting: str, before_deg: float
) -> None:
    """Block matching (BM 9; BM 7 with uniqueness 5), the jar cap from the front, trial 0
    frame 0: a hole from 3 mm left of the optical axis to 7 mm right of it parted the
    horizontal line, which kept the band's left half (22 mm of its 60 mm arc, straight within
    the threshold), and every line was straight: a box 8-11 mm wide, ``before_deg`` off the
    truth's wrist angle (the bench's angle spread 20-22 degrees, its limit 15). The segment
    now spans the hole the axis pierces: the line is the band's arc, and the cap a round
    within the paper's limits (18-22 degrees off from its rims, 44-48 mm wide)."""
    from lpc_core.perception.reconstruction import wrap_half_turn

    view, result = _setting_frame(setting, "jar_cap", 0, 0, "front")
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert result.lines[0].model == "circle"
    assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
    error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
    assert abs(error) < 25.0, (error, before_deg)
    assert result.grasp_width_m is not None
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.020


@pytest.mark.parametrize(("setting", "frame"), [("base40", 3), ("3way5-ss", 3), ("3way5-ss", 4)])
def test_a_hexagonal_prism_whose_crease_seeds_make_an_arc_is_no_disc(
    setting: str, frame: int
) -> None:
    """SGBM 7 on a 40 mm baseline (base40) and 3-way SGBM 5 supersampled (3way5-ss), the
    hexagonal prism, trial 1: four of the side face's six uncut seeds lie where the lines
    leave it at the crease, smoothed into an arc, and the circle through the six held them
    within 0.5-1.2 mm RMS, under half the rectangle's residual: a disc 43-44 mm wide, 38-42
    degrees off the prism's axis (the bench's angle spread 18 degrees, its limit 15). The two
    seeds the capture volume cut lie on the face 41-54 mm from that circle's centre, which no
    round face 21.5 mm in radius holds (laser._disc_holds_cut_seeds): the face stays a box."""
    from lpc_core.perception.reconstruction import wrap_half_turn

    view, result = _setting_frame(setting, "hexagonal_prism", 1, frame, "")
    assert result.shape == "cuboid", (result.shape, result.grasp_width_m)
    assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
    error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
    assert abs(error) < 2.0, error
    assert result.grasp_width_m is not None
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.008, result.grasp_width_m


def test_a_banana_whose_crest_stands_above_a_circle_on_its_side_is_no_disc() -> None:
    """SGBM 5 in HH mode with a stiffer smoothness (the sweep's hh5), the banana, trial 1
    frame 1: the RANSAC circle on the table found follows the banana's side, 80 mm across,
    its band up to 35.5 mm high, and took 0.60 of the runs from the free cylinder's 0.93: a
    disc 54 mm wide, 90 degrees off the banana (the bench's angle spread 28 degrees, its limit
    15). Seven samples beyond the circle stand 1.7-3.0 mm above its band and top: the banana's
    crest, which no disc lying on the table holds (laser._disc_shares). The free cylinder
    stands: 8 degrees off, 39 mm wide (the truth 36)."""
    from lpc_core.perception.reconstruction import wrap_half_turn

    view, result = _setting_frame("hh5", "banana", 1, 1, "")
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert "disc_axis" not in result.extra
    assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
    error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
    assert abs(error) < 10.0, error
    assert result.grasp_width_m is not None
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.005, result.grasp_width_m


@pytest.mark.parametrize(("frame", "before_deg"), [(1, -39.5), (2, -39.0)])
def test_a_jar_cap_whose_rims_turn_its_axis_lies_flat_on_the_table_found(
    frame: int, before_deg: float
) -> None:
    """SGBM 7 with sparse dots on a 35 mm baseline (the sweep's sparse35), the jar cap from
    the front, trial 1: its lines cover too little of a ball's chord, and the cylinder took
    its axis from the band's rims (laser._rim_axis), ``before_deg`` off the truth's wrist
    angle; the disc search was not asked. The support search finds the table, and the disc
    lying flat on it holds the runs: within 2 degrees (the rims stand where the search finds
    no table, as under BM 7 with uniqueness 5)."""
    view, result = _setting_frame("sparse35", "jar_cap", 1, frame, "front")
    error = _disc_angle_error(view, result)
    assert abs(error) < 2.0, (error, before_deg)
    view, result = _setting_frame("bm7-u5", "jar_cap", 0, 2, "front")
    assert "rim_axis" in result.extra and "disc_axis" not in result.extra


def test_a_ball_rests_on_no_plane_its_runs_lie_behind() -> None:
    """3-way SGBM 7 with twice the shot noise (the sweep's 3way7-shot), the 70 mm ball, trial 0
    frame 1: the support search took a plane beside the ball's -x side, the true ball 15.6 mm
    into it, for the table, and the contact refit made the ball 50.3 mm; two of the lines'
    run samples lie 5.3 and 6.7 mm behind that plane, and the ball keeps its own fit, 77.9."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from services.cli import _laser_views as lv
    from services.cli.bench.sweep import SETTINGS

    views = lv.views(
        "functional", 2, 5, 0, names=["sphere_large"], sensor=SETTINGS["3way7-shot"].sensor()
    )
    view = next(v for v in views if (v.trial, v.frame) == (0, 1))
    result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
    assert result.shape == "sphere"
    error = result.grasp_width_m - view.truth.grasp_width_m
    assert -0.003 < error < 0.009, error


def test_a_jar_cap_whose_lines_are_all_straight_is_a_disc_on_the_table() -> None:
    """SGBM 7 under sparse dots of uneven brightness on a 35 mm baseline (the sweep's
    sparse35), the jar cap from the front, trial 1 frame 4: depth in 1 mm steps, runs of 12-18
    samples, every line straight pieces (laser._polyhedral), so no round was fitted and the
    face was a box 12 mm wide, 72 degrees off the truth's wrist angle (the angle errors'
    spread 23 degrees, the bench's limit 15). The table the support search found holds a
    disc explaining 0.95 of the runs, the face 0.77: a cylinder within a degree. Its width is the
    round width rules' (55 mm until a rim plateau smoothed on past a segment end stopped counting
    as a support, `_smeared_past`; 37.6 mm since), so only a bound far inside the box's 48 mm
    shortfall is asserted here."""
    from lpc_core.perception.reconstruction import wrap_half_turn

    view, result = _setting_frame("sparse35", "jar_cap", 1, 4, "front")
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert "disc_axis" in result.extra
    assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
    error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
    assert abs(error) < 1.0, error  # 72.1 before
    assert result.grasp_width_m is not None
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.025  # 48 mm short before


def test_a_tapering_torso_takes_its_axis_between_the_turns_its_taper_allows() -> None:
    """SGBM 11, the horse toy, trial 0 frame 4: the line along x runs along the ellipsoid
    torso and bends away toward both its ends, and the free cylinder fit turned its axis about
    the view to bend it (21.3 degrees off the truth's wrist angle). A fit started from the
    mirror image of that turn about the outline's longest extent turns the other way and
    explains the runs within the cylinder margin: the taper's, so the axis lies between the
    two (laser._tapered_tilt), within 5 degrees. (Block matching, block 7, trial 0 frame 3,
    20.0 degrees off, was this test's frame: no axis guess holds 0.9 of its runs, and the fit
    along the outline's longest extent, tried then (laser._cylinder_candidate), holds more of
    them than the grid's, 1.5 degrees off, with no turn left to mirror.)"""
    from lpc_core.perception.reconstruction import wrap_half_turn

    view, result = _bench_frame("horse_toy", 0, 4, suite="irregular", kind="sgbm", block_size=11)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert "tapered_tilt" in result.extra
    assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
    error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
    assert abs(error) < 5.0, error  # 21.3 before


def test_a_banana_lying_on_the_table_keeps_its_free_fit_over_a_guessed_disc() -> None:
    """The banana under BM 7 on sparser dots (the sweep's bm7-w), trial 0 frame 2: the free
    cylinder lies on the table found (0.5 degrees off it, 1.1 mm from it) and explains 0.94
    of the runs; no disc came from the table's RANSAC circle, and the last resort, a circle
    through three samples on its side 78 mm across, held 0.62 and took the frame, 82.8
    degrees off. A round lying on its side stands its diameter high: the free fit, the richer
    solid ahead by its margin, stands (laser._lies_on)."""
    from lpc_core.perception.reconstruction import wrap_half_turn

    view, result = _setting_frame("bm7-w", "banana", 0, 2)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert "disc_axis" not in result.extra
    assert result.wrist_angle_rad is not None and view.truth.wrist_angle_rad is not None
    error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
    assert abs(error) < 5.0, error  # 82.8 before
    assert result.grasp_width_m is not None
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.005  # 42 mm wide before


def _axis_error_deg(view: View, result: Reconstruction) -> float:
    """Degrees between the result's axis and the truth's (either way along it)."""
    cos = abs(float(np.asarray(result.axis) @ np.asarray(view.truth.axis)))
    return float(np.degrees(np.arccos(min(1.0, cos))))


def test_a_cut_line_leaving_the_face_turns_a_tied_box_onto_its_axis() -> None:
    """SGBM (block 9), the box tilted left, trial 1 frame 1: four uncut seeds and four cut by
    the capture volume; the count's directions tie, and the seeds' own pick lay 3.7 degrees
    off the truth's axis. Where the cut lines leave the face (the scans' edge_past_m) lie on
    its sides as uncut seeds' ends do, and with them the box is within a degree
    (laser._with_face_edges). SGBM (block 7), the same pose: one such point lies 3.1 mm past
    a side an uncut seed settles, inside the band the matcher carried the face on; it is
    moved in onto that side (laser._edges_onto_uncut_sides), or the box turned 4.0 degrees
    (1.5 with it)."""
    from services.cli import _laser_views as lv

    view, result = _bench_frame("cuboid_tilt_left", 1, 1, kind="sgbm", block_size=9)
    lines = replace(cut_scan_lines(view.depth, lv.INTRINSICS), edge_past_m=None)
    without = reconstruct_laser(lines, seed=view.seq)
    assert _axis_error_deg(view, without) > 3.0  # the premise: the tie without the points
    assert _axis_error_deg(view, result) < 1.0
    view, result = _bench_frame("cuboid_tilt_left", 1, 1, kind="sgbm", block_size=7)
    assert _axis_error_deg(view, result) < 2.0


def test_an_edge_point_past_an_uncut_side_still_turns_the_box() -> None:
    """super2, the box tilted right, trial 1 frame 0: a cut line's edge point lies more than
    3 mm past a side an uncut seed settles. Dropped (stop 41's rule), the box turned 8.2
    degrees off its axis and read 1.4 mm narrow; moved in onto that side it still says how far along
    the side the face reaches (laser._edges_onto_uncut_sides)."""
    view, result = _setting_frame("super2", "cuboid_tilt_right", 1, 0, suite="functional")
    assert result.grasp_width_m is not None
    assert _axis_error_deg(view, result) < 2.0
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.0005


def test_the_trimmed_seeds_turn_the_box_where_they_lie_nearer_their_sides() -> None:
    """BM 9 at P2 x 4 (bm9-p4), the upright box, trial 1 frame 3: every uncut seed is an
    occluding one, fattened by its own share of the window; the count on them picked a
    direction through two that happen to line up, 6.5 degrees off the truth's axis (2.2 mm
    wide). Each taking back its share (laser._unfattened_seeds), the trimmed seeds lie
    nearer the sides of the rectangle their own count gives than of that one, and the box
    stands 0.4 degrees off (1.6 mm wide)."""
    view, result = _setting_frame("bm9-p4", "cuboid_upright", 1, 3, suite="functional")
    assert result.grasp_width_m is not None
    assert _axis_error_deg(view, result) < 1.5
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.002
