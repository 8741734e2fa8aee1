"""The full-point-cloud benchmark: 3-D models fitted to the whole cropped cloud.

This is the controller the paper measures its four-line method against (Castro et al. 2022,
``castro2022continuous`` in ``reference/paper.tex``): crop the depth frame to a box in front
of the hand, downsample it on a 2 mm voxel grid, remove the supporting plane, split the rest
into Euclidean clusters, take the segment nearest the optical axis, fit a sphere, a cylinder
and a cuboid (up to three mutually perpendicular planes) by RANSAC and keep the model with
the best inlier fraction. The output follows the laser method's conventions
(``lpc_core.perception.reconstruction.Reconstruction`` with ``method="cloud"``).

Every RANSAC here is vectorised: a ``(trials, k)`` index array is drawn from the frame's
generator, every minimal hypothesis is solved at once and all are scored in one broadcast on a
random subset of the points; only the winner is refined by least squares on all of them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import lru_cache, partial
from typing import NamedTuple, Protocol, Self

import numpy as np
from scipy import ndimage
from scipy.linalg.blas import dgemm
from scipy.spatial import ConvexHull, QhullError, cKDTree

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.reconstruction import Reconstruction, wrap_half_turn
from lpc_core.perception.solids import (
    CylinderSolid,
    PlaneSolid,
    SphereSolid,
    fattening_trim_m,
    resting_width,
)


@dataclass(frozen=True, kw_only=True)
class CloudParams:
    """Every threshold of the cloud method, in SI units.

    The crop box and the 2 mm voxel are the benchmark controller's own settings; the rest were
    tuned on simulated D435 frames (``lpc bench compare``).
    """

    crop_xy_m: float = 0.100  # |x|, |y| within this
    crop_z_min_m: float = 0.115
    crop_z_max_m: float = 0.315
    voxel_m: float = 0.002
    # Supporting plane: the largest plane with (almost) nothing behind it, seen from the camera.
    support_planes: int = 1
    support_trials: int = 200  # a table a quarter of the cloud is still found 96% of the time
    support_threshold_m: float = 0.003
    support_min_points: int = 150
    support_max_behind_fraction: float = 0.03
    # A segment with more than this part behind the supporting plane does not rest on it: an
    # object's segment had at most 5 % there (BM 7, 11, SGBM 7 frames), mismatches straddling
    # a box's face taken for the plane 36-53 % (see _behind_support).
    segment_max_behind_fraction: float = 0.25
    # Clusters: connected cells of this size (26-neighbourhood). Points closer than a cell
    # along every axis always join; gaps wider than 2 sqrt(3) cells (14 mm) always split.
    cluster_cell_m: float = 0.004
    # The optical axis "pierces" a segment or a face that comes this close to it.
    pierce_tolerance_m: float = 0.0045
    min_segment_points: int = 100
    # Normals by local PCA over this many neighbours (the point itself included).
    normal_neighbours: int = 10
    # Model fitting.
    fit_threshold_m: float = 0.0015
    normal_tolerance_rad: float = float(np.radians(30.0))
    radius_min_m: float = 0.005
    radius_max_m: float = 0.060
    sphere_trials: int = 128
    cylinder_trials: int = 128
    face_trials: int = 96
    score_sample: int = 384
    fit_points: int = 1000  # the models are fitted on at most this many points of the segment
    refine_iterations: int = 2
    min_face_fraction: float = 0.05
    min_inlier_fraction: float = 0.3
    # Edges (see ``lpc_core.perception.laser.LaserParams``, which has the same two): a sphere's
    # or cylinder's width comes from its inliers at least ``silhouette_margin_px`` inside its
    # silhouette, and a cuboid face's side that no other face meets (an occluding edge) moves
    # in by ``edge_fattening_px``.
    silhouette_margin_px: float = 6.0
    # A wider window, or a stronger smoothness, pulls a round's rim toward the camera further
    # in than that margin (SGBM 11: +2.5 mm within 2 px of the silhouette, +1.0 at 4-6, +0.3
    # at 8-10). While the band of ``rim_band_px`` just outside the margin lies out of the fit
    # by more than ``rim_bulge_m`` and its median's noise (median), the margin moves in by the
    # band; only where the frame's residuals are correlated like a window matcher's and every
    # rim has its background far behind (see _round_facing). 0 turns it off.
    rim_band_px: float = 2.0
    rim_bulge_m: float = 0.0003
    # A resting ball wide enough in view (half-width at least this many silhouette margins)
    # takes its resting width from the points past the margin (see _rest_past_rims). 0 turns
    # it off (4: 24 px at the benchmark's focal length; at 20 px the 40 mm ball came in too).
    rest_margin_span: float = 4.0
    # A window matcher flattens a standing can's or a ball's arc over its flanks, not over its
    # crest: where the crest alone (its close points at least ``crest_inset`` of the
    # half-width in view inside the camera-facing fit's silhouette) spans a width more than
    # ``crest_narrower_m`` narrower, the crest's radius stands (see _flattened_flanks); only
    # where the frame's residuals are correlated like a window matcher's, and a ball only
    # where no resting fit applies and its fit stands off its table (_touches). 0 turns it
    # off. A faceted ridge
    # turned toward the camera (a hexagonal prism's edge) also bends tighter than the fit:
    # where the crest's middle (its close points at least 1 - ``ridge_middle`` of the
    # half-width in) stands out of the crest's circle by more than ``ridge_proud_m`` beyond
    # the rest of the crest, the fit stands.
    crest_inset: float = 0.3
    crest_narrower_m: float = 0.0025
    ridge_middle: float = 0.35
    ridge_proud_m: float = 0.0001
    edge_fattening_px: float = 0.0
    # A round resting on the supporting plane is fitted again touching it, as the four-line
    # method does (``LaserParams.rest_gap_ratio``, ``solids.resting_width``). 0 turns it off.
    rest_gap_ratio: float = 0.7
    rest_float_ratio: float = 0.25
    rest_max_tilt_rad: float = float(np.radians(10.0))
    # A table under the object holds thousands of points; a plane of a few hundred was as
    # often a wall, or a box's face, as the table (SGBM 7, BM 5: balls 12-16 mm off on it).
    rest_min_support_points: int = 500
    # With edge_fattening_px 0, measure it on each frame's scan lines (see
    # lpc_core.perception.laser.measured_fattening_px).
    measure_fattening: bool = True
    # Where the scan lines show none, a frame whose residuals are correlated like a window
    # matcher's takes the window's fattening (the four-line method's two parameters of the
    # same names), but only on an occluding side with its background far behind: at least
    # ``far_background_ratio`` of the side's depth further, or no depth at all, 8-30 px out
    # in the image (see _far_behind). Where the table lies 40-50 mm behind the face (the 40
    # mm bar lying, the lying box), the simulated SGBM fattened nothing there: 2 px on every
    # side cost the bar 3.5-5.8 mm (SGBM 7). At a ratio of 0.25 the bar seen from 0.2 m lost
    # 1 mm; at 0.5 the box tilted left (background 100-120 mm behind) kept 3.3 mm of 3.6.
    window_fattening_px: float = 3.0
    window_correlation_gate: float = 0.25
    far_background_ratio: float = 0.35
    # Where neither shows one, a frame with no depth past an occluding side facing +x (a
    # block matcher's, see _hole_past) takes a 5 x 5 window's fattening on the sides with
    # their background far behind, as the four-line method's ``hole_fattening_px`` does.
    hole_fattening_px: float = 2.0
    # An occluding side of a cuboid face with a stretch (a strip two voxels wide) further out
    # than this past its median stretch was fattened there, and the median stretch bounds it
    # (see _strip_sides). Half a voxel: a clean edge's strips agree closer than that.
    side_tolerance_m: float = 0.001
    # Where a matcher made the frame, an occluding side across the face's shorter extent ends
    # at its stretch's first gap wider than this on the face's plane, going out from the
    # face's middle: past it lies the matcher's fill of the background, which parts from the
    # face's plane (off it, or no depth) and comes back to it (SGBM 9 with P2 x 3, the upright
    # box at 0.175 m: 7-25 px past its sides, dipping 3-7 mm toward the camera on the way).
    # Three voxels: neighbouring voxels' centroids lie up to two apart, so a wider gap holds
    # an empty voxel at least (at two voxels, BM 5's and 3-way SGBM 7's sparse dots left
    # such gaps inside the face and cut it 0.4-1.4 mm narrower). 0 turns it off.
    side_gap_m: float = 0.006
    # A box's faces are flat: a cuboid whose largest face bends across its inliers at least
    # like a round of this radius is a round's arc that the face's band holds (see
    # _bent_face). Twice ``radius_max_m``: the simulated matchers' box faces bend at most 2.7
    # per metre (a 370 mm radius), the arcs taken for faces 8.9-16.3. 0 turns it off.
    flat_face_min_radius_m: float = 0.12

    def __post_init__(self) -> None:
        positive = (
            "crop_xy_m", "crop_z_min_m", "crop_z_max_m", "voxel_m", "support_threshold_m",
            "cluster_cell_m", "pierce_tolerance_m", "fit_threshold_m", "normal_tolerance_rad",
            "radius_min_m", "radius_max_m", "side_tolerance_m",
        )  # fmt: skip
        for name in positive:
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {value}")
        counts = (
            "support_trials", "min_segment_points", "sphere_trials", "cylinder_trials",
            "face_trials", "score_sample", "support_min_points", "fit_points",
            "rest_min_support_points",
        )  # fmt: skip
        for name in counts:
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.normal_neighbours < 3:
            raise ValueError(f"normal_neighbours must be at least 3, got {self.normal_neighbours}")
        if self.support_planes < 0 or self.refine_iterations < 0:
            raise ValueError("support_planes and refine_iterations must not be negative")
        if self.crop_z_max_m <= self.crop_z_min_m:
            raise ValueError("crop_z_max_m must be greater than crop_z_min_m")
        if self.radius_max_m <= self.radius_min_m:
            raise ValueError("radius_max_m must be greater than radius_min_m")
        for name in (
            "silhouette_margin_px",
            "rim_band_px",
            "rim_bulge_m",
            "rest_margin_span",
            "crest_inset",
            "crest_narrower_m",
            "edge_fattening_px",
            "window_fattening_px",
            "hole_fattening_px",
            "far_background_ratio",
            "rest_gap_ratio",
            "rest_max_tilt_rad",
            "side_gap_m",
            "flat_face_min_radius_m",
        ):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")
        for name in (
            "support_max_behind_fraction",
            "segment_max_behind_fraction",
            "min_face_fraction",
            "min_inlier_fraction",
        ):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be within [0, 1], got {getattr(self, name)}")


# --------------------------------------------------------------------------- fit models


@dataclass(frozen=True)
class FailedFit:
    """A fit that did not produce a model: falsy, and says why."""

    reason: str

    def __bool__(self) -> bool:
        return False


class FitModel(Protocol):
    """What RANSAC refinement needs from a 3-D model: estimate from points, then residuals."""

    @classmethod
    def estimate(
        cls, points: np.ndarray, normals: np.ndarray | None = None
    ) -> Self | FailedFit: ...

    def residuals(self, points: np.ndarray) -> np.ndarray: ...


def _as_points(points: np.ndarray, name: str = "points") -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {points.shape}")
    return points


@dataclass(frozen=True)
class PlaneModel:
    """Plane ``n . p + d = 0`` with ``|n| = 1``, fitted by total least squares (PCA).

    Minimises the sum of squared point-to-plane distances; needs at least 3 points. The normal
    is oriented so that the camera (the origin) lies on its negative side (``d < 0``), so a
    positive residual sign means "behind the plane".

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> uv = rng.uniform(-0.05, 0.05, (200, 2))
    >>> points = np.column_stack([uv, np.full(200, 0.2)])
    >>> model = PlaneModel.estimate(points)
    >>> np.allclose(model.normal, [0, 0, 1]), round(model.offset, 6)
    (True, -0.2)
    """

    normal: np.ndarray  # (3,), unit
    offset: float  # metres

    @property
    def params(self) -> tuple[float, float, float, float]:
        return (*map(float, self.normal), float(self.offset))

    @classmethod
    def estimate(
        cls, points: np.ndarray, normals: np.ndarray | None = None
    ) -> PlaneModel | FailedFit:
        points = _as_points(points)
        if len(points) < 3:
            return FailedFit(f"a plane needs 3 points, got {len(points)}")
        centroid = points.mean(axis=0)
        _, s, vt = np.linalg.svd(points - centroid, full_matrices=False)
        if s[1] <= 1e-9 * max(s[0], 1e-12):
            return FailedFit("points are collinear")
        normal = vt[2]
        offset = -float(normal @ centroid)
        if offset > 0:
            normal, offset = -normal, -offset
        return cls(normal, offset)

    def signed_distances(self, points: np.ndarray) -> np.ndarray:
        return _as_points(points) @ self.normal + self.offset

    def residuals(self, points: np.ndarray) -> np.ndarray:
        return np.abs(self.signed_distances(points))


@dataclass(frozen=True)
class SphereModel:
    """Sphere ``|p - c| = r``, fitted algebraically (Kasa's linear form).

    Solves ``|p|^2 + D.p + G = 0`` in the least-squares sense on centred, scaled points, then
    ``c = -D/2`` and ``r^2 = |c|^2 - G``; needs at least 4 non-coplanar points.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> v = rng.normal(size=(300, 3))
    >>> points = 0.03 * v / np.linalg.norm(v, axis=1, keepdims=True) + [0.0, 0.01, 0.2]
    >>> model = SphereModel.estimate(points)
    >>> np.round(model.center, 6).tolist(), round(model.radius, 6)
    ([0.0, 0.01, 0.2], 0.03)
    """

    center: np.ndarray  # (3,) metres
    radius: float  # metres

    @property
    def params(self) -> tuple[float, float, float, float]:
        return (*map(float, self.center), float(self.radius))

    @classmethod
    def estimate(
        cls, points: np.ndarray, normals: np.ndarray | None = None
    ) -> SphereModel | FailedFit:
        points = _as_points(points)
        if len(points) < 4:
            return FailedFit(f"a sphere needs 4 points, got {len(points)}")
        mean = points.mean(axis=0)
        scale = max(float(np.abs(points - mean).max()), 1e-9)
        q = (points - mean) / scale
        a = np.column_stack([q, np.ones(len(q))])
        b = -(q * q).sum(axis=1)
        solution, _, rank, _ = np.linalg.lstsq(a, b, rcond=None)
        if rank < 4:
            return FailedFit("points are coplanar")
        center = -solution[:3] / 2
        r2 = float(center @ center - solution[3])
        if r2 <= 0:
            return FailedFit("imaginary radius")
        return cls(center * scale + mean, float(np.sqrt(r2) * scale))

    def residuals(self, points: np.ndarray) -> np.ndarray:
        return np.abs(np.linalg.norm(_as_points(points) - self.center, axis=1) - self.radius)


@dataclass(frozen=True)
class CylinderModel:
    """Infinite cylinder: distance from ``p`` to the line ``c + t a`` equals ``r``.

    The axis ``a`` is the direction least represented in the surface normals (the smallest
    eigenvector of ``sum n n^T``); the centre and radius come from an algebraic circle fit of
    the points projected on the plane normal to ``a``. Needs at least 3 points with normals.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> phi, t = rng.uniform(0, 2 * np.pi, 300), rng.uniform(-0.05, 0.05, 300)
    >>> normals = np.column_stack([np.cos(phi), np.zeros(300), np.sin(phi)])
    >>> points = 0.02 * normals + np.column_stack([np.zeros(300), t, np.full(300, 0.2)])
    >>> model = CylinderModel.estimate(points, normals)
    >>> np.round(np.abs(model.axis), 6).tolist(), round(model.radius, 6)
    ([0.0, 1.0, 0.0], 0.02)
    """

    center: np.ndarray  # (3,) a point on the axis, metres
    axis: np.ndarray  # (3,) unit
    radius: float  # metres

    @property
    def params(self) -> tuple[float, ...]:
        return (*map(float, self.center), *map(float, self.axis), float(self.radius))

    @classmethod
    def estimate(
        cls, points: np.ndarray, normals: np.ndarray | None = None
    ) -> CylinderModel | FailedFit:
        points = _as_points(points)
        if normals is None:
            return FailedFit("a cylinder fit needs normals")
        normals = _as_points(normals, "normals")
        if len(points) < 3 or len(normals) != len(points):
            return FailedFit(f"a cylinder needs 3 points with normals, got {len(points)}")
        eigenvalues, eigenvectors = np.linalg.eigh(normals.T @ normals)
        if eigenvalues[1] <= 1e-6 * eigenvalues[2]:
            return FailedFit("normals are all parallel")
        axis = eigenvectors[:, 0]
        circle = _fit_circle_across(points, axis)
        if isinstance(circle, FailedFit):
            return circle
        center, radius = circle
        return cls(center, axis, radius)

    def distances_to_axis(self, points: np.ndarray) -> np.ndarray:
        v = _as_points(points) - self.center
        along = v @ self.axis
        return np.sqrt(np.maximum((v * v).sum(axis=1) - along * along, 0.0))

    def residuals(self, points: np.ndarray) -> np.ndarray:
        return np.abs(self.distances_to_axis(points) - self.radius)


def _orthonormal_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def _fit_circle_across(
    points: np.ndarray, axis: np.ndarray
) -> tuple[np.ndarray, float] | FailedFit:
    """Algebraic circle fit (Kasa) of the points projected across ``axis``."""
    e1, e2 = _orthonormal_basis(axis)
    uv = np.column_stack([points @ e1, points @ e2])
    mean = uv.mean(axis=0)
    scale = max(float(np.abs(uv - mean).max()), 1e-9)
    q = (uv - mean) / scale
    a = np.column_stack([q, np.ones(len(q))])
    b = -(q * q).sum(axis=1)
    solution, _, rank, _ = np.linalg.lstsq(a, b, rcond=None)
    if rank < 3:
        return FailedFit("projected points are collinear")
    c2 = -solution[:2] / 2
    r2 = float(c2 @ c2 - solution[2])
    if r2 <= 0:
        return FailedFit("imaginary radius")
    c2 = c2 * scale + mean
    center = c2[0] * e1 + c2[1] * e2 + float(np.mean(points @ axis)) * axis
    return center, float(np.sqrt(r2) * scale)


# --------------------------------------------------------------------------- cloud steps


@lru_cache(maxsize=8)
def _rays(intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    rx, ry = intrinsics.pixel_rays()
    return np.ascontiguousarray(rx).ravel(), np.ascontiguousarray(ry).ravel()


def _check_depth(depth: np.ndarray, intrinsics: Intrinsics) -> None:
    if not isinstance(depth, np.ndarray) or depth.dtype != np.uint16:
        raise ValueError(
            f"depth must be a uint16 ndarray, got {getattr(depth, 'dtype', type(depth))}"
        )
    expected = (intrinsics.height, intrinsics.width)
    if depth.shape != expected:
        raise ValueError(f"depth must have shape {expected} (intrinsics), got {depth.shape}")


def crop_points(depth: np.ndarray, intrinsics: Intrinsics, params: CloudParams) -> np.ndarray:
    """Deproject the depth pixels that fall in the crop box: ``(N, 3)`` metres, camera frame."""
    _check_depth(depth, intrinsics)
    flat = depth.ravel()
    lo = int(np.ceil(params.crop_z_min_m / intrinsics.depth_scale))
    hi = int(np.floor(params.crop_z_max_m / intrinsics.depth_scale))
    index = np.flatnonzero((flat >= lo) & (flat <= hi))
    rx, ry = _rays(intrinsics)
    z = flat[index] * intrinsics.depth_scale
    x = rx[index] * z
    y = ry[index] * z
    keep = (np.abs(x) <= params.crop_xy_m) & (np.abs(y) <= params.crop_xy_m)
    return np.column_stack([x[keep], y[keep], z[keep]])


def voxel_downsample(
    points: np.ndarray, voxel_m: float, origin: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Centroids of the points in each occupied voxel, and how many points each holds.

    The grid is anchored at ``origin`` (default: the origin of the camera frame), so the same
    point always falls in the same voxel. Returns ``(M, 3)`` centroids in voxel-key order and
    ``(M,)`` counts.
    """
    points = _as_points(points)
    if not np.isfinite(voxel_m) or voxel_m <= 0:
        raise ValueError(f"voxel_m must be a positive finite number, got {voxel_m}")
    if len(points) == 0:
        return np.empty((0, 3)), np.empty(0, dtype=np.int64)
    base = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64)
    # Row-wise on the transpose: reductions along contiguous rows are several times faster.
    columns = np.ascontiguousarray(points.T)
    cells = np.floor((columns - base[:, None]) / voxel_m).astype(np.int64)
    cells -= cells.min(axis=1)[:, None]
    span = cells.max(axis=1) + 1
    keys = (cells[0] * span[1] + cells[1]) * span[2] + cells[2]
    # One sort and a segmented sum: cheaper than np.unique's inverse plus three bincounts.
    order = np.argsort(keys)
    sorted_keys = keys[order]
    starts = np.flatnonzero(np.concatenate([[True], sorted_keys[1:] != sorted_keys[:-1]]))
    counts = np.diff(np.append(starts, len(keys)))
    sums = np.add.reduceat(columns[:, order], starts, axis=1)
    return np.ascontiguousarray((sums / counts).T), counts


