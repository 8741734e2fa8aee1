"""The four-line method's wrist angle on a box under a stereo matcher: the seeds at a face's
edges scatter by the matcher's fattening, and the face's direction is chosen within that
scatter (``laser._scattered_direction``), or beyond it by a least-squares fit of every seed
to its nearest side; seeds that fit a rectangle keep the direction chosen within the
sensor's own tolerance."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any
from unittest import mock

import numpy as np
import pytest

from lpc_core.perception import laser
from lpc_core.perception.laser import (
    LaserParams,
    _edge_direction,
    _pooled_sides_direction,
    _scattered_direction,
    reconstruct_laser,
)
from lpc_core.perception.reconstruction import Reconstruction
from lpc_core.perception.scans import cut_scan_lines

TOL, WIDE = LaserParams().edge_tolerance_m, LaserParams().scattered_edge_tolerance_m


def _rectangle_seeds(angle_deg: float, length: float, width: float) -> np.ndarray:
    """Eight seeds on a rectangle's sides (three on each long side, one on each short one),
    the rectangle's long axis at ``angle_deg``."""
    a, h = length / 2, width / 2
    local = [(-0.3 * a, h), (0.0, h), (0.3 * a, h), (-0.3 * a, -h), (0.0, -h), (0.3 * a, -h)]
    local += [(a, 0.0), (-a, 0.0)]
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    return np.array([(c * x - s * y, s * x + c * y) for x, y in local])


def test_seeds_on_a_rectangle_but_one_keep_the_direction() -> None:
    """lpc's noise model leaves at most one seed off a side (a bevel, a corner): the direction
    is the one chosen within the sensor's tolerance, as it was."""
    uv = _rectangle_seeds(20.0, 0.1, 0.035)
    uv[1] += 0.002 * np.array([-math.sin(math.radians(20.0)), math.cos(math.radians(20.0))])
    given = np.array([math.cos(0.3), math.sin(0.3)])
    got = _scattered_direction(uv, np.zeros(len(uv), dtype=bool), given, TOL, WIDE)
    assert got is given


def test_scattered_seeds_of_a_rectangle_give_its_direction() -> None:
    """Seeds moved outward by 0-2.5 mm (a matcher's fattening, varying along each side): two
    or more lie off the sides a wrong direction gives them, and the direction chosen within
    the scatter is the rectangle's, within 3 degrees."""
    truth = 20.0
    uv = _rectangle_seeds(truth, 0.1, 0.035)
    c, s = math.cos(math.radians(truth)), math.sin(math.radians(truth))
    normal = np.array([-s, c])
    outward = [2.5, 0.0, 1.0, 0.5, 2.0, 0.0]  # mm, along each long side's outward normal
    for k, mm in enumerate(outward):
        uv[k] += (1 if k < 3 else -1) * 0.001 * mm * normal
    wrong = np.array([math.cos(math.radians(35.0)), math.sin(math.radians(35.0))])
    got = _scattered_direction(uv, np.zeros(len(uv), dtype=bool), wrong, TOL, WIDE)
    error = math.degrees(math.atan2(got[1], got[0])) - truth
    assert abs((error + 45.0) % 90.0 - 45.0) < 3.0


def test_a_fattened_face_taken_for_rounded_gets_the_best_pooled_fit() -> None:
    """The upright box under SGBM 7 with the OpenCV sample's smoothness (cvsample), trial 1
    frame 2, its face's seeds in the face's plane (mm, sorted around it; two cut by the
    capture volume). The count's direction is 11.6 degrees off the box's axis and the best
    pooled fit 1.3, but it leaves an uncut seed 14.5 mm inside its sides, more than a quarter
    of the seeds' minimum-area rectangle's 51 mm width (a seed smeared past its side widened
    it), so the face counts as rounded and the minimum-area rectangle's direction, along the
    line between two seeds, stands: 6.6 degrees off. With the matcher's fattening measured,
    the best pooled fit from that rectangle is 1.3 degrees off; without it (lpc's noise
    model), the minimum-area rectangle's direction stands."""
    uv = 0.001 * np.array(
        [
            [-23.91, -0.75], [-26.35, -29.89], [-0.01, -54.37], [12.35, -12.74],
            [31.83, 0.96], [37.95, 42.72], [-0.0, 54.29], [-16.72, 18.65],
        ]
    )  # fmt: skip
    cropped = np.array([False, False, True, False, False, False, True, False])
    reach = np.zeros(len(uv))
    truth = 71.43  # degrees: the box's axis in the face's plane

    def off(fattened: bool) -> float:
        got, _ = laser._seeds_direction(uv, cropped, reach, LaserParams(), fattened=fattened)
        error = math.degrees(math.atan2(got[1], got[0])) - truth
        return abs((error + 45.0) % 90.0 - 45.0)

    assert off(False) > 6.0
    assert off(True) < 1.5


