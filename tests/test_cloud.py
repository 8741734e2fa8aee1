"""Tests of lpc_core.perception.cloud, the full-point-cloud benchmark method.

Frames come from a small ray caster below (primitives seen by the 424x240 D435 stand-in, range
noise 0.3 mm RMS, 1 mm quantisation), so these tests do not depend on lpc_core.sim.scene.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import pytest
from scipy import ndimage

from lpc_core.perception.cloud import (
    CloudParams,
    CylinderModel,
    PlaneModel,
    SphereModel,
    _aimed_past,
    _camera_facing,
    _column_counts,
    _contiguous,
    _facing_passes,
    _flattened_flanks,
    _support_refit,
    _within_support,
    crop_points,
    estimate_normals,
    find_support,
    find_support_plane,
    fit_cuboid,
    fit_cylinder,
    fit_sphere,
    grid_clusters,
    nearest_segment,
    plane_hypotheses,
    reconstruct_cloud,
    smallest_eigenvectors,
    support_hypotheses,
    voxel_downsample,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from lpc_core.perception.reconstruction import Reconstruction
    from lpc_core.sim.stereo import StereoSensor
    from services.cli._laser_views import View
from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.solids import PlaneSolid, silhouette_distance

INTR = Intrinsics()
PARAMS = CloudParams()
# The ray caster's edges are exact (no matching window fattens them): no stereo trim.
EXACT_EDGES = CloudParams(edge_fattening_px=0.0)

# --------------------------------------------------------------------------- ray caster


def _directions() -> np.ndarray:
    rx, ry = INTR.pixel_rays()
    return np.stack([rx, ry, np.ones_like(rx)], axis=-1)  # z = 1, so the hit distance is z


def _hit_sphere(center: tuple[float, float, float], radius: float) -> np.ndarray:
    d, c = _directions(), np.asarray(center)
    a, b = (d * d).sum(-1), -2 * d @ c
    disc = b * b - 4 * a * (c @ c - radius**2)
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / (2 * a)
    return np.where(disc >= 0, t, np.inf)


def _hit_plane(normal: tuple[float, float, float], point: tuple[float, float, float]):
    n = np.asarray(normal, dtype=float)
    with np.errstate(divide="ignore"):
        t = (n @ np.asarray(point)) / (_directions() @ n)
    return np.where(t > 0, t, np.inf)


def _hit_box(center, rotation: np.ndarray, size) -> np.ndarray:
    half = np.asarray(size) / 2
    origin = rotation.T @ -np.asarray(center, dtype=float)
    d = _directions() @ rotation
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - origin) / d, (half - origin) / d
    near, far = np.minimum(t1, t2).max(-1), np.maximum(t1, t2).min(-1)
    return np.where((far >= near) & (near > 0), near, np.inf)


def _hit_cylinder(center, axis, radius: float, length: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    d = _directions()
    o = -np.asarray(center, dtype=float)
    d_perp = d - (d @ axis)[..., None] * axis
    o_perp = o - (o @ axis) * axis
    a, b = (d_perp**2).sum(-1), 2 * d_perp @ o_perp
    disc = b * b - 4 * a * (o_perp @ o_perp - radius**2)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-b - np.sqrt(disc)) / (2 * a)
        t = np.where((disc >= 0) & (np.abs(o @ axis + t * (d @ axis)) <= length / 2), t, np.inf)
        for end in (-length / 2, length / 2):
            tc = (end - o @ axis) / (d @ axis)
            rim = o_perp + tc[..., None] * d_perp
            t = np.where(((rim**2).sum(-1) <= radius**2) & (tc > 0), np.minimum(t, tc), t)
    return t


def _frame(*hits: np.ndarray, seed: int = 0, noise_m: float = 0.0003) -> np.ndarray:
    z = np.minimum.reduce(hits)
    z = z + np.random.default_rng(seed).normal(0.0, noise_m, z.shape)
    return np.where(np.isfinite(z), np.rint(z / INTR.depth_scale), 0).astype(np.uint16)


def _fattened(z: np.ndarray, k_px: int, baseline_m: float = 0.05) -> np.ndarray:
    """Exact depth as a block matcher with a (2k+1)-pixel window sees it: a pixel within k
    pixels of one nearer by more than a pixel of disparity (z^2 / (f B)) takes that nearer
    depth (edge fattening, and a curved rim pulled toward its front)."""
    offsets = np.arange(-k_px, k_px + 1)
    disc = np.hypot(offsets[:, None], offsets[None, :]) <= k_px + 0.5
    nearest = ndimage.minimum_filter(z, footprint=disc, mode="nearest")
    with np.errstate(invalid="ignore"):
        step = z - nearest > nearest**2 / (INTR.fx * baseline_m)
    return np.where(step, nearest, z)


def _rotation(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _segment(depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The voxelised cloud of a frame holding one object and nothing else, with normals."""
    cloud, _ = voxel_downsample(crop_points(depth, INTR, PARAMS), PARAMS.voxel_m)
    return cloud, estimate_normals(cloud, PARAMS.normal_neighbours)


def _angle_error_deg(a: float, b: float) -> float:
    return float(np.degrees(abs((a - b + np.pi / 2) % np.pi - np.pi / 2)))


# --------------------------------------------------------------------------- steps


def _functional_frame(
    sensor: StereoSensor, name: str, trial: int, frame: int
) -> tuple[View, Reconstruction]:
    """The stereo frame ``(trial, frame)`` of the functional object ``name`` seen by
    ``sensor`` (2 trials x 5 frames, seed 0), and the full cloud's result on it."""
    from services.cli import _laser_views as lv

    views = lv.views("functional", 2, 5, 0, names=[name], sensor=sensor)
    view = next(v for v in views if (v.trial, v.frame) == (trial, frame))
    return view, reconstruct_cloud(view.depth, INTR, seed=view.seq)


def test_voxel_downsample_counts_points_on_a_grid():
    # A 1 mm lattice of 10x10x10 points, cell centres at 0.5 mm: eight points per 2 mm voxel.
    axis = (np.arange(10) + 0.5) * 0.001
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3) + 0.1
    centroids, counts = voxel_downsample(points, 0.002)
    assert len(centroids) == 125
    assert np.all(counts == 8)
    assert counts.sum() == len(points)
    offsets = (centroids - 0.1) / 0.001  # voxel centres sit at 1, 3, 5, 7, 9 mm
    np.testing.assert_allclose(offsets, np.rint(offsets), atol=1e-6)
    assert set(np.rint(offsets).ravel().astype(int)) == {1, 3, 5, 7, 9}


def test_voxel_downsample_empty_and_bad_voxel():
    centroids, counts = voxel_downsample(np.empty((0, 3)), 0.002)
    assert centroids.shape == (0, 3) and counts.shape == (0,)
    with pytest.raises(ValueError, match="voxel_m"):
        voxel_downsample(np.zeros((3, 3)), 0.0)
    with pytest.raises(ValueError, match="points"):
        voxel_downsample(np.zeros((3, 2)), 0.002)


def test_crop_points_keeps_only_the_crop_box():
    depth = np.full((INTR.height, INTR.width), 200, dtype=np.uint16)
    depth[:, :10] = 400  # beyond z 315 mm
    points = crop_points(depth, INTR, PARAMS)
    assert len(points) > 0
    assert np.all(np.abs(points[:, :2]) <= 0.1 + 1e-12)
    np.testing.assert_allclose(points[:, 2], 0.2)


def test_smallest_eigenvectors_matches_eigh():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(500, 3, 3))
    cov = a @ a.transpose(0, 2, 1)
    got = smallest_eigenvectors(cov)
    want = np.linalg.eigh(cov)[1][:, :, 0]
    np.testing.assert_allclose(np.abs((got * want).sum(axis=1)), 1.0, atol=1e-6)


def test_find_support_plane_removes_the_table_under_a_ball():
    depth = _frame(_hit_sphere((0.0, 0.0, 0.2), 0.03), _hit_plane((0, 0, 1), (0, 0, 0.23)))
    cloud, _ = voxel_downsample(crop_points(depth, INTR, PARAMS), PARAMS.voxel_m)
    mask = find_support_plane(cloud, PARAMS, np.random.default_rng(0))
    assert mask is not None
    on_table = cloud[:, 2] > 0.2285
    assert mask[on_table].mean() > 0.98
    assert mask[cloud[:, 2] < 0.22].mean() < 0.01  # the ball stays