def _sample(n: int, size: int, rng: np.random.Generator) -> np.ndarray:
    return np.arange(n) if n <= size else rng.choice(n, size, replace=False)


# Rows (x, y, z, x, y): the rotated rows of a cross product are then slices of one gather.
_XYZXY = np.array([0, 1, 2, 0, 1])


def plane_hypotheses(
    points: np.ndarray, picks: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planes through the point triples ``points[picks]`` ((T, 3) indices): unit normals
    facing away from the camera as rows (3, T), offsets (T,) and which triples span a plane.

    On a few hundred triples the cost is the count of array operations, not their size (the
    support search runs on every frame of the aim step and every round of the four-line
    method): one gather of (x, y, z, x, y) rows serves the cross product's rotations as
    slices, where a (T, 3) layout took four gathers (34 -> 26 us a call), the norm is three
    rows added, and the flips negate in place where the sign is wrong, with no sign vector
    to build and multiply (26 -> 20 us)."""
    # (5, 3, T): coordinate, corner, triple; gathered at the 3T picks, whatever the cloud.
    # take, not [] indexing: the same elements without the fancy index's set-up.
    rows = points.take(picks.T, axis=0).transpose(2, 0, 1).take(_XYZXY, axis=0)
    p0 = rows[:, 0]
    a, b = rows[:, 1] - p0, rows[:, 2] - p0
    normals = a[1:4] * b[2:5] - a[2:5] * b[1:4]
    squares = normals * normals
    # The reduction adds the rows in order onto 0.0: the same sum, as no square is -0.0.
    norms = np.sqrt(np.add.reduce(squares, axis=0))
    valid = norms > 1e-10
    # A degenerate triple's normal stays as it is (the division by 1.0 it had).
    np.divide(normals, norms, out=normals, where=valid)
    moments = normals * p0[:3]
    # Added row by row, not reduced: a reduction starts from +0.0, and a degenerate triple's
    # offset of -0.0 would come out +0.0.
    sums = moments[0] + moments[1]
    sums += moments[2]
    # The offset is -sums; where that is positive the plane faces the camera: flip it.
    flip = sums < 0.0
    offsets = np.negative(sums)
    np.negative(normals, out=normals, where=flip)
    np.negative(offsets, out=offsets, where=flip)
    return normals, offsets, valid


# The support among a frame's scan-line samples (the aim step's, and a resting round's in the
# four-line method): the table under an object holds a third or more of them, and 64 triples
# find it; 30 samples at least, so that a few stray ones are no plane.
SCAN_LINE_SUPPORT = CloudParams(support_trials=64, support_min_points=30)


def _support_refit(points: np.ndarray) -> tuple[np.ndarray, float] | None:
    """``PlaneModel.estimate``'s plane through ``points`` as (unit normal away from the camera,
    offset), or None, from ``PlaneSolid``'s closed-form eigenvector where it can: the same
    plane to the last bits at a third of the SVD's cost (the support search refits on every
    frame of the aim step and every resting round). Where the points are (nearly) collinear,
    or their plane passes through the camera (one scan line's own plane: no side of it is
    behind the other), PlaneModel's own test and its SVD's sign decide, as before."""
    return _support_fit(points)[0]


def _support_fit(
    points: np.ndarray,
) -> tuple[tuple[np.ndarray, float] | None, PlaneSolid | None]:
    """``_support_refit``'s plane, and the ``PlaneSolid`` fitted on the way (None where none
    was, or it failed)."""
    solid = PlaneSolid.estimate(points) if len(points) >= 3 else None
    if not solid:
        solid = None
    else:
        normal = -solid.normal
        offset = -float(normal @ solid.point)
        if offset < -1e-9:
            return (normal, offset), solid
    model = PlaneModel.estimate(points)
    return ((model.normal, model.offset) if model else None), solid


def _column_counts(hits: np.ndarray) -> np.ndarray:
    """Per column of each (S, T) boolean matrix of ``hits`` (..., S, T), how many of its rows
    are true, as int32 (..., T).

    Byte sums down at most 255 rows at a time, in uint8: no sum can wrap, and a reduction in
    the array's own type runs without the buffered cast to a wider one that an int32 sum
    of the bytes went through (a third of the support search's scoring in callgrind; a
    boolean .sum() casts every element to int64). Several matrices in one array are counted
    in one reduction."""
    rows = hits.view(np.uint8)
    s = rows.shape[-2]
    counts = np.add.reduce(rows[..., :255, :], axis=-2, dtype=np.uint8).astype(np.int32)
    for start in range(255, s, 255):
        counts += np.add.reduce(rows[..., start : start + 255, :], axis=-2, dtype=np.uint8)
    return counts


class SupportHypotheses(NamedTuple):
    """A support search's planes through point triples and their scores on (a sample of) the
    points: what ``find_support_plane`` draws and counts before it picks one. Searches over
    the same points that differ only in how much may lie behind the plane share them
    (``support_max_behind_fraction``; the four-line method's table search and its disc's,
    which also tries these planes for a table)."""

    normals: np.ndarray  # (3, T) unit, facing away from the camera
    offsets: np.ndarray  # (T,)
    valid: np.ndarray  # (T,) the triple spans a plane
    signed: np.ndarray  # (S, T) signed distances of the scored points
    sampled: bool  # the scored points are a sample of the points, not all of them
    behind: np.ndarray  # (T,) scored points behind each plane
    inliers: np.ndarray  # (T,) scored points on each plane


def support_hypotheses(
    points: np.ndarray, params: CloudParams, rng: np.random.Generator
) -> SupportHypotheses | None:
    """``find_support_plane``'s planes and scores (``SupportHypotheses``), or ``None`` when
    there are too few points for a support."""
    n = len(points)
    if n < max(3, params.support_min_points):
        return None
    threshold = params.support_threshold_m
    # A flat size, then the (T, 3) view: the same draws in the same order, without the shape
    # tuple's np.prod that the generator calls through numpy's Python wrapper.
    picks = rng.integers(0, n, size=3 * params.support_trials).reshape(-1, 3)
    normals, offsets, valid = plane_hypotheses(points, picks)
    # All the points when they are few (no copy: _sample's arange would only copy them).
    sampled = n > params.score_sample
    if not sampled:
        sub = np.ascontiguousarray(points)
    else:
        sub = points[_sample(n, params.score_sample, rng)]
    # (S, T): the offsets first, then BLAS adds sub @ normals onto them (beta = 1), as the
    # column-major (T, S) = (T, 3) @ (3, S) that np.matmul hands it. matmul's beta = 0 zeroed
    # the output before the kernel stored its sums, and the offsets came in a second pass
    # (16.8 -> 12.3 us a call). The kernel adds each sum of products to what the output holds
    # as it stores it: the same rounded sum plus offset, bit for bit (every recorded frame's).
    signed = np.empty((len(sub), len(offsets)))
    signed[...] = offsets
    signed = dgemm(1.0, normals.T, sub.T, 1.0, signed.T, overwrite_c=True).T
    # |d| <= t is d >= -t less d > t; both tests into one array, counted in one reduction.
    hits = np.empty((2, *signed.shape), dtype=bool)
    np.greater(signed, threshold, out=hits[0])
    np.greater_equal(signed, -threshold, out=hits[1])
    behind, front = _column_counts(hits)
    return SupportHypotheses(normals, offsets, valid, signed, sampled, behind, front - behind)


class Support(NamedTuple):
    """A support search's plane: its points (``mask``), and ``PlaneSolid.estimate`` of exactly
    those points where the search fitted that on its way (``plane``), else ``None``."""

    mask: np.ndarray
    plane: PlaneSolid | None


def find_support_plane(
    points: np.ndarray,
    params: CloudParams,
    rng: np.random.Generator,
    hypotheses: SupportHypotheses | None = None,
) -> np.ndarray | None:
    """Mask of the supporting plane's points (``find_support``'s), or ``None``."""
    found = find_support(points, params, rng, hypotheses)
    return None if found is None else found.mask


def find_support(
    points: np.ndarray,
    params: CloudParams,
    rng: np.random.Generator,
    hypotheses: SupportHypotheses | None = None,
) -> Support | None:
    """The supporting plane's points (``Support``), or ``None`` when there is no such plane.

    The supporting plane is the largest plane that has (almost) no point behind it as seen from
    the camera: the table under an object qualifies; the front face of a box standing on it
    does not, because the table and the box's sides lie behind that face. ``hypotheses``:
    ``support_hypotheses(points, p, rng)`` already drawn, with ``p`` as ``params`` but for
    ``support_max_behind_fraction`` (``rng`` is then not used).
    """
    if hypotheses is None:
        hypotheses = support_hypotheses(points, params, rng)
        if hypotheses is None:
            return None
    n = len(points)
    threshold = params.support_threshold_m
    normals, offsets, s = hypotheses.normals, hypotheses.offsets, len(hypotheses.signed)
    ok = hypotheses.valid & (hypotheses.behind <= params.support_max_behind_fraction * s)
    if not np.logical_or.reduce(ok):
        return None
    # The method, not np.argmax's Python wrapper: the search runs on every resting round.
    best = int(np.where(ok, hypotheses.inliers, -1).argmax())
    signed_all = points @ normals[:, best] + offsets[best]
    mask = np.abs(signed_all) <= threshold
    refit, plane = _support_fit(points[mask])
    if refit is not None:
        signed_all = points @ refit[0] + refit[1]
        fitted, mask = mask, np.abs(signed_all) <= threshold
        # The fit is the refit plane's own only where its points are those it was fitted on
        # (about half the resting rounds' searches): the caller need not fit them again.
        if plane is not None and not bool((mask == fitted).all()):
            plane = None
    behind_all = np.count_nonzero(signed_all > threshold)
    # The hypothesis passed on the sample; the whole cloud may hold a little more behind by the
    # sample's chance alone: three standard deviations of the sampled fraction, with the finite
    # population correction (none when the sample is the whole cloud). A table seen through a
    # sparse dot pattern has a noise tail past the threshold; the table behind a box's face is
    # far more than that.
    f = params.support_max_behind_fraction
    allowed = f + 3.0 * math.sqrt(f * (1.0 - f) / s * (n - s) / max(n - 1, 1))
    if np.count_nonzero(mask) < params.support_min_points or behind_all > allowed * n:
        return None
    return Support(mask, plane)


def grid_clusters(points: np.ndarray, cell_m: float) -> np.ndarray:
    """Label of each point's cluster: connected components of the occupied cells of a grid.

    Two points whose coordinates differ by at most ``cell_m`` along every axis fall in the same
    or touching cells and so share a cluster; points more than ``2 sqrt(3) cell_m`` apart with
    nothing between them never do. Labelling the occupancy grid (``scipy.ndimage.label``,
    26-neighbourhood) costs a fraction of a k-d tree's pair search on the same cloud.
    """
    points = _as_points(points)
    if not np.isfinite(cell_m) or cell_m <= 0:
        raise ValueError(f"cell_m must be a positive finite number, got {cell_m}")
    if len(points) == 0:
        return np.empty(0, dtype=np.int64)
    columns = np.ascontiguousarray(points.T)
    cells = np.floor(columns / cell_m).astype(np.int64)
    cells -= cells.min(axis=1)[:, None]
    occupied = np.zeros(tuple(cells.max(axis=1) + 1), dtype=bool)
    occupied[cells[0], cells[1], cells[2]] = True
    grid, _ = ndimage.label(occupied, structure=np.ones((3, 3, 3), dtype=bool))
    return grid[cells[0], cells[1], cells[2]].astype(np.int64) - 1


def nearest_segment(
    points: np.ndarray, labels: np.ndarray, min_points: int, tolerance_m: float
) -> np.ndarray | None:
    """Mask of the segment nearest the optical axis with at least ``min_points`` points.

    Distance to the axis is the segment's closest point's; when the axis pierces several
    segments (closest points within ``tolerance_m`` of it), the one nearest the camera wins.
    """
    if len(points) == 0:
        return None
    counts = np.bincount(labels)
    order = np.argsort(labels, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    radial = np.hypot(points[order, 0], points[order, 1])
    closest = np.minimum.reduceat(radial, starts)
    nearest_z = np.minimum.reduceat(points[order, 2], starts)
    big = counts >= min_points
    if not big.any():
        return None
    pierced = big & (closest <= tolerance_m)
    if pierced.any():
        best = int(np.argmin(np.where(pierced, nearest_z, np.inf)))
    else:
        best = int(np.argmin(np.where(big, closest, np.inf)))
    return labels == best


def smallest_eigenvectors(cov: np.ndarray) -> np.ndarray:
    """Unit eigenvector of the smallest eigenvalue of each symmetric 3x3 matrix, ``(N, 3)``.

    Closed form (Smith 1961, trigonometric eigenvalues), then the longest cross product of two
    rows of ``A - lambda I``; about twice as fast as a batched ``eigh`` on small matrices.
    """
    q = (cov[:, 0, 0] + cov[:, 1, 1] + cov[:, 2, 2]) / 3
    a00, a11, a22 = cov[:, 0, 0] - q, cov[:, 1, 1] - q, cov[:, 2, 2] - q
    a01, a02, a12 = cov[:, 0, 1], cov[:, 0, 2], cov[:, 1, 2]
    p = np.sqrt((a00**2 + a11**2 + a22**2 + 2 * (a01**2 + a02**2 + a12**2)) / 6)
    safe = np.where(p > 0, p, 1.0)
    det = a00 * (a11 * a22 - a12**2) - a01 * (a01 * a22 - a12 * a02) + a02 * (a01 * a12 - a11 * a02)
    phi = np.arccos(np.clip(det / (2 * safe**3), -1.0, 1.0)) / 3
    shift = 2 * p * np.cos(phi + 2 * np.pi / 3)  # the smallest eigenvalue, minus q
    rows = np.stack(
        [
            np.column_stack([a00 - shift, a01, a02]),
            np.column_stack([a01, a11 - shift, a12]),
            np.column_stack([a02, a12, a22 - shift]),
        ],
        axis=1,
    )
    crosses = np.stack(
        [
            np.cross(rows[:, 0], rows[:, 1]),
            np.cross(rows[:, 0], rows[:, 2]),
            np.cross(rows[:, 1], rows[:, 2]),
        ],
        axis=1,
    )
    lengths = (crosses * crosses).sum(axis=2)
    pick = np.argmax(lengths, axis=1)
    take = np.arange(len(cov))
    vectors = crosses[take, pick]
    norms = np.sqrt(lengths[take, pick])
    # A rank-0 or rank-1 deviation leaves no usable cross product: any unit vector will do.
    degenerate = norms <= 1e-30
    vectors[degenerate] = (0.0, 0.0, 1.0)
    norms[degenerate] = 1.0
    return vectors / norms[:, None]


def estimate_normals(
    points: np.ndarray, neighbours: int, at: np.ndarray | None = None
) -> np.ndarray:
    """Unit normals by PCA over nearest neighbours among ``points``, facing the camera.

    Normals are computed at ``at`` (default: at every point of ``points``).
    """
    query = points if at is None else at
    k = min(neighbours, len(points))
    _, index = cKDTree(points).query(query, k=k)
    local = points[index]  # (N, k, 3)
    local = local - local.mean(axis=1, keepdims=True)
    normals = smallest_eigenvectors(local.transpose(0, 2, 1) @ local)
    flip = (normals * query).sum(axis=1) > 0
    normals[flip] *= -1
    return normals


# --------------------------------------------------------------------------- model RANSAC


@dataclass(frozen=True)
class _Fit:
    model: SphereModel | CylinderModel | PlaneModel
    inliers: np.ndarray  # bool mask over the segment


def _best(counts: np.ndarray, valid: np.ndarray) -> int | None:
    scored = np.where(valid, counts, -1)
    best = int(np.argmax(scored))
    return None if scored[best] <= 0 else best


def _score_round(
    points: np.ndarray,
    normals: np.ndarray,
    centers: np.ndarray,
    radii: np.ndarray,
    axes: np.ndarray | None,
    params: CloudParams,
    rng: np.random.Generator,
) -> np.ndarray:
    """Inlier counts of ``T`` spheres (``axes=None``) or cylinders on a random subset.

    Distances are expanded into dot products (``|p - c|^2 = |p|^2 - 2 p.c + |c|^2``) so the
    ``(S, T)`` tables come from matrix products instead of an ``(S, T, 3)`` broadcast.
    """
    sub = _sample(len(points), params.score_sample, rng)
    origin = points.mean(axis=0)  # centred, so the expansion loses no precision
    p, nrm, c = points[sub] - origin, normals[sub], centers - origin
    dist2 = (p * p).sum(axis=1)[:, None] - 2 * (p @ c.T) + (c * c).sum(axis=1)
    towards = (nrm * p).sum(axis=1)[:, None] - nrm @ c.T  # (p - c) . n
    if axes is not None:
        along = p @ axes.T - (c * axes).sum(axis=1)  # (p - c) . a
        dist2 -= along * along
        towards -= along * (nrm @ axes.T)  # the radial part's . n
    dist = np.sqrt(np.maximum(dist2, 0.0))
    close = np.abs(dist - radii) <= params.fit_threshold_m
    facing = np.abs(towards) >= np.cos(params.normal_tolerance_rad) * dist
    return (close & facing).sum(axis=0)


def _sphere_inliers(
    points: np.ndarray, normals: np.ndarray, model: SphereModel, params: CloudParams
) -> np.ndarray:
    v = points - model.center
    dist = np.linalg.norm(v, axis=1)
    facing = np.abs((v * normals).sum(axis=1)) >= np.cos(params.normal_tolerance_rad) * dist
    return (np.abs(dist - model.radius) <= params.fit_threshold_m) & facing


def fit_sphere(
    points: np.ndarray, normals: np.ndarray, params: CloudParams, rng: np.random.Generator
) -> _Fit | FailedFit:
    """RANSAC sphere: 4-point hypotheses solved as one batch of 4x4 systems."""
    n = len(points)
    if n < 4:
        return FailedFit("fewer than 4 points")
    mean = points.mean(axis=0)
    scale = 0.05
    q = (points - mean) / scale
    picks = rng.integers(0, n, size=(params.sphere_trials, 4))
    qs = q[picks]  # (T, 4, 3)
    a = np.concatenate([qs, np.ones((*qs.shape[:2], 1))], axis=2)
    b = -(qs * qs).sum(axis=2)
    det = np.linalg.det(a)
    valid = np.abs(det) > 1e-9
    a[~valid] = np.eye(4)
    solution = np.linalg.solve(a, b[..., None])[..., 0]
    centers = -solution[:, :3] / 2
    r2 = (centers * centers).sum(axis=1) - solution[:, 3]
    radii = np.sqrt(np.maximum(r2, 0.0)) * scale
    centers = centers * scale + mean
    valid &= (r2 > 0) & (radii >= params.radius_min_m) & (radii <= params.radius_max_m)
    counts = _score_round(points, normals, centers, radii, None, params, rng)
    best = _best(counts, valid)
    if best is None:
        return FailedFit("no sphere hypothesis")
    model: SphereModel | FailedFit = SphereModel(centers[best], float(radii[best]))
    inliers = _sphere_inliers(points, normals, model, params)
    for _ in range(params.refine_iterations):
        refined = SphereModel.estimate(points[inliers])
        if not refined or not params.radius_min_m <= refined.radius <= params.radius_max_m:
            break
        refined_inliers = _sphere_inliers(points, normals, refined, params)
        if refined_inliers.sum() < inliers.sum():
            break
        model, inliers = refined, refined_inliers
    # A sphere seen from outside has its centre beyond the surface the camera sees.
    if model.center[2] <= points[inliers, 2].min():
        return FailedFit("sphere centre in front of its surface")
    return _Fit(model, inliers)


def _cylinder_inliers(
    points: np.ndarray, normals: np.ndarray, model: CylinderModel, params: CloudParams
) -> np.ndarray:
    v = points - model.center
    radial = v - np.outer(v @ model.axis, model.axis)
    dist = np.linalg.norm(radial, axis=1)
    facing = np.abs((radial * normals).sum(axis=1)) >= np.cos(params.normal_tolerance_rad) * dist
    return (np.abs(dist - model.radius) <= params.fit_threshold_m) & facing


def fit_cylinder(
    points: np.ndarray, normals: np.ndarray, params: CloudParams, rng: np.random.Generator
) -> _Fit | FailedFit:
    """RANSAC cylinder from two points with normals: axis ``n1 x n2``, centre where the two
    normal lines meet across the axis.

    The inliers also take in the end cap when one is in view (points on a plane across the
    axis, within the radius, with normals along the axis): a can seen from above shows its lid,
    and leaving it out would hand the lid to the cuboid's planes.
    """
    n = len(points)
    if n < 3:
        return FailedFit("fewer than 3 points")
    picks = rng.integers(0, n, size=(params.cylinder_trials, 2))
    p1, p2 = points[picks[:, 0]], points[picks[:, 1]]
    n1, n2 = normals[picks[:, 0]], normals[picks[:, 1]]
    axes = np.cross(n1, n2)
    norms = np.linalg.norm(axes, axis=1)
    valid = norms > np.sin(np.radians(3.0))
    axes = axes / np.where(valid, norms, 1.0)[:, None]
    # Closest points of the lines p1 + t n1 and p2 + s n2; both normals are already across the
    # axis, so in the cross-section the lines meet. Normals face the camera: t, s < 0.
    w = p1 - p2
    cos12 = (n1 * n2).sum(axis=1)
    d, e = (n1 * w).sum(axis=1), (n2 * w).sum(axis=1)
    denom = np.where(valid, 1.0 - cos12**2, 1.0)
    t = (cos12 * e - d) / denom
    s = (e - cos12 * d) / denom
    radii = -(t + s) / 2
    centers = p1 + t[:, None] * n1
    valid &= (t < 0) & (s < 0) & (radii >= params.radius_min_m) & (radii <= params.radius_max_m)
    counts = _score_round(points, normals, centers, radii, axes, params, rng)
    best = _best(counts, valid)
    if best is None:
        return FailedFit("no cylinder hypothesis")
    model = CylinderModel(centers[best], axes[best], float(radii[best]))
    inliers = _cylinder_inliers(points, normals, model, params)
    for _ in range(params.refine_iterations):
        refined = CylinderModel.estimate(points[inliers], normals[inliers])
        if not refined or not params.radius_min_m <= refined.radius <= params.radius_max_m:
            break
        refined_inliers = _cylinder_inliers(points, normals, refined, params)
        if refined_inliers.sum() < inliers.sum():
            break
        model, inliers = refined, refined_inliers
    return _Fit(model, inliers | _cap_inliers(points, normals, model, inliers, params))


def _cap_inliers(
    points: np.ndarray,
    normals: np.ndarray,
    model: CylinderModel,
    side: np.ndarray,
    params: CloudParams,
) -> np.ndarray:
    along = (points - model.center) @ model.axis
    candidates = (
        ~side
        & (np.abs(normals @ model.axis) >= np.cos(params.normal_tolerance_rad))
        & (model.distances_to_axis(points) <= model.radius + params.fit_threshold_m)
    )
    if candidates.sum() < max(3, params.min_face_fraction * len(points)):
        return np.zeros(len(points), dtype=bool)
    # Only one end faces the camera, so the candidates' median finds its plane.
    level = float(np.median(along[candidates]))
    return candidates & (np.abs(along - level) <= params.fit_threshold_m)


def _plane_inliers(
    points: np.ndarray, normals: np.ndarray, normal: np.ndarray, offset: float, params: CloudParams
) -> np.ndarray:
    close = np.abs(points @ normal + offset) <= params.fit_threshold_m
    return close & (np.abs(normals @ normal) >= np.cos(params.normal_tolerance_rad))


def _best_face(
    points: np.ndarray,
    normals: np.ndarray,
    hyp_normals: np.ndarray,
    hyp_offsets: np.ndarray,
    valid: np.ndarray,
    params: CloudParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, float] | None:
    sub = _sample(len(points), params.score_sample, rng)
    close = np.abs(points[sub] @ hyp_normals.T + hyp_offsets) <= params.fit_threshold_m
    aligned = np.abs(normals[sub] @ hyp_normals.T) >= np.cos(params.normal_tolerance_rad)
    best = _best((close & aligned).sum(axis=0), valid)
    if best is None:
        return None
    return hyp_normals[best], float(hyp_offsets[best])


def _refine_face(
    points: np.ndarray,
    normals: np.ndarray,
    normal: np.ndarray,
    offset: float,
    params: CloudParams,
    fixed_normal: bool,
) -> tuple[PlaneModel, np.ndarray]:
    inliers = _plane_inliers(points, normals, normal, offset, params)
    if inliers.sum() >= 3:
        if fixed_normal:
            offset = -float(np.mean(points[inliers] @ normal))
        else:
            refined = PlaneModel.estimate(points[inliers])
            if refined:
                normal, offset = refined.normal, refined.offset
        inliers = _plane_inliers(points, normals, normal, offset, params)
    return PlaneModel(normal, offset), inliers


@dataclass(frozen=True)
class _CuboidFit:
    faces: tuple[PlaneModel, ...]
    face_inliers: tuple[np.ndarray, ...]

    @property
    def inliers(self) -> np.ndarray:
        return np.logical_or.reduce(self.face_inliers)


def fit_cuboid(
    points: np.ndarray, normals: np.ndarray, params: CloudParams, rng: np.random.Generator
) -> _CuboidFit | FailedFit:
    """Up to three mutually perpendicular planes, found one after another on the points the
    earlier faces left. The second face's hypotheses are built perpendicular to the first
    (two points and the first normal); the third face's normal is fixed by the first two."""
    n = len(points)
    if n < 3:
        return FailedFit("fewer than 3 points")
    trials = params.face_trials
    picks = rng.integers(0, n, size=(trials, 3))
    rows, hyp_d, valid = plane_hypotheses(points, picks)
    hyp_n = np.ascontiguousarray(rows.T)
    first = _best_face(points, normals, hyp_n, hyp_d, valid, params, rng)
    if first is None:
        return FailedFit("no plane hypothesis")
    face, inliers = _refine_face(points, normals, *first, params, fixed_normal=False)
    if inliers.sum() < 3:
        return FailedFit("the best plane lost its inliers when refined")
    faces, face_inliers = [face], [inliers]
    taken = inliers.copy()
    min_face = max(3, int(np.ceil(params.min_face_fraction * n)))
    for _ in range(2):
        rest = np.flatnonzero(~taken)
        if len(rest) < min_face:
            break
        if len(faces) == 1:
            a = points[rest[rng.integers(0, len(rest), trials)]]
            b = points[rest[rng.integers(0, len(rest), trials)]]
            hyp_n = np.cross(faces[0].normal, b - a)
            norms = np.linalg.norm(hyp_n, axis=1)
            valid = norms > 1e-6
            hyp_n = hyp_n / np.where(valid, norms, 1.0)[:, None]
        else:
            a = points[rest[rng.integers(0, len(rest), trials)]]
            hyp_n = np.broadcast_to(np.cross(faces[0].normal, faces[1].normal), (trials, 3))
            valid = np.ones(trials, dtype=bool)
        hyp_d = -(hyp_n * a).sum(axis=1)
        found = _best_face(points[rest], normals[rest], hyp_n, hyp_d, valid, params, rng)
        if found is None:
            break
        face, inliers = _refine_face(points, normals, *found, params, fixed_normal=True)
        inliers &= ~taken
        if inliers.sum() < min_face:
            break
        faces.append(face)
        face_inliers.append(inliers)
        taken |= inliers
    return _CuboidFit(tuple(faces), tuple(face_inliers))


