"""Tests for lpc_core.perception.scans: the capture-volume crop and the four scan lines,
on analytic scenes."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from lpc_core.perception.intrinsics import D435_424X240, Intrinsics
from lpc_core.perception.scans import (
    ScanLines,
    ScanParams,
    _orthonormal_columns,
    capture_points,
    cut_scan_lines,
    past_line_ends,
    residual_correlation,
    squared_steps,
)
from lpc_core.sim.scene import NoiseModel, Plane, Scene, render_depth, sphere_object

INTR = D435_424X240
PARAMS = ScanParams()


def _render(scene: Scene, intr: Intrinsics = INTR) -> np.ndarray:
    return render_depth(scene, intr, np.eye(4), np.random.default_rng(0), NoiseModel.exact())


def _wall(z: float) -> Scene:
    return Scene((), Plane(np.array([0.0, 0.0, z]), np.array([0.0, 0.0, -1.0])))


def _ball(r: float, z: float = 0.2) -> Scene:
    return Scene((sphere_object("ball", (0.0, 0.0, z), r),), None)


def _off_plane(lines: ScanLines, i: int) -> np.ndarray:
    phi = lines.angles_rad[i]
    p = lines.points[i]
    return np.abs(-math.sin(phi) * p[:, 0] + math.cos(phi) * p[:, 1])


def test_cut_wall_counts_match_pixel_geometry() -> None:
    # A wall at z0 facing the camera: on each line only the pixels exactly on the image line
    # through the principal point are within ±0.5 mm (the next pixel off the line is
    # z0 / fx = 0.94 mm away, or z0 / (fx sqrt 2) = 0.66 mm on the diagonals), and the
    # ±50 mm crop keeps |column offset| <= 0.05 fx / z0 = 53.25 px: 2 * 53 + 1 points.
    z0 = 0.2
    lines = cut_scan_lines(_render(_wall(z0)), INTR)
    expected = 2 * math.floor(0.05 * INTR.fx / z0) + 1
    assert list(lines.counts) == [expected] * 4
    assert lines.total_points == 4 * expected
    assert lines.ok and bool(np.all(lines.line_ok))
    for i in range(4):
        assert np.all(_off_plane(lines, i) <= PARAMS.band_m + 1e-12)
        assert np.allclose(lines.points[i][:, 2], z0)
    # The full crop: every pixel with |offset| <= 53 in both directions.
    assert lines.capture_count == expected**2
    assert len(capture_points(_render(_wall(z0)), INTR)) == expected**2


def test_cut_sphere_points_on_surface_and_counts() -> None:
    # Ball of radius r at depth c on the optical axis. Its silhouette's half-angle is
    # asin(r / c); the pixels k steps from the centre along a line lie inside it when
    # k * step / fx < tan(asin(r / c)), step = 1 on the axes and sqrt 2 on the diagonals.
    r, c = 0.03, 0.2
    lines = cut_scan_lines(_render(_ball(r, c)), INTR)
    tan_half = math.tan(math.asin(r / c))
    on_axis = 2 * math.floor(INTR.fx * tan_half) + 1
    diagonal = 2 * math.floor(INTR.fx * tan_half / math.sqrt(2.0)) + 1
    assert list(lines.counts) == [on_axis, diagonal, on_axis, diagonal]
    centre = np.array([0.0, 0.0, c])
    for i in range(4):
        p = lines.points[i]
        assert np.all(_off_plane(lines, i) <= PARAMS.band_m + 1e-12)
        # Each point is the quantised depth along its own pixel ray: the true surface depth
        # on that ray is within half a depth unit.
        d = p / p[:, 2:3]
        dd = np.sum(d * d, axis=1)
        b = d @ centre
        z_true = (b - np.sqrt(b * b - dd * (centre @ centre - r * r))) / dd
        assert np.max(np.abs(p[:, 2] - z_true)) <= 0.5e-3 + 1e-9
        # Distance to the centre is 1-Lipschitz along the ray: within 0.5 mm * |d| of r.
        radial = np.abs(np.linalg.norm(p - centre, axis=1) - r)
        assert np.all(radial <= 0.5e-3 * np.sqrt(dd) + 1e-9)


def test_cut_points_sorted_by_s_and_plane_coords() -> None:
    lines = cut_scan_lines(_render(_ball(0.04, 0.21)), INTR)
    for i in range(4):
        sz = lines.plane_coords(i)
        phi = lines.angles_rad[i]
        p = lines.points[i]
        assert sz.shape == (len(p), 2)
        assert np.allclose(sz[:, 0], p[:, 0] * math.cos(phi) + p[:, 1] * math.sin(phi))
        assert np.allclose(sz[:, 1], p[:, 2])
        assert np.all(np.diff(sz[:, 0]) >= 0)
        assert len(lines.pixels[i]) == len(p)


def test_cut_pixels_index_the_depth_image() -> None:
    depth = _render(_ball(0.03))
    lines = cut_scan_lines(depth, INTR)
    for i in range(4):
        z_units = depth.reshape(-1)[lines.pixels[i]]
        assert np.allclose(z_units * INTR.depth_scale, lines.points[i][:, 2])


def test_cut_of_a_depth_at_an_odd_address_reads_the_same_pixels() -> None:
    # A decoded frame's depth views its payload at an odd address (the cut gathers its bytes).
    depth = _render(_ball(0.03))
    buffer = bytearray(depth.nbytes + 1)
    odd = np.frombuffer(buffer, dtype=np.uint16, offset=1, count=depth.size).reshape(depth.shape)
    odd[...] = depth
    assert not odd.flags.aligned
    for a, b in zip(
        cut_scan_lines(odd, INTR).points, cut_scan_lines(depth, INTR).points, strict=True
    ):
        assert a.size > 30 and a.tobytes() == b.tobytes()


def test_cut_min_points_marks_short_lines_but_keeps_them() -> None:
    # A 3 mm ball at 200 mm spans about 3 px per line: fewer than min_points = 10.
    lines = cut_scan_lines(_render(_ball(0.003)), INTR)
    assert lines.total_points > 0
    assert np.all(lines.counts < PARAMS.min_points)
    assert not lines.ok and not np.any(lines.line_ok)
    loose = cut_scan_lines(_render(_ball(0.003)), INTR, ScanParams(min_points=1))
    assert loose.ok


def test_cut_outside_volume_and_invalid_depth_give_no_points() -> None:
    assert cut_scan_lines(_render(_wall(0.30)), INTR).total_points == 0  # beyond z 250 mm
    assert cut_scan_lines(_render(_wall(0.12)), INTR).total_points == 0  # nearer than 150 mm
    empty = cut_scan_lines(np.zeros((240, 424), np.uint16), INTR)
    assert empty.total_points == 0 and empty.capture_count == 0
    assert all(p.shape == (0, 3) for p in empty.points)
    assert len(capture_points(np.zeros((240, 424), np.uint16), INTR)) == 0


def test_cut_volume_edges_are_inclusive() -> None:
    for z0 in (0.150, 0.250):
        assert cut_scan_lines(_render(_wall(z0)), INTR).total_points > 0


def test_cut_other_params_follow_geometry() -> None:
    # A wider band keeps three rows/columns on the axis-aligned lines at 200 mm
    # (the neighbours are 0.94 mm away).
    params = ScanParams(band_m=0.001, angles_deg=(0.0, 90.0))
    lines = cut_scan_lines(_render(_wall(0.2)), INTR, params)
    assert list(lines.counts) == [3 * 107, 3 * 107]
    assert np.allclose(np.degrees(lines.angles_rad), [0.0, 90.0])


def test_cut_reads_the_depth_past_each_line_end() -> None:
    # A 30 mm ball at 200 mm: every line ends on the ball's silhouette, and 8-30 px past it
    # the image holds the wall behind (out of the capture volume), or nothing without one.
    for wall, expected in ((0.40, 0.40), (0.23, 0.23), (None, 0.0)):
        scene = _ball(0.03)
        if wall is not None:
            scene = Scene(scene.objects, _wall(wall).support)
        lines = cut_scan_lines(_render(scene), INTR)
        assert lines.past_ends_m is not None and lines.past_ends_m.shape == (4, 2)
        assert np.allclose(lines.past_ends_m, expected, atol=0.0011), (wall, lines.past_ends_m)
    # A line without points reads nothing past its ends; one that the wall ends (at the
    # capture volume's side) reads the wall past them.
    empty = cut_scan_lines(np.zeros((240, 424), np.uint16), INTR)
    assert np.array_equal(empty.past_ends_m, np.zeros((4, 2)))
    wall = cut_scan_lines(_render(_wall(0.2)), INTR)
    assert np.allclose(wall.past_ends_m, 0.2)


def test_past_line_ends_is_the_median_of_the_pixels_past_the_end_and_skips_no_depth() -> None:
    # One line along the row through the principal point, its points at columns 100-199: the
    # pixels 8, 10, ..., 30 columns before column 100 and after column 199 are read.
    depth = np.zeros((240, 424), np.uint16)
    row = round(INTR.ppy)
    depth[row, 100 - 30 : 100 - 7 : 2] = np.arange(300, 312)  # median 305.5 mm
    depth[row, 199 + 8 : 199 + 31 : 2] = [0] * 11 + [700]  # one pixel with depth
    pixels = row * 424 + np.arange(100, 200)
    past = past_line_ends(depth, INTR, np.array([0.0]), pixels, [0, 100])
    assert past == pytest.approx(np.array([[0.3055, 0.7]]))
    # Near the image's border the pixels outside it count as no depth.
    edge = row * 424 + np.arange(3, 20)
    assert past_line_ends(depth, INTR, np.array([0.0]), edge, [0, 17])[0, 0] == 0.0


def test_capture_points_inside_volume() -> None:
    depth = render_depth(
        _ball(0.03), INTR, np.eye(4), np.random.default_rng(3), NoiseModel(shadow=False)
    )
    pts = capture_points(depth, INTR)
    assert len(pts) > 2000
    assert np.all(np.abs(pts[:, :2]) <= 0.05) and np.all((pts[:, 2] >= 0.15) & (pts[:, 2] <= 0.25))
    assert cut_scan_lines(depth, INTR).capture_count == len(pts)


@pytest.mark.parametrize("limits", [(-0.05, 0.05), (0.01, 0.05)])
def test_cut_capture_count_is_the_capture_points(limits: tuple[float, float]) -> None:
    # Off-centre limits leave pixels whose depth interval is empty (x and y ask for
    # disjoint depths): the count then takes its two-comparison path.
    params = ScanParams(x_limits_m=limits, y_limits_m=limits)
    depth = np.random.default_rng(5).integers(0, 320, size=(240, 424)).astype(np.uint16)
    depth[:, ::7] = 65535
    count = cut_scan_lines(depth, INTR, params).capture_count
    assert count == len(capture_points(depth, INTR, params)) > 100


def test_cut_invalid_input_raises_value_error_naming_depth() -> None:
    good = np.zeros((240, 424), np.uint16)
    with pytest.raises(ValueError, match="depth"):
        cut_scan_lines(good.astype(np.float32), INTR)
    with pytest.raises(ValueError, match="depth"):
        cut_scan_lines(good[:, :400], INTR)
    with pytest.raises(ValueError, match="depth"):
        cut_scan_lines(good.tolist(), INTR)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="depth"):
        capture_points(good[None], INTR)


def test_scan_params_validation() -> None:
    with pytest.raises(ValueError, match="band_m"):
        ScanParams(band_m=-1.0)
    with pytest.raises(ValueError, match="z_limits_m"):
        ScanParams(z_limits_m=(0.25, 0.15))
    with pytest.raises(ValueError, match="min_points"):
        ScanParams(min_points=-1)


def _slanted_line(error: np.ndarray) -> tuple[np.ndarray, ...]:
    """One horizontal scan line, a pixel apart at 200 mm, over a face whose depth rises
    0.3 mm a sample, with ``error`` added and the 1 mm quantum applied."""
    x = (np.arange(len(error)) - len(error) / 2) * 0.2 / 380.0
    z = np.round((0.2 + 0.3e-3 * np.arange(len(error)) + error) * 1000) / 1000
    return (np.column_stack([x, np.zeros_like(x), z]),)


def test_residual_correlation_tells_errors_shared_by_neighbours_from_per_pixel_noise() -> None:
    rng = np.random.default_rng(3)
    per_pixel = rng.normal(0.0, 0.7e-3, 400)
    # Each error shared by three neighbouring samples (an average over them), same RMS.
    shared = np.convolve(rng.normal(0.0, 0.7e-3 * math.sqrt(3), 402), np.ones(3) / 3, "valid")
    white = residual_correlation(np.zeros(1), _slanted_line(per_pixel))
    correlated = residual_correlation(np.zeros(1), _slanted_line(shared))
    assert white < 0.1, white  # the fit over 20 samples leaves it a little negative
    assert correlated > 0.2, correlated
    assert correlated > white + 0.3


def test_residual_correlation_skips_steps_and_short_lines() -> None:
    step = np.where(np.arange(400) % 20 < 10, 0.0, 0.004)  # a 4 mm jump inside every piece
    assert residual_correlation(np.zeros(1), _slanted_line(step)) == 0.0
    assert residual_correlation(np.zeros(1), _slanted_line(np.zeros(19))) == 0.0
    assert residual_correlation(np.zeros(1), (np.empty((0, 3)),)) == 0.0


def test_cut_finds_the_first_background_pixel_past_each_line_end() -> None:
    # The 30 mm ball at 200 mm before a wall at 0.40 m: past every line's end the first pixel
    # beyond the capture volume is the wall's, just outside the ball's silhouette (its ray
    # within a pixel of the grazing ray, outside it).
    scene = Scene(_ball(0.03).objects, _wall(0.40).support)
    lines = cut_scan_lines(_render(scene), INTR)
    far = lines.far_past_m
    assert far is not None and far.shape == (4, 2, 3)
    assert np.allclose(far[:, :, 2], 0.40, atol=0.0011), far
    # The angle off the ball's centre (on the optical axis, 0.2 m away) of each point.
    off = np.degrees(np.arctan2(np.hypot(far[:, :, 0], far[:, :, 1]), far[:, :, 2]))
    grazing = math.degrees(math.asin(0.03 / 0.2))
    pixel = math.degrees(1 / INTR.fx)
    assert (off > grazing).all() and (off < grazing + pixel).all(), (off, grazing)
    # Nothing behind the ball, or a wall inside the capture volume (on the lines
    # themselves): no pixel past the ends shows the far background.
    for scene in (_ball(0.03), Scene(_ball(0.03).objects, _wall(0.23).support)):
        assert np.array_equal(cut_scan_lines(_render(scene), INTR).far_past_m, np.zeros((4, 2, 3)))


def test_scans_step_follows_a_change_of_intrinsics_mid_stream() -> None:
    """The scans state keeps the last intrinsics it built: a frame with other intrinsics (a
    camera reopened at another resolution or focal length) is cut with its own, exactly as
    a fresh state would, and so is a frame with the first ones again."""
    from lpc_core.perception.pipeline import ScansState, intrinsics_to_message, scans_step
    from schemas import DepthFrame, encode, to_wire

    other = Intrinsics(width=320, height=200, fx=180.0, fy=181.0, ppx=160.5, ppy=99.5)
    frames = [
        DepthFrame(
            seq=seq,
            t_ns=seq,
            intrinsics=intrinsics_to_message(intr),
            depth=to_wire(_render(_ball(0.02), intr)),
        )
        for seq, intr in enumerate([INTR, other, other, INTR])
    ]
    state = ScansState()
    for frame in frames:
        state, out = scans_step(state, frame, 0)
        _, fresh = scans_step(ScansState(seq=state.seq - 1), frame, 0)
        assert encode(out) == encode(fresh)
    counts = [len(line.points.data) for line in out.lines]
    assert sum(counts) > 0


def _correlation_line_by_line(angles: np.ndarray, points: list[np.ndarray]) -> float:
    """``residual_correlation`` as it was written, one line at a time (20-sample pieces)."""
    piece, starts, s_parts, z_parts, offset = 20, [], [], [], 0
    for phi, pts in zip(angles.tolist(), points, strict=True):
        n = len(pts)
        if n < piece:
            continue
        s = pts[:, 0] * math.cos(phi) + pts[:, 1] * math.sin(phi)
        gaps = np.flatnonzero(squared_steps(pts) > 0.008**2) + 1
        bounds = [0, *gaps.tolist(), n]
        for a, b in itertools.pairwise(bounds):
            if (b - a) // piece:
                starts.append(offset + a + piece * np.arange((b - a) // piece))
        s_parts.append(s)
        z_parts.append(pts[:, 2])
        offset += n
    if not starts:
        return 0.0
    at = np.concatenate(starts)[:, None] + np.arange(piece)
    s_all, z_all = np.concatenate(s_parts)[at], np.concatenate(z_parts)[at]
    x = s_all - s_all.mean(axis=1, keepdims=True)
    x /= np.maximum(np.ptp(x, axis=1, keepdims=True), 1e-12)
    q, _ = np.linalg.qr(np.stack([x * x, x, np.ones_like(x)], axis=2))
    r = z_all - np.einsum("pij,pj->pi", q, np.einsum("pij,pi->pj", q, z_all))
    power = np.einsum("pi,pi->p", r, r)
    keep = (np.abs(r).max(axis=1) <= 0.0015) & (power > 0)
    if not keep.any():
        return 0.0
    lag1 = np.einsum("pi,pi->p", r[keep, :-1], r[keep, 1:])
    return float(np.mean(lag1 / power[keep]) * piece / (piece - 1))


def test_residual_correlation_takes_the_lines_at_once_to_the_bit() -> None:
    """All lines in one pass: the value line by line gave, to the bit, with jumps, short
    lines and single-precision points."""
    rng = np.random.default_rng(3)
    for trial in range(300):
        lines = []
        for _ in range(int(rng.integers(1, 5))):
            n = int(rng.integers(0, 120))
            s = np.cumsum(rng.uniform(0.0005, 0.004, n)) - 0.1
            if n and trial % 2:
                s[int(rng.integers(0, n)) :] += rng.uniform(0.0, 0.03)  # a jump, maybe a gap
            z = 0.2 + 0.01 * np.sin(30 * s) + rng.normal(0, 0.0004, n)
            lines.append(np.column_stack([0.8 * s, 0.6 * s, z]))
        if trial % 7 == 0:
            lines = [line.astype(np.float32) for line in lines]
        angles = rng.uniform(-3.0, 3.0, len(lines))
        want = np.float64(_correlation_line_by_line(angles, lines))
        got = np.float64(residual_correlation(angles, lines))
        assert got.view(np.int64) == want.view(np.int64)


def test_orthonormal_columns_is_qr_to_the_bit() -> None:
    """The Q of ``np.linalg.qr`` without its R: the same bits in double and single precision,
    and a stack that is not all finite gives what ``qr`` gives."""
    rng = np.random.default_rng(5)
    for shape in ((1, 20, 3), (37, 20, 3), (4, 7, 2)):
        a = rng.normal(size=shape)
        for m in (a, a.astype(np.float32)):
            got, want = _orthonormal_columns(m), np.linalg.qr(m)[0]
            assert got.dtype == want.dtype
            assert got.tobytes() == want.tobytes()
    a = rng.normal(size=(3, 20, 3))
    a[1, 4, 2] = np.inf
    np.testing.assert_array_equal(_orthonormal_columns(a), np.linalg.qr(a)[0])


def test_orthonormal_columns_without_numpys_gufuncs(monkeypatch: pytest.MonkeyPatch) -> None:
    """On a numpy whose private gufuncs are not those of 2.x, ``np.linalg.qr`` itself."""
    import lpc_core.perception.scans as scans

    monkeypatch.setattr(scans, "_QR_R_RAW", None)
    a = np.random.default_rng(6).normal(size=(5, 20, 3))
    assert _orthonormal_columns(a).tobytes() == np.linalg.qr(a)[0].tobytes()


def test_cut_finds_where_a_line_cut_at_the_capture_volumes_side_leaves_the_face() -> None:
    """A face sloping along x (z = 0.2 + 0.3 x), 120 x 60 mm, with nothing behind it: the
    line along x is cut at the capture volume's sides (x = +-50 mm) and leaves the face at
    its edges (x = +-60 mm), within a pixel (1.1 mm there) on the face's own depth; the
    lines' other ends lie inside the capture volume (the face's sides at y = +-30 mm): none."""
    xs, ys = INTR.pixel_rays()
    z = 0.2 / (1.0 - 0.3 * xs)  # the ray (xs, ys, 1) meets z = 0.2 + 0.3 x there
    face = (np.abs(xs * z) <= 0.06) & (np.abs(ys * z) <= 0.03)
    depth = np.where(face, np.rint(z / INTR.depth_scale), 0).astype(np.uint16)
    lines = cut_scan_lines(depth, INTR)
    edge = lines.edge_past_m
    assert edge is not None and edge.shape == (4, 2, 3)
    pixel = 0.2 / INTR.fx
    for point, x in ((edge[0, 0], -0.06), (edge[0, 1], 0.06)):
        assert point[0] == pytest.approx(x, abs=1.5 * pixel), edge[0]
        assert point[2] == pytest.approx(0.2 + 0.3 * point[0], abs=0.0005), edge[0]
        assert point[1] == pytest.approx(0.0, abs=1e-9)
    # The 90-degree line ends at the face's sides inside the capture volume, and the two
    # diagonal lines too.
    assert np.array_equal(edge[1:], np.zeros((3, 2, 3))), edge
    # A face wider than the walk past the side (40 px): the line never leaves it there.
    wide = np.where(np.abs(ys * z) <= 0.03, np.rint(z / INTR.depth_scale), 0).astype(np.uint16)
    assert np.array_equal(cut_scan_lines(wide, INTR).edge_past_m[0], np.zeros((2, 3)))