def test_find_support_gives_its_fit_of_the_support_points():
    """Where the search's refit kept the points it was fitted on, ``find_support`` hands that
    fit over: the plane ``PlaneSolid.estimate`` fits to the support's points, to the bit."""
    depth = _frame(_hit_sphere((0.0, 0.0, 0.2), 0.03), _hit_plane((0, 0, 1), (0, 0, 0.23)))
    cloud, _ = voxel_downsample(crop_points(depth, INTR, PARAMS), PARAMS.voxel_m)
    found = find_support(cloud, PARAMS, np.random.default_rng(0))
    assert found is not None and found.plane is not None
    assert np.array_equal(found.mask, find_support_plane(cloud, PARAMS, np.random.default_rng(0)))
    own = PlaneSolid.estimate(cloud[found.mask])
    assert found.plane.point.tolist() == own.point.tolist()
    assert found.plane.normal.tolist() == own.normal.tolist()
    np.testing.assert_allclose(found.plane.normal, [0.0, 0.0, -1.0], atol=1e-3)  # the table


def test_find_support_plane_skips_a_box_face_with_the_table_behind_it():
    # The box's front face is bigger than the visible table, but the table lies behind it.
    box = _hit_box((0.0, 0.0, 0.2 + 0.02), np.eye(3), (0.13, 0.13, 0.04))
    depth = _frame(box, _hit_plane((0, 0, 1), (0, 0, 0.28)))
    cloud, _ = voxel_downsample(crop_points(depth, INTR, PARAMS), PARAMS.voxel_m)
    front = cloud[:, 2] < 0.205
    assert front.sum() > (cloud[:, 2] > 0.275).sum()
    mask = find_support_plane(cloud, PARAMS, np.random.default_rng(0))
    assert mask is not None
    assert not mask[front].any()
    assert mask[cloud[:, 2] > 0.275].mean() > 0.98


def test_find_support_plane_on_shared_hypotheses_is_the_search_it_replaces():
    """The four-line method draws a frame's support planes once for both its table searches
    (``support_hypotheses``): each search on them finds the mask its own draws find, for
    every fraction allowed behind, on all the points and on a sample of them."""
    box = _hit_box((0.0, 0.0, 0.2 + 0.02), np.eye(3), (0.13, 0.13, 0.04))
    depth = _frame(box, _hit_plane((0, 0, 1), (0, 0, 0.28)))
    cloud, _ = voxel_downsample(crop_points(depth, INTR, PARAMS), PARAMS.voxel_m)
    found = 0
    for size in (300, len(cloud)):  # under and over score_sample's 384
        points = cloud[np.random.default_rng(1).permutation(len(cloud))[:size]]
        shared = support_hypotheses(points, PARAMS, np.random.default_rng(0))
        assert shared is not None and shared.sampled == (size > PARAMS.score_sample)
        for fraction in (0.0, 0.03, 1.0):
            search = replace(PARAMS, support_max_behind_fraction=fraction)
            own = find_support_plane(points, search, np.random.default_rng(0))
            again = find_support_plane(points, search, np.random.default_rng(5), shared)
            assert (own is None) == (again is None)
            if own is not None:
                found += 1
                assert np.array_equal(own, again)
    assert found >= 2
    assert support_hypotheses(cloud[:149], PARAMS, np.random.default_rng(0)) is None


def test_find_support_plane_none_for_a_lone_ball():
    depth = _frame(_hit_sphere((0.0, 0.0, 0.2), 0.03))
    cloud, _ = voxel_downsample(crop_points(depth, INTR, PARAMS), PARAMS.voxel_m)
    assert find_support_plane(cloud, PARAMS, np.random.default_rng(0)) is None


def test_the_support_refit_is_plane_models_plane() -> None:
    """The support search refits its best hypothesis with PlaneSolid's closed-form eigenvector
    where PlaneModel's SVD gives the same plane: normal away from the camera, offset, to 1e-12;
    through the camera (a scan line's own plane) and on collinear points, PlaneModel decides."""
    rng = np.random.default_rng(3)
    uv = rng.uniform(-0.08, 0.08, (120, 2))
    table = np.column_stack([uv[:, 0], 0.06 + 0.3 * uv[:, 1], 0.3 + uv[:, 1]])
    table += rng.normal(0.0, 0.001, table.shape)
    normal, offset = _support_refit(table)
    model = PlaneModel.estimate(table)
    np.testing.assert_allclose(normal, model.normal, atol=1e-12)
    assert offset == pytest.approx(model.offset, abs=1e-12)
    assert offset < 0  # the camera's side: behind is n . p + d > 0
    # One scan line's samples lie in a plane through the optical axis (offset 0): which side
    # is behind is the SVD's sign, as before.
    line = np.column_stack([uv[:, 0], np.zeros(120), 0.3 + 0.5 * uv[:, 1] ** 2])
    through = _support_refit(line)
    model = PlaneModel.estimate(line)
    assert through is not None
    np.testing.assert_array_equal(through[0], model.normal)
    assert through[1] == model.offset
    straight = np.column_stack([uv[:, 0], np.full(120, 0.05), np.full(120, 0.3)])
    assert _support_refit(straight) is None
    assert _support_refit(table[:2]) is None


def test_plane_hypotheses_are_the_triples_planes_facing_away_from_the_camera() -> None:
    # Against np.cross and np.linalg.norm, degenerate triples (a repeated point, three
    # collinear) flagged.
    rng = np.random.default_rng(5)
    table = np.column_stack([rng.uniform(-0.05, 0.05, (300, 2)), rng.normal(0.25, 0.002, 300)])
    table[7] = table[3]
    table[11] = 0.5 * (table[3] + table[9])
    picks = rng.integers(0, len(table), size=(64, 3))
    picks[0] = (3, 7, 9)
    picks[1] = (3, 9, 11)
    normals, offsets, valid = plane_hypotheses(table, picks)
    assert not valid[0] and not valid[1] and valid[2:].all()
    p0, p1, p2 = (table[picks[:, i]] for i in range(3))
    cross = np.cross(p1 - p0, p2 - p0)[2:]
    unit = cross / np.linalg.norm(cross, axis=1)[:, None]
    unit *= np.where(np.einsum("ij,ij->i", unit, p0[2:]) < 0, -1.0, 1.0)[:, None]
    np.testing.assert_allclose(normals.T[2:], unit, rtol=0, atol=1e-12)
    np.testing.assert_allclose(offsets[2:], -np.einsum("ij,ij->i", unit, p0[2:]), atol=1e-12)
    assert (offsets[2:] <= 0).all()  # the camera (the origin) on the normals' negative side


def test_grid_clusters_separates_objects_30mm_apart():
    # Two balls of 25 mm radius whose surfaces are 30 mm apart.
    depth = _frame(_hit_sphere((-0.04, 0.0, 0.2), 0.025), _hit_sphere((0.04, 0.0, 0.2), 0.025))
    cloud, _ = voxel_downsample(crop_points(depth, INTR, PARAMS), PARAMS.voxel_m)
    labels = grid_clusters(cloud, PARAMS.cluster_cell_m)
    big = np.flatnonzero(np.bincount(labels) >= 100)
    assert len(big) == 2
    left = labels == labels[np.argmin(cloud[:, 0])]
    assert np.all(cloud[left, 0] < 0) and np.all(cloud[~left & np.isin(labels, big), 0] > 0)


def test_grid_clusters_joins_within_a_cell_and_splits_beyond_two_diagonals():
    cell = 0.004
    # Along a line: steps of 3.9 mm always join; a 14 mm gap (> 2 sqrt(3) cells) never does.
    x = np.concatenate([np.arange(10) * 0.0039, 0.0351 + 0.014 + np.arange(10) * 0.0039])
    for shift in (0.0, 0.0013, 0.0027):
        points = np.column_stack([x + shift, np.full(20, 0.01), np.full(20, 0.2)])
        labels = grid_clusters(points, cell)
        assert len(set(labels[:10])) == 1 and len(set(labels[10:])) == 1
        assert labels[0] != labels[10]
    assert grid_clusters(np.empty((0, 3)), cell).shape == (0,)
    with pytest.raises(ValueError, match="cell_m"):
        grid_clusters(np.zeros((2, 3)), 0.0)