def _bent_face(points: np.ndarray, face: PlaneModel, params: CloudParams) -> bool:
    """Whether a cuboid's face, through its inlier ``points``, bends like a round's arc: the
    quadratic surface fitted across the face (least squares, the depth off the plane against
    the two in-plane coordinates) curves, along its most bent direction, at least like a
    circle of ``flat_face_min_radius_m``.

    The face's band (``fit_threshold_m`` either side) holds a strip of a round's arc 20-30 mm
    wide, and a matcher's smoothed rims let two or three such strips explain a lying or
    upright can as well as its own cylinder does (SGBM 7 at 0.04 dots/px², IR supersampled,
    HH with P2 x 4, BM 9 with a prefilter cap of 25: 40-49 % of the segment against 36-47 %).
    Across the strip the arc still bends by its radius, 17-40 per metre for these cans; a
    box's face, even under the coarsest matcher's noise, bends less than 3 per metre."""
    if params.flat_face_min_radius_m <= 0 or len(points) < 6:
        return False
    q = points - points.mean(axis=0)
    u = np.cross(face.normal, (1.0, 0.0, 0.0))
    if float(np.linalg.norm(u)) < 0.5:
        u = np.cross(face.normal, (0.0, 1.0, 0.0))
    u /= np.linalg.norm(u)
    v = np.cross(face.normal, u)
    scale = 0.01  # centred and scaled to centimetres for a well-conditioned solve
    x, y, w = q @ u / scale, q @ v / scale, q @ face.normal / scale
    design = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=1)
    coef, _, rank, _ = np.linalg.lstsq(design, w, rcond=None)
    if rank < 6:
        return False
    hessian = np.array([[2 * coef[0], coef[1]], [coef[1], 2 * coef[2]]]) / scale
    bend = float(np.max(np.abs(np.linalg.eigvalsh(hessian))))
    return bend * params.flat_face_min_radius_m >= 1.0


