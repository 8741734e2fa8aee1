"""The four-line method on scan lines ray-cast from analytic solids, with seeded D435-like noise.

Each scan plane through the optical axis is sampled as the camera would: one ray per pixel step
(1/f; sqrt(2)/f on the diagonals), depth noise 0.3 mm RMS, 1 mm depth quantisation, and the
paper's capture volume (|x|, |y| <= 50 mm, 150 <= z <= 250 mm).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import pytest

from lpc_core.perception.laser import (
    LaserParams,
    LineModels,
    _ball_width,
    _beyond_edges,
    _circumcircles,
    _cross,
    _disc_possible,
    _disc_shares,
    _lying_disc,
    _row_medians,
    _short_of_ball,
    _support_rng,
    analyse_lines,
    principal_direction,
    reconstruct_laser,
    sort_around,
    sphere_from_circles,
)
from lpc_core.perception.reconstruction import wrap_half_turn
from lpc_core.perception.solids import PlaneSolid, SphereSolid, orthonormal_basis

Hit = Callable[[np.ndarray], np.ndarray]  # (n, 3) ray directions with z = 1 -> (n,) depth
ANGLES_DEG = (0.0, 45.0, 90.0, 135.0)
WIDTH_TOL_MM = 2.0
ANGLE_TOL_DEG = 2.0
# The scans here have exact edges (no matching window fattens them): a box's occluding edges
# are where its last samples are, so the default stereo trim of LaserParams is turned off.
EXACT_EDGES = LaserParams(edge_fattening_px=0.0)


@dataclass(frozen=True)
class Lines:
    angles_rad: np.ndarray
    points: tuple[np.ndarray, ...]


def scan(hit: Hit, seed: int = 0, noise_m: float = 0.0003, f: float = 213.0) -> Lines:
    rng = np.random.default_rng(seed)
    points = []
    for phi in np.radians(ANGLES_DEG):
        diagonal = abs(math.sin(2 * phi)) > 0.5
        step = (math.sqrt(2) if diagonal else 1.0) / f
        q = np.arange(-0.4, 0.4, step)
        dirs = np.column_stack([q * math.cos(phi), q * math.sin(phi), np.ones_like(q)])
        z = hit(dirs)
        z = np.round((z + rng.normal(0, noise_m, z.shape)) * 1000) / 1000  # 1 mm depth unit
        p = dirs * np.where(np.isfinite(z), z, 0.0)[:, None]
        keep = (
            np.isfinite(z)
            & (z >= 0.15)
            & (z <= 0.25)
            & (np.abs(p[:, 0]) <= 0.05)
            & (np.abs(p[:, 1]) <= 0.05)
        )
        points.append(p[keep])
    return Lines(np.radians(ANGLES_DEG), tuple(points))


def fattened(hit: Hit, k_px: float, f: float = 213.0, baseline_m: float = 0.05) -> Hit:
    """``hit`` as a block matcher sees it: a sample within ``k_px`` pixels of one nearer by
    more than a pixel of disparity (z^2 / (f B)) takes that nearer depth, as a matching
    window straddling the two would give it (edge fattening, and the rim of a curved surface
    pulled toward its front)."""

    def fat(dirs: np.ndarray) -> np.ndarray:
        z = hit(dirs)
        z = np.where(np.isfinite(z), z, np.inf)
        apart = np.hypot(*(dirs[:, None, :2] - dirs[None, :, :2]).transpose(2, 0, 1)) * f
        nearest = np.where(apart <= k_px + 1e-9, z[None, :], np.inf).min(axis=1)
        with np.errstate(invalid="ignore"):
            step = z - nearest > nearest**2 / (f * baseline_m)
        return np.where(step, nearest, z)

    return fat


def sphere(center: tuple[float, float, float], radius: float) -> Hit:
    c = np.asarray(center)

    def hit(d: np.ndarray) -> np.ndarray:
        a = np.einsum("ij,ij->i", d, d)
        b = d @ c
        disc = b * b - a * (c @ c - radius**2)
        with np.errstate(invalid="ignore"):
            return np.where(disc >= 0, (b - np.sqrt(disc)) / a, np.inf)

    return hit


def cylinder(
    center: tuple[float, float, float], axis: tuple[float, float, float], radius: float,
    half_length: float = 0.2,
) -> Hit:  # fmt: skip
    c, a = np.asarray(center), np.asarray(axis) / np.linalg.norm(axis)

    def hit(d: np.ndarray) -> np.ndarray:
        dd = d - np.outer(d @ a, a)
        cc = c - (c @ a) * a
        qa = np.einsum("ij,ij->i", dd, dd)
        qb = dd @ cc
        disc = qb * qb - qa * (cc @ cc - radius**2)
        with np.errstate(invalid="ignore"):
            t = np.where(disc >= 0, (qb - np.sqrt(disc)) / qa, np.inf)
            along = np.abs(t * (d @ a) - c @ a)
        return np.where(along <= half_length, t, np.inf)

    return hit


def box(center: tuple[float, float, float], rotation: np.ndarray, size: tuple[float, ...]) -> Hit:
    c, half = np.asarray(center), np.asarray(size) / 2

    def hit(d: np.ndarray) -> np.ndarray:
        o = rotation.T @ -c
        dl = d @ rotation
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - o) / dl, (half - o) / dl
        near = np.nanmax(np.minimum(t1, t2), axis=1)
        far = np.nanmin(np.maximum(t1, t2), axis=1)
        return np.where((near <= far) & (far > 0), near, np.inf)

    return hit


def plane(point: tuple[float, float, float], normal: tuple[float, float, float]) -> Hit:
    p, n = np.asarray(point), np.asarray(normal)

    def hit(d: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore"):
            t = (p @ n) / (d @ n)
        return np.where(t > 0, t, np.inf)

    return hit


def union(*hits: Hit) -> Hit:
    return lambda d: np.min([h(d) for h in hits], axis=0)


def rotation_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rotation_x(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def axial_error_deg(got_rad: float | None, want_rad: float) -> float:
    assert got_rad is not None
    return abs(math.degrees(wrap_half_turn(got_rad - want_rad)))


def image_angle(axis: np.ndarray) -> float:
    return wrap_half_turn(math.atan2(axis[1], axis[0]))


# --------------------------------------------------------------------------- shapes


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reconstruct_laser_sphere(seed: int) -> None:
    result = reconstruct_laser(scan(sphere((0.003, -0.002, 0.225), 0.025), seed), seed=seed)
    assert result.shape == "sphere", result.reason
    assert result.grasp_width_mm == pytest.approx(50.0, abs=WIDTH_TOL_MM)
    assert result.wrist_angle_rad is None
    assert result.center_m is not None
    assert np.allclose(result.center_m, (0.003, -0.002, 0.225), atol=0.002)
    assert [ln.model for ln in result.lines] == ["circle"] * 4
    assert 0.9 <= result.confidence <= 1.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reconstruct_laser_upright_narrow_cylinder(seed: int) -> None:
    # The paper measured its 40 mm cylinder at 60 +- 4.5 mm.
    lines = scan(cylinder((0.002, 0.0, 0.205), (0.0, 1.0, 0.0), 0.020), seed)
    result = reconstruct_laser(lines, seed=seed)
    assert result.shape == "cylinder", result.reason
    assert result.grasp_width_mm == pytest.approx(40.0, abs=WIDTH_TOL_MM)
    assert axial_error_deg(result.wrist_angle_rad, math.radians(90.0)) < ANGLE_TOL_DEG
    # The vertical scan plane contains the axis: it sees a generator, a straight line.
    assert result.lines[2].model == "line"


@pytest.mark.parametrize("seed", [0, 1])
def test_reconstruct_laser_tilted_cylinder(seed: int) -> None:
    axis = np.array([math.cos(math.radians(30)), math.sin(math.radians(30)), 0.3])
    lines = scan(cylinder((0.0, 0.003, 0.22), tuple(axis), 0.0375), seed)
    result = reconstruct_laser(lines, seed=seed)
    assert result.shape == "cylinder", result.reason
    assert result.grasp_width_mm == pytest.approx(75.0, abs=WIDTH_TOL_MM)
    assert axial_error_deg(result.wrist_angle_rad, image_angle(axis)) < ANGLE_TOL_DEG


@pytest.mark.parametrize("seed", [0, 1])
def test_reconstruct_laser_cuboid_face_at_angle(seed: int) -> None:
    # A 40 x 120 mm face, turned 60 degrees in the image and tilted 20 degrees in depth.
    rotation = rotation_x(20.0) @ rotation_z(60.0)
    lines = scan(box((0.002, -0.001, 0.215), rotation, (0.040, 0.120, 0.030)), seed)
    result = reconstruct_laser(lines, seed=seed)
    assert result.shape == "cuboid", result.reason
    assert result.grasp_width_mm == pytest.approx(40.0, abs=WIDTH_TOL_MM)
    assert axial_error_deg(result.wrist_angle_rad, image_angle(rotation[:, 1])) < ANGLE_TOL_DEG
    assert [ln.model for ln in result.lines] == ["line"] * 4


def test_reconstruct_laser_ignores_table_behind_sphere() -> None:
    scene = union(sphere((0.0, 0.0, 0.19), 0.02), plane((0.0, 0.0, 0.235), (0.0, 0.3, -1.0)))
    result = reconstruct_laser(scan(scene, 3), seed=3)
    assert result.shape == "sphere", result.reason
    assert result.grasp_width_mm == pytest.approx(40.0, abs=WIDTH_TOL_MM)


def test_reconstruct_laser_ignores_neighbouring_cylinder() -> None:
    scene = union(
        box((0.0, 0.0, 0.2), rotation_z(0.0), (0.04, 0.12, 0.03)),
        cylinder((0.045, 0.0, 0.215), (0.0, 1.0, 0.0), 0.015),
    )
    result = reconstruct_laser(scan(scene, 4), EXACT_EDGES, seed=4)
    assert result.shape == "cuboid", result.reason
    assert result.grasp_width_mm == pytest.approx(40.0, abs=WIDTH_TOL_MM)


def _width_errors_mm(hit: Hit, truth_mm: float, params: LaserParams) -> np.ndarray:
    errors = []
    for seed in range(4):
        result = reconstruct_laser(scan(hit, seed), params, seed=seed)
        assert result.grasp_width_m is not None, result.reason
        errors.append(result.grasp_width_mm - truth_mm)
    return np.array(errors)


_TABLE = plane((0.0, 0.0, 0.3), (0.0, 0.0, -1.0))


@pytest.mark.parametrize(
    "hit",
    [
        sphere((0.0, 0.0, 0.2), 0.02),
        union(cylinder((0.0, 0.0, 0.2), (0.0, 1.0, 0.0), 0.02), _TABLE),
    ],
    ids=["sphere", "cylinder"],
)
def test_reconstruct_laser_curved_width_fits_the_arc_facing_the_camera(hit: Hit) -> None:
    # A 7 x 7 window (3 px each way) widens the fit on every inlier by 4-9 mm.
    every_inlier = replace(EXACT_EDGES, silhouette_margin_px=0.0)
    fat = fattened(hit, 3.0)
    assert np.abs(_width_errors_mm(fat, 40.0, every_inlier)).min() > 3.5
    assert np.abs(_width_errors_mm(fat, 40.0, EXACT_EDGES)).max() < 1.0
    # Without fattening the fit on every inlier stands: the camera-facing fit is within
    # silhouette_tolerance_m of it.
    plain = _width_errors_mm(hit, 40.0, EXACT_EDGES)
    np.testing.assert_array_equal(plain, _width_errors_mm(hit, 40.0, every_inlier))
    assert np.abs(plain).max() < 0.5


def test_reconstruct_laser_box_seeds_move_in_from_occluding_edges() -> None:
    # Box face 40 mm wide, turned 20 degrees, the table 100 mm behind: both sides occlude.
    hit = union(box((0.0, 0.0, 0.2), rotation_z(20.0), (0.04, 0.12, 0.03)), _TABLE)
    for k in (2.0, 3.0, 4.0):
        fat = fattened(hit, k)
        # Each occluding side grows by about k px (0.94 mm a pixel at 0.2 m).
        assert _width_errors_mm(fat, 40.0, EXACT_EDGES).min() > 1.4 * k
        assert np.abs(_width_errors_mm(fat, 40.0, LaserParams(edge_fattening_px=k))).max() < 0.5
    # 3 px of trim on a sensor that does not fatten: the face comes out narrower by up to
    # 2 x 3 px (2.8 mm a side at 0.2 m, less the half sample the seeds move out).
    narrow = _width_errors_mm(hit, 40.0, LaserParams(edge_fattening_px=3.0))
    assert ((narrow > -5.6) & (narrow < -2.0)).all()


def test_reconstruct_laser_reports_too_few_points_on_a_line() -> None:
    lines = scan(sphere((0.0, 0.0, 0.2), 0.02))
    short = Lines(lines.angles_rad, (*lines.points[:2], lines.points[2][:5], lines.points[3]))
    result = reconstruct_laser(short)
    assert result.shape == "none"
    assert "too few points on line 2" in result.reason
    assert result.grasp_width_m is None and result.wrist_angle_rad is None


def test_reconstruct_laser_reports_axis_missing_the_object() -> None:
    result = reconstruct_laser(scan(sphere((0.035, 0.035, 0.2), 0.012)))
    assert result.shape == "none"
    assert result.reason


def test_analyse_lines_fits_nothing_once_a_line_decides_the_frame() -> None:
    lines = scan(sphere((0.0, 0.0, 0.2), 0.02))
    short = Lines(lines.angles_rad, (*lines.points[:2], lines.points[2][:5], lines.points[3]))
    models = analyse_lines(short)
    assert "too few points on line 2" in models[2].reason
    assert all(not m.fits for m in models)
    assert len(analyse_lines(lines)[0].fits) == 3  # and all three models when none does


def test_analyse_lines_fits_no_circle_or_ellipse_on_straight_pieces() -> None:
    # A box tilted 35 degrees: every line crosses the top face onto the front face.
    rotation = rotation_x(35.0) @ rotation_z(30.0)
    lines = scan(box((0.0, 0.0, 0.215), rotation, (0.040, 0.120, 0.040)), 1)
    models = analyse_lines(lines, seed=1)
    reasons = [ln.fits[m].reason for ln in models for m in ("circle", "ellipse")]
    assert any("straight pieces" in r for r in reasons)
    assert all(r.startswith("not fitted") for r in reasons)
    result = reconstruct_laser(lines, seed=1)
    assert result.shape == "cuboid", result.reason
    assert result.grasp_width_mm == pytest.approx(40.0, abs=WIDTH_TOL_MM)
    # The sides of a cylinder's lines curve away: the richer models are fitted there.
    curved = analyse_lines(scan(cylinder((0.0, 0.0, 0.2), (0.0, 1.0, 0.0), 0.02), 1), seed=1)
    assert any(ln.fits["circle"] or ln.fits["ellipse"] for ln in curved)


def test_reconstruct_laser_fits_no_sphere_or_cylinder_on_straight_pieces() -> None:
    # The axis pierces near the crease: the runs lie on two faces, no one plane holds them.
    rotation = rotation_x(45.0) @ rotation_z(30.0)
    lines = scan(box((0.0, 0.02, 0.215), rotation, (0.040, 0.120, 0.040)), 1)
    result = reconstruct_laser(lines, EXACT_EDGES, seed=1)
    assert result.shape == "cuboid", result.reason
    assert result.grasp_width_mm == pytest.approx(40.0, abs=WIDTH_TOL_MM)
    assert result.extra["f_cuboid"] < 0.9
    assert "f_sphere" not in result.extra and "f_cylinder" not in result.extra


def test_reconstruct_laser_shuffled_points_give_the_sorted_result() -> None:
    lines = scan(cylinder((0.0, 0.0, 0.2), (1.0, 0.2, 0.1), 0.025), 3)
    rng = np.random.default_rng(4)
    shuffled = Lines(lines.angles_rad, tuple(p[rng.permutation(len(p))] for p in lines.points))
    assert reconstruct_laser(shuffled, seed=5) == reconstruct_laser(lines, seed=5)


def test_reconstruct_laser_is_deterministic_per_seed() -> None:
    lines = scan(cylinder((0.0, 0.0, 0.2), (1.0, 0.2, 0.1), 0.025), 5)
    assert reconstruct_laser(lines, seed=7) == reconstruct_laser(lines, seed=7)


def test_reconstruct_laser_rejects_mismatched_lines() -> None:
    lines = scan(sphere((0.0, 0.0, 0.2), 0.02))
    with pytest.raises(ValueError, match="angles"):
        reconstruct_laser(Lines(lines.angles_rad[:3], lines.points))


def test_reconstruct_laser_paper_variant_sphere_and_cuboid() -> None:
    paper = LaserParams(variant="paper")
    ball = reconstruct_laser(scan(sphere((0.0, 0.0, 0.22), 0.03), 6), paper, seed=6)
    assert ball.shape == "sphere", ball.reason
    assert ball.grasp_width_mm == pytest.approx(60.0, abs=4.0)
    face = reconstruct_laser(scan(box((0.0, 0.0, 0.2), rotation_z(0.0), (0.04, 0.12, 0.03)), 6),
                             paper, seed=6)  # fmt: skip
    assert face.shape == "cuboid", face.reason


# --------------------------------------------------------------------------- Algorithm 1


def test_principal_direction_finds_collinear_seeds() -> None:
    # Eight seeds around a 40 x 100 rectangle: three on the right edge (x = 20).
    seeds = np.array(
        [[20, -30], [20, 0], [20, 30], [0, 50], [-20, 30], [-20, 0], [-20, -30], [0, -50]], float
    )
    first = principal_direction(seeds, math.radians(10))
    assert first is not None
    assert abs(first[0]) < 1e-12 and abs(first[1]) == pytest.approx(60.0)


def test_principal_direction_first_versus_straightest() -> None:
    # At seed 1 the turn is 8 degrees (within alpha_max); at seed 5 it is 0.
    bend = math.radians(8)
    seeds = np.array(
        [
            [0.0, 0.0],
            [10.0, 0.0],
            [10 + 10 * math.cos(bend), 10 * math.sin(bend)],
            [15.0, 30.0],
            [0.0, 40.0],
            [-10.0, 30.0],
            [-20.0, 20.0],
            [-10.0, 5.0],
        ]
    )
    seeds[4:7] = [[-5.0, 35.0], [-10.0, 30.0], [-15.0, 25.0]]
    first = principal_direction(seeds, math.radians(10), pick="first")
    straightest = principal_direction(seeds, math.radians(10), pick="straightest")
    assert first is not None and straightest is not None
    assert np.allclose(first, seeds[2] - seeds[0])
    assert np.allclose(straightest, seeds[5] - seeds[3]) or np.allclose(
        straightest, seeds[6] - seeds[4]
    )


def test_principal_direction_none_when_no_three_collinear() -> None:
    octagon = np.array(
        [[math.cos(a), math.sin(a)] for a in np.radians(np.arange(0, 360, 45) + 22.5)]
    )
    assert principal_direction(octagon, math.radians(10)) is None


def test_principal_direction_rejects_too_few_seeds() -> None:
    with pytest.raises(ValueError, match="seeds"):
        principal_direction(np.zeros((2, 2)))


def test_sort_around_orders_by_angle() -> None:
    points = np.array([[0.0, 1.0], [1.0, 0.0], [-1.0, 0.0], [0.0, -1.0]])
    order = sort_around(points, np.zeros(2))
    assert points[order].tolist() == [[0.0, -1.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]]


def test_sphere_from_circles_exact() -> None:
    center, radius = np.array([0.004, -0.006, 0.21]), 0.03
    angles = np.radians([0.0, 45.0, 90.0, 135.0])
    s_c = center[0] * np.cos(angles) + center[1] * np.sin(angles)
    extreme = center + radius * np.array([[1.0, 0, 0], [0, 1.0, 0]])
    got = sphere_from_circles(angles, np.column_stack([s_c, np.full(4, center[2])]), extreme)
    assert got is not None
    assert np.allclose(got[0], center) and got[1] == pytest.approx(radius)
    assert sphere_from_circles(angles[:1], np.zeros((1, 2)), extreme) is None


# --------------------------------------------------------------------------- parameters


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("threshold_m", 0.0),
        ("radius_limits_m", (0.05, 0.005)),
        ("min_points_per_line", 2),
        ("alpha_max_rad", -1.0),
        ("min_solid_fraction", 1.5),
        ("variant", "other"),
    ],
)
def test_laser_params_reject_bad_values(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        LaserParams(**{field: value})  # type: ignore[arg-type]


@pytest.mark.parametrize("seed", range(4))
def test_a_ball_seen_without_its_rim_is_no_box_or_disc(seed: int) -> None:
    """A stereo matcher loses a small ball's grazing rim: each line keeps only the cap, a flat
    run and two sides a few millimetres long, straight within 1 mm as any short arc is. The
    lines were taken for straight pieces and the ball for a 19 mm disc; one circle holds each
    whole segment, so the circle is fitted and the ball found."""
    centre = np.array([0.002, -0.001, 0.222])
    lines = scan(sphere(tuple(centre), 0.02), seed)
    cap = tuple(p[np.hypot(*(p[:, :2] - centre[:2]).T) <= 0.6 * 0.02] for p in lines.points)
    result = reconstruct_laser(Lines(lines.angles_rad, cap), seed=1)
    assert result.shape == "sphere", result.reason
    assert result.grasp_width_mm == pytest.approx(40.0, abs=3.0)


@pytest.mark.parametrize("matcher", [None, "sgbm"])
def test_a_bumpy_potato_is_as_wide_as_its_runs_span(matcher: str | None) -> None:
    """The 62 mm sweet potato's bumps curve its pierced arc more tightly than the whole: the
    cylinder fitted 30-48 mm (median 38 mm on lpc's noise model, 42 mm on SGBM 7), and the
    object failed the paper's 20 mm rule. Its runs span more across the axis than any inlier
    of that cylinder could, and that span is the width (laser._round_width)."""
    from lpc_core.perception.scans import cut_scan_lines
    from services.cli import _laser_views as lv

    sensor = None
    if matcher is not None:
        pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
        from lpc_core.sim.stereo import Matcher, StereoSensor

        sensor = StereoSensor(matcher=Matcher(kind=matcher, block_size=7))
    widths = []
    for view in lv.views("irregular", 1, 5, 0, names=["sweet_potato"], sensor=sensor):
        result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert result.shape == "cylinder", (view.frame, result.shape, result.reason)
        widths.append(result.grasp_width_mm)
    assert abs(float(np.median(widths)) - 62.0) < 15.0, widths


def test_a_rough_round_takes_its_outline_for_an_axis_where_no_guess_holds_its_arcs(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The sweet potato is no cylinder: no axis guess holds 0.9 of its arcs, and on a block
    matcher's noisy samples the grid's best direction may run across it, a 98 mm round 65 deg
    off (BM 7 with a high texture threshold, trial 0 frame 1). Its outline's longest extent
    (laser._seeds_axis, longest) is then tried too, and holds more of the arcs along the
    potato (laser._cylinder_candidate)."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception import laser
    from lpc_core.perception.scans import cut_scan_lines
    from services.cli import _laser_views as lv
    from services.cli.bench.sweep import SETTINGS

    views = lv.views("irregular", 2, 5, 0, names=["sweet_potato"],
                     sensor=SETTINGS["bm7-t20"].sensor())  # fmt: skip
    view = next(v for v in views if (v.trial, v.frame) == (0, 1))
    lines = cut_scan_lines(view.depth, lv.INTRINSICS)
    truth = view.truth.wrist_angle_rad

    def off_deg(result: laser.Reconstruction) -> float:
        return abs(math.degrees(wrap_half_turn(result.wrist_angle_rad - truth)))

    result = reconstruct_laser(lines, seed=view.seq)
    seeds_axis = laser._seeds_axis
    monkeypatch.setattr(
        laser, "_seeds_axis", lambda ls, p, *, longest=False: None if longest else seeds_axis(ls, p)
    )
    before = reconstruct_laser(lines, seed=view.seq)
    assert result.shape == before.shape == "cylinder"
    assert off_deg(before) > 45.0 and before.grasp_width_mm > 90.0
    assert off_deg(result) < 10.0
    assert abs(result.grasp_width_mm - 62.0) < 25.0


def test_a_bumpy_potato_spans_its_segments_where_a_block_matcher_ends_its_runs_short() -> None:
    """Under BM 9 with a strict speckle filter the sweet potato's runs end 5-10 mm inside its
    limbs, and the runs alone made it 32-44 mm wide (median 39.6, short of the paper's 20 mm
    rule for 62 mm). Where the runs span more than a round could, the lines' segments, whose
    samples past the runs are the potato's surface up to the plateau the matcher smears past
    its rim, span it (laser._round_width, _runs_to_rims)."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception.scans import cut_scan_lines
    from services.cli import _laser_views as lv
    from services.cli.bench.sweep import SETTINGS

    views = lv.views("irregular", 2, 5, 0, names=["sweet_potato"],
                     sensor=SETTINGS["bm9-s150"].sensor())  # fmt: skip
    widths = []
    for view in views:
        result = reconstruct_laser(cut_scan_lines(view.depth, lv.INTRINSICS), seed=view.seq)
        assert result.shape == "cylinder", (view.trial, view.frame, result.reason)
        widths.append(result.grasp_width_mm)
    assert abs(float(np.median(widths)) - 62.0) <= 20.0, widths
    # The segments stop at the rims: no frame reads the potato wider than it is.
    assert max(widths) < 62.0, widths


def test_a_bumpy_potato_is_no_narrower_than_its_runs_where_its_fit_took_one_bump(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Under BM 9 with a 25 % uniqueness ratio the sweet potato's trimmed fit curves along one
    bump: 28-37 mm across where its runs span 38-48 mm and the whole arc's fit 37-47 mm, and
    the median width (36.9 mm) missed the paper's 20 mm rule for 62 mm. Where the runs and the
    whole arc's fit both reach past the trimmed fit by more than a matcher fattens, and the
    segments go on past the runs, the whole arc's fit is the width (laser._bump_fit).
    The 40 mm cylinder lying under SGBM 9 (fattened: fits of 34-36 mm, runs spanning 43 mm,
    the whole arc's fit 49 mm) keeps its width."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception import laser
    from lpc_core.perception.scans import cut_scan_lines
    from services.cli import _laser_views as lv
    from services.cli.bench.sweep import SETTINGS

    views = list(lv.views("irregular", 2, 5, 0, names=["sweet_potato"],
                          sensor=SETTINGS["bm9-c25"].sensor()))  # fmt: skip
    lines = [cut_scan_lines(v.depth, lv.INTRINSICS) for v in views]

    def widths() -> list[float]:
        results = [reconstruct_laser(ls, seed=v.seq) for ls, v in zip(lines, views, strict=True)]
        assert all(r.shape == "cylinder" for r in results), [r.reason for r in results]
        return [r.grasp_width_mm for r in results]

    after = widths()
    monkeypatch.setattr(laser, "_bump_fit", lambda *a: False)
    before = widths()
    assert abs(float(np.median(before)) - 62.0) > 20.0, before
    assert abs(float(np.median(after)) - 62.0) <= 20.0, after
    # The segments stop at the rims: no frame reads the potato wider than it is.
    assert max(after) < 62.0, after

    sgbm9 = SETTINGS["sgbm9"].sensor()
    lying = lv.views("functional", 1, 5, 0, names=["cylinder_lying"], sensor=sgbm9)
    lying = [v for v in lying if v.frame in (1, 4)]
    for view in lying:
        scan_lines = cut_scan_lines(view.depth, lv.INTRINSICS)
        monkeypatch.undo()
        width = reconstruct_laser(scan_lines, seed=view.seq).grasp_width_mm
        monkeypatch.setattr(laser, "_bump_fit", lambda *a: False)
        assert width == reconstruct_laser(scan_lines, seed=view.seq).grasp_width_mm


def test_a_band_with_no_table_beside_it_bends_along_a_cylinder(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The jar cap from the front under BM 7 with a low texture threshold, trial 1 frames
    0-2: every run is a straight piece, no table shows on two lines, so no disc is tried, and
    the 15 mm band won as a face 14-15 mm wide, 88 deg off. A cylinder along the runs' short
    spread holds the band's receding ends as well (laser._band_candidate): a round 49-65 mm
    across along the cap's axis."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception import laser
    from lpc_core.perception.scans import cut_scan_lines
    from services.cli import _laser_views as lv
    from services.cli.bench.sweep import SETTINGS

    views = [
        v
        for v in lv.views(
            "irregular", 2, 5, 0, names=["jar_cap"], sensor=SETTINGS["bm7-t6"].sensor()
        )
        if v.detail == "front" and v.trial == 1 and v.frame < 3
    ]
    lines = [cut_scan_lines(v.depth, lv.INTRINSICS) for v in views]

    def off_deg(result: laser.Reconstruction, view: lv.View) -> float:
        truth = view.truth.wrist_angle_rad
        return abs(math.degrees(wrap_half_turn(result.wrist_angle_rad - truth)))

    after = [reconstruct_laser(ls, seed=v.seq) for ls, v in zip(lines, views, strict=True)]
    monkeypatch.setattr(laser, "_band_candidate", lambda *a: None)
    before = [reconstruct_laser(ls, seed=v.seq) for ls, v in zip(lines, views, strict=True)]
    for b, a, v in zip(before, after, views, strict=True):
        assert b.shape == "cuboid" and off_deg(b, v) > 80.0 and b.grasp_width_mm < 20.0
        assert a.shape == "cylinder" and off_deg(a, v) < 30.0
        assert abs(a.grasp_width_mm - 60.0) < 15.0


_BALL = sphere((0.0, 0.0, 0.2), 0.02)
_LYING = union(cylinder((0.0, 0.0, 0.2), (0.0, 1.0, 0.0), 0.02), _TABLE)


@pytest.mark.parametrize(
    ("hit", "shape", "fattening_px"),
    [(_BALL, "sphere", 0.0), (_LYING, "cylinder", 0.0), (_BALL, "sphere", 3.0),
     (_LYING, "cylinder", 3.0)],
    ids=["sphere", "cylinder", "fattened-sphere", "fattened-cylinder"],
)  # fmt: skip
def test_the_camera_facing_trim_stops_once_it_keeps_the_points_it_kept(
    hit: Hit, shape: str, fattening_px: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Once a pass of laser._camera_facing keeps the points the refit was fitted on, the fit on
    every inlier stands where the refit is within the tolerance by more than a refit of the
    same points can move it (laser._SETTLED_M); the passes left are not fitted. The result is
    the three passes' on every seed, and without fattening some seeds are spared passes."""
    from lpc_core.perception import laser

    fits = []
    for solid_type in (laser.SphereSolid, laser.CylinderSolid):
        estimate = solid_type.estimate

        def counted(*args: object, _estimate=estimate, **kwargs: object) -> object:
            fits.append(1)
            return _estimate(*args, **kwargs)

        monkeypatch.setattr(solid_type, "estimate", counted)
    if fattening_px:
        hit = fattened(hit, fattening_px)
    candidate = laser._sphere_candidate if shape == "sphere" else laser._cylinder_candidate
    shortened = 0
    for seed in range(4):
        lines = analyse_lines(scan(hit, seed), EXACT_EDGES, seed=seed)
        clean = np.concatenate([ln.points.take(ln.run, axis=0) for ln in lines])
        round_ = candidate(lines, clean, EXACT_EDGES)
        pixel = laser._pixel_rad(lines, EXACT_EDGES)
        results = []
        for settled in (laser._SETTLED_M, (math.inf, math.inf)):
            monkeypatch.setattr(laser, "_SETTLED_M", settled)
            fits.clear()
            facing = laser._camera_facing(round_.solid, clean, EXACT_EDGES, pixel, round_.residuals)
            results.append((facing is round_.solid, facing.radius, len(fits)))
        (stood, radius, passes), (all_stood, all_radius, all_passes) = results
        assert (stood, radius) == (all_stood, all_radius), seed
        assert all_passes == 3
        shortened += passes < all_passes
    # A fattened rim moves the trim (and the refit stands narrower): every pass is fitted.
    assert (shortened == 0) if fattening_px else (shortened > 0)


def test_a_fattened_ball_whose_plateau_free_refit_fails_is_refitted_once(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A ball whose lines show a matcher's fattening is refitted without their end plateaus
    (laser._plateau_free) before anything else; where that refit fails, the camera-facing fit
    stands, as it would without the end-plateau rule, and the refit, which would fail the same
    way, is not tried again after the camera-facing trim (_without_end_plateaus)."""
    from lpc_core.perception import laser

    lines = scan(sphere((0.003, -0.002, 0.225), 0.025), 1)
    tried: list[str] = []

    def failing(_lines: object, full: object, _params: object) -> None:
        tried.append(type(full).__name__)

    monkeypatch.setattr(laser, "_fattened", lambda _lines: True)
    monkeypatch.setattr(laser, "_plateau_free", failing)
    result = reconstruct_laser(lines, EXACT_EDGES, seed=1)
    assert result.shape == "sphere", result.reason
    assert tried == ["SphereSolid"]
    facing = reconstruct_laser(lines, replace(EXACT_EDGES, end_plateaus=False), seed=1)
    assert facing.shape == "sphere"
    assert result.grasp_width_m == facing.grasp_width_m
    assert result.center_m == facing.center_m


def _ball_lines(halves: list[float]) -> tuple[list[LineModels], SphereSolid]:
    """Four scan lines across a 40 mm ball 200 mm before the camera, each with samples on
    its front surface out to ``halves[k]`` mm either side of the optical axis."""
    radius, depth = 0.02, 0.2
    lines = []
    for k, (angle, half) in enumerate(zip(np.radians([0, 45, 90, 135]), halves, strict=True)):
        t = np.linspace(-half, half, 60) / 1000
        z = depth - np.sqrt(radius * radius - t * t)
        points = np.column_stack([t * math.cos(angle), t * math.sin(angle), z])
        lines.append(LineModels(index=k, angle=float(angle), total=60, points=points))
    return lines, SphereSolid(center=np.array([0.0, 0.0, depth]), radius=radius)


def test_short_of_ball_needs_two_lines_short_of_the_balls_chord() -> None:
    """A ball's lines cross its chord whole; a band (the jar cap from the front) covers less
    than _BALL_SPAN of it on two lines or more; one short line is not enough."""
    params = LaserParams()
    whole, ball = _ball_lines([19.9] * 4)
    assert not _short_of_ball(whole, ball, params)
    one, ball = _ball_lines([19.9, 5.0, 19.9, 19.9])
    assert not _short_of_ball(one, ball, params)
    two, ball = _ball_lines([19.9, 5.0, 19.9, 6.0])
    assert _short_of_ball(two, ball, params)
    # Samples off the ball (a wall 50 mm behind its centre) do not lengthen a line's cover.
    wall, ball = _ball_lines([19.9, 5.0, 19.9, 6.0])
    for ln in wall[1::2]:
        t = np.linspace(-0.04, 0.04, 30)
        c, s = math.cos(ln.angle), math.sin(ln.angle)
        behind = np.column_stack([t * c, t * s, np.full(30, 0.25)])
        ln.points = np.concatenate([ln.points, behind])
    assert _short_of_ball(wall, ball, params)


def test_ball_width_keeps_no_contact_with_a_plane_its_runs_lie_behind() -> None:
    """A ball takes its contact refit's width from a support none of its samples lie behind;
    a plane beside it that cuts through it (the ball's samples up to 6 mm behind it) is no
    support: the ball keeps its own fit's width."""
    params = LaserParams()
    lines, ball = _ball_lines([19.9] * 4)
    clean = np.concatenate([ln.points for ln in lines])
    # The table 1 mm below the ball's lowest sample, its normal up (-y) toward the camera.
    low = float(clean[:, 1].max())
    table = PlaneSolid(point=np.array([0.0, low + 0.001, 0.2]), normal=np.array([0.0, -1.0, 0.0]))
    assert _ball_width(clean, ball, table, 0.0401, params) == pytest.approx(0.0401)
    # A plane 6 mm inside the ball's +x side, facing -x: the +x line's last samples lie behind.
    wall = PlaneSolid(point=np.array([0.014, 0.0, 0.2]), normal=np.array([-1.0, 0.0, 0.0]))
    assert float(((clean - wall.point) @ wall.normal).min()) < -0.0045
    assert _ball_width(clean, ball, wall, 0.0201, params) == pytest.approx(0.04)
    assert _ball_width(clean, ball, None, None, params) == pytest.approx(0.04)


def _face_then_flat(
    angle: float, on_face: int = 20, flat: int = 8
) -> tuple[LineModels, PlaneSolid]:
    """A scan line at ``angle`` over a face turned 17 degrees toward it (depth z = 0.2 - 0.3
    s, s along the line, nearer the camera toward its +s end), ``on_face`` samples 0.0047 rad
    apart on it, then ``flat`` more, where the segment ends, at the last face sample's depth:
    the fill a semi-global matcher carries past a box's side."""
    c, s_ = math.cos(angle), math.sin(angle)
    q = -0.05 + 0.0047 * np.arange(on_face + flat)
    z = 0.2 / (1.0 + 0.3 * q)
    z[on_face:] = z[on_face - 1]
    points = np.column_stack([q * z * c, q * z * s_, z])
    line = LineModels(index=0, angle=angle, total=len(q), points=points,
                      sz=np.column_stack([q * z, z]), run=np.arange(on_face))  # fmt: skip
    normal = -np.array([0.3 * c, 0.3 * s_, 1.0]) / math.hypot(0.3, 1.0)
    return line, PlaneSolid(point=np.array([0.0, 0.0, 0.2]), normal=normal)


def test_beyond_edges_drops_a_walk_along_the_rows_that_keeps_the_edges_depth() -> None:
    """Past a box's side a semi-global matcher carries the face's disparity into the
    background along the image rows: 8 samples at the edge's depth, 2.2 mm behind the face at
    their end, falling away like a bevel and longer than the 3-pixel fattening, were kept as
    more of the box (half the signal, the box tilted left, trial 1 frame 1: 17.3 mm too wide,
    11.0 with the fill dropped). A line within 30 degrees of the rows drops it; the diagonal
    and vertical lines keep it (on the diagonals the soap bar's rounded edges look the same);
    so does a line along the rows whose walk turns away from the edge's depth (a bevel)."""
    params = replace(LaserParams(), edge_fattening_px=3.0)
    for degrees, kept in ((0.0, 0), (20.0, 0), (180.0, 0), (45.0, 1), (90.0, 1)):
        line, face = _face_then_flat(math.radians(degrees))
        beyond, _ = _beyond_edges([line], face, params)
        assert len(beyond) == kept, degrees
    line, face = _face_then_flat(0.0)
    z = line.points[:, 2].copy()
    z[20:] += 0.0006 * np.arange(1, 9)  # 0.6 mm a sample further: 4.8 mm at its end
    scale = z / line.points[:, 2]
    bevel = replace(line, points=line.points * scale[:, None], sz=line.sz * scale[:, None])
    beyond, _ = _beyond_edges([bevel], face, params)
    assert len(beyond) == 1


def test_beyond_edges_walks_no_step_across_a_rows_gap_wider_than_the_fattening() -> None:
    """Past a box's side a matcher left a row's pixels unmatched, more of them than its
    window's reach fills, and carried the face's disparity on past them: the walk along the
    rows stops at the gap (SGBM 5, the box tilted left, trial 0 frame 2: 7.1 mm too wide with
    the fill past the gap kept as a bevel, 0.2 so). What is left of it, no longer than the
    fattening, is the smear. A gap no wider than the fattening does not stop it, nor does one
    on a vertical line (a block matcher's holes on the hexagonal prism's steep next face)."""
    params = replace(LaserParams(), edge_fattening_px=3.0)

    def walk(degrees: float, gap: int) -> tuple[int, bool]:
        line, face = _face_then_flat(math.radians(degrees), flat=12)
        z = line.points[:, 2].copy()
        z[20:] += 0.0006 * np.arange(1, 13)  # falling away from the face: a bevel's shape
        scale = z / line.points[:, 2]
        keep = np.r_[0:21, 21 + gap : len(z)]
        line = replace(line, points=(line.points * scale[:, None])[keep],
                       sz=(line.sz * scale[:, None])[keep])  # fmt: skip
        beyond, smeared = _beyond_edges([line], face, params)
        return len(beyond), smeared

    assert walk(0.0, 5) == (0, True)
    assert walk(180.0, 5) == (0, True)
    assert walk(0.0, 0) == (1, False)
    assert walk(0.0, 3) == (1, False)
    assert walk(90.0, 5) == (1, False)


def test_a_hole_the_optical_axis_pierces_joins_the_segments_either_side() -> None:
    """A block matcher's hole where the optical axis pierces a round (the jar cap from the
    front under BM 9, trial 0 frame 0: no samples from 3 mm left of the axis to 7 mm right of
    it) parted the horizontal line's segment, and the line kept the nearer side alone, a
    stretch of the arc that a straight line holds. The axis pierces the hole: the surface it
    pierces is the one on both sides, so the segment spans both."""
    lines = scan(cylinder((0.0, 0.0, 0.23), (0.0, 1.0, 0.0), 0.03))
    horizontal = lines.points[0]
    holed = horizontal[(horizontal[:, 0] <= -0.003) | (horizontal[:, 0] >= 0.007)]
    models = analyse_lines(Lines(lines.angles_rad, (holed, *lines.points[1:])))
    s = models[0].sz[:, 0]
    assert s.min() < -0.02 and s.max() > 0.02, (s.min(), s.max())
    # A hole beside the axis still ends the segment there: the line keeps the side it crosses.
    beside = horizontal[(horizontal[:, 0] <= 0.004) | (horizontal[:, 0] >= 0.014)]
    s = analyse_lines(Lines(lines.angles_rad, (beside, *lines.points[1:])))[0].sz[:, 0]
    assert s.min() < -0.02 and 0.003 < s.max() < 0.005, (s.min(), s.max())


def test_a_line_thinned_by_holes_is_fitted_again_across_them() -> None:
    """A block matcher's texture check leaves the diagonal line across the can a stretch of
    ten samples through the axis, then a 9 mm hole (the surface rising behind it, a jump
    past ``segment_gap_m``), then the rest of the arc. One of the ten is off the arc, so the
    line's run is nine, short of ``min_points_per_line``, and the frame had no shape; the
    arc goes on past the hole, and the line fitted across it finds the can."""
    lines = scan(cylinder((0.0, 0.0, 0.23), (0.0, 1.0, 0.0), 0.03))
    diagonal = lines.points[1]
    s = (diagonal[:, 0] + diagonal[:, 1]) / math.sqrt(2)
    at = int(np.abs(s).argmin())
    keep = np.zeros(len(s), dtype=bool)
    keep[at - 8 : at + 2] = True
    keep |= (s >= s[at + 1] + 0.009) & (s <= 0.025)
    holed = diagonal[keep]
    holed[4] *= (holed[4, 2] + 0.003) / holed[4, 2]  # 3 mm behind the arc
    found = reconstruct_laser(Lines(lines.angles_rad, (lines.points[0], holed, *lines.points[2:])))
    assert found.shape == "cylinder", found.reason
    assert abs(found.grasp_width_m - 0.06) * 1000 <= WIDTH_TOL_MM, found.grasp_width_m


def _ball_in_clumps(seed: int) -> Lines:
    """A 40 mm ball whose diagonal line a block matcher's texture check left in four clumps
    (holes of 4-7 mm between them, the surface going on across each), 11 samples where a
    whole line holds 26, two of them 3 mm behind the arc (mismatched windows)."""
    lines = scan(sphere((0.0, 0.0, 0.242), 0.02), seed)
    diagonal = lines.points[1]
    s = (diagonal[:, 0] + diagonal[:, 1]) / math.sqrt(2)
    clumps = ((-0.0155, -0.012), (-0.005, 0.002), (0.0075, 0.0105), (0.0145, 0.017))
    holed = diagonal[np.any([(s >= lo) & (s <= hi) for lo, hi in clumps], axis=0)]
    behind = [3, 8]
    holed[behind] *= ((holed[behind, 2] + 0.003) / holed[behind, 2])[:, None]
    return Lines(lines.angles_rad, (lines.points[0], holed, *lines.points[2:]))


@pytest.mark.parametrize("seed", range(6))
def test_a_ball_seen_through_holes_counts_the_samples_its_holes_hid(seed: int) -> None:
    """The arc holds 9 of the 11 samples left, or fewer, short of ``min_points_per_line``,
    and the frame had no shape (all 6 seeds); across its holes the run spans 16 samples'
    worth of the arc."""
    found = reconstruct_laser(_ball_in_clumps(seed), seed=seed)
    assert found.shape == "sphere", found.reason
    assert abs(found.grasp_width_m - 0.04) * 1000 <= WIDTH_TOL_MM, found.grasp_width_m


def _ball_into_a_slope(seed: int) -> Lines:
    """A 40 mm ball whose diagonal line runs on past its far flank, without a jump, into a
    trough and then a steep face rising toward the camera and bending toward it (the
    sweep's 40 mm ball beside such a face: SGBM 7 on a 47 mm baseline, 3-way SGBM 7)."""
    lines = scan(sphere((0.0, 0.0, 0.242), 0.02), seed)
    diagonal = lines.points[1]
    ball = diagonal[(diagonal[:, 0] + diagonal[:, 1]) / math.sqrt(2) <= 0.018]
    s = np.arange(0.0195, 0.058, 0.0008)
    trough = np.where(s < 0.025, 0.236 + (s - 0.0195) * 0.5, 0.239)
    bend = 0.1748 + np.sqrt(np.maximum(0.0485**2 - (s - 0.0099) ** 2, 0.0))
    z = np.where(s > 0.03, np.minimum(trough, np.maximum(bend, 0.239 - 2.63 * (s - 0.03))), trough)
    z = np.round(z * 1000) / 1000  # 1 mm depth unit
    c = math.cos(math.radians(45.0))
    tail = np.column_stack([s * c, s * c, z])
    return Lines(
        lines.angles_rad, (lines.points[0], np.concatenate([ball, tail]), *lines.points[2:])
    )


@pytest.mark.parametrize("seed", range(6))
def test_a_ball_running_into_a_slope_keeps_the_arc_through_the_axis(seed: int) -> None:
    """The slope holds more samples than the ball's arc on the diagonal line, so RANSAC's
    circle may lie concave along it and the ball's crest, the run through the axis is short,
    and the line took the slope's run 40-58 mm off the axis: no solid explained the lines
    (3 of these 6 seeds). A convex circle on the points that circle left out holds the arc."""
    found = reconstruct_laser(_ball_into_a_slope(seed), seed=seed)
    assert found.shape == "sphere", found.reason
    assert abs(found.grasp_width_m - 0.04) * 1000 <= WIDTH_TOL_MM, found.grasp_width_m
    line = analyse_lines(_ball_into_a_slope(seed), seed=seed)[1]
    assert line.sz[line.run[0], 0] < 0.0 < line.sz[line.run[-1], 0]


def _rounded_before(line: LineModels, face: PlaneSolid, samples: int = 8) -> LineModels:
    """``line`` with ``samples`` more before its first, 0.0047 rad apart, each 0.6 mm further
    behind ``face`` than the last: the object's own side falling away at that end too."""
    c, s_ = math.cos(line.angle), math.sin(line.angle)
    q = line.sz[0, 0] / line.sz[0, 1] - 0.0047 * np.arange(samples, 0, -1)
    ray = np.column_stack([q * c, q * s_, np.ones(samples)])
    on_plane = (face.point @ face.normal) / (ray @ face.normal)
    z = on_plane + 0.0006 * np.arange(samples, 0, -1)
    points = np.concatenate([ray * z[:, None], line.points])
    sz = np.concatenate([np.column_stack([q * z, z]), line.sz])
    return replace(line, points=points, sz=sz, run=line.run + samples)


def test_beyond_edges_drops_a_fall_on_the_occlusion_side_unless_both_ends_fall() -> None:
    """Past a box's side facing -x (the second imager sits along +x) lies the band of
    background only the left image shows; a semi-global matcher carries the face's disparity
    into it and it falls away from a face turned away like a bevel, on the diagonal lines as
    on the rows (the functional boxes' -x sides 9 mm out, median, where such a walk set them,
    13 smooth settings). A diagonal line whose walk heads -x drops it; one heading +x keeps
    it; and so does a line whose other end falls away as well (the soap bar's rounded sides,
    7.8 -> 9.4 mm width MAE had they been dropped too), and a frame that shows no fattening."""
    params = replace(LaserParams(), edge_fattening_px=3.0)
    for degrees, kept in ((135.0, 0), (225.0, 0), (45.0, 1), (315.0, 1)):
        line, face = _face_then_flat(math.radians(degrees))
        beyond, _ = _beyond_edges([line], face, params)
        assert len(beyond) == kept, degrees
    line, face = _face_then_flat(math.radians(135.0))
    beyond, _ = _beyond_edges([_rounded_before(line, face)], face, params)
    assert len(beyond) == 2
    # No fattening measured (lpc's noise model fills nothing): the fall is kept.
    beyond, _ = _beyond_edges([line], face, replace(params, edge_fattening_px=0.0))
    assert len(beyond) == 1
    # On its own, the fall at the first end heads +x: kept, and the fill at the last dropped.
    line, face = _face_then_flat(math.radians(135.0), flat=0)
    line = replace(line, points=line.points[:20], sz=line.sz[:20])
    beyond, _ = _beyond_edges([_rounded_before(line, face)], face, params)
    assert len(beyond) == 1


def test_row_medians_are_nanmedians_of_the_rows() -> None:
    """_lying_disc's disc tops: np.nanmedian of each row's samples, without masked arrays,
    odd and even counts, ties, one row and many."""
    rng = np.random.default_rng(0)
    for trial in range(200):
        n, rows = int(rng.integers(3, 300)), int(rng.integers(1, 40))
        values = rng.normal(size=n) * 0.01
        if trial % 2:
            values = np.round(values, 4) + 0.5  # ties, no zeros
        present = rng.random((rows, n)) < rng.random()
        present[:, :3] = True
        want = np.nanmedian(np.where(present, values, np.nan), axis=1)
        assert np.array_equal(_row_medians(values, present).view(np.int64), want.view(np.int64))


def test_cross_is_np_cross_to_the_bit() -> None:
    """The round frames' view angles take ``_cross`` for ``np.cross``: the same bits."""
    rng = np.random.default_rng(0)
    for trial in range(3000):
        a = rng.normal(size=3) * 10.0 ** rng.uniform(-4, 2, 3)
        b = a * rng.normal() if trial % 5 == 0 else rng.normal(size=3)
        assert np.array_equal(_cross(a, b).view(np.int64), np.cross(a, b).view(np.int64))


def _lying_cap() -> tuple[np.ndarray, PlaneSolid]:
    """A 60 mm cap 16 mm tall lying on a table 250 mm ahead, seen from the front: its band's
    front arc and its top's front half, and the table it lies on."""
    centre, radius, tall = np.array([0.0, 0.05, 0.25]), 0.03, 0.016
    angle, up = np.meshgrid(np.radians(np.linspace(-60, 60, 25)), np.linspace(0, tall, 9))
    band = np.column_stack([radius * np.sin(angle).ravel(), -up.ravel(),
                            -radius * np.cos(angle).ravel()])  # fmt: skip
    across, depth = np.meshgrid(np.linspace(-0.02, 0.02, 9), np.linspace(-0.02, 0.0, 5))
    top = np.column_stack([across.ravel(), np.full(across.size, -tall), depth.ravel()])
    table = PlaneSolid(point=centre.copy(), normal=np.array([0.0, -1.0, 0.0]))
    return centre + np.concatenate([band, top]), table


def test_lying_disc_weighs_only_the_circles_that_can_be_a_disc() -> None:
    """The scored search weighs only the circles ``_disc_possible`` keeps, and finds the disc
    weighing all of them finds: the same circle, share and solid."""
    clean, table = _lying_cap()
    params = LaserParams()
    found = _lying_disc(clean, table, params, scored=True)
    assert found is not None
    solid, fraction = found
    # Every circle weighed, as before the search kept only the possible ones.
    d = clean - table.point
    height = d @ table.normal
    e1, e2 = orthonormal_basis(table.normal)
    uv = d @ np.column_stack([e1, e2])
    camera = -table.point @ np.column_stack([e1, e2])
    picks = _support_rng().integers(0, len(clean), size=(256, 3))
    centres, radii = _circumcircles(uv.take(picks, axis=0))
    possible = _disc_possible(centres, radii, float(height.max()), camera, params)
    assert 0 < np.count_nonzero(possible) < len(radii)
    shares = _disc_shares(uv, height, centres, radii, camera, params, scored=True)
    best = int(np.argmax(shares.sum(axis=1)))
    assert fraction == np.count_nonzero(shares[best]) / len(clean)
    assert solid.radius == radii[best]
    assert abs(solid.radius - 0.03) < 0.002