def test_nearest_segment_picks_the_one_on_the_axis_and_skips_small_ones():
    depth = _frame(
        _hit_sphere((-0.05, 0.0, 0.2), 0.025),  # beside the axis
        _hit_sphere((0.03, 0.0, 0.25), 0.03),  # on the axis, farther
        _hit_sphere((0.0, 0.0, 0.13), 0.002),  # on the axis and nearest, but tiny
    )
    cloud, _ = voxel_downsample(crop_points(depth, INTR, PARAMS), PARAMS.voxel_m)
    labels = grid_clusters(cloud, PARAMS.cluster_cell_m)
    mask = nearest_segment(cloud, labels, 100, PARAMS.pierce_tolerance_m)
    assert mask is not None
    assert np.all(cloud[mask, 2] > 0.215) and np.mean(cloud[mask, 0]) > 0
    assert nearest_segment(cloud, labels, 100_000, PARAMS.pierce_tolerance_m) is None


# --------------------------------------------------------------------------- models


def test_plane_model_estimate_faces_away_from_the_camera():
    rng = np.random.default_rng(0)
    uv = rng.uniform(-0.05, 0.05, (200, 2))
    model = PlaneModel.estimate(np.column_stack([uv, 0.2 + 0.1 * uv[:, 0]]))
    assert model and model.offset < 0
    assert model.residuals(np.array([[0.0, 0.0, 0.2]]))[0] < 1e-12
    assert not PlaneModel.estimate(np.zeros((2, 3)))


def test_sphere_model_estimate_fails_on_coplanar_points():
    rng = np.random.default_rng(0)
    flat = np.column_stack([rng.uniform(size=(20, 2)), np.zeros(20)])
    failed = SphereModel.estimate(flat)
    assert not failed and "coplanar" in failed.reason


def test_cylinder_model_needs_normals():
    failed = CylinderModel.estimate(np.zeros((5, 3)))
    assert not failed and "normals" in failed.reason


def test_fit_sphere_recovers_radius_from_a_noisy_frame():
    cloud, normals = _segment(_frame(_hit_sphere((0.01, -0.005, 0.21), 0.032), seed=3))
    fit = fit_sphere(cloud, normals, PARAMS, np.random.default_rng(0))
    assert fit
    assert abs(fit.model.radius - 0.032) < 0.001
    np.testing.assert_allclose(fit.model.center, (0.01, -0.005, 0.21), atol=0.0015)
    assert fit.inliers.mean() > 0.8


@pytest.mark.parametrize("angle_deg", [-60.0, 0.0, 35.0, 90.0])
def test_fit_cylinder_recovers_radius_and_axis(angle_deg):
    a = np.radians(angle_deg)
    axis = _rotation((-np.sin(a), np.cos(a), 0), np.radians(20)) @ (np.cos(a), np.sin(a), 0)
    depth = _frame(_hit_cylinder((0.0, 0.0, 0.2), axis, 0.025, 0.2), seed=4)
    cloud, normals = _segment(depth)
    fit = fit_cylinder(cloud, normals, PARAMS, np.random.default_rng(1))
    assert fit
    assert abs(fit.model.radius - 0.025) < 0.001
    assert np.degrees(np.arccos(min(1.0, abs(fit.model.axis @ axis)))) < 3.0
    assert fit.inliers.mean() > 0.8


def test_fit_cuboid_finds_three_perpendicular_faces():
    rotation = _rotation((1, 1, 0), np.radians(35)) @ _rotation((0, 0, 1), np.radians(20))
    depth = _frame(_hit_box((0.0, 0.0, 0.23), rotation, (0.06, 0.05, 0.07)), seed=5)
    cloud, normals = _segment(depth)
    fit = fit_cuboid(cloud, normals, PARAMS, np.random.default_rng(2))
    assert fit and len(fit.faces) == 3
    for face in fit.faces:  # each face normal is one of the box's axes
        assert np.degrees(np.arccos(min(1.0, np.abs(rotation.T @ face.normal).max()))) < 3.0
    assert fit.inliers.mean() > 0.9


# --------------------------------------------------------------------------- whole frames


def test_reconstruct_cloud_ball_on_a_table():
    depth = _frame(_hit_sphere((0.005, 0.0, 0.2), 0.03), _hit_plane((0, -1, 1), (0, 0.0, 0.24)))
    result = reconstruct_cloud(depth, INTR, seed=7)
    assert result.shape == "sphere" and result.method == "cloud"
    assert abs(result.grasp_width_m - 0.06) < 0.003
    assert result.wrist_angle_rad is None
    assert result.points == len(voxel_downsample(crop_points(depth, INTR, PARAMS), 0.002)[0])
    assert result.extra["raw_points"] > result.points > result.extra["segment_points"]
    assert result.extra["support_points"] > 1000


@pytest.mark.parametrize("angle_deg", [-45.0, 10.0, 80.0])
def test_reconstruct_cloud_cylinder_lying_on_a_table(angle_deg):
    a = np.radians(angle_deg)
    axis = np.array([np.cos(a), np.sin(a), 0.0])
    depth = _frame(
        _hit_cylinder((0.0, 0.0, 0.2), axis, 0.02, 0.14), _hit_plane((0, 0, 1), (0, 0, 0.22))
    )
    result = reconstruct_cloud(depth, INTR, seed=8)
    assert result.shape == "cylinder"
    assert abs(result.grasp_width_m - 0.04) < 0.003
    assert _angle_error_deg(result.wrist_angle_rad, a) < 3.0


def test_reconstruct_cloud_box_reports_the_pierced_face():
    # Front face 40 x 120 mm, long side at 30 degrees in the image; the box is 50 mm deep.
    rotation = _rotation((0, 0, 1), np.radians(30))
    depth = _frame(
        _hit_box((0.0, 0.0, 0.225), rotation, (0.12, 0.04, 0.05)),
        _hit_plane((0, 0, 1), (0, 0, 0.25)),
    )
    result = reconstruct_cloud(depth, INTR, EXACT_EDGES, seed=9)
    assert result.shape == "cuboid"
    assert abs(result.grasp_width_m - 0.04) < 0.004
    assert _angle_error_deg(result.wrist_angle_rad, np.radians(30)) < 3.0


def test_reconstruct_cloud_forgives_aiming_beside_the_object():
    # The benchmark needs the object only near the axis: a ball 45 mm to the side is taken.
    depth = _frame(_hit_sphere((0.045, -0.01, 0.2), 0.02), _hit_plane((0, 0, 1), (0, 0, 0.22)))
    result = reconstruct_cloud(depth, INTR, seed=2)
    assert result.shape == "sphere"
    assert abs(result.grasp_width_m - 0.04) < 0.003
    np.testing.assert_allclose(result.center_m, (0.045, -0.01, 0.2), atol=0.002)


def test_reconstruct_cloud_keeps_a_lone_face_that_looks_like_a_support():
    # Seen square on with nothing behind it, a box's face passes the support-plane test;
    # removing it would leave nothing, so it stays and is fitted.
    depth = _frame(_hit_box((0.0, 0.0, 0.22), np.eye(3), (0.05, 0.09, 0.04)))
    result = reconstruct_cloud(depth, INTR, EXACT_EDGES, seed=4)
    assert result.shape == "cuboid"
    assert abs(result.grasp_width_m - 0.05) < 0.004
    assert _angle_error_deg(result.wrist_angle_rad, np.pi / 2) < 3.0


def test_reconstruct_cloud_puts_back_a_face_taken_for_the_table_with_a_stray_through_it():
    # A lone box face (the table behind it unmatched, as BM's texture check leaves it) passes
    # the support-plane test; a stray slab of mismatches beside it, off the axis, straddles
    # its plane. Nothing to grasp reaches through its table: the face is put back and fitted
    # (on main the slab was taken, 29.6 mm wide).
    face = _hit_box((0.0, 0.0, 0.22), np.eye(3), (0.09, 0.2, 0.04))
    stray = _hit_box((0.08, 0.0, 0.206), _rotation((0, 1, 0), np.radians(60)), (0.03, 0.03, 0.003))
    result = reconstruct_cloud(_frame(face, stray, seed=4), INTR, EXACT_EDGES, seed=4)
    assert result.shape == "cuboid"
    assert abs(result.grasp_width_m - 0.09) < 0.004
    assert result.extra["support_points"] == 0.0