def _min_area_rectangle(uv: np.ndarray) -> np.ndarray:
    """Unit direction of one side of the smallest rectangle around 2-D points (rotating
    calipers over the convex hull's edges)."""
    try:
        hull = uv[ConvexHull(uv).vertices]
    except QhullError:
        centred = uv - uv.mean(axis=0)
        return np.linalg.svd(centred, full_matrices=False)[2][0]
    edges = np.roll(hull, -1, axis=0) - hull
    edges = edges / np.maximum(np.linalg.norm(edges, axis=1), 1e-12)[:, None]
    across = np.column_stack([-edges[:, 1], edges[:, 0]])
    along_extent = np.ptp(hull @ edges.T, axis=0)
    across_extent = np.ptp(hull @ across.T, axis=0)
    return edges[int(np.argmin(along_extent * across_extent))]


# The turns of a face's direction searched from the smallest rectangle's (see
# _straightest_sides): every degree over a quarter turn (a rectangle's sides repeat every 90),
# then every tenth of one over +-1 around the best.
_SIDE_TURNS_RAD = (
    np.radians(np.arange(-45.0, 45.0, 1.0)),
    np.radians(np.arange(-1.0, 1.05, 0.1)),
)
# The turns of ``side`` along which the points that are a strip's extreme take part (see
# _straightest_sides): every direction lies within 7.5 degrees of one of them or of its normal.
_EXTREME_TURNS_RAD = np.radians(np.arange(0.0, 90.0, 15.0))


def _straightest_sides(
    uv: np.ndarray, side: np.ndarray, strip_m: float, fine_m: float
) -> np.ndarray:
    """Unit direction along which the face's points ``uv`` (2-D) have the straightest sides:
    cut in strips ``strip_m`` wide along each side, the median absolute deviation of the
    strips' extremes (each side's), summed over the four sides, is smallest. The search
    starts from ``side`` and covers every direction.

    A stereo matcher fattens an occluding edge by an amount that varies along it (3-15 px at
    SGBM 7 where the background is far and dim), and the smallest rectangle around the points
    turns to follow the stretches that reach furthest: the full cloud's upright box was
    3.1-3.8 degrees off its axis at SGBM 5-9 (up to 9.5), and 0.7-0.8 on the exact depth of the
    same poses. Those stretches lie beyond the median strip of their side, whose deviation
    leaves them out. Under a strong smoothness term (SGBM 7 with P1 x 3, P2 x 6) the face's
    depth fills the dim background and the occluded band beside it in blotches up to 100 mm
    across, and the smallest rectangle turned the upright box 18-38 degrees on 6 of 10
    frames: further than any turn near it reaches. Only the points that are a strip's extreme
    (strips ``fine_m`` wide) along one of six directions 15 degrees apart take part: a turn of
    up to 7.5 degrees hardly makes another one extreme."""
    keep = np.zeros(len(uv), dtype=bool)
    start = math.atan2(side[1], side[0]) + _EXTREME_TURNS_RAD
    for angle in start:
        direction = np.array([math.cos(angle), math.sin(angle)])
        a, b = uv @ direction, uv @ np.array([-direction[1], direction[0]])
        for across, along in ((a, b), (b, a)):
            lows, highs = _strip_extremes(across[:, None], along[:, None], fine_m)
            keep[lows] = True
            keep[highs] = True
    edge = uv[keep]
    best = math.atan2(side[1], side[0])
    for turns in _SIDE_TURNS_RAD:
        angles = best + turns
        directions = np.column_stack([np.cos(angles), np.sin(angles)])
        along_u = edge @ directions.T
        across_u = edge @ np.column_stack([-directions[:, 1], directions[:, 0]]).T
        spread = _sides_spread(along_u, across_u, strip_m) + _sides_spread(
            across_u, along_u, strip_m
        )
        best = float(angles[int(np.argmin(spread))])
    return np.array([math.cos(best), math.sin(best)])