def _with_and_without_the_rule(
    suite: str, trials: int, frames: int, name: str, pick: Callable[[Any], bool]
) -> tuple[Any, Reconstruction, Reconstruction]:
    """The view of ``name`` that ``pick`` chooses under SGBM 7, and its reconstructions with
    the scattered-seeds rule turned off and on (both must be cuboids), without the trim of a
    fattening no face run shows (``window_fattening_px``), which moves both widths alike."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from services.cli import _laser_views as lv

    views = lv.views(suite, trials, frames, 0, names=[name], sensor=StereoSensor())
    view = next(v for v in views if pick(v))
    # Without where the cut lines leave the face (scans recorded before it was measured):
    # those side seeds settle these frames' direction on their own.
    lines = replace(cut_scan_lines(view.depth, lv.INTRINSICS), edge_past_m=None)
    rule_off = LaserParams(scattered_edge_tolerance_m=0, window_fattening_px=0)
    # Without the crease's direction as well, which would hide the rule on a box whose lines
    # run on onto its next face (the lying box), nor the fattened seeds' trims taken back
    # before the count, which would hide it where the trimmed seeds fit a rectangle. The
    # rule off goes without the best pooled fit as well, which otherwise refines a
    # minimum-area rectangle's direction wherever a fattening was measured.
    with (
        mock.patch.object(laser, "_crease_direction", lambda *_: None),
        mock.patch.object(laser, "_unfattened_seeds", lambda seeds, _: seeds.points.copy()),
    ):
        with mock.patch.object(laser, "_best_pooled_fit", lambda *_: None):
            before = reconstruct_laser(lines, rule_off, seed=view.seq)
        after = reconstruct_laser(lines, LaserParams(window_fattening_px=0), seed=view.seq)
    assert before.shape == after.shape == "cuboid"
    return view, before, after


def _angle_off(result: Reconstruction, view: Any) -> float:
    from services.cli.bench.accuracy import _angle_error

    return abs(_angle_error(result.wrist_angle_rad, view.truth.wrist_angle_rad))


def test_a_prism_under_semi_global_matching_gets_its_axis() -> None:
    """SGBM 7, the 40 mm prism of the rotation test rolled 90 degrees, first frame: the
    seeds of its long sides scatter by 1-8 px, and the count within 1.5 mm chose a direction
    3.9 degrees off the prism's axis; within the scatter it is 0.3 degrees off, and the width
    comes 1 mm nearer the truth."""
    view, before, after = _with_and_without_the_rule(
        "rotation", 1, 1, "prism_40", lambda v: v.detail.strip() == "roll  90 deg"
    )
    assert _angle_off(before, view) > 3.0
    assert _angle_off(after, view) < 1.0
    width = view.truth.grasp_width_m
    assert abs(after.grasp_width_m - width) < abs(before.grasp_width_m - width)


def test_a_run_ended_inside_the_face_does_not_pull_the_pooled_fit() -> None:
    """A long side's seed 10 mm inside the face (a matcher's hole ended its run there) and
    another 2 mm out: no rectangle holds them within 3 mm, and the fit over every seed on
    its nearest side would turn 12 degrees; it loses seeds the count holds within 1.5 mm, so
    the count's direction (2 degrees off) stays."""
    truth = 20.0
    uv = _rectangle_seeds(truth, 0.1, 0.035)
    c, s = math.cos(math.radians(truth)), math.sin(math.radians(truth))
    normal = np.array([-s, c])
    uv[2] -= 0.010 * normal
    uv[0] += 0.002 * normal
    uncut = np.zeros(len(uv), dtype=bool)
    count = _edge_direction(uv, uncut, TOL)
    pooled = _pooled_sides_direction(uv, uncut, count)
    assert abs(math.degrees(math.atan2(pooled[1], pooled[0])) - truth) > 10.0
    assert _scattered_direction(uv, uncut, count, TOL, WIDE) is count