def test_reconstruct_cloud_puts_back_a_face_taken_for_the_table_with_a_band_of_it_bent_off():
    # A lone box face (no table matched) passes the support-plane test; a band across it lies
    # 4 mm nearer (a matcher bent its depth off the plane), beside the axis. The band stays
    # within 10 mm of the plane: it rests on nothing, the face is put back and fitted (on
    # main the band was taken, 29.3 mm wide for 90).
    face = _hit_box((0.0, 0.0, 0.22), np.eye(3), (0.09, 0.2, 0.04))
    band = _hit_box((0.0, -0.06, 0.216), np.eye(3), (0.09, 0.03, 0.04))
    result = reconstruct_cloud(_frame(face, band, seed=4), INTR, EXACT_EDGES, seed=4)
    assert result.shape == "cuboid"
    assert abs(result.grasp_width_m - 0.09) < 0.004
    assert result.extra["support_points"] == 0.0


def _flat_patch(xs: tuple[float, float], ys: tuple[float, float], z: float) -> np.ndarray:
    """Points 2 mm apart on a patch across the optical axis at depth ``z``."""
    x, y = np.meshgrid(np.arange(*xs, 0.002), np.arange(*ys, 0.002))
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def test_within_support_is_a_band_of_the_plane_not_an_object_on_it() -> None:
    face = _flat_patch((-0.03, 0.03), (-0.02, 0.02), 0.16)
    band = _flat_patch((0.0, 0.02), (0.0, 0.01), 0.155)
    assert _within_support(band, face, PARAMS)
    # The jar cap, 15 mm high, lying on its table: it rests on the plane.
    cap = band - np.array([0.0, 0.0, 0.01])
    assert not _within_support(cap, face, PARAMS)
    # Larger than the plane: the rest of a lying can around the band of it taken for a plane.
    assert not _within_support(face, band, PARAMS)


def test_reconstruct_cloud_can_with_its_lid_in_view():
    # An upright can (axis along -y) seen 40 degrees from above: side and lid in view.
    axis = _rotation((1, 0, 0), np.radians(40)) @ (0.0, -1.0, 0.0)
    depth = _frame(_hit_cylinder((0.0, 0.03, 0.24), axis, 0.0375, 0.1), seed=6)
    result = reconstruct_cloud(depth, INTR, seed=5)
    assert result.shape == "cylinder"
    assert abs(result.grasp_width_m - 0.075) < 0.003
    assert result.extra["cylinder_fraction"] > 0.85


def test_reconstruct_cloud_is_reproducible_for_a_seed():
    depth = _frame(_hit_sphere((0.0, 0.0, 0.2), 0.025), _hit_plane((0, 0, 1), (0, 0, 0.225)))
    assert reconstruct_cloud(depth, INTR, seed=3) == reconstruct_cloud(depth, INTR, seed=3)


def test_reconstruct_cloud_from_a_depth_frame_message():
    # What the reconstructor service does with --method cloud: decode, then call.
    from lpc_core.perception.pipeline import (
        depth_image,
        intrinsics_from_message,
        intrinsics_to_message,
    )
    from schemas import DepthFrame, decode, encode, to_wire

    depth = _frame(_hit_sphere((0.0, 0.0, 0.2), 0.025), _hit_plane((0, 0, 1), (0, 0, 0.225)))
    message = DepthFrame(
        seq=41, t_ns=1, intrinsics=intrinsics_to_message(INTR), depth=to_wire(depth)
    )
    frame = decode("lpc/camera/depth", encode(message))
    result = reconstruct_cloud(
        depth_image(frame), intrinsics_from_message(frame.intrinsics), seed=frame.seq
    )
    assert result == reconstruct_cloud(depth, INTR, seed=41)
    assert result.shape == "sphere"


def test_reconstruct_cloud_empty_frame_is_none_with_a_reason():
    result = reconstruct_cloud(np.zeros((INTR.height, INTR.width), np.uint16), INTR)
    assert result.shape == "none" and not result.ok
    assert "crop box" in result.reason and result.points == 0


def test_reconstruct_cloud_too_few_points_is_none_with_a_reason():
    depth = _frame(_hit_sphere((0.0, 0.0, 0.2), 0.004))  # a 8 mm bead: a few dozen voxels
    result = reconstruct_cloud(depth, INTR)
    assert result.shape == "none"
    assert "at least 100 points" in result.reason
    assert 0 < result.points < 100


def test_reconstruct_cloud_rejects_wrong_dtype_and_shape():
    with pytest.raises(ValueError, match="depth"):
        reconstruct_cloud(np.zeros((INTR.height, INTR.width), np.float32), INTR)
    with pytest.raises(ValueError, match="depth"):
        reconstruct_cloud(np.zeros((10, 10), np.uint16), INTR)
    with pytest.raises(ValueError, match="depth"):
        reconstruct_cloud([[0]], INTR)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("field", "value"),
    [("voxel_m", 0.0), ("fit_points", 0), ("crop_z_max_m", 0.1), ("min_inlier_fraction", 2.0)],
)
def test_cloud_params_rejects_bad_values(field, value):
    with pytest.raises(ValueError, match=field):
        CloudParams(**{field: value})


# --------------------------------------------------------------------------- edges


def _width_errors_mm(hits: tuple[np.ndarray, ...], truth_m: float, params: CloudParams):
    z = np.minimum.reduce(hits)
    errors = []
    for seed in range(3):
        result = reconstruct_cloud(_frame(z, seed=seed), INTR, params, seed=seed)
        assert result.grasp_width_m is not None, result.reason
        errors.append(1000 * (result.grasp_width_m - truth_m))
    return np.array(errors)


def test_reconstruct_cloud_ball_width_from_the_part_facing_the_camera():
    # A 3-pixel fattening (7 x 7 window) widens the fit on every inlier by several mm.
    ball = _fattened(np.minimum(_hit_sphere((0.0, 0.0, 0.2), 0.02),
                                _hit_plane((0, 0, 1), (0, 0, 0.3))), 3)  # fmt: skip
    every_inlier = CloudParams(silhouette_margin_px=0.0)
    assert _width_errors_mm((ball,), 0.04, every_inlier).min() > 3.0
    assert np.abs(_width_errors_mm((ball,), 0.04, PARAMS)).max() < 1.0


def test_reconstruct_cloud_box_sides_move_in_from_occluding_edges():
    # Front face 40 x 120 mm, 30 degrees in the image, the table 75 mm behind it: the two
    # long sides occlude the table, and each grows by k px (0.94 mm a pixel at 0.225 m).
    box = _hit_box((0.0, 0.0, 0.225), _rotation((0, 0, 1), np.radians(30)), (0.12, 0.04, 0.05))
    table = _hit_plane((0, 0, 1), (0, 0, 0.3))
    for k in (2, 3, 4):
        fat = _fattened(np.minimum(box, table), k)
        assert _width_errors_mm((fat,), 0.04, EXACT_EDGES).min() > 1.5 * k
        trimmed = CloudParams(edge_fattening_px=float(k))
        assert np.abs(_width_errors_mm((fat,), 0.04, trimmed)).max() < 1.5


def _tilted_face() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A box's 40 x 120 mm front face square-on at 0.2 m, 30 degrees in the image, the table
    behind: the box's and the table's depth, and each pixel's ray at 0.2 m along and across the
    face's long side."""
    angle = np.radians(30)
    box = _hit_box((0.0, 0.0, 0.225), _rotation((0, 0, 1), angle), (0.12, 0.04, 0.05))
    table = _hit_plane((0, 0, 1), (0, 0, 0.3))
    rays = _directions()
    x, y = 0.2 * rays[..., 0], 0.2 * rays[..., 1]
    along = x * np.cos(angle) + y * np.sin(angle)
    across = -x * np.sin(angle) + y * np.cos(angle)
    return box, table, along, across


def test_reconstruct_cloud_box_side_ignores_a_locally_fattened_stretch():
    # Front face 40 x 120 mm square-on at 0.2 m, 30 degrees in the image, the table behind.
    # A matcher fattens a 30 mm stretch of one long side by 12 mm (about 13 px) at the face's
    # own depth, where a scan line would see no depth change: the stretch must not bound it.
    box, table, along, across = _tilted_face()
    stretch = (along >= 0.02) & (along <= 0.05) & (across > 0.02) & (across <= 0.032)
    bulge = np.where(stretch & ~np.isfinite(box), 0.2, np.inf)
    assert np.count_nonzero(np.isfinite(bulge)) > 300
    every_extreme = CloudParams(side_tolerance_m=1.0)
    assert _width_errors_mm((box, table, bulge), 0.04, every_extreme).min() > 8.0
    assert np.abs(_width_errors_mm((box, table, bulge), 0.04, PARAMS)).max() < 1.5
    # Without the stretch the sides stay the extremes, as before.
    clean = _width_errors_mm((box, table), 0.04, PARAMS)
    assert np.array_equal(clean, _width_errors_mm((box, table), 0.04, every_extreme))