def _strip_extremes(
    across: np.ndarray, along: np.ndarray, strip_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per column of ``across`` and ``along`` (n points, k directions): the points cut in
    strips ``strip_m`` wide along ``along``, the flat indices (column-major, as
    ``ravel(order="F")``) of each strip's lowest and highest ``across``, column by column."""
    k = across.shape[1]
    strips = np.floor((along - along.min(axis=0)) / strip_m).astype(np.intp)
    width = int(strips.max()) + 1
    key = (strips + width * np.arange(k)).ravel(order="F")
    order = _grouped_order(across.ravel(order="F"), key)
    key = key[order]
    change = np.flatnonzero(key[1:] != key[:-1])
    return order[np.concatenate([[0], change + 1])], order[np.concatenate([change, [len(key) - 1]])]


def _sides_spread(across: np.ndarray, along: np.ndarray, strip_m: float) -> np.ndarray:
    """Per direction (column): the median absolute deviation of the strips' lowest ``across``
    plus that of their highest (see ``_strip_extremes``)."""
    n, k = across.shape
    lows, highs = _strip_extremes(across, along, strip_m)
    values = across.ravel(order="F")
    return _grouped_mad(values[lows], lows // n, k) + _grouped_mad(values[highs], highs // n, k)


def _grouped_mad(x: np.ndarray, group: np.ndarray, k: int) -> np.ndarray:
    """Median absolute deviation of ``x`` about its median within each of ``k`` groups."""
    median = _grouped_median(x, group, k)
    return _grouped_median(np.abs(x - median[group]), group, k)


def _grouped_median(x: np.ndarray, group: np.ndarray, k: int) -> np.ndarray:
    """Median of ``x`` within each of ``k`` groups (``group``: each value's, none empty)."""
    xs = x[_grouped_order(x, group)]
    counts = np.bincount(group, minlength=k)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return 0.5 * (xs[starts + (counts - 1) // 2] + xs[starts + counts // 2])


def _grouped_order(x: np.ndarray, group: np.ndarray) -> np.ndarray:
    """Indices that sort by ``group`` (integers), then by ``x`` within each: one argsort of
    the group plus ``x`` scaled into [0, 2/3) (np.lexsort's two stable passes cost 4 times
    as much on the 30 000 values of a face's 52 directions)."""
    low = float(x.min())
    span = float(x.max()) - low
    return np.argsort(group + (x - low) / (1.5 * span if span > 0 else 1.0))


def _camera_facing(
    points: np.ndarray, model: SphereModel | CylinderModel, params: CloudParams, pixel_rad: float
) -> SphereModel | CylinderModel:
    """The model refitted (geometrically) on the points within ``fit_threshold_m`` of it and
    at least ``silhouette_margin_px`` inside its silhouette: the part that faces the camera,
    which edge fattening and the steep rim do not reach. Twice, since fattened points widen
    the first fit's silhouette. The model as it was when too few points remain."""
    return _facing_passes(points, model, params, pixel_rad)[0]


def _facing_passes(
    points: np.ndarray,
    model: SphereModel | CylinderModel,
    params: CloudParams,
    pixel_rad: float,
    passes: int = 0,
    from_points: bool = False,
    banded_sides: tuple[bool, bool] = (True, True),
) -> tuple[SphereModel | CylinderModel, int]:
    """_camera_facing's fit, and the refits it made counting the ``passes`` already made on
    ``model`` (its margin still ``silhouette_margin_px``): two such passes resume with the
    rim band's. With ``from_points`` the margin counts from the silhouette the close points
    show on each side (_points_silhouette) instead of the fit's. The rim band runs on the
    sides (_points_silhouette's order) ``banded_sides`` names: its margin moves in there
    only."""
    margin = params.silhouette_margin_px * pixel_rad
    if margin <= 0:
        return model, passes
    solid = _solid(model)
    need = max(10, len(points) // 8)
    band = params.rim_band_px * pixel_rad
    one_sided = not all(banded_sides)
    margins = [margin, margin]
    while True:
        residuals = solid.residuals(points)
        close = residuals <= params.fit_threshold_m
        if one_sided:
            inside, gaps = _points_silhouette(points, solid, close)
            if len(gaps) != 2:
                break
            # Each side's own margin: a point's distance in past it (0 at the margin).
            for (side, _), side_margin in zip(gaps, margins, strict=True):
                inside[side] -= side_margin - margin
            banded = np.zeros(len(points), dtype=bool)
            for (side, _), on in zip(gaps, banded_sides, strict=True):
                banded |= side & on
        elif from_points:
            inside, gaps = _points_silhouette(points, solid, close)
            # The cap keeps a small round's fit on enough arc: the margin within the outer
            # half of its half-width in view.
            cap = max(0.0, _half_width(solid) / 2 - margin)
            for side, gap in gaps:
                if gap > 0:
                    inside[side] -= min(cap, gap)
        else:
            inside = solid.silhouette_distance(points)
        if passes >= 2:
            # The fit's own rim band: points pulled toward the camera lie outside the solid.
            rim = close & (inside >= margin - band) & (inside < margin)
            if one_sided:
                rim &= banded
            if band <= 0 or np.count_nonzero(rim) < 5:
                break
            outward = _outward(points, solid)
            spread = 1.4826 * float(np.median(np.abs(outward[close & (inside >= margin)])))
            # The band's median against its own noise (a median's error, 1.25 sd / sqrt(n)).
            noise = 3.0 * 1.2533 * spread / math.sqrt(np.count_nonzero(rim))
            if float(np.median(outward[rim])) <= max(params.rim_bulge_m, noise):
                break
            if one_sided:
                # The margin stays put on the other side: ``inside`` counts from each side's.
                margins = [m + band * on for m, on in zip(margins, banded_sides, strict=True)]
                inside = np.where(banded, inside - band, inside)
            else:
                margin += band
        keep = close & (inside >= margin)
        if np.count_nonzero(keep) < need:
            break
        refit = (
            SphereSolid.estimate(points[keep], init=(solid.center, solid.radius))
            if isinstance(solid, SphereSolid)
            else CylinderSolid.estimate(points[keep], solid.axis, iterations=2)
        )
        if not refit or not params.radius_min_m <= refit.radius <= params.radius_max_m:
            break
        solid = refit
        passes += 1
    return _model(solid), passes


def _round_facing(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    points: np.ndarray,
    model: SphereModel | CylinderModel,
    params: CloudParams,
    support: np.ndarray | None = None,
) -> SphereModel | CylinderModel:
    """The round's camera-facing fit (_camera_facing): its rim band moves in past the margin
    only where a window matcher made the frame, and only on a side with its background far
    behind (_far_sides), where the matcher pulls the rim toward the camera: a can standing
    tilted before its table has the table just past one side, not the other. On one side
    only where the round does not lie along the supporting plane (``support``, its points;
    _along_table): a can lying on its table leaves the fit there to the resting fit."""
    pixel_rad = 1.0 / intrinsics.fx
    fixed, passes = _facing_passes(points, model, replace(params, rim_band_px=0.0), pixel_rad)
    # Fewer than two passes: the rim band's run would have stopped where this one did.
    if passes < 2:
        return fixed
    far = _far_sides(depth, intrinsics, fixed, params)
    if not any(far) or (not all(far) and _along_table(fixed, support)):
        return fixed
    banded = params.rim_band_px > 0 and _window_matched(depth, intrinsics, params)
    if all(far) and _wider_than_points(points, fixed, params):
        run = params if banded else replace(params, rim_band_px=0.0)
        return _facing_passes(points, model, run, pixel_rad, from_points=True)[0]
    if not banded:
        return fixed
    # The band's run makes the same two passes first: resume from them.
    return _facing_passes(points, fixed, params, pixel_rad, passes, banded_sides=far)[0]


def _flattened_flanks(
    points: np.ndarray, model: SphereModel | CylinderModel, params: CloudParams
) -> SphereModel | CylinderModel:
    """The round refitted (a cylinder's axis kept) on its crest: its close points at least
    ``crest_inset`` of its half-width in view inside its silhouette, where that spans a width
    more than ``crest_narrower_m`` narrower than ``model``; else ``model``.

    A window matcher carries the rims' depth toward the camera over the flanks (a window's
    reach and, with strong smoothness, further: SGBM 11 and P1 x 3 with P2 x 6 left the 50-75
    mm cans 2-5 mm wide), and the camera-facing fit (_round_facing) follows the flattened arc
    where no rim band stands out of it. The crest lies further in than a window reaches from
    either rim (its half-width in view is 26-39 px at the benchmark's ranges), so its bend is
    the can's own; a tight window's smoothing bends it slightly more than the can does, and
    the crest's fit has its own noise: its width came out 0.5-1.5 mm narrower on SGBM 3-7,
    within ``crest_narrower_m``, so only a larger gap tells a flattened arc. (A block
    matcher's frames mostly read too little correlation for the caller's gate, BM 11's too.)

    A ball's arc flattens alike: the 70 mm ball on SGBM 11, where the table's plane was not
    found, fitted 3.6-6.6 mm wide at the 6 px margin, 1.1-2.1 on its crest. A cap alone
    trades its radius against its centre's depth, and a tight window bends it tighter still
    (SGBM 7, the same ball resting: its crest 0.8-5.2 mm narrower than a fit that was right), so
    the caller leaves a ball whose fit touches its table (_touches) to that fit.

    A prism standing with an edge toward the camera, taken for a cylinder, has a crest that
    bends tighter too, but as a ridge: its faces meet in the crest's middle, which stands out
    of the crest's circle where a can's arc sits on it (over the outer crest, the studied
    settings' hexagonal prism read +0.04..+0.39 mm, mostly +0.19 and more; the standing cans
    the rule fired on -0.11..+0.12, with two noisy frames and two lying cans at 0.18-0.22);
    the narrower radius there would shrink the prism past its width (_proud_ridge)."""
    if params.crest_narrower_m <= 0:
        return model
    solid = _solid(model)
    close = solid.residuals(points) <= params.fit_threshold_m
    crest = close & (solid.silhouette_distance(points) >= params.crest_inset * _half_width(solid))
    if np.count_nonzero(crest) < max(10, len(points) // 8):
        return model
    refit = (
        SphereSolid.estimate(points[crest], init=(solid.center, solid.radius))
        if isinstance(solid, SphereSolid)
        else CylinderSolid.estimate(points[crest], solid.axis, iterations=2)
    )
    if (
        not refit
        or not params.radius_min_m <= refit.radius
        or 2 * (model.radius - refit.radius) <= params.crest_narrower_m
        or (isinstance(refit, CylinderSolid) and _proud_ridge(points[crest], refit, params))
    ):
        return model
    return _model(refit)


def _proud_ridge(crest: np.ndarray, solid: CylinderSolid, params: CloudParams) -> bool:
    """Whether the crest's middle (points at least 1 - ``ridge_middle`` of the half-width in
    view inside ``solid``'s silhouette) lies out of ``solid`` by more than ``ridge_proud_m``
    beyond the rest of ``crest`` (medians): two faces meeting in a ridge, not an arc."""
    if params.ridge_proud_m <= 0:
        return False
    middle = solid.silhouette_distance(crest) >= (1 - params.ridge_middle) * _half_width(solid)
    if min(np.count_nonzero(middle), np.count_nonzero(~middle)) < 5:
        return False
    outward = _outward(crest, solid)
    proud = float(np.median(outward[middle])) - float(np.median(outward[~middle]))
    return proud > params.ridge_proud_m


def _along_table(model: SphereModel | CylinderModel, support: np.ndarray | None) -> bool:
    """Whether the cylinder's axis lies nearer the supporting plane (``support``, its points)
    than its normal: a can lying on its table, the table along a whole side of it. False for
    a sphere, or without such a plane."""
    if not isinstance(model, CylinderModel) or support is None or len(support) < 3:
        return False
    table = _support_refit(support)
    return table is not None and abs(float(table[0] @ model.axis)) < math.sqrt(0.5)


def _solid(model: SphereModel | CylinderModel) -> SphereSolid | CylinderSolid:
    if isinstance(model, SphereModel):
        return SphereSolid(center=model.center, radius=model.radius)
    return CylinderSolid(point=model.center, axis=model.axis, radius=model.radius)


def _model(solid: SphereSolid | CylinderSolid) -> SphereModel | CylinderModel:
    """``_solid``'s inverse."""
    if isinstance(solid, SphereSolid):
        return SphereModel(solid.center, solid.radius)
    return CylinderModel(solid.point, solid.axis, solid.radius)


def _half_width(solid: SphereSolid | CylinderSolid) -> float:
    """The round's half-width in view (radians): asin(radius / range) of its centre (a
    cylinder's: across its axis)."""
    if isinstance(solid, SphereSolid):
        reach = float(np.linalg.norm(solid.center))
    else:
        c = solid.point
        reach = float(np.linalg.norm(c - (c @ solid.axis) * solid.axis))
    return math.asin(min(1.0, solid.radius / reach)) if reach > 0 else 0.0


def _points_silhouette(
    points: np.ndarray, solid: SphereSolid | CylinderSolid, close: np.ndarray
) -> tuple[np.ndarray, list[tuple[np.ndarray, float]]]:
    """Each point's view angle in from the solid's silhouette, and on each side of the solid
    in view (left and right of a cylinder's axis; of a sphere's centre) that side's points
    with how far in the ``close`` points' own edge lies (their 2nd percentile; nan with fewer
    than 10 close points there)."""
    inside = solid.silhouette_distance(points)
    if isinstance(solid, SphereSolid):
        centre = solid.center
        across = np.cross(centre, (0.0, 1.0, 0.0))
    else:
        centre = solid.point
        across = np.cross(solid.axis, centre)
    norm = float(np.linalg.norm(across))
    if norm < 1e-9:
        return inside, []
    along = (points - centre) @ (across / norm)
    gaps = []
    for side in (along > 0, along <= 0):
        edge = inside[side & close]
        gaps.append((side, float(np.percentile(edge, 2)) if len(edge) >= 10 else math.nan))
    return inside, gaps


def _wider_than_points(
    points: np.ndarray, model: SphereModel | CylinderModel, params: CloudParams
) -> bool:
    """Whether the fit's silhouette lies beyond its close points' on both sides by more than
    a voxel in view (``voxel_m`` over the range): the grid alone leaves the points' edge up
    to a voxel inside the true silhouette, and an occluded side (a matcher's left-right
    check) only one side. Rims a window matcher pulled toward the camera flatten the arc and
    widen the fit past both edges (SGBM 11's upright 60 mm can: 3-8 px each side at 64-78
    mm); per-pixel noise, as lpc's noise model's, leaves them within a pixel."""
    solid = _solid(model)
    close = solid.residuals(points) <= params.fit_threshold_m
    _, gaps = _points_silhouette(points, solid, close)
    voxel = params.voxel_m / float(np.linalg.norm(model.center))
    return len(gaps) == 2 and all(gap > voxel for _, gap in gaps)


def _far_sides(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    model: SphereModel | CylinderModel,
    params: CloudParams,
) -> tuple[bool, bool]:
    """Whether the background past each side of the round lies far behind it (_far_behind), in
    _points_silhouette's order: a cylinder's two sides across its axis; a sphere's both when
    all four of its rims (left, right, up, down in view) are far, else neither. A table just
    behind a rim (a ball or a can lying on it) takes the window's pull the other way."""
    middle = model.center
    ray = middle / np.linalg.norm(middle)
    ratio = params.far_background_ratio

    def far(e: np.ndarray) -> bool:
        return _far_behind(depth, intrinsics, middle + model.radius * e, e, ratio=ratio)

    if isinstance(model, CylinderModel):
        across = np.cross(model.axis, ray)
        if np.linalg.norm(across) < 1e-6:
            return False, False
        across /= np.linalg.norm(across)
        return far(across), far(-across)
    e1 = np.cross(ray, (0.0, 1.0, 0.0))
    e1 /= np.linalg.norm(e1)
    every = all(far(sign * e) for e in (e1, np.cross(ray, e1)) for sign in (1.0, -1.0))
    return every, every


def _window_matched(depth: np.ndarray, intrinsics: Intrinsics, params: CloudParams) -> bool:
    """Whether the frame's scan lines hold residuals correlated like a window matcher's
    (``scans.residual_correlation`` at least ``window_correlation_gate``, as _measured_fattening
    asks): per-pixel noise, as lpc's noise model's, pulls no rim."""
    from lpc_core.perception.scans import cut_scan_lines, residual_correlation

    scan_lines = cut_scan_lines(depth, intrinsics)
    correlation = residual_correlation(scan_lines.angles_rad, scan_lines.points)
    return correlation >= params.window_correlation_gate


def _outward(points: np.ndarray, solid: SphereSolid | CylinderSolid) -> np.ndarray:
    """Signed distance of each point from the solid's surface, positive outside it."""
    if isinstance(solid, SphereSolid):
        return np.linalg.norm(points - solid.center, axis=1) - solid.radius
    w = points - solid.point
    across = w - np.outer(w @ solid.axis, solid.axis)
    return np.linalg.norm(across, axis=1) - solid.radius


def _pierced_face(
    points: np.ndarray, fit: _CuboidFit, params: CloudParams
) -> tuple[PlaneModel, np.ndarray, int]:
    """The face the optical axis pierces (see ``_cuboid_geometry``), its points, its index."""
    ranking = []
    for face, inliers in zip(fit.faces, fit.face_inliers, strict=True):
        face_points = points[inliers]
        radial = float(np.hypot(face_points[:, 0], face_points[:, 1]).min())
        missed = True
        t = 0.0
        if abs(face.normal[2]) > 1e-6:
            t = -face.offset / face.normal[2]  # where the optical axis meets the face's plane
            gap = np.linalg.norm(face_points - (0.0, 0.0, t), axis=1).min()
            missed = not (t > 0 and gap <= params.pierce_tolerance_m)
        ranking.append((missed, -t if not missed else radial))
    index = min(range(len(fit.faces)), key=ranking.__getitem__)
    return fit.faces[index], points[fit.face_inliers[index]], index


def _cuboid_geometry(
    points: np.ndarray,
    whole: np.ndarray,
    fit: _CuboidFit,
    pierced: tuple[PlaneModel, np.ndarray, int],
    params: CloudParams,
    pixel_rad: float = 0.0,
    support: np.ndarray | None = None,
    trimmed: Callable[[np.ndarray, np.ndarray], bool] | None = None,
    matched: bool = False,
) -> tuple[float, np.ndarray, np.ndarray]:
    """Grasp width, principal axis and centre of the face the optical axis pierces.

    The optical axis enters a convex solid through the face whose plane it meets last (as in
    the slab test), so the pierced face is, of the faces whose plane the axis meets within
    ``pierce_tolerance_m`` of their own points, the one met furthest; when the axis meets
    none (the benchmark forgives loose aiming), the face whose points come closest to the
    axis. Its edges follow the other faces' normals when there are any, else its smallest
    bounding rectangle, or where a matcher made the frame (``matched``) the straightest sides
    near it (``_straightest_sides``); the principal axis runs along its longer side and the
    grasp width is its shorter side, measured on the whole segment (``whole``), not only on
    the subset the faces were fitted on, so that the extreme points are not lost to
    sampling. A side that no other face's points reach, nor the supporting plane's
    (``support``, see ``_on_support``), is an occluding edge: where stretches of it reach
    further out than the rest, the median stretch bounds it (``_strip_sides``), and it moves
    in by ``edge_fattening_px`` (stereo matching's fattening lies on the face's own plane
    there), if ``trimmed`` (given the side's middle and its outward direction, both 3-D) says
    so or is None. Where a matcher made the frame, a side standing on the supporting plane
    goes out to the line the two planes meet on (``_contact_lines``).
    """
    face, face_points, index = pierced
    others = [f.normal for i, f in enumerate(fit.faces) if i != index]
    if others:
        e1 = others[0] - (others[0] @ face.normal) * face.normal
        e1 /= np.linalg.norm(e1)
    else:
        helper, _ = _orthonormal_basis(face.normal)
        e2h = np.cross(face.normal, helper)
        uv = np.column_stack([face_points @ helper, face_points @ e2h])
        side = _min_area_rectangle(uv)
        if matched:
            # A matcher fattened the face's occluding edges: the smallest rectangle follows
            # the stretches that reach furthest (see _straightest_sides).
            side = _straightest_sides(uv, side, 2 * params.voxel_m, params.voxel_m)
        e1 = side[0] * helper + side[1] * e2h
    e2 = np.cross(face.normal, e1)
    s1, s2 = face_points @ e1, face_points @ e2
    # The whole segment's points on the face, within two voxels of the subset's rectangle.
    margin = 2 * params.voxel_m
    w1, w2 = whole @ e1, whole @ e2
    on_face = (
        (np.abs(face.signed_distances(whole)) <= params.fit_threshold_m)
        & (w1 >= s1.min() - margin)
        & (w1 <= s1.max() + margin)
        & (w2 >= s2.min() - margin)
        & (w2 <= s2.max() + margin)
    )
    face_whole = whole[on_face]
    s1, s2 = face_whole @ e1, face_whole @ e2
    extremes = (float(s1.min()), float(s1.max()), float(s2.min()), float(s2.max()))
    # A side that another face's points reach is a shared edge; only the others occlude the
    # background, which a matcher fattens.
    near = 2 * params.voxel_m
    met = np.zeros(len(points), dtype=bool)
    for i, inliers in enumerate(fit.face_inliers):
        if i != index:
            met |= inliers
    o1, o2 = points[met] @ e1, points[met] @ e2
    standing = _on_support(face, (e1, e2), extremes, support, near)
    occluding = [
        not np.any(np.abs(o - edge) <= near) and not on_support
        for edge, o, on_support in zip(extremes, (o1, o1, o2, o2), standing, strict=True)
    ]
    strip_m, tolerance = 2 * params.voxel_m, params.side_tolerance_m
    strips = (*_strip_sides(s1, s2, strip_m, tolerance), *_strip_sides(s2, s1, strip_m, tolerance))
    lo1, hi1, lo2, hi2 = (
        strip if free else edge
        for strip, edge, free in zip(strips, extremes, occluding, strict=True)
    )
    if matched and params.side_gap_m > 0:
        # Only the two sides across the face's shorter extent, which the grasp spans: along
        # the longer one a gap in the face (a band without depth across a 120 mm face, SGBM 7
        # with P1 x 3 and P2 x 6) cut it shorter than the grasp.
        gap = params.side_gap_m
        if hi1 - lo1 <= hi2 - lo2:
            cut, k = _strip_sides(s1, s2, strip_m, tolerance, gap), 0
        else:
            cut, k = _strip_sides(s2, s1, strip_m, tolerance, gap), 2
        sides = [lo1, hi1, lo2, hi2]
        for j in (0, 1):
            if occluding[k + j]:
                sides[k + j] = cut[j]
        lo1, hi1, lo2, hi2 = sides
    if matched and any(standing):
        # A matcher's window straddles the crease where the face meets its table: the points
        # within about half a window of it lie off both planes, and the face stops short of
        # the line the two planes meet on (2-3 mm at SGBM 5-11, the lying box 37 mm for 40).
        # A side standing on the table goes out to that line, if it lies no further out than
        # twice the reach within which the table's points stood on the side.
        lines = _contact_lines(face, (e1, e2), (lo1, hi1, lo2, hi2), support)
        lo1, hi1, lo2, hi2 = (
            line if on and line is not None and 0 < (line - edge) * out <= 2 * near else edge
            for edge, line, on, out in zip(
                (lo1, hi1, lo2, hi2), lines, standing, (-1, 1, -1, 1), strict=True
            )
        )
    if params.edge_fattening_px > 0 and pixel_rad > 0:
        # Only the fattening within fit_threshold_m of a slanted face was counted as its own.
        z = float(np.median(face_whole[:, 2]))
        fattening_rad = params.edge_fattening_px * pixel_rad
        trim1, trim2 = (
            fattening_trim_m(face.normal[2], e, z, fattening_rad, params.fit_threshold_m)
            for e in (e1, e2)
        )
        steps = (trim1, -trim1, trim2, -trim2)
        if trimmed is not None:
            base = -face.offset * face.normal
            mid1, mid2 = (lo2 + hi2) / 2 * e2 + base, (lo1 + hi1) / 2 * e1 + base
            middles = (lo1 * e1 + mid1, hi1 * e1 + mid1, lo2 * e2 + mid2, hi2 * e2 + mid2)
            outward = (-e1, e1, -e2, e2)
            occluding = [
                free and trimmed(middle, out)
                for free, middle, out in zip(occluding, middles, outward, strict=True)
            ]
        lo1, hi1, lo2, hi2 = (
            edge + step if free else edge
            for edge, step, free in zip((lo1, hi1, lo2, hi2), steps, occluding, strict=True)
        )
        if hi1 < lo1:
            lo1 = hi1 = (lo1 + hi1) / 2
        if hi2 < lo2:
            lo2 = hi2 = (lo2 + hi2) / 2
    extent1, extent2 = hi1 - lo1, hi2 - lo2
    center = (lo1 + hi1) / 2 * e1 + (lo2 + hi2) / 2 * e2 - face.offset * face.normal
    if extent1 >= extent2:
        return extent2, e1, center
    return extent1, e2, center


# A side runs along the line where the face's plane meets its table's within this angle.
_CONTACT_PARALLEL_RAD = math.radians(5.0)


def _contact_lines(
    face: PlaneModel,
    basis: tuple[np.ndarray, np.ndarray],
    sides: tuple[float, float, float, float],
    support: np.ndarray | None,
) -> list[float | None]:
    """Where the line on which the face's plane meets the supporting plane (refitted to
    ``support``) crosses the middle of the face's nearer side that it runs along (within
    ``_CONTACT_PARALLEL_RAD``), per side ``(lo1, hi1, lo2, hi2)`` along the in-plane
    ``basis``; None for the others, and for all where the planes are near parallel."""
    out: list[float | None] = [None] * 4
    table = _support_refit(support) if support is not None and len(support) >= 3 else None
    if table is None:
        return out
    normal, offset = table
    a1, a2 = float(normal @ basis[0]), float(normal @ basis[1])
    c = float(normal @ (-face.offset * face.normal)) + offset
    slope = math.hypot(a1, a2)
    if slope < math.sin(math.pi / 6):
        # Within 30 degrees of the table's plane (a lying box's top) the face stands on no side.
        return out
    for k, (a, b) in enumerate(((a1, a2), (a2, a1))):
        if abs(b) <= math.sin(_CONTACT_PARALLEL_RAD) * slope:
            lo, hi = sides[2 * k : 2 * k + 2]
            middle = (sides[2 - 2 * k] + sides[3 - 2 * k]) / 2
            line = -(b * middle + c) / a
            out[2 * k + (abs(line - hi) < abs(line - lo))] = line
    return out


def _on_support(
    face: PlaneModel,
    basis: tuple[np.ndarray, np.ndarray],
    extremes: tuple[float, float, float, float],
    support: np.ndarray | None,
    near: float,
) -> list[bool]:
    """Which of the face's sides ``(lo1, hi1, lo2, hi2)`` (at ``extremes`` along the in-plane
    ``basis``) stand on the supporting plane: its points within ``near`` of the face's plane
    and of the side line cover half the side's length or more. Nothing lies behind such an
    edge for a matcher to fatten (a lying box's bottom edge on the table); the table that
    only touches a corner of a side (beside an upright box's foot) does not count."""
    if support is None or not len(support):
        return [False] * 4
    close = support[np.abs(face.signed_distances(support)) <= near]
    c1, c2 = close @ basis[0], close @ basis[1]
    out = []
    for k, edge in enumerate(extremes):
        across, along = (c1, c2) if k < 2 else (c2, c1)
        lo, hi = extremes[2:] if k < 2 else extremes[:2]
        on = (np.abs(across - edge) <= near) & (along >= lo) & (along <= hi)
        cells = np.unique(np.floor((along[on] - lo) / near)).size
        out.append(cells >= 0.5 * max(math.ceil((hi - lo) / near), 1))
    return out


def _strip_sides(
    across: np.ndarray, along: np.ndarray, strip_m: float, tolerance_m: float, gap_m: float = 0.0
) -> tuple[float, float]:
    """The two sides, in ``across``, of a face's points whose coordinate along those sides is
    ``along``. The points are cut in strips ``strip_m`` wide along the sides. A side whose
    strips all reach within ``tolerance_m`` of the median strip's extreme is their extreme, as
    a clean edge's is; else the matcher fattened stretches of that edge more than the rest
    (by 6-27 px on stereo frames, where the background is far and dim, at the face's own
    depth on a face seen square-on, so no scan line's depth shows it), and the median strip's
    extreme bounds the face. With ``gap_m`` (> 0), each strip keeps only its points that run
    on from the face's middle without a gap wider than that (``_contiguous``)."""
    strips = np.floor((along - along.min()) / strip_m).astype(np.intp)
    if gap_m > 0:
        across, strips = _contiguous(across, strips, gap_m)
    order = np.argsort(strips, kind="stable")
    strip = strips[order]
    starts = np.flatnonzero(np.concatenate([[True], strip[1:] != strip[:-1]]))
    lows = np.minimum.reduceat(across[order], starts)
    highs = np.maximum.reduceat(across[order], starts)
    lo_edge, hi_edge = float(np.median(lows)), float(np.median(highs))
    lo, hi = float(lows.min()), float(highs.max())
    return (
        lo if lo >= lo_edge - tolerance_m else lo_edge,
        hi if hi <= hi_edge + tolerance_m else hi_edge,
    )


# A gap parts a matcher's fill from a face only this far out or further, of the way from the
# face's middle to its extreme point on that side: a fill as wide as twice the face's half-width
# still ends past it (p2x3-lr3's upright box at 0.175 m: 17.5 mm, fills up to 20 mm), while a
# curved face's points on its plane, which a gap nearer the middle parts (the soap bar: 13 mm
# narrow as it was, 15-18 mm with every gap), keep their width.
_FILL_GAP_OUTER = 1.0 / 3.0


def _contiguous(
    across: np.ndarray, strips: np.ndarray, gap_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The points of each strip that run on from the face's middle (the median of ``across``)
    without a gap wider than ``gap_m`` in the outer part (``_FILL_GAP_OUTER``): ``across``
    and ``strips`` of those."""
    middle = float(np.median(across))
    order = np.lexsort((across, strips))
    a, k = across[order], strips[order]
    new_strip = np.concatenate([[True], k[1:] != k[:-1]])
    steps = np.concatenate([[0.0], np.diff(a)])
    # Only a gap _FILL_GAP_OUTER of the way out or further (see there).
    hi, lo = float(a.max()) - middle, middle - float(a.min())
    prev = np.concatenate([[middle], a[:-1]])
    reach = _FILL_GAP_OUTER
    outer = np.where(a > middle, prev - middle >= reach * hi, middle - a >= reach * lo)
    broken = new_strip | ((steps > gap_m) & outer)
    run = np.cumsum(broken) - 1
    # Each strip's run nearest the middle.
    distance = np.abs(a - middle)
    by = np.lexsort((distance, k))
    first = np.concatenate([[True], k[by][1:] != k[by][:-1]])
    mid_run = np.empty(k.max() + 1, dtype=np.intp)
    mid_run[k[by][first]] = run[by][first]
    keep = run == mid_run[k]
    return a[keep], k[keep]


def _measured_fattening(
    depth: np.ndarray, intrinsics: Intrinsics, face: PlaneModel, params: CloudParams
) -> tuple[float, float | None]:
    """The edge fattening (pixels) the frame shows at the pierced ``face``'s edges, measured on
    the four scan lines as the four-line method measures it
    (``lpc_core.perception.laser.measured_fattening_px``); where they show none, the
    window's (``window_fattening_px``, which may be 0) if their residuals are correlated like
    a matcher's: then the second value is that correlation (``scans.residual_correlation``),
    else None."""
    from lpc_core.perception.laser import measured_fattening_px
    from lpc_core.perception.scans import cut_scan_lines, residual_correlation
    from lpc_core.perception.solids import PlaneSolid

    # PlaneModel's normal points away from the camera, PlaneSolid's toward it.
    plane = PlaneSolid(point=-face.offset * face.normal, normal=-face.normal)
    scan_lines = cut_scan_lines(depth, intrinsics)
    measured = measured_fattening_px(scan_lines, plane)
    if measured > 0:
        return measured, None
    correlation = residual_correlation(scan_lines.angles_rad, scan_lines.points)
    if correlation < params.window_correlation_gate:
        return 0.0, None
    return params.window_fattening_px, correlation


def _past_side(
    depth: np.ndarray, intrinsics: Intrinsics, middle: np.ndarray, outward: np.ndarray
) -> tuple[np.ndarray, float] | None:
    """The depths (depth units, 0 where none) 8-30 px out in the image from a face's side's
    ``middle`` along the side's ``outward`` direction (those inside the image), and the
    cosine of that image direction with +x; None when the side lies behind the camera,
    faces along the ray or has no such pixel in the image. 8 px is past a 9 x 9 window's
    fattened band; up to 30 px reaches past the hole that an occlusion or the projector's
    shadow leaves, as wide as the disparity jump (4-6 px for a table 40 mm behind at 0.3 m),
    as the scan lines' ``past_ends_m`` reads it (scans._PAST_STEPS_PX)."""
    if float(middle[2]) <= 0:
        return None

    def pixel(p: np.ndarray) -> tuple[float, float]:
        u = intrinsics.ppx + intrinsics.fx * p[0] / p[2]
        return u, intrinsics.ppy + intrinsics.fy * p[1] / p[2]

    u0, v0 = pixel(middle)
    u1, v1 = pixel(middle + 0.005 * outward)
    du, dv = u1 - u0, v1 - v0
    norm = math.hypot(du, dv)
    if norm == 0:
        return None
    steps = np.arange(8.0, 31.0, 2.0)
    u = np.rint(u0 + steps * du / norm).astype(np.intp)
    v = np.rint(v0 + steps * dv / norm).astype(np.intp)
    inside = (u >= 0) & (u < intrinsics.width) & (v >= 0) & (v < intrinsics.height)
    if not inside.any():
        return None
    return depth[v[inside], u[inside]], du / norm


def _far_behind(
    depth: np.ndarray, intrinsics: Intrinsics, middle: np.ndarray, outward: np.ndarray, ratio: float
) -> bool:
    """Whether the background past a face's side lies far behind it: the median of the depths
    past it (_past_side) at least ``ratio`` of the side's depth further, or no depth there at
    all (nothing in range)."""
    past = _past_side(depth, intrinsics, middle, outward)
    if past is None:
        return False
    values = past[0][past[0] > 0]
    if not len(values):
        return True
    return float(np.median(values)) * intrinsics.depth_scale >= float(middle[2]) * (1.0 + ratio)


def _table_near(middle: np.ndarray, table: tuple[np.ndarray, float] | None, ratio: float) -> bool:
    """Whether the supporting plane (``table``: unit normal away from the camera, offset)
    meets the ray through a face's side's ``middle`` within ``ratio`` of the side's depth
    behind it: the background just past the side (a lying box's long sides, the table 40 mm
    below them)."""
    if table is None:
        return False
    normal, offset = table
    facing = float(normal @ middle)
    if facing <= 0:
        return False
    return -offset / facing <= 1.0 + ratio


# A face's side faces +x in the image within 60 degrees: the cosine of its outward direction
# there with +x at least this.
_FACING_X = 0.5


def _hole_past(
    depth: np.ndarray, intrinsics: Intrinsics, middle: np.ndarray, outward: np.ndarray
) -> bool:
    """Whether a face's side faces +x in the image (within 60 degrees) and the image holds no
    depth past it (_past_side), as the four-line method's ``laser._hole_past_edge`` asks of
    its lines' ends. The second imager sits along +x: its shadow band lies on a near
    object's other side, and past a side facing +x both imagers see the background, which
    lpc's noise model always gives depth; a block matcher leaves none there on most frames
    where neither the lines nor the residuals show its fattening."""
    past = _past_side(depth, intrinsics, middle, outward)
    return past is not None and past[1] > _FACING_X and not np.any(past[0] > 0)


def _fattened_past(
    depth: np.ndarray, intrinsics: Intrinsics, middle: np.ndarray, outward: np.ndarray, ratio: float
) -> bool:
    """Whether the fattening the scan lines measured widened a face's side: on a side facing +x
    in the image (within 60 degrees, see _hole_past) only where its background lies far
    behind (_far_behind), on every other side always. Past a side facing +x both imagers
    see the background, and a matcher carries the face's disparity over it only where the
    background lies far behind; where it lies near (the table 30 % behind a box tilted right,
    SGBM 5), the window's pixels there take depths between the two, off the face's plane,
    and the side was not widened (1.9 mm narrow over the 278 such frames of the 59 study
    settings with the trim). The other side holds the second imager's shadow band, which a
    matcher fills with the face's depth whatever lies behind, and past it the fill itself
    reads near (SGBM with P1 x 3 and P2 x 6: box MAE 3.9 -> 4.6 mm with every side asked)."""
    past = _past_side(depth, intrinsics, middle, outward)
    if past is None or past[1] <= _FACING_X:
        return True
    return _far_behind(depth, intrinsics, middle, outward, ratio)


def _canonical_axis(axis: np.ndarray) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    i = int(np.argmax(np.abs(axis)))
    return -axis if axis[i] < 0 else axis


def _axis_angle(axis: np.ndarray) -> float:
    return wrap_half_turn(float(np.arctan2(axis[1], axis[0])))


# --------------------------------------------------------------------------- entry point


def _none(reason: str, points: int, extra: dict[str, float]) -> Reconstruction:
    return Reconstruction(shape="none", method="cloud", reason=reason, points=points, extra=extra)


def _rest_plane(support: np.ndarray, params: CloudParams) -> PlaneSolid | None:
    """The supporting plane through ``support`` (its points; none when the frame had no such
    plane) for the resting rules, fitted once per frame; ``None`` where they are off, the
    points too few or the fit failed."""
    if params.rest_gap_ratio == 0 or len(support) < max(3, params.rest_min_support_points):
        return None
    plane = PlaneSolid.estimate(support)
    return plane if plane else None


def _resting_width(
    segment: np.ndarray,
    plane: PlaneSolid | None,
    centre: np.ndarray,
    radius: float,
    axis: np.ndarray | None,
    params: CloudParams,
    tolerance_m: float | None = None,
) -> float | None:
    """The width of a round resting on the supporting plane (``_rest_plane``), fitted again
    touching it (``solids.resting_width``; where it already touches it within ``tolerance_m``,
    by default the fit threshold, the fit stands)."""
    if plane is None:
        return None
    return resting_width(
        segment,
        plane,
        centre,
        radius,
        axis,
        gap_ratio=params.rest_gap_ratio,
        float_ratio=params.rest_float_ratio,
        max_tilt_rad=params.rest_max_tilt_rad,
        tolerance_m=params.fit_threshold_m if tolerance_m is None else tolerance_m,
        radius_limits_m=(params.radius_min_m, params.radius_max_m),
    )


def _rest_past_rims(
    segment: np.ndarray,
    plane: PlaneSolid,
    sphere: SphereModel,
    intrinsics: Intrinsics,
    params: CloudParams,
) -> float | None:
    """A resting ball's width (_resting_width) fitted again on its close points at least
    ``silhouette_margin_px`` inside the camera-facing fit's silhouette, where its half-width in
    view spans at least ``rest_margin_span`` margins; else None.

    The resting refit on all inliers keeps the rims, which a window matcher pulls toward the
    camera (the margin's reason), and the contact then holds a radius too large for them: the
    70 mm ball resting came out +1 to +2.6 mm wide on SGBM 11, HH 9 without the left-right
    check and the wide-window block matchers. Past the margin the refit sheds that pull. On a
    ball spanning few pixels the margin takes most of its view, and the cap left trades its
    radius against the contact (the 40 mm ball at 12-20 px half-width came out narrower
    still on most studied settings), so only a ball wide in view takes it."""
    if params.rest_margin_span <= 0:
        return None
    solid = _solid(sphere)
    margin_rad = params.silhouette_margin_px / intrinsics.fx
    if _half_width(solid) < params.rest_margin_span * margin_rad:
        return None
    close = solid.residuals(segment) <= params.fit_threshold_m
    inside = close & (solid.silhouette_distance(segment) >= margin_rad)
    if np.count_nonzero(inside) < 10:
        return None
    return _resting_width(segment[inside], plane, sphere.center, sphere.radius, None, params)


def _lifted_rest(
    segment: np.ndarray,
    plane: PlaneSolid | None,
    facing: SphereModel,
    whole: SphereModel,
    params: CloudParams,
) -> float | None:
    """The width of a ball whose camera-facing fit (``facing``) floats off the supporting plane
    (``_rest_plane``) while its fit on every inlier (``whole``) rests on it, fitted again
    touching it from ``whole`` (``_resting_width`` with no tolerance: even where ``whole``
    already touches it within the fit threshold); else ``None``.

    On a cap a free sphere trades its radius against its centre's depth, and a block
    matcher's noisy cap lets the trade run: BM 9 with a prefilter cap of 25, the 40 mm ball,
    trial 1: caps 31-35 mm across standing 4.4-6.5 mm off the table, too far for the resting
    rule, where the whole fit touches it or sinks 2.5 mm into it."""
    if plane is None:
        return None
    lifted = float((facing.center - plane.point) @ plane.normal) - facing.radius
    if lifted <= params.fit_threshold_m:
        return None
    return _resting_width(segment, plane, whole.center, whole.radius, None, params, 0.0)


def _touches(plane: PlaneSolid | None, sphere: SphereModel, params: CloudParams) -> bool:
    """Whether ``sphere`` stands on the supporting plane (``_rest_plane``) within the fit
    threshold: the table then holds the camera-facing fit's radius against its centre's
    depth, which a refit on the crest alone (_flattened_flanks) would trade."""
    if plane is None:
        return False
    gap = float((sphere.center - plane.point) @ plane.normal) - sphere.radius
    return abs(gap) <= params.fit_threshold_m


def _behind_support(segment: np.ndarray, support: np.ndarray, params: CloudParams) -> bool:
    """Whether more than ``segment_max_behind_fraction`` of ``segment`` lies more than
    ``support_threshold_m`` behind the plane through ``support``, as seen from the camera.
    Nothing to grasp reaches through its table: the plane is an object's face, the largest
    plane of a frame whose table a block matcher's texture check left unmatched (13 % of the
    pixels had depth on a lying box's frames at BM 7), and the segment is a stray stretch of
    mismatches that straddles the face's plane."""
    plane = _support_refit(support)
    if plane is None:
        return False
    normal, offset = plane
    behind = np.count_nonzero(segment @ normal + offset > params.support_threshold_m)
    return behind > params.segment_max_behind_fraction * len(segment)


def _within_support(segment: np.ndarray, support: np.ndarray, params: CloudParams) -> bool:
    """Whether ``segment``, fewer points than ``support``, stays within the thinnest solid
    the fits take (twice ``radius_min_m``) of the plane through ``support``, on either side
    (95th percentile of the distances). Nothing resting on a table stays that close to it:
    the plane is an object's face taken for the table, where no table was matched, and the
    segment a band of that same face whose depth the matcher bent off its plane by more
    than ``support_threshold_m`` (the lying box's front face at HH 9: its upper band 2-7 mm
    nearer, kept as the object, 15-20 mm wide for 40). A segment larger than the plane is
    left alone: a lying can's front band within 3 mm of a plane holds fewer points than the
    rest of the can, and fitted whole, with no table to rest it on, the can scattered by
    +-8 mm (BM 11, HH 9 with uneven dots: 38.8 -> 47.4, 43.0 -> 31.9 mm for 40)."""
    if len(segment) >= len(support):
        return False
    plane = _support_refit(support)
    if plane is None:
        return False
    normal, offset = plane
    distance = np.abs(segment @ normal + offset)
    return float(np.percentile(distance, 95)) < 2 * params.radius_min_m


def _aimed_past(segment: np.ndarray, support: np.ndarray, params: CloudParams) -> bool:
    """Whether the optical axis meets ``support`` and misses ``segment`` (neither comes within
    ``pierce_tolerance_m`` of it, as nearest_segment asks), and the segment lies beside the
    support's outline in view. The hand aims at what it grasps: where the axis meets the
    plane taken for the table and no segment, and the segment hides none of the plane, that
    plane is the object's face (BM 5 with texture threshold 30 left a lying box's table as
    patches of about 100 points, the box's face the largest plane, and a patch beside it the
    segment: 7-18 mm wide for 40). An object aimed beside on its table lies within the
    table's outline, hiding part of it."""
    tolerance = params.pierce_tolerance_m
    if float(np.hypot(segment[:, 0], segment[:, 1]).min()) <= tolerance:
        return False
    if not np.any(np.hypot(support[:, 0], support[:, 1]) <= tolerance):
        return False
    # A segment in front of the plane's outline in view hides part of it, as a ball on its
    # table does; one beside the outline does not rest on it.
    view = support[:, :2] / support[:, 2:]
    middle = np.median(segment[:, :2] / segment[:, 2:], axis=0)
    try:
        hull = ConvexHull(view)
    except QhullError:
        return False
    return bool(np.max(hull.equations[:, :2] @ middle + hull.equations[:, 2]) > 0)


def reconstruct_cloud(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    params: CloudParams = CloudParams(),
    seed: int = 0,
) -> Reconstruction:
    """Reconstruct the object nearest the optical axis from one full depth frame.

    Parameters
    ----------
    depth : (H, W) uint16 ndarray
        The depth frame in ``intrinsics.depth_scale`` units, 0 meaning no depth.
    intrinsics : Intrinsics
        Must match the frame's size.
    params : CloudParams
    seed : int
        Seeds every RANSAC draw (use the frame's ``seq``).

    Returns a ``Reconstruction`` with ``method="cloud"``; ``points`` counts the points after the
    crop and the voxel grid, and ``extra`` holds ``raw_points`` (cropped, before the grid),
    ``support_points``, ``segments``, ``segment_points`` and each model's inlier fraction.
    A frame with nothing to fit gives ``shape="none"`` and a ``reason``.
    """
    rng = np.random.default_rng(seed)
    raw = crop_points(depth, intrinsics, params)
    extra: dict[str, float] = {"raw_points": float(len(raw))}
    if len(raw) == 0:
        return _none("no points in the crop box", 0, extra)
    cloud, _ = voxel_downsample(raw, params.voxel_m)
    used = len(cloud)

    keep = np.ones(used, dtype=bool)
    removed: list[np.ndarray] = []
    for _ in range(params.support_planes):
        left = np.flatnonzero(keep)
        mask = find_support_plane(cloud[left], params, rng)
        if mask is None:
            break
        removed.append(left[mask])
        keep[left[mask]] = False
    # If removing the plane left nothing to grasp, or only something behind it, the plane was
    # the object: put it back.
    while True:
        rest = cloud[keep]
        labels = grid_clusters(rest, params.cluster_cell_m)
        found = nearest_segment(rest, labels, params.min_segment_points, params.pierce_tolerance_m)
        if not removed:
            break
        if (
            found is not None
            and not _behind_support(rest[found], cloud[removed[-1]], params)
            and not _aimed_past(rest[found], cloud[removed[-1]], params)
            and not _within_support(rest[found], cloud[removed[-1]], params)
        ):
            break
        keep[removed.pop()] = True
    extra["support_points"] = float(used - keep.sum())
    extra["segments"] = float(labels.max() + 1) if len(labels) else 0.0
    if found is None:
        return _none(f"no segment with at least {params.min_segment_points} points", used, extra)
    whole = rest[found]
    extra["segment_points"] = float(len(whole))
    # A random subset keeps the fits' cost flat; normals still use the whole segment.
    segment = whole[np.sort(_sample(len(whole), params.fit_points, rng))]
    extra["fit_points"] = float(len(segment))
    normals = estimate_normals(whole, params.normal_neighbours, at=segment)

    fits = {
        "sphere": fit_sphere(segment, normals, params, rng),
        "cylinder": fit_cylinder(segment, normals, params, rng),
        "cuboid": fit_cuboid(segment, normals, params, rng),
    }
    fractions = {name: float(fit.inliers.mean()) if fit else 0.0 for name, fit in fits.items()}
    for name, fraction in fractions.items():
        extra[f"{name}_fraction"] = fraction
    shape = max(fractions, key=fractions.__getitem__)
    cuboid = fits["cuboid"]
    if (
        shape == "cuboid"
        and isinstance(cuboid, _CuboidFit)
        and _bent_face(segment[cuboid.face_inliers[0]], cuboid.faces[0], params)
    ):
        # No box: the next best model decides, and may still explain too little.
        extra["bent_face"] = 1.0
        fractions = {**fractions, "cuboid": 0.0}
        shape = max(fractions, key=fractions.__getitem__)
    confidence = fractions[shape]
    if confidence < params.min_inlier_fraction:
        return _none(f"best model ({shape}) explains {confidence:.0%} of the segment", used, extra)
    fit = fits[shape]
    pixel_rad = 1.0 / intrinsics.fx
    support = cloud[~keep]
    if isinstance(fit, _Fit) and isinstance(fit.model, SphereModel):
        sphere = _round_facing(depth, intrinsics, segment, fit.model, params)
        plane = _rest_plane(support, params)
        resting = _resting_width(
            segment[fit.inliers], plane, sphere.center, sphere.radius, None, params
        )
        if resting is not None:
            resting = _rest_past_rims(segment, plane, sphere, intrinsics, params) or resting
        if resting is None and sphere is not fit.model:
            resting = _lifted_rest(segment[fit.inliers], plane, sphere, fit.model, params)
        if (
            resting is None
            and params.crest_narrower_m > 0
            and not _touches(plane, sphere, params)
            and _window_matched(depth, intrinsics, params)
        ):
            sphere = _flattened_flanks(segment, sphere, params)
        return Reconstruction(
            shape="sphere", method="cloud",
            grasp_width_m=2 * sphere.radius if resting is None else resting,
            center_m=tuple(map(float, sphere.center)), confidence=confidence,
            points=used, extra=extra,
        )  # fmt: skip
    if isinstance(fit, _Fit) and isinstance(fit.model, CylinderModel):
        cylinder = _round_facing(depth, intrinsics, segment, fit.model, params, support)
        resting = _resting_width(
            segment[fit.inliers],
            _rest_plane(support, params),
            cylinder.center,
            cylinder.radius,
            cylinder.axis,
            params,
        )
        # A can lying on its table keeps the resting fit's width; per-pixel noise, as lpc's
        # noise model's, flattens no flank, and a tapering object's crest bends tighter.
        if (
            resting is None
            and params.crest_narrower_m > 0
            and _window_matched(depth, intrinsics, params)
        ):
            cylinder = _flattened_flanks(segment, cylinder, params)
        axis = _canonical_axis(cylinder.axis)
        on_axis = segment[fit.inliers] - cylinder.center
        middle = cylinder.center + float(np.median(on_axis @ axis)) * axis
        return Reconstruction(
            shape="cylinder", method="cloud",
            grasp_width_m=2 * cylinder.radius if resting is None else resting,
            wrist_angle_rad=_axis_angle(axis), center_m=tuple(map(float, middle)),
            axis=tuple(map(float, axis)), confidence=confidence, points=used, extra=extra,
        )  # fmt: skip
    assert isinstance(fit, _CuboidFit)
    pierced = _pierced_face(segment, fit, params)
    trimmed = None
    matched = params.edge_fattening_px > 0
    if params.edge_fattening_px == 0 and params.measure_fattening:
        fattening, correlation = _measured_fattening(depth, intrinsics, pierced[0], params)
        extra["fattening_px"] = fattening
        params = replace(params, edge_fattening_px=fattening)
        if correlation is not None:
            extra["residual_correlation"] = correlation
            ratio = params.far_background_ratio
            trimmed = partial(_far_behind, depth, intrinsics, ratio=ratio)
        elif fattening > 0:
            # The lines measured it: taken off every side but one facing +x whose background
            # is near (_fattened_past).
            ratio = params.far_background_ratio
            trimmed = partial(_fattened_past, depth, intrinsics, ratio=ratio)
        # A matcher made the frame whether or not its window is trimmed (window_fattening_px 0).
        matched = fattening > 0 or correlation is not None
    holes: list[bool] = []
    if extra.get("fattening_px") == 0.0 and trimmed is None and params.hole_fattening_px > 0:
        # Neither the lines nor the residuals show a matcher: a block matcher's hole past a
        # side facing +x may (_hole_past); the geometry untrimmed, its sides asked on the way.
        def asked(middle: np.ndarray, outward: np.ndarray) -> bool:
            holes.append(_hole_past(depth, intrinsics, middle, outward))
            return False

        trimmed = asked
        params = replace(params, edge_fattening_px=params.hole_fattening_px)
    width, axis, center = _cuboid_geometry(
        segment, whole, fit, pierced, params, pixel_rad, support=support, trimmed=trimmed,
        matched=matched,
    )  # fmt: skip
    if any(holes):
        extra["fattening_px"] = params.hole_fattening_px
        table = _support_refit(support) if len(support) >= 3 else None
        ratio = params.far_background_ratio

        def far(middle: np.ndarray, outward: np.ndarray) -> bool:
            # A block matcher's missing depth tells no far background: the table may lie there,
            # and where no table was found (left unmatched, as on BM 7's lying box) nothing does.
            return (
                table is not None
                and _far_behind(depth, intrinsics, middle, outward, ratio)
                and not _table_near(middle, table, ratio)
            )

        width, axis, center = _cuboid_geometry(
            segment, whole, fit, pierced, params, pixel_rad, support=support, trimmed=far,
            matched=matched,
        )  # fmt: skip
    axis = _canonical_axis(axis)
    extra["cuboid_faces"] = float(len(fit.faces))
    return Reconstruction(
        shape="cuboid", method="cloud", grasp_width_m=width, wrist_angle_rad=_axis_angle(axis),
        center_m=tuple(map(float, center)), axis=tuple(map(float, axis)),
        confidence=confidence, points=used, extra=extra,
    )  # fmt: skip


__all__ = [
    "SCAN_LINE_SUPPORT",
    "CloudParams",
    "CylinderModel",
    "FailedFit",
    "FitModel",
    "PlaneModel",
    "SphereModel",
    "Support",
    "SupportHypotheses",
    "crop_points",
    "estimate_normals",
    "find_support",
    "find_support_plane",
    "fit_cuboid",
    "fit_cylinder",
    "fit_sphere",
    "grid_clusters",
    "nearest_segment",
    "plane_hypotheses",
    "reconstruct_cloud",
    "smallest_eigenvectors",
    "support_hypotheses",
    "voxel_downsample",
]