def test_an_upright_box_under_semi_global_matching_gets_its_axis() -> None:
    """SGBM 7, the upright box, trial 1 frame 4: its long sides' seeds scatter by 1-14 px
    (the background behind its top is far and dim), beyond any tolerance. Without the
    scattered rule the direction was 4.5 degrees off its axis (6.9 before the rounded-face
    rule, which fixed this trial's first frame on its own), with it 2.1."""
    view, before, after = _with_and_without_the_rule(
        "functional", 2, 5, "cuboid_upright", lambda v: (v.trial, v.frame) == (1, 4)
    )
    assert _angle_off(before, view) > 4.0
    assert _angle_off(after, view) < 2.5


def test_a_lying_box_whose_count_leaves_one_seed_off_gets_its_axis() -> None:
    """SGBM 7, the lying box, trial 1 frame 4: the count within 1.5 mm holds all uncut seeds
    but one, which a direction 5.6 degrees off the box's axis leaves beyond 3 mm; the fit of
    every seed to its nearest side holds them all within 3 mm, 0.4 degrees off."""
    view, before, after = _with_and_without_the_rule(
        "functional", 2, 5, "cuboid_lying", lambda v: (v.trial, v.frame) == (1, 4)
    )
    assert _angle_off(before, view) > 4.0
    assert _angle_off(after, view) < 1.0


def test_a_tilted_box_whose_count_turned_gets_its_axis_from_the_best_pooled_fit() -> None:
    """SGBM 7, the box tilted left, trial 0 frame 2: its seeds lie 1-5 mm outside the face's
    sides (each by its own fattening), and the count within 1.5 mm leaves two off along a
    direction 7.6 degrees off the box's axis. The pooled fit started from it stays there;
    started every 10 degrees, the one that leaves the seeds nearest the sides is 0.7 degrees
    off, and the width comes nearer the truth."""
    view, before, after = _with_and_without_the_rule(
        "functional", 2, 5, "cuboid_tilt_left", lambda v: (v.trial, v.frame) == (0, 2)
    )
    assert _angle_off(before, view) > 6.0
    assert _angle_off(after, view) < 1.5
    width = view.truth.grasp_width_m
    assert abs(after.grasp_width_m - width) < abs(before.grasp_width_m - width)


def test_an_upright_box_with_a_seed_moved_12_px_gets_its_axis() -> None:
    """SGBM 7, the upright box, trial 1 frame 1: one seed lies 12 mm outside its side, and
    the count turned 20 degrees off the box's axis, along it; the best pooled fit is 2.1
    degrees off, and the width 10 mm nearer the truth. (Since a run goes on across a
    matcher's excursion off the face's plane, ``laser._across_excursions``, the count alone
    is 5.2 degrees off and 17 mm wide.)"""
    view, before, after = _with_and_without_the_rule(
        "functional", 2, 5, "cuboid_upright", lambda v: (v.trial, v.frame) == (1, 1)
    )
    assert _angle_off(before, view) > 4.5
    assert _angle_off(after, view) < 3.0
    width = view.truth.grasp_width_m
    assert abs(after.grasp_width_m - width) < abs(before.grasp_width_m - width) - 0.005