def test_reconstruct_cloud_box_side_ends_where_a_matchers_fill_parts_from_the_face():
    # Front face 40 x 120 mm square-on at 0.2 m, 30 degrees in the image, the table behind. A
    # matcher's smoothness fills the background along the whole of one long side: 8 mm that
    # part from the face's plane (5 mm nearer), then 10 mm back on it (SGBM 9, P2 x 3, the
    # upright box at 0.175 m: 7-25 px past its sides). Every stretch of the side reaches as
    # far, so the median stretch does not bound it; the gap on the face's plane does.
    box, table, along, across = _tilted_face()
    beside = (np.abs(along) <= 0.06) & ~np.isfinite(box)
    parted = np.where(beside & (across > 0.02) & (across <= 0.028), 0.195, np.inf)
    back = np.where(beside & (across > 0.028) & (across <= 0.038), 0.2, np.inf)
    z = (_fattened(np.minimum(box, table), 1), parted, back)
    # A matcher made the frame (a pixel's fattening trimmed, as on a 3 x 3 window).
    matched = CloudParams(edge_fattening_px=1.0)
    assert _width_errors_mm(z, 0.04, replace(matched, side_gap_m=0.0)).min() > 15.0
    assert np.abs(_width_errors_mm(z, 0.04, matched)).max() < 1.5
    # On a frame no matcher made, the side keeps its extreme.
    exact = _width_errors_mm(z, 0.04, EXACT_EDGES)
    assert np.array_equal(exact, _width_errors_mm(z, 0.04, replace(EXACT_EDGES, side_gap_m=0.0)))


def test_only_a_gap_in_the_outer_part_parts_a_fill_from_the_face():
    # Ten strips, each points every 2 mm from -20 to +20 mm, a 7 mm gap at +8 mm (a curved
    # face's band on its plane, two fifths of the way out: kept) and one at +30 mm past which a
    # fill runs to +40 mm (three quarters of the way out: cut there).
    row = np.concatenate([np.arange(-0.020, 0.0081, 0.002), np.arange(0.015, 0.0301, 0.002),
                          np.arange(0.037, 0.0401, 0.002)])  # fmt: skip
    across = np.tile(row, 10)
    strips = np.repeat(np.arange(10), len(row))
    kept, kept_strips = _contiguous(across, strips, 0.006)
    assert kept.max() == pytest.approx(0.029)
    assert kept.min() == pytest.approx(-0.020)
    assert np.array_equal(np.unique(kept_strips), np.arange(10))


def test_a_block_matchers_hole_past_a_side_facing_x_trims_the_far_sides() -> None:
    # A face seen square on (the lines measure no fattening) fattened 2 px a side, its
    # background 90 mm behind, and no depth past its right side (a block matcher's hole):
    # the sides move in by a 5 x 5 window's 2 px (52.7 mm on main).
    z = np.minimum(
        _hit_box((0.0, 0.0, 0.22), np.eye(3), (0.05, 0.09, 0.04)),
        _hit_plane((0, 0, 1), (0, 0, 0.31)),
    )
    z = _fattened(z, 2)
    box = z < 0.25
    cols, rows = np.flatnonzero(box.any(axis=0)), np.flatnonzero(box.any(axis=1))
    z[rows.min() : rows.max() + 1, cols.max() + 1 : cols.max() + 36] = np.inf
    z = z + np.random.default_rng(3).normal(0.0, 0.0003, z.shape)
    depth = np.where(np.isfinite(z), np.rint(z / INTR.depth_scale), 0).astype(np.uint16)
    result = reconstruct_cloud(depth, INTR, seed=3)
    assert result.extra["fattening_px"] == PARAMS.hole_fattening_px
    assert abs(result.grasp_width_m - 0.05) < 0.0015
    untrimmed = reconstruct_cloud(depth, INTR, CloudParams(hole_fattening_px=0.0), seed=3)
    assert untrimmed.grasp_width_m - 0.05 > 0.002


def test_find_support_plane_keeps_a_sparse_dot_table_with_a_noise_tail() -> None:
    """Stereo at 0.04 dots/px² (SGBM 7), the 60 mm ball, trial 0 frame 0: the table's plane
    passed on the 384 sampled points (9 behind), but the whole cloud held 3.2 % behind it, past
    the 3 % the sample was held to. The table was kept, the ball merged with it and the frame
    came out a 147 mm box."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import StereoRig
    from services.cli import _laser_views as lv

    sensor = StereoSensor(rig=StereoRig(dot_density=0.04))
    view = next(lv.views("functional", 2, 5, 0, names=["sphere_large"], sensor=sensor))
    cloud, _ = voxel_downsample(crop_points(view.depth, INTR, PARAMS), PARAMS.voxel_m)
    mask = find_support_plane(cloud, PARAMS, np.random.default_rng(view.seq))
    assert mask is not None
    assert mask.mean() > 0.5  # the table is most of the crop
    result = reconstruct_cloud(view.depth, INTR, seed=view.seq)
    assert result.shape == "sphere", (result.shape, result.reason)
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.004


def test_on_support_finds_the_side_a_face_stands_on_not_a_corner_the_table_touches() -> None:
    from lpc_core.perception.cloud import _on_support

    # A face in the plane z = 0.2, 40 x 60 mm; the table meets it along its y = +30 mm side
    # and runs from there toward the camera.
    face = PlaneModel(np.array([0.0, 0.0, 1.0]), -0.2)
    basis = (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    extremes = (-0.02, 0.02, -0.03, 0.03)
    x, d = np.meshgrid(np.arange(-0.05, 0.05, 0.002), np.arange(0.0, 0.05, 0.002))
    table = np.column_stack([x.ravel(), np.full(x.size, 0.031), 0.2 - d.ravel()])
    assert _on_support(face, basis, extremes, table, 0.004) == [False, False, False, True]
    # Only a corner of that side touches the table (an upright box's foot beside it).
    corner = table[table[:, 0] > 0.012]
    assert _on_support(face, basis, extremes, corner, 0.004) == [False] * 4
    assert _on_support(face, basis, extremes, None, 0.004) == [False] * 4


def test_a_lying_box_side_on_the_table_is_not_trimmed_as_an_occluding_edge() -> None:
    """SGBM 7, the lying 40 mm box, trial 1 frame 0: no other face met the side it lies on, so
    it was taken for an occluding edge and moved in by the 4 px fattening the scan lines
    measured: 30 mm wide. The table's points along it make it a contact edge: 34.7 mm along
    the face's straightest sides, 0.6 degrees off its axis (35.7 along the smallest
    rectangle's, 1.1 off)."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor

    view, result = _functional_frame(StereoSensor(), "cuboid_lying", 1, 0)
    assert result.shape == "cuboid", (result.shape, result.reason)
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.006


def test_aimed_past_a_plane_the_axis_meets_to_a_patch_beside_it() -> None:
    # A face across the optical axis at 0.16 m, and a 1 cm patch 3 cm below the axis.
    face = _flat_patch((-0.03, 0.03), (-0.02, 0.02), 0.16)
    patch = _flat_patch((0.0, 0.01), (0.03, 0.04), 0.14)
    assert _aimed_past(patch, face, PARAMS)
    # A segment the axis meets is the object, whatever the plane behind it shows there.
    assert not _aimed_past(patch - np.array([0.0, 0.03, 0.0]), face, PARAMS)
    # A segment in front of the plane's outline hides part of it: a ball aimed beside on its
    # table (test_reconstruct_cloud_forgives_aiming_beside_the_object).
    ball = _flat_patch((0.015, 0.025), (0.0, 0.01), 0.14)
    assert not _aimed_past(ball, face, PARAMS)
    # A plane the axis misses (a table beside the object) is the table.
    assert not _aimed_past(patch, face + np.array([0.05, 0.0, 0.0]), PARAMS)


