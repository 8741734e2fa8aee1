"""3-D least-squares solids: recover known spheres, cylinders and planes from noisy patches."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lpc_core.perception.solids import (
    CylinderSolid,
    PlaneSolid,
    SphereSolid,
    best_cylinder_axis,
    einsum_norms,
    fit_circle_2d,
    hemisphere_directions,
    orthonormal_basis,
)

NOISE_M = 0.0003  # about the D435's range noise at 200 mm


def _cap(center: np.ndarray, radius: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """Points on the camera-facing half of a sphere, within 60 degrees of its front pole."""
    polar = rng.uniform(0, np.radians(60), n)
    azimuth = rng.uniform(0, 2 * np.pi, n)
    unit = np.column_stack(
        [np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), -np.cos(polar)]
    )
    return center + radius * unit + rng.normal(0, NOISE_M, (n, 3))


def _half_cylinder(
    center: np.ndarray, axis: np.ndarray, radius: float, n: int, rng: np.random.Generator
) -> np.ndarray:
    """Points on the side of a cylinder facing the camera (at the origin), 60 mm long."""
    axis = axis / np.linalg.norm(axis)
    toward = -center - (-center @ axis) * axis
    toward /= np.linalg.norm(toward)
    side = np.cross(axis, toward)
    along = rng.uniform(-0.03, 0.03, n)
    angle = rng.uniform(-np.radians(70), np.radians(70), n)
    radial = np.cos(angle)[:, None] * toward + np.sin(angle)[:, None] * side
    return center + along[:, None] * axis + radius * radial + rng.normal(0, NOISE_M, (n, 3))


def test_sphere_solid_recovers_cap() -> None:
    rng = np.random.default_rng(1)
    center = np.array([0.005, -0.01, 0.22])
    sphere = SphereSolid.estimate(_cap(center, 0.025, 300, rng))
    assert sphere
    assert np.linalg.norm(sphere.center - center) < 0.001
    assert sphere.radius == pytest.approx(0.025, abs=0.0005)


def test_sphere_solid_rejects_coplanar_points() -> None:
    rng = np.random.default_rng(2)
    flat = np.column_stack([rng.uniform(-0.02, 0.02, (50, 2)), np.full(50, 0.2)])
    assert not SphereSolid.estimate(flat)


def test_sphere_solid_rejects_bad_shape() -> None:
    with pytest.raises(ValueError, match="points"):
        SphereSolid.estimate(np.zeros((10, 2)))


@pytest.mark.parametrize(
    "guess_offset_deg", [0.0, 10.0, 25.0], ids=["exact", "10deg-off", "25deg-off"]
)
def test_cylinder_solid_recovers_axis_and_radius(guess_offset_deg: float) -> None:
    rng = np.random.default_rng(3)
    axis = np.array([np.cos(0.5), np.sin(0.5), 0.2])
    axis /= np.linalg.norm(axis)
    center = np.array([0.0, 0.005, 0.21])
    points = _half_cylinder(center, axis, 0.02, 300, rng)
    e1, _ = orthonormal_basis(axis)
    guess = np.cos(np.radians(guess_offset_deg)) * axis + np.sin(np.radians(guess_offset_deg)) * e1
    cylinder = CylinderSolid.estimate(points, guess, iterations=10)
    assert cylinder
    assert np.degrees(np.arccos(min(1.0, abs(cylinder.axis @ axis)))) < 1.0
    assert cylinder.radius == pytest.approx(0.02, abs=0.0005)
    assert np.median(cylinder.residuals(points)) < 2 * NOISE_M


def test_cylinder_solid_rejects_zero_axis() -> None:
    with pytest.raises(ValueError, match="axis"):
        CylinderSolid.estimate(np.random.default_rng(0).normal(size=(10, 3)), np.zeros(3))


def test_best_cylinder_axis_finds_axis_within_grid_spacing() -> None:
    rng = np.random.default_rng(4)
    axis = np.array([0.0, 1.0, 0.0])
    points = _half_cylinder(np.array([0.0, 0.0, 0.2]), axis, 0.03, 200, rng)
    found, count = best_cylinder_axis(points, hemisphere_directions(200), 0.0015)
    assert np.degrees(np.arccos(min(1.0, abs(found @ axis)))) < 15.0
    assert count > 150


def test_best_cylinder_axis_skips_circles_outside_the_radius_limits() -> None:
    rng = np.random.default_rng(4)
    axis = np.array([0.0, 1.0, 0.0])
    points = _half_cylinder(np.array([0.0, 0.0, 0.2]), axis, 0.03, 200, rng)
    found, count = best_cylinder_axis(points, hemisphere_directions(200), 0.0015, (0.005, 0.05))
    assert np.degrees(np.arccos(min(1.0, abs(found @ axis)))) < 15.0
    assert count > 150
    # A gently curved sheet (radius 0.5 m): its circles hold every point, all too wide.
    sheet = _half_cylinder(np.array([0.0, 0.0, 0.7]), axis, 0.5, 4000, rng)
    sheet = sheet[np.abs(sheet[:, 0]) < 0.04]
    _, wide = best_cylinder_axis(sheet, hemisphere_directions(200), 0.0015)
    _, within = best_cylinder_axis(sheet, hemisphere_directions(200), 0.0015, (0.005, 0.05))
    assert wide > 0.9 * len(sheet)
    assert within < 0.5 * len(sheet)


def test_plane_solid_normal_faces_camera() -> None:
    rng = np.random.default_rng(5)
    normal = np.array([0.3, -0.2, -1.0])
    normal /= np.linalg.norm(normal)
    e1, e2 = orthonormal_basis(normal)
    uv = rng.uniform(-0.02, 0.02, (100, 2))
    points = np.array([0, 0, 0.2]) + uv[:, :1] * e1 + uv[:, 1:] * e2
    plane = PlaneSolid.estimate(points + rng.normal(0, NOISE_M, points.shape))
    assert plane
    assert plane.normal @ normal > 0.999
    assert plane.normal[2] < 0


def test_plane_solid_rejects_collinear_points() -> None:
    t = np.linspace(0, 0.05, 20)
    assert not PlaneSolid.estimate(np.column_stack([t, 2 * t, 0.2 + t]))


def test_fit_circle_2d_exact_and_degenerate() -> None:
    angle = np.linspace(0, 2, 12)
    uv = np.column_stack([0.01 + 0.03 * np.cos(angle), -0.02 + 0.03 * np.sin(angle)])
    got = fit_circle_2d(uv)
    assert got is not None
    assert np.allclose(got[0], [0.01, -0.02], atol=1e-9) and got[1] == pytest.approx(0.03)
    assert fit_circle_2d(np.column_stack([angle, 2 * angle])) is None


def test_hemisphere_directions_are_unit_and_face_forward() -> None:
    dirs = hemisphere_directions(50)
    assert dirs.shape == (50, 3)
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
    assert (dirs[:, 2] >= 0).all()
    with pytest.raises(ValueError, match="count"):
        hemisphere_directions(0)


def test_silhouette_distance_sphere_and_cylinder() -> None:
    centre, r = np.array([0.0, 0.0, 0.2]), 0.02
    half = math.asin(r / 0.2)  # the silhouette cone's half angle
    sphere = SphereSolid(center=centre, radius=r)
    front = np.array([[0.0, 0.0, 0.18]])
    rim = np.array([[math.sin(half), 0.0, math.cos(half)]]) * math.sqrt(0.2**2 - r**2)
    beyond = np.array([[math.tan(half + 0.01), 0.0, 1.0]]) * 0.19
    got = sphere.silhouette_distance(np.concatenate([front, rim, beyond]))
    np.testing.assert_allclose(got, [half, 0.0, -0.01], atol=1e-9)
    # A cylinder along y: the same in every cross-section, scaled by the point's distance
    # across the axis over its range (the angle it subtends in view).
    cylinder = CylinderSolid(point=centre, axis=np.array([0.0, 1.0, 0.0]), radius=r)
    up = np.array([0.0, 0.05, 0.0])
    np.testing.assert_allclose(cylinder.silhouette_distance(rim + up), [0.0], atol=1e-9)
    np.testing.assert_allclose(
        cylinder.silhouette_distance(front + up),
        [half * 0.18 / math.hypot(0.18, 0.05)],
        atol=1e-9,
    )
    # A camera inside the solid sees no silhouette.
    assert np.isinf(SphereSolid(center=centre, radius=0.3).silhouette_distance(front)).all()


def test_silhouette_distance_matches_cross_product_form() -> None:
    rng = np.random.default_rng(8)
    points = rng.normal(size=(40, 3)) * 0.02 + [0.0, 0.0, 0.2]
    centre = np.array([0.003, -0.002, 0.22])
    got = SphereSolid(center=centre, radius=0.02).silhouette_distance(points)
    cross = np.cross(points, centre)
    off = np.arctan2(np.sqrt(np.einsum("ij,ij->i", cross, cross)), points @ centre)
    assert np.array_equal(got, math.asin(0.02 / math.sqrt(centre @ centre)) - off)


def test_round_distances_match_the_whole_array_forms() -> None:
    """The sphere's residuals and the cylinder's residuals and silhouette distances, worked
    column by column, are the bits of the (N, 3) forms (np.einsum's squared norms for the
    cylinder's), on contiguous points and on a transposed (Fortran-ordered) array alike."""
    rng = np.random.default_rng(9)
    for k in range(20):
        points = rng.normal(size=(int(rng.integers(5, 300)), 3)) * 0.02 + [0.0, 0.0, 0.2]
        if k % 2:
            points = np.asfortranarray(points)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        centre, r = rng.normal(size=3) * 0.01 + [0.0, 0.0, 0.22], 0.02
        w = points - centre
        assert np.array_equal(
            SphereSolid(center=centre, radius=r).residuals(points),
            np.abs(np.sqrt((w * w).sum(axis=1)) - r),
        )
        cylinder = CylinderSolid(point=centre, axis=axis, radius=r)
        q = w - (w @ axis)[:, None] * axis
        assert np.array_equal(
            cylinder.residuals(points), np.abs(np.sqrt(np.einsum("ij,ij->i", q, q)) - r)
        )
        across = points - (points @ axis)[:, None] * axis
        c = centre - (centre @ axis) * axis
        cross = np.cross(across, c)
        off = np.arctan2(np.sqrt(np.einsum("ij,ij->i", cross, cross)), across @ c)
        angle = math.asin(r / math.sqrt(c @ c)) - off
        scale = np.einsum("ij,ij->i", across, across) / np.einsum("ij,ij->i", points, points)
        assert np.array_equal(cylinder.silhouette_distance(points), angle * np.sqrt(scale))


def test_einsum_norms_are_einsums_bits_in_either_precision() -> None:
    """Row-wise squared norms as ``np.einsum("ij,ij->i", d, d)`` gives them, to the bit, on
    float64 rows (summed (x^2 + z^2) + y^2), on float32 rows (which einsum sums in turn: a
    float32 array through the float64 order differs on about a fifth of its rows) and on a
    transposed array."""
    rng = np.random.default_rng(12)
    for dtype in (np.float64, np.float32):
        for k in range(10):
            d = (rng.normal(size=(int(rng.integers(1, 400)), 3)) * 0.2).astype(dtype)
            if k % 2:
                d = np.asfortranarray(d)
            got = einsum_norms(d)
            assert got.dtype == dtype
            assert np.array_equal(got, np.einsum("ij,ij->i", d, d))


def test_cylinder_offsets_are_signed_distances_from_the_surface() -> None:
    axis = np.array([0.0, 1.0, 0.0])
    cylinder = CylinderSolid(point=np.array([0.0, 0.0, 0.2]), axis=axis, radius=0.02)
    points = np.array([[0.0, 0.5, 0.2], [0.03, -0.1, 0.2], [0.0, 0.0, 0.21]])
    assert np.allclose(cylinder.offsets(points), [-0.02, 0.01, -0.01], atol=1e-15)
    assert np.array_equal(cylinder.residuals(points), np.abs(cylinder.offsets(points)))


def test_solve_gives_numpys_bits_and_raises_on_a_singular_system() -> None:
    """The sphere's and cylinder's steps solve through LAPACK's dgesv directly: the same
    floats numpy.linalg.solve gives, on the normal equations of random Jacobians."""
    from lpc_core.perception.solids import _solve

    rng = np.random.default_rng(3)
    for size in (4, 5):
        for _ in range(200):
            jacobian = rng.normal(size=(40, size)) * rng.uniform(1e-3, 1e3, size)
            a, b = jacobian.T @ jacobian, rng.normal(size=size)
            assert _solve(a, b) == np.linalg.solve(a, b).tolist()
    # A normal matrix's strided corner, as the sphere's step takes it.
    aug = rng.normal(size=(5, 30))
    normal = aug @ aug.T
    assert (
        _solve(normal[:4, :4], normal[:4, 4])
        == np.linalg.solve(normal[:4, :4], normal[:4, 4]).tolist()
    )
    with pytest.raises(np.linalg.LinAlgError):
        _solve(np.zeros((4, 4)), np.ones(4))
    with pytest.raises(np.linalg.LinAlgError):
        _solve(np.ones((5, 5)), np.ones(5))