def _stereo_view(name: str, trial: int, frame: int, **matcher: Any) -> Any:
    """Trial ``trial``'s frame ``frame`` of the functional suite's ``name`` (2 trials x 5
    frames, as the bench's stereo sweep), under a matcher of the given settings."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher
    from services.cli import _laser_views as lv

    sensor = StereoSensor(matcher=Matcher(**matcher))
    views = lv.views("functional", 2, 5, 0, names=[name], sensor=sensor)
    return next(v for v in views if (v.trial, v.frame) == (trial, frame))


def test_a_box_face_broken_by_holes_gets_its_axis() -> None:
    """BM 5, the box tilted right, trial 1 frame 1: the matcher's holes broke two lines 20-30
    mm inside the face, and the seeds there, on no side, turned the box 62 degrees off its
    axis and left it 16 mm narrow; the samples past the holes lie on the face's plane, and
    the face's runs go on through them: 0.8 degrees, the width within 1 mm. The frame leaves
    no depth past the box's right edge, and the hole's fattening (tests/test_box_bm.py) takes
    2 px a side off: 2.9 mm narrow so (BM 5 over-trims the box tilted right)."""
    from services.cli import _laser_views as lv

    view = _stereo_view("cuboid_tilt_right", 1, 1, kind="bm", block_size=5)
    lines = cut_scan_lines(view.depth, lv.INTRINSICS)
    untrimmed = reconstruct_laser(lines, LaserParams(hole_fattening_px=0.0), seed=view.seq)
    result = reconstruct_laser(lines, seed=view.seq)
    assert result.shape == untrimmed.shape == "cuboid"
    assert _angle_off(result, view) < 1.5
    assert abs(untrimmed.grasp_width_m - view.truth.grasp_width_m) < 0.002
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.003


def test_a_box_face_whose_runs_stop_at_a_holes_border_gets_its_axis() -> None:
    """BM 5, the box tilted right, trial 0 frame 2: two lines' runs stopped 1-3 samples short
    of the holes that split them (the holes' borders leave the face), and the seeds there,
    5-20 mm inside the face, turned the box 17 degrees off its axis; joined across the holes,
    0.7 degrees."""
    from services.cli import _laser_views as lv

    view = _stereo_view("cuboid_tilt_right", 0, 2, kind="bm", block_size=5)
    result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
    assert result.shape == "cuboid"
    assert _angle_off(result, view) < 1.5


def test_a_stray_last_sample_at_the_capture_edge_leaves_the_seed_cut(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """SGBM 7, the box tilted left, trial 0 frame 3: the line along the box reaches the
    capture volume's edge, but its last sample lies 1.5 mm behind the face and ends the run a
    sample short, past the crop margin; counted on a side, that seed turned the box 7.5
    degrees off its axis. Cut, as the segment's end is: 0.7 degrees (with the fattened
    seeds' trims taken back before the count, 2.4: checked below)."""
    from services.cli import _laser_views as lv

    view = _stereo_view("cuboid_tilt_left", 0, 3)
    lines = cut_scan_lines(view.depth, lv.INTRINSICS)
    result = reconstruct_laser(lines, seed=view.seq)
    assert result.shape == "cuboid"
    assert _angle_off(result, view) < 2.5
    monkeypatch.setattr(laser, "_unfattened_seeds", lambda seeds, _: seeds.points.copy())
    result = reconstruct_laser(lines, seed=view.seq)
    assert _angle_off(result, view) < 1.5


def test_a_lying_box_gets_its_axis_from_the_crease_to_its_next_face(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """SGBM 5, the lying box, trial 1 frame 1: the seeds at the face's sides scatter by the
    matcher's fattening and the rectangle through them lies 2.4 degrees off the box's axis;
    three lines run on past the crease onto the next face, and where the two faces' planes
    meet (each fitted to its interior, where no fattening moves it) the box's edge lies 0.2
    degrees off."""
    from services.cli import _laser_views as lv

    view = _stereo_view("cuboid_lying", 1, 1, kind="sgbm", block_size=5)
    lines = cut_scan_lines(view.depth, lv.INTRINSICS)
    after = reconstruct_laser(lines, seed=view.seq)
    monkeypatch.setattr(laser, "_crease_direction", lambda *_: None)
    before = reconstruct_laser(lines, seed=view.seq)
    assert before.shape == after.shape == "cuboid"
    assert _angle_off(before, view) > 2.0
    assert _angle_off(after, view) < 0.5
    assert after.grasp_width_m == before.grasp_width_m


def test_a_run_ending_on_the_fattening_ramp_is_trimmed_as_an_occluding_edge(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """SGBM 7, the box tilted right, trial 1 frame 0: a face run stops a sample or two short
    of its segment's end, those samples 0.3-3 mm behind the face (the matcher's fattening
    ramping down to the far background before the segment ends). Not counted as occluding,
    its side kept the fattening and the box was 3.1 mm wide; counted, with the rest of the
    frame's trim the ramp's samples left, within 0.1 mm."""
    from services.cli import _laser_views as lv

    view = _stereo_view("cuboid_tilt_right", 1, 0)
    lines = cut_scan_lines(view.depth, lv.INTRINSICS)
    after = reconstruct_laser(lines, seed=view.seq)
    monkeypatch.setattr(laser, "_ramp_ends", lambda ln, *_: [0] * (2 * len(ln)))
    before = reconstruct_laser(lines, seed=view.seq)
    assert before.shape == after.shape == "cuboid"
    width = view.truth.grasp_width_m
    assert before.grasp_width_m - width > 0.0025
    assert abs(after.grasp_width_m - width) < 0.001


def test_a_seed_cut_where_the_face_ends_breaks_the_counts_tie() -> None:
    """The box tilted right at 'dim' (trial 3 frame 2; 85 mm wide against the capture
    volume's 100 mm): its four uncut seeds lie one on each side, and every direction over 56
    degrees puts each on a side; that span's middle was 28 degrees off the face's axis (74.1
    degrees in the face's frame). The line along x, cut at the capture volume's side at
    x = +49.6 mm, has the background past its end: the face ends within 15 mm of it, and
    the directions keeping its side that near are 7 degrees off."""
    uv = np.array(
        [
            [-0.0496, -0.0004], [-0.0458, -0.0481], [-0.0, -0.0519], [0.0396, -0.0409],
            [0.0496, 0.0006], [0.0481, 0.0507], [-0.0, 0.0518], [-0.0408, 0.0426],
        ]
    )  # fmt: skip
    cut = np.array([True, False, True, False, True, False, True, False])
    reach = np.array([0.0, 0.0, 0.0, 0.0, 0.0154, 0.0, 0.0, 0.0])
    truth = 74.1

    def off(u: np.ndarray) -> float:
        return abs((math.degrees(math.atan2(u[1], u[0])) - truth + 90.0) % 180.0 - 90.0)

    assert off(_edge_direction(uv, cut, TOL)) > 25.0
    assert off(_edge_direction(uv, cut, TOL, reach)) < 8.0
    assert off(_edge_direction(uv, cut, TOL, np.zeros(8))) > 25.0


def test_the_face_ends_past_a_cut_seed_only_off_its_plane() -> None:
    """A seed cut at the capture volume's side 200 mm away: with the depth past the line's
    end on the face's plane the face goes on (no reach); 40 mm behind it, or 10 mm in front
    (the next face past a crease), the face ends within the past window's middle, 19 px
    along the line (17.9 mm at a pixel of 4.7 mrad); no depth there tells nothing."""
    face = laser.PlaneSolid(point=np.array([0.0, 0.0, 0.2]), normal=np.array([0.0, 0.0, -1.0]))
    end = [0.049, 0.0, 0.2]
    pixel = 0.0047

    def reach(behind: float) -> float:
        return laser._face_ends_past(end, 1.0, 0.0, 1.0, behind, face, pixel)

    assert reach(0.201) == 0.0
    assert reach(0.0) == 0.0
    assert reach(0.24) == pytest.approx(19 * pixel * 0.2)
    assert reach(0.19) == pytest.approx(0.01786)


def test_fattened_seeds_move_back_along_their_lines_by_their_share() -> None:
    """Each uncut seed moves toward its line's other end by its share of the window's trim
    (an angle: times its depth), at most 0.3 of its run; cut seeds and those without a share
    stay."""
    points = np.array([[-0.02, 0.0, 0.4], [0.02, 0.0, 0.4], [0.0, -0.02, 0.4], [0.0, 0.02, 0.4]])
    seeds = laser._Seeds(
        points=points,
        cropped=np.array([False, False, True, False]),
        fattened=np.array([1.0, 0.0, 1.0, 1.5]),
    )
    trim_rad = 0.005  # 2 mm at 0.4 m
    got = laser._unfattened_seeds(seeds, trim_rad)
    assert got[0] == pytest.approx([-0.018, 0.0, 0.4])
    assert got[1] == pytest.approx(points[1])
    assert got[2] == pytest.approx(points[2])
    assert got[3] == pytest.approx([0.0, 0.017, 0.4])
    far = laser._unfattened_seeds(seeds, 0.05)  # 20 mm: capped at 0.3 of the 40 mm run
    assert far[0] == pytest.approx([-0.008, 0.0, 0.4])


def test_a_tilted_box_whose_seeds_took_different_fattenings_gets_its_axis(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """SGBM 7, the box tilted left, trial 1 frame 0: its long sides' seeds lie 1-10 mm out,
    each by the fattening its background gave it, and no rectangle holds them; the count
    turned 7.1 degrees off its axis. With each seed's share of the window's trim taken back
    along its line (a whole window where its run stopped short of its segment with a far
    background behind it), they fit a rectangle as well, 1.2 degrees off."""
    from services.cli import _laser_views as lv

    view = _stereo_view("cuboid_tilt_left", 1, 0)
    # Without where the cut lines leave the face (as ``_with_and_without_the_rule``).
    lines = replace(cut_scan_lines(view.depth, lv.INTRINSICS), edge_past_m=None)
    after = reconstruct_laser(lines, seed=view.seq)
    monkeypatch.setattr(laser, "_unfattened_seeds", lambda seeds, _: seeds.points.copy())
    before = reconstruct_laser(lines, seed=view.seq)
    assert before.shape == after.shape == "cuboid"
    assert _angle_off(before, view) > 6.0
    assert _angle_off(after, view) < 1.5


def test_a_face_run_goes_on_across_a_matchers_excursion_off_the_plane() -> None:
    """BM 7 with a texture threshold of 20, the box tilted right, trial 0 frame 0, its line
    at 45 degrees: five samples 1.6-2.5 mm behind the face (a disparity half a pixel off over
    a dim patch), then eight on it again to the segment's end. The run stopped before them,
    and its seed, 27 mm inside the face, turned the box's axis 17 degrees."""
    params = LaserParams()
    face = [0.1, -0.4, 0.5, -0.3, 0.1, 0.2, -0.6, -0.2, -1.4, -0.9, 1.1, 0.0, 0.4, 1.3, 0.9]
    off = [-2.2, -2.5, -2.0, -1.6, -1.9]
    again = [-0.7, -0.2, -0.5, 0.7, 0.4, 0.1, -0.4, 0.1]
    heights = 0.001 * np.array(face + off + again)
    run = np.arange(len(face))
    got = laser._across_excursions(run, heights, params)
    assert (got[0], got[-1]) == (0, len(heights) - 1)
    # Mirrored: the run's first end goes on as well.
    got = laser._across_excursions(run + len(off + again), heights[::-1].copy(), params)
    assert (got[0], got[-1]) == (0, len(heights) - 1)
    # An edge leaves the plane for good: the next face parts from it with every sample.
    crease = 0.001 * np.array([*face, -1.8, -2.4, -3.1, -3.9, -4.6, -5.3, -6.0, -6.8])
    assert laser._across_excursions(run, crease, params) is run
    # Further off than 2.5 times the face's tolerance: a background, or another object.
    step = 0.001 * np.array(face + [-4.0] * 5 + again)
    assert laser._across_excursions(run, step, params) is run
    # A lone sample either side of the plane: its noise (BM 5, the box tilted right, trial 0
    # frame 2).
    noise = 0.001 * np.array([*face, 1.8, -1.7, *again])
    assert laser._across_excursions(run, noise, params) is run
    # Back to the first side after snapping across: noise too.
    wobble = 0.001 * np.array([*face, 1.8, 1.7, -1.7, 1.9, *again])
    assert laser._across_excursions(run, wobble, params) is run


def test_a_face_run_goes_on_across_a_shift_that_snaps_back_past_the_plane() -> None:
    """The box tilted right, its line along y past the face's middle: under BM 7 with a
    texture threshold of 20 (trial 0 frame 4) two samples 1.6-1.8 mm in front of the face,
    then one 1.7 mm behind it as the disparity snaps back, then the face again; under sparse
    dots 35 mm apart (trial 1 frame 3) four samples climbing to 3.3 mm (at 21 cm, under a
    pixel's disparity), then 1.6 mm behind. The runs stopped before them, and their seeds,
    29-35 mm inside the face, turned the box's axis 29-33 degrees (2.0 and 2.2 joined)."""
    params = LaserParams()
    face = [0.1, -0.4, 0.5, -0.3, 0.1, 0.2, -0.6, -0.2, -1.4, -0.9, 1.1, 0.0, 0.4, 1.3, 0.9]
    again = [-1.1, -1.2, -0.6, -0.0, 0.6, 1.2, 1.1, 0.2, -0.6, -0.7]
    run = np.arange(len(face))
    for shift in ([1.8, 1.6, -1.7], [1.6, 2.2, 2.7, 3.3, -1.6]):
        heights = 0.001 * np.array(face + shift + again)
        got = laser._across_excursions(run, heights, params)
        assert (got[0], got[-1]) == (0, len(heights) - 1)
    # Longer than a window: the face resumes past something else.
    long = 0.001 * np.array(face + [-2.0] * 10 + again)
    assert laser._across_excursions(run, long, params) is run


def _tilted_face_line(past: list[tuple[float, float]]) -> tuple[Any, Any]:
    """A scan line along x over a face tilted 22 degrees about y (z = 0.2 + 0.4 x), samples
    1.3 mm apart from x = -44.7 mm on, and before them ``past`` (x, height in front of the
    face, mm), outward first; and the face's plane."""
    from lpc_core.perception.laser import LineModels
    from lpc_core.perception.solids import PlaneSolid

    normal = np.array([0.4, 0.0, -1.0]) / math.hypot(0.4, 1.0)
    face_x = -0.0447 + 0.0013 * np.arange(60)
    rows = [(0.001 * x, 0.001 * h) for x, h in past] + [(x, 0.0) for x in face_x]
    points = np.array([[x, 0.0, 0.2 + 0.4 * x] + h * normal for x, h in rows])
    sz = np.column_stack([points[:, 0], points[:, 2]])
    line = LineModels(index=0, angle=0.0, total=len(points), points=points, sz=sz)
    return line, PlaneSolid(point=np.array([0.0, 0.0, 0.2]), normal=normal)


def test_a_face_run_leaves_out_a_few_samples_past_a_bump_at_its_end() -> None:
    """The box tilted right, trial 0 frame 2, its line at 45 degrees (SGBM 7 with 2.5 times
    the shot noise): past the face's edge two samples 1.8-3.2 mm in front of its plane, a
    hole of 7 pixels, then two on the plane's extension 10 mm further along. The rule for a
    bump (a remote's buttons, the face going on past them) joined them to the run, and its
    seed, 11 mm outside the face, turned the box 20.2 degrees (3.5 without them). Five
    samples past the bump are the face going on, and two past a bump measured pixel by pixel
    (a remote's button, no hole) the face's end: kept."""
    params = LaserParams()
    line, plane = _tilted_face_line([(-56.5, -0.2), (-55.3, 0.2), (-48.3, 1.8), (-46.9, 3.2)])
    run = laser._face_run(line, plane, params)
    assert run is not None
    assert run.run[0] == 4
    past = [(-58.0 + 1.3 * k, 0.2) for k in range(5)]
    line, plane = _tilted_face_line([*past, (-50.0, 1.8), (-48.0, 3.2)])
    run = laser._face_run(line, plane, params)
    assert run is not None
    assert run.run[0] == 0
    button = [(-56.3 + 1.3 * k, 2.5) for k in range(9)]
    line, plane = _tilted_face_line([(-58.9, 0.1), (-57.6, -0.1), *button])
    run = laser._face_run(line, plane, params)
    assert run is not None
    assert run.run[0] == 0