def test_a_lying_box_whose_table_a_texture_check_left_in_patches_is_not_a_patch() -> None:
    """BM 5 with texture threshold 30 (bm5-t30), the lying 40 mm box, trial 1 frame 0: the
    table was left as patches of about 100 points, the box's camera-facing face was the
    largest plane, and the patch nearest the axis came out a 6.9 mm box. The axis meets the
    face and misses the patch: the face is put back, and the box is 41.2 mm."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from services.cli.bench.sweep import SETTINGS

    sensor = SETTINGS["bm5-t30"].sensor()
    view, result = _functional_frame(sensor, "cuboid_lying", 1, 0)
    assert result.shape == "cuboid", (result.shape, result.reason)
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.003


def test_a_lying_box_whose_face_was_taken_for_the_table_is_not_a_band_of_it() -> None:
    """HH 9 without left-right check (hh9-nolr), the lying 40 mm box, trial 1 frame 3: no table
    was matched, the box's front face was the largest plane, and a band of that face 2-7 mm
    nearer (95 % within 7.3 mm of its plane) came out a 14.8 mm box. The band rests on
    nothing: the face is put back, and the box is 41.7 mm."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from services.cli.bench.sweep import SETTINGS

    view, result = _functional_frame(SETTINGS["hh9-nolr"].sensor(), "cuboid_lying", 1, 3)
    assert result.shape == "cuboid", (result.shape, result.reason)
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.003


def test_the_lines_fattening_comes_off_a_side_facing_x_only_over_a_far_background() -> None:
    """SGBM 5, the box tilted right, trial 1 frame 0: the lines measure 3.3 px of fattening.
    Past the face's side facing +x (0.226 m) the table lies 0.29-0.30 m away, under 35 %
    behind: the matcher did not widen that side, and with the trim it came out 1.6 mm
    inside, the box 3.6 mm narrow for 85 mm. The side facing -x (the shadow band's) is
    trimmed as before."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from services.cli.bench.sweep import SETTINGS

    view, result = _functional_frame(SETTINGS["sgbm5"].sensor(), "cuboid_tilt_right", 1, 0)
    assert result.shape == "cuboid", (result.shape, result.reason)
    assert result.extra["fattening_px"] > 3.0
    assert "residual_correlation" not in result.extra
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.001


def _face_grid(angle_rad: float, bulges: list[tuple[float, float, float, float]]) -> np.ndarray:
    """Points 2 mm apart on a 120 x 40 mm face whose long side runs at ``angle_rad``, and on
    ``bulges`` past it (each ``(along_lo, along_hi, across_lo, across_hi)`` in metres, in the
    face's own frame): a matcher's fattened stretches of its edges."""
    along, across = np.meshgrid(np.arange(-0.06, 0.0601, 0.002), np.arange(-0.02, 0.0201, 0.002))
    local = [np.column_stack([along.ravel(), across.ravel()])]
    for lo, hi, near, far in bulges:
        a, c = np.meshgrid(np.arange(lo, hi + 1e-9, 0.002), np.arange(near, far + 1e-9, 0.002))
        local.append(np.column_stack([a.ravel(), c.ravel()]))
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.concatenate(local) @ np.array([[c, s], [-s, c]])


def _turn_deg(direction: np.ndarray, angle_rad: float) -> float:
    """How far ``direction`` is from the face's sides (either pair), in degrees."""
    off = np.degrees(np.arctan2(direction[1], direction[0]) - angle_rad)
    return abs((off + 45.0) % 90.0 - 45.0)


def test_straightest_sides_leave_out_the_stretches_a_matcher_fattened() -> None:
    """A 30 mm stretch of each long side fattened by 6 mm, at opposite ends: the smallest
    rectangle turns 3-4 degrees to take both in; the sides' strips hold the face's direction."""
    from lpc_core.perception.cloud import _min_area_rectangle, _straightest_sides

    angle = np.radians(30.0)
    uv = _face_grid(angle, [(0.02, 0.05, 0.022, 0.026), (-0.05, -0.02, -0.026, -0.022)])
    smallest = _min_area_rectangle(uv)
    assert _turn_deg(smallest, angle) > 2.5
    assert _turn_deg(_straightest_sides(uv, smallest, 0.004, 0.002), angle) < 0.3
    # A clean face keeps its direction.
    clean = _face_grid(angle, [])
    assert (
        _turn_deg(_straightest_sides(clean, _min_area_rectangle(clean), 0.004, 0.002), angle) < 0.3
    )


def test_an_upright_box_under_semi_global_matching_gets_its_axis_from_the_whole_cloud() -> None:
    """SGBM 7, the upright box, trial 0 frame 2: one face in view, its long sides fattened by
    3-15 px that vary along them (the background is far and dim); the smallest rectangle
    around the face's points was 9.5 degrees off the box's axis, the straightest sides 0.1."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception.reconstruction import wrap_half_turn
    from lpc_core.sim.stereo import StereoSensor

    view, result = _functional_frame(StereoSensor(), "cuboid_upright", 0, 2)
    assert result.shape == "cuboid", (result.shape, result.reason)
    error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
    assert abs(error) < 1.0


def test_an_upright_box_under_strong_smoothness_gets_its_axis_from_a_whole_turn() -> None:
    """SGBM 7 with P1 x 3 and P2 x 6, the upright 35 mm box, trial 1 frame 3: the smoothness
    filled the dim background and the occluded band beside the face with the face's depth in
    blotches, and the smallest rectangle around the face's points was 20 degrees off the
    box's axis, beyond the 15 degrees searched near it: the box came out 39.3 mm, 12.1
    degrees off. Searched over every direction, the straightest sides give 34.5 mm, 0.3."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception.reconstruction import wrap_half_turn
    from services.cli.bench.sweep import SETTINGS

    sensor = SETTINGS["p1x3p2x6"].sensor()
    view, result = _functional_frame(sensor, "cuboid_upright", 1, 3)
    assert result.shape == "cuboid", (result.shape, result.reason)
    error = np.degrees(wrap_half_turn(result.wrist_angle_rad - view.truth.wrist_angle_rad))
    assert abs(error) < 2.0
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.0015


def test_contact_lines_are_where_the_face_meets_its_table_along_a_side() -> None:
    """A face in the plane z = 0.2 (in-plane basis x, y) and a table y = 0.03 under it: the
    line they meet on crosses the face's high y side at 0.03; a table along neither side
    (turned 30 degrees) or parallel to the face gives none."""
    from lpc_core.perception.cloud import PlaneModel, _contact_lines

    face = PlaneModel(np.array([0.0, 0.0, 1.0]), -0.2)
    basis = (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    sides = (-0.06, 0.06, -0.017, 0.027)
    grid = np.stack(np.meshgrid(np.linspace(-0.1, 0.1, 21), np.linspace(0.2, 0.3, 11)), -1)
    flat = grid.reshape(-1, 2)
    table = np.column_stack([flat[:, 0], np.full(len(flat), 0.03), flat[:, 1]])
    lines = _contact_lines(face, basis, sides, table)
    assert lines[:3] == [None, None, None]
    assert lines[3] == pytest.approx(0.03, abs=1e-9)
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    turned = (table - [0.0, 0.03, 0.0]) @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) + [
        0.0,
        0.03,
        0.0,
    ]
    assert _contact_lines(face, basis, sides, turned) == [None] * 4
    parallel = np.column_stack([flat, np.full(len(flat), 0.25)])
    assert _contact_lines(face, basis, sides, parallel) == [None] * 4


def test_a_lying_box_under_a_matcher_reaches_the_line_it_stands_on() -> None:
    """SGBM 5, the lying box's 40 mm front face, trial 0 frame 0: the window straddles the
    crease where the face meets the table, and the face's points stopped 3.0 mm short of the
    line the two planes meet on: 37.2 mm. Its side standing on the table goes out to that
    line: 40.3 mm."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from services.cli.bench.sweep import SETTINGS

    sensor = SETTINGS["sgbm5"].sensor()
    view, result = _functional_frame(sensor, "cuboid_lying", 0, 0)
    assert result.shape == "cuboid", (result.shape, result.reason)
    assert abs(result.grasp_width_m - view.truth.grasp_width_m) < 0.001


def test_a_can_fitted_wider_than_its_points_counts_its_margin_from_them() -> None:
    """SGBM 11, the upright 60 mm can, trial 0 frame 2: the rims a wide window pulled toward
    the camera flattened the arc, and the fit (72.8 mm) kept its silhouette 2.4 and 8.2 px
    beyond its points, so the 6 px margin from it kept the pulled rims. Wider than its
    points on both sides by more than a voxel, the fit counts its margin from the points'
    silhouette: 65.1 mm."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from lpc_core.sim.stereo_settings import Matcher

    sensor = StereoSensor(matcher=Matcher(block_size=11))
    view, result = _functional_frame(sensor, "cylinder_upright", 0, 2)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert abs(1000 * (result.grasp_width_m - view.truth.grasp_width_m)) < 7.0


def test_a_clean_can_fit_is_not_wider_than_its_points() -> None:
    from lpc_core.perception.cloud import _wider_than_points

    points, start = _pulled_can(0.0, 3.5)
    fixed = _camera_facing(points, start, CloudParams(rim_band_px=0.0), 1 / INTR.fx)
    assert not _wider_than_points(points, fixed, PARAMS)
    # The same points under a fit 2 mm too wide: its silhouette 5 px past them each side.
    wide = CylinderModel(fixed.center + np.array([0.0, 0.0, 0.002]), fixed.axis, 0.032)
    assert _wider_than_points(points, wide, PARAMS)


def _pulled_can(pull_m: float, decay_px: float) -> tuple[np.ndarray, CylinderModel]:
    """A 30 mm can's camera-facing side at 0.25 m, its rims pulled out of the surface (toward
    the camera) by ``pull_m`` decaying over ``decay_px`` in from the silhouette, as a wide
    window pulls them (SGBM 11: +2.5 mm within 2 px, +1.0 at 4-6, +0.3 at 8-10), and the
    RANSAC start a little off."""
    return _can_pulled_in(lambda inside_px: pull_m * np.exp(-inside_px / decay_px))


def _flanked_can(pull_m: float, reach_px: float) -> tuple[np.ndarray, CylinderModel]:
    """_pulled_can's 30 mm can, its flanks pulled toward the camera by ``pull_m`` at the
    silhouette, falling linearly to nothing ``reach_px`` in (a window's reach), its crest
    untouched."""
    return _can_pulled_in(lambda inside_px: pull_m * np.clip(1.0 - inside_px / reach_px, 0.0, 1.0))


def _can_pulled_in(
    pull: Callable[[np.ndarray], np.ndarray],
) -> tuple[np.ndarray, CylinderModel]:
    """The 30 mm can's camera-facing side at 0.25 m, each point pulled toward the camera,
    across the axis, by ``pull`` of its distance in from the silhouette (px), and the RANSAC
    start a little off."""
    rng = np.random.default_rng(0)
    centre, radius, axis = np.array([0.0, 0.0, 0.25]), 0.03, np.array([0.0, 1.0, 0.0])
    phi, y = rng.uniform(-np.pi / 2, np.pi / 2, 4000), rng.uniform(-0.05, 0.05, 4000)
    points = np.column_stack([radius * np.sin(phi), y, 0.25 - radius * np.cos(phi)])
    points += rng.normal(0.0, 0.0003, points.shape)
    inside_px = silhouette_distance(points, centre, radius, axis) * INTR.fx
    points, inside_px = points[inside_px > 0], inside_px[inside_px > 0]
    across = points - centre
    across[:, 1] = 0.0
    points += across / np.linalg.norm(across, axis=1)[:, None] * pull(inside_px)[:, None]
    start = CylinderModel(centre + np.array([0.001, 0.0, 0.002]), axis, radius + 0.003)
    return points, start


def _flanked_ball(pull_m: float, reach_px: float) -> tuple[np.ndarray, SphereModel]:
    """A 70 mm ball's camera-facing half at 0.22 m, 0.3 mm noise, its flanks pulled toward the
    camera (out along the normal) by ``pull_m`` at the silhouette, falling linearly to nothing
    ``reach_px`` in (a window's reach), its crest untouched; and a RANSAC start a little off."""
    rng = np.random.default_rng(0)
    centre, radius = np.array([0.0, 0.0, 0.22]), 0.035
    normals = rng.normal(size=(6000, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    normals[:, 2] = -np.abs(normals[:, 2])
    points = centre + radius * normals + rng.normal(0.0, 0.0003, (6000, 3))
    inside_px = silhouette_distance(points, centre, radius) * INTR.fx
    points, normals, inside_px = (
        points[inside_px > 0],
        normals[inside_px > 0],
        inside_px[inside_px > 0],
    )
    points += normals * (pull_m * np.clip(1.0 - inside_px / reach_px, 0.0, 1.0))[:, None]
    return points, SphereModel(centre + np.array([0.001, 0.0, 0.002]), radius + 0.003)


# A 60 mm can (the crest within 1.6 mm, the fit on an unpulled arc within 0.3) and a 70 mm
# ball (1.0, 0.5): a cap's fit has fewer points across the crest than a can's band.
ROUNDS = pytest.mark.parametrize(
    ("flanked", "radius", "crest_mm", "arc_mm"),
    [(_flanked_can, 0.03, 1.6, 0.3), (_flanked_ball, 0.035, 1.0, 0.5)],
    ids=["can", "ball"],
)


@ROUNDS
def test_a_round_whose_flanks_a_window_flattened_takes_its_crests_radius(
    flanked, radius: float, crest_mm: float, arc_mm: float
) -> None:
    points, start = flanked(0.003, 9.0)
    fixed = _camera_facing(points, start, CloudParams(rim_band_px=0.0), 1 / INTR.fx)
    assert 1000 * (fixed.radius - radius) > 3.0  # the 6 px margin keeps the flattened flanks
    crest = _flattened_flanks(points, fixed, PARAMS)
    assert abs(1000 * (crest.radius - radius)) < crest_mm
    assert _flattened_flanks(points, fixed, replace(PARAMS, crest_narrower_m=0.0)) is fixed


@ROUNDS
def test_a_round_whose_crest_bends_as_its_flanks_keeps_its_fit(
    flanked, radius: float, crest_mm: float, arc_mm: float
) -> None:
    points, start = flanked(0.0, 9.0)
    fixed = _camera_facing(points, start, CloudParams(rim_band_px=0.0), 1 / INTR.fx)
    assert _flattened_flanks(points, fixed, PARAMS) is fixed
    assert abs(1000 * (fixed.radius - radius)) < arc_mm


def _edge_on_prism(circumradius: float) -> tuple[np.ndarray, CylinderModel]:
    """A hexagonal prism standing 0.25 m away with an edge toward the camera: the two faces
    that meet in it (the next two are edge-on), 0.3 mm noise, and a cylinder's RANSAC start."""
    rng = np.random.default_rng(0)
    corners = np.radians([-60.0, 0.0, 60.0])
    x, z = circumradius * np.sin(corners), 0.25 - circumradius * np.cos(corners)
    face, t = rng.integers(0, 2, 2000), rng.uniform(0.0, 1.0, 2000)
    points = np.column_stack(
        [
            x[face] + t * (x[face + 1] - x[face]),
            rng.uniform(-0.05, 0.05, 2000),
            z[face] + t * (z[face + 1] - z[face]),
        ]
    )
    points += rng.normal(0.0, 0.0003, points.shape)
    start = CylinderModel(np.array([0.001, 0.0, 0.252]), np.array([0.0, 1.0, 0.0]), 0.03)
    return points, start


def test_a_prisms_ridge_keeps_the_fit_the_crest_would_shrink() -> None:
    points, start = _edge_on_prism(0.03)
    fixed = _camera_facing(points, start, CloudParams(rim_band_px=0.0), 1 / INTR.fx)
    assert _flattened_flanks(points, fixed, PARAMS) is fixed
    # Without the ridge's test the crest, the faces meeting in it, takes 5 mm off the radius.
    ridged = _flattened_flanks(points, fixed, replace(PARAMS, ridge_proud_m=0.0))
    assert 1000 * (fixed.radius - ridged.radius) > 4.0


def test_camera_facing_moves_in_past_a_rim_band_a_wide_window_pulled() -> None:
    points, start = _pulled_can(0.003, 3.5)
    fixed = _camera_facing(points, start, CloudParams(rim_band_px=0.0), 1 / INTR.fx)
    moved = _camera_facing(points, start, PARAMS, 1 / INTR.fx)
    assert 1000 * (fixed.radius - 0.03) > 1.7  # the 6 px margin keeps 1.8 mm of the pull
    assert 1000 * (moved.radius - 0.03) < 1.3


def test_camera_facing_keeps_its_margin_on_an_unpulled_rim() -> None:
    points, start = _pulled_can(0.0, 3.5)
    fixed = _camera_facing(points, start, CloudParams(rim_band_px=0.0), 1 / INTR.fx)
    moved = _camera_facing(points, start, PARAMS, 1 / INTR.fx)
    assert moved.radius == fixed.radius
    assert abs(1000 * (moved.radius - 0.03)) < 0.3


def test_facing_passes_resumed_after_the_margin_passes_match_a_fresh_run() -> None:
    """_round_facing resumes the rim band's run from the margin-only run's two passes instead
    of making them again: the radius comes out bit for bit as a fresh run's."""
    points, start = _pulled_can(0.003, 3.5)
    pixel_rad = 1 / INTR.fx
    fixed, passes = _facing_passes(points, start, CloudParams(rim_band_px=0.0), pixel_rad)
    assert passes == 2
    resumed, total = _facing_passes(points, fixed, PARAMS, pixel_rad, passes)
    assert total > passes  # the band moved in past the pulled rim
    assert resumed.radius == _camera_facing(points, start, PARAMS, pixel_rad).radius


def test_the_rim_band_moves_in_on_the_banded_side_only() -> None:
    """A can pulled toward the camera on its +x rim only (the window's pull where the
    background lies far behind; none where the table lies just past the other rim): the band
    run on that side alone moves in past the pull; on the other side alone it stays."""
    points, start = _pulled_can(0.003, 3.5)
    unpulled, _ = _pulled_can(0.0, 3.5)
    points = np.where((points[:, 0] > 0)[:, None], points, unpulled)  # same draws, +x pulled
    pixel_rad = 1 / INTR.fx
    fixed, passes = _facing_passes(points, start, CloudParams(rim_band_px=0.0), pixel_rad)
    pulled_side, _ = _facing_passes(
        points, fixed, PARAMS, pixel_rad, passes, banded_sides=(True, False)
    )
    other_side, _ = _facing_passes(
        points, fixed, PARAMS, pixel_rad, passes, banded_sides=(False, True)
    )
    assert 1000 * (fixed.radius - 0.03) > 0.6
    assert 1000 * abs(pulled_side.radius - 0.03) < 0.6 * 1000 * (fixed.radius - 0.03)
    assert other_side.radius == fixed.radius


def test_a_tilted_can_under_a_wide_window_bands_the_rim_with_far_background() -> None:
    """SGBM 11, the 50 mm can standing tilted right, trial 1 frame 1: the table lies just
    past one rim (0.09 of the range nearer than the axis), far behind the other. Every rim
    had to be far for the rim band, so the fit kept the pulled rims: 55.3 mm. Banded on the
    far side only: 50.7 mm."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from services.cli.bench.sweep import SETTINGS

    sensor = SETTINGS["sgbm11"].sensor()
    view, result = _functional_frame(sensor, "cylinder_tilt_right", 1, 1)
    assert result.shape == "cylinder", (result.shape, result.reason)
    assert abs(1000 * (result.grasp_width_m - view.truth.grasp_width_m)) < 2.0


@pytest.mark.parametrize("rows", [1, 30, 254, 255, 256, 384, 510, 511, 766])
def test_column_counts_match_a_wide_sum_past_the_byte_range(rows: int) -> None:
    # The support search counts each hypothesis's points in uint8 chunks of 255 rows: the
    # counts must be the int32 sums whatever the row count, all-true columns included.
    rng = np.random.default_rng(rows)
    hits = rng.random((rows, 64)) < rng.random(64)
    hits[:, 0] = True
    hits[:, 1] = False
    counts = _column_counts(hits)
    assert counts.dtype == np.int32
    np.testing.assert_array_equal(counts, hits.sum(axis=0))
    assert counts[0] == rows and counts[1] == 0


def test_a_ball_whose_cap_fit_floats_off_the_table_is_fitted_touching_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """BM 9 with a prefilter cap of 25 on sparse dots, the 40 mm ball, trial 1 frame 3: the
    fit on every inlier is 41 mm across and touches the table; the camera-facing refit on the
    block matcher's noisy cap traded its radius for depth, 31 mm across and 6.5 mm off the
    table, too far for the resting rule: 8.5 mm narrow. Fitted touching the table from the
    whole fit (cloud._lifted_rest): within 1.5 mm."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.perception import cloud
    from services.cli import _laser_views as lv
    from services.cli.bench.sweep import SETTINGS

    sensor = SETTINGS["bm9-c25"].sensor()
    views = lv.views("functional", 2, 5, 0, names=["sphere_small"], sensor=sensor)
    view = next(v for v in views if (v.trial, v.frame) == (1, 3))
    truth = view.truth.grasp_width_m
    result = reconstruct_cloud(view.depth, INTR, seed=view.seq)
    monkeypatch.setattr(cloud, "_lifted_rest", lambda *args: None)
    floating = reconstruct_cloud(view.depth, INTR, seed=view.seq)
    assert result.shape == floating.shape == "sphere"
    assert abs(1000 * (result.grasp_width_m - truth)) < 1.5, result.grasp_width_m
    assert 1000 * (floating.grasp_width_m - truth) < -5.0, floating.grasp_width_m


def test_a_strip_of_a_cans_arc_is_a_bent_face_and_a_noisy_box_face_is_not() -> None:
    """The points a plane's 1.5 mm band holds on a 50 mm can (a 28 mm strip across its axis,
    80 mm along it) bend like the can, 40 per metre; a 60 x 40 mm box face with 0.5 mm of
    range noise bends by its noise alone."""
    from lpc_core.perception.cloud import _bent_face

    rng = np.random.default_rng(3)
    # A can along y, radius 25 mm, 200 mm away; the plane touches its crest at z = 0.175.
    theta = rng.uniform(-0.6, 0.6, 2000)
    y = rng.uniform(-0.04, 0.04, 2000)
    can = np.stack([0.025 * np.sin(theta), y, 0.2 - 0.025 * np.cos(theta)], axis=1)
    face = PlaneModel(np.array([0.0, 0.0, 1.0]), -0.1758)
    strip = can[face.residuals(can) <= CloudParams().fit_threshold_m]
    assert 20 < 1000 * np.ptp(strip[:, 0]) < 35
    assert _bent_face(strip, face, CloudParams())
    flat = np.stack(
        [
            rng.uniform(-0.03, 0.03, 800),
            rng.uniform(-0.02, 0.02, 800),
            0.2 + rng.normal(0, 5e-4, 800),
        ],
        axis=1,
    )
    box = PlaneModel(np.array([0.0, 0.0, 1.0]), -0.2)
    assert not _bent_face(flat, box, CloudParams())
    # Off, the strip is a face like any other.
    assert not _bent_face(strip, face, replace(CloudParams(), flat_face_min_radius_m=0.0))


def test_a_can_whose_smoothed_arc_two_planes_explain_stays_a_cylinder() -> None:
    """SGBM 7 in HH mode with P1 / 2, P2 x 4 (hh7-p2x4), the upright 60 mm can, trial 0 frame 2:
    two perpendicular planes held 48.6 % of the segment against the cylinder's 47.2 %, and the
    can was taken for a box; its largest face bends like the can's arc."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from services.cli.bench.sweep import SETTINGS

    _, result = _functional_frame(SETTINGS["hh7-p2x4"].sensor(), "cylinder_upright", 0, 2)
    assert result.shape == "cylinder", (result.shape, result.extra)
    assert result.extra["bent_face"] == 1.0
    assert result.extra["cuboid_fraction"] > result.extra["cylinder_fraction"]


def _resting_ball_widths_mm(radius_m: float, params: CloudParams) -> np.ndarray:
    """Width errors (mm, three noise seeds) of a ball resting on a table tilted toward the
    camera, 0.28 m away, its rims pulled toward the camera by a 9 x 9 window."""
    touch = (0, 0, 0.28 + radius_m * 2**0.5)  # the plane through it lies radius_m from its centre
    z = _fattened(
        np.minimum(_hit_sphere((0.0, 0.0, 0.28), radius_m), _hit_plane((0, -1, 1), touch)), 4
    )
    errors = []
    for seed in range(3):
        result = reconstruct_cloud(_frame(z, seed=seed), INTR, params, seed=seed)
        assert result.shape == "sphere", result.reason
        errors.append(1000 * (result.grasp_width_m - 2 * radius_m))
    return np.array(errors)


def test_a_resting_ball_wide_in_view_takes_its_width_past_the_rims() -> None:
    # The 70 mm ball spans ~27 px of half-width at 0.28 m (at least 4 margins): its resting
    # refit past the margin sheds the rims' pull on every seed; the 40 mm ball (~15 px) keeps
    # the refit on all its inliers.
    kept = replace(PARAMS, rest_margin_span=0.0)
    past, every = _resting_ball_widths_mm(0.035, PARAMS), _resting_ball_widths_mm(0.035, kept)
    assert np.all(every > 2.5) and np.all(past < every - 0.3)
    small = _resting_ball_widths_mm(0.02, PARAMS)
    assert np.array_equal(small, _resting_ball_widths_mm(0.02, kept))
