"""A simulated D435-like depth camera: analytic primitives, a z-buffer renderer, a noise model.

Frames and units: metres throughout. The WORLD frame has z up and, by convention here, the
support (table) at z = 0. The camera frame is RealSense's: x right, y down, z forward; a camera
pose is the 4x4 world-from-camera transform.

Rays: a primitive is intersected with rays cast from the origin of the frame it is expressed in,
with directions ``(x/z, y/z, 1)`` per pixel. The renderer moves the primitives into the camera
frame (a handful of 3-vectors) instead of moving ~100k rays into the world, and because the
direction's z is 1 the ray parameter of a hit *is* its depth.

Noise (``NoiseModel``): range noise RMS = z² s / (f B) (Intel's depth RMS formula with subpixel
s ≈ 0.08, baseline B = 50 mm, f = fx), quantisation to the depth unit, random holes, flying
pixels at depth edges, the occlusion shadow seen from the second imager at +B along x (it falls
to the LEFT of near objects), and the min/max range. Invalid depth is 0, as on the device.

Everything is a pure function of its arguments: randomness only from the ``rng`` passed in.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Literal, Protocol, Self

import numpy as np

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.reconstruction import wrap_half_turn

TruthShape = Literal["sphere", "cylinder", "cuboid"]

_EPS_T = 1e-9
"""Hits closer than this (metres along a unit-z ray) are treated as the ray's own origin."""

_EYE3 = np.eye(3)

_AXIS_ALONG_VIEW = 0.1
"""A principal axis whose image-plane projection is shorter than this (unit axis, i.e. within
~5.7 degrees of the optical axis) has no defined wrist angle."""


# --------------------------------------------------------------------------- small helpers


def _vec3(value: object, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite 3-vector, got {value!r}")
    return arr


def _unit(value: object, name: str) -> np.ndarray:
    arr = _vec3(value, name)
    norm = float(np.linalg.norm(arr))
    if norm < 1e-12:
        raise ValueError(f"{name} must be non-zero, got {value!r}")
    return arr / norm


def _rotation(value: object, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3, 3) or not float(np.abs(arr @ arr.T - _EYE3).max()) <= 1e-6:
        raise ValueError(f"{name} must be a 3x3 rotation matrix")
    (a, b, c), (d, e, f), (g, h, i) = arr.tolist()
    if a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) < 0:
        raise ValueError(f"{name} must be a proper rotation (det +1)")
    return arr


def _positive(value: float, name: str) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number, got {value}")
    return value


def check_pose(pose: object, name: str = "camera_pose") -> np.ndarray:
    """Validate a 4x4 rigid transform and return it as float64."""
    arr = np.asarray(pose, dtype=np.float64)
    if arr.shape != (4, 4) or not np.isfinite(arr).all():
        raise ValueError(f"{name} must be a finite 4x4 matrix")
    if arr[3].tolist() != [0.0, 0.0, 0.0, 1.0]:
        raise ValueError(f"{name} must have a last row of (0, 0, 0, 1)")
    _rotation(arr[:3, :3], name)
    return arr


def rotation_about(axis: Sequence[float], angle_rad: float) -> np.ndarray:
    """Rotation matrix by ``angle_rad`` about ``axis`` (right-hand rule, Rodrigues)."""
    k = _unit(axis, "axis")
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle_rad) * kx + (1.0 - np.cos(angle_rad)) * (kx @ kx)


def make_pose(rotation: object = None, translation: object = (0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 rigid transform from a rotation matrix (default identity) and a translation."""
    pose = np.eye(4)
    if rotation is not None:
        pose[:3, :3] = _rotation(rotation, "rotation")
    pose[:3, 3] = _vec3(translation, "translation")
    return pose


def invert_pose(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform, without a general matrix inverse."""
    inv = np.eye(4)
    inv[:3, :3] = pose[:3, :3].T
    inv[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return inv


def look_at(
    eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 0.0, 1.0)
) -> np.ndarray:
    """World-from-camera pose of a camera at ``eye`` whose optical axis (+z) points at ``target``.

    The camera's y axis (image down) is as close to ``-up`` as the view allows; when the view is
    along ``up`` the world y axis stands in for it.
    """
    eye_v = _vec3(eye, "eye")
    z = _unit(np.asarray(target, dtype=np.float64) - eye_v, "target - eye")
    up_v = _unit(up, "up")
    x = np.cross(z, up_v)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, (0.0, 1.0, 0.0)) if abs(z[1]) < 0.9 else np.cross(z, (1.0, 0.0, 0.0))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.column_stack([x, y, z]), eye_v)


@dataclass(frozen=True, eq=False)
class Rays:
    """Ray directions ``(dx, dy, dz)`` from the frame origin, as broadcastable arrays.

    The renderer passes a row of x/z slopes (1, w), a column of y/z slopes (h, 1) and dz = 1,
    so linear and quadratic forms of the direction cost one or two full-size operations each
    (the row and column terms are summed while still small). Coefficients are converted to
    Python floats so that float32 rays stay float32. ``dd`` (|d|²) may be given precomputed.
    """

    dx: np.ndarray | float
    dy: np.ndarray | float
    dz: np.ndarray | float
    dd: np.ndarray | None = None

    @classmethod
    def single(cls, direction: Sequence[float]) -> Rays:
        d = np.asarray(direction, dtype=np.float64)
        return cls(d[0:1], d[1:2], d[2:3])

    @property
    def shape(self) -> tuple[int, ...]:
        return np.broadcast(self.dx, self.dy, self.dz).shape

    def lin(self, a: Sequence[float]) -> np.ndarray:
        """a . d for each ray."""
        a0, a1, a2 = (float(x) for x in a)
        return (self.dx * a0 + self.dz * a2) + self.dy * a1

    def quad(self, m: np.ndarray) -> np.ndarray:
        """d^T m d for each ray (m symmetric 3x3)."""
        m = np.asarray(m, dtype=np.float64)
        row = self.dx * (self.dx * float(m[0, 0]) + self.dz * (2.0 * float(m[0, 2])))
        row = row + float(m[2, 2]) * self.dz * self.dz
        col = self.dy * (self.dy * float(m[1, 1]) + self.dz * (2.0 * float(m[1, 2])))
        return (row + col) + (self.dx * (2.0 * float(m[0, 1]))) * self.dy

    def norm2(self) -> np.ndarray:
        return self.quad(np.eye(3)) if self.dd is None else self.dd


def _entry(t_near: np.ndarray, t_far: np.ndarray) -> np.ndarray:
    """Entry parameter of a hit interval [t_near, t_far], inf where the ray misses it.

    Rays that start inside a solid see nothing of it (the camera is never inside an object).
    """
    return np.where((t_near <= t_far) & (t_near > _EPS_T), t_near, np.inf)


# --------------------------------------------------------------------------- primitives


class Primitive(Protocol):
    """A solid that can be ray cast. Rays start at the origin of the primitive's frame."""

    def intersect(self, rays: Rays) -> np.ndarray:
        """Ray parameter of the first hit along ``t * d`` for each ray, inf if none."""
        ...

    def transformed(self, pose: np.ndarray) -> Primitive:
        """The same solid moved by the rigid transform ``pose``."""
        ...

    def bounds(self) -> tuple[np.ndarray, float]:
        """A bounding sphere (centre, radius)."""
        ...

    def support(self, direction: np.ndarray) -> float:
        """max over the solid of p . direction (for bounding boxes and resting on a table)."""
        ...


@dataclass(frozen=True, eq=False)
class Sphere:
    center: np.ndarray
    radius: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        object.__setattr__(self, "radius", _positive(self.radius, "radius"))

    def intersect(self, rays: Rays) -> np.ndarray:
        # |t d - c|² = r²  ->  (d.d) t² - 2 (d.c) t + (c.c - r²) = 0; keep the entry root.
        c = self.center
        dd = rays.norm2()
        b = rays.lin(c)
        cc = float(c @ c) - self.radius**2
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (b - np.sqrt(b * b - dd * cc)) / dd
        return np.where(t > _EPS_T, t, np.inf)

    def transformed(self, pose: np.ndarray) -> Sphere:
        return Sphere(pose[:3, :3] @ self.center + pose[:3, 3], self.radius)

    def bounds(self) -> tuple[np.ndarray, float]:
        return self.center, self.radius

    def support(self, direction: np.ndarray) -> float:
        return float(self.center @ direction + self.radius * np.linalg.norm(direction))


def _cone_support(
    center: np.ndarray, axis: np.ndarray, r0: float, r1: float, length: float, d: np.ndarray
) -> float:
    # A truncated cone is the convex hull of its two end discs.
    along = float(axis @ d)
    across = float(np.sqrt(max(float(d @ d) - along * along, 0.0)))
    ends = (-0.5 * length * along + r0 * across, 0.5 * length * along + r1 * across)
    return float(center @ d) + max(ends)


def _axial_slab(
    rays: Rays, axis: np.ndarray, h0: float, half: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(d.a, entry, exit) of the slab |h| <= half between the caps, h = h0 + t (d.a)."""
    da = rays.lin(axis)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / da
        s1 = (-half - h0) * inv
        s2 = (half - h0) * inv
    return da, np.fmin(s1, s2), np.fmax(s1, s2)


@dataclass(frozen=True, eq=False)
class Cylinder:
    """Solid capped cylinder: ``center`` is the middle of the axis segment of ``length``."""

    center: np.ndarray
    axis: np.ndarray
    radius: float
    length: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        object.__setattr__(self, "axis", _unit(self.axis, "axis"))
        object.__setattr__(self, "radius", _positive(self.radius, "radius"))
        object.__setattr__(self, "length", _positive(self.length, "length"))

    def intersect(self, rays: Rays) -> np.ndarray:
        # Convex solid = infinite cylinder ∩ slab between the caps: intersect the two intervals.
        # Infinite cylinder: |w + t d|² - (h0 + t d.a)² = r², w = -c, h0 = w.a.
        c, a = self.center, self.axis
        h0 = float(-c @ a)
        qc = float(c @ c) - h0 * h0 - self.radius**2
        da, lo, hi = _axial_slab(rays, a, h0, 0.5 * self.length)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            qa = rays.norm2() - da * da
            mqb = rays.lin(c) + h0 * da  # -(w.d - h0 d.a)
            sq = np.sqrt(mqb * mqb - qa * qc)
            inv = 1.0 / qa
            # NaN roots (the ray misses the infinite cylinder) propagate into a miss.
            t_near = np.maximum((mqb - sq) * inv, lo)
            t_far = np.minimum((mqb + sq) * inv, hi)
        if qc <= 0:
            # The origin lies within the infinite cylinder: rays parallel to the axis (0/0
            # roots) stay inside it, so only the caps bound them.
            parallel = qa <= 1e-12
            t_near = np.where(parallel, lo, t_near)
            t_far = np.where(parallel, hi, t_far)
        return _entry(t_near, t_far)

    def transformed(self, pose: np.ndarray) -> Cylinder:
        rot = pose[:3, :3]
        return Cylinder(rot @ self.center + pose[:3, 3], rot @ self.axis, self.radius, self.length)

    def bounds(self) -> tuple[np.ndarray, float]:
        return self.center, float(np.hypot(self.radius, 0.5 * self.length))

    def support(self, direction: np.ndarray) -> float:
        r = self.radius
        return _cone_support(self.center, self.axis, r, r, self.length, direction)


@dataclass(frozen=True, eq=False)
class Cone:
    """Solid truncated cone: radius ``radius_bottom`` at ``center - axis*length/2``,
    ``radius_top`` at ``center + axis*length/2`` (a conic mug)."""

    center: np.ndarray
    axis: np.ndarray
    radius_bottom: float
    radius_top: float
    length: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        object.__setattr__(self, "axis", _unit(self.axis, "axis"))
        for name in ("radius_bottom", "radius_top"):
            value = float(getattr(self, name))
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a non-negative finite number, got {value}")
            object.__setattr__(self, name, value)
        if max(self.radius_bottom, self.radius_top) <= 0:
            raise ValueError("radius_bottom or radius_top must be positive")
        object.__setattr__(self, "length", _positive(self.length, "length"))

    def intersect(self, rays: Rays) -> np.ndarray:
        # Lateral quadric |p - c|² - h² = (k h + m)², k = (r1 - r0)/L, m = (r0 + r1)/2, is a
        # double cone; between the caps only the object's nappe lies (the apex is outside the
        # slab), so each root is kept if its h is within the slab, and caps are discs.
        c, a = self.center, self.axis
        r0, r1, length = self.radius_bottom, self.radius_top, self.length
        h0 = float(-c @ a)
        ww = float(c @ c)
        k = (r1 - r0) / length
        m = 0.5 * (r0 + r1)
        q = k * h0 + m
        half = 0.5 * length
        da = rays.lin(a)
        wd = -rays.lin(c)
        dd = rays.norm2()
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            qa = dd - (1.0 + k * k) * da * da
            qb = wd - h0 * da - k * q * da
            qc = ww - h0 * h0 - q * q
            sq = np.sqrt(qb * qb - qa * qc)
            best = np.full(np.broadcast(da, dd).shape, np.inf)
            for t in ((-qb - sq) / qa, (-qb + sq) / qa):
                h = h0 + t * da
                ok = (t > _EPS_T) & (np.abs(h) <= half) & (k * h + m >= 0.0)
                best = np.where(ok & (t < best), t, best)
            for sign, radius in ((-1.0, r0), (1.0, r1)):
                t = (sign * half - h0) / da
                rad2 = ww + 2.0 * t * wd + t * t * dd - half * half
                ok = (t > _EPS_T) & (rad2 <= radius * radius)
                best = np.where(ok & (t < best), t, best)
        return best

    def transformed(self, pose: np.ndarray) -> Cone:
        rot = pose[:3, :3]
        return Cone(
            rot @ self.center + pose[:3, 3],
            rot @ self.axis,
            self.radius_bottom,
            self.radius_top,
            self.length,
        )

    def bounds(self) -> tuple[np.ndarray, float]:
        return self.center, float(
            np.hypot(max(self.radius_bottom, self.radius_top), 0.5 * self.length)
        )

    def support(self, direction: np.ndarray) -> float:
        return _cone_support(
            self.center, self.axis, self.radius_bottom, self.radius_top, self.length, direction
        )


@dataclass(frozen=True, eq=False)
class Cuboid:
    """Solid box: ``rotation`` columns are the box's local x, y, z axes; ``size`` the full
    edge lengths along them."""

    center: np.ndarray
    rotation: np.ndarray
    size: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        object.__setattr__(self, "rotation", _rotation(self.rotation, "rotation"))
        size = _vec3(self.size, "size")
        if np.any(size <= 0):
            raise ValueError(f"size must be positive, got {self.size!r}")
        object.__setattr__(self, "size", size)

    def _slabs(self, rays: Rays, track_face: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # Slab method (Kay and Kajiya): the box is the intersection of three slabs.
        ol = -(self.center @ self.rotation)
        t_near: np.ndarray = np.asarray(-np.inf)
        t_far: np.ndarray = np.asarray(np.inf)
        face = np.zeros(rays.shape, dtype=np.int64)
        with np.errstate(invalid="ignore", divide="ignore"):
            for k in range(3):
                half = 0.5 * float(self.size[k])
                inv = 1.0 / rays.lin(self.rotation[:, k])
                t1 = (-half - float(ol[k])) * inv
                t2 = (half - float(ol[k])) * inv
                lo = np.fmin(t1, t2)
                if track_face:
                    face = np.where(lo > t_near, k, face)
                t_near = np.fmax(t_near, lo)
                t_far = np.fmin(t_far, np.fmax(t1, t2))
        return t_near, t_far, face

    def interval(self, rays: Rays) -> tuple[np.ndarray, np.ndarray]:
        """(entry, exit) ray parameters of the box; entry > exit where the ray misses."""
        t_near, t_far, _ = self._slabs(rays, track_face=False)
        return t_near, t_far

    def entered_face(self, rays: Rays) -> tuple[np.ndarray, np.ndarray]:
        """(t, local axis index of the face each ray enters by)."""
        t_near, t_far, face = self._slabs(rays, track_face=True)
        return _entry(t_near, t_far), face

    def intersect(self, rays: Rays) -> np.ndarray:
        t_near, t_far, _ = self._slabs(rays, track_face=False)
        return _entry(t_near, t_far)

    def transformed(self, pose: np.ndarray) -> Cuboid:
        rot = pose[:3, :3]
        return Cuboid(rot @ self.center + pose[:3, 3], rot @ self.rotation, self.size)

    def bounds(self) -> tuple[np.ndarray, float]:
        return self.center, float(0.5 * np.linalg.norm(self.size))

    def support(self, direction: np.ndarray) -> float:
        return float(self.center @ direction + 0.5 * np.abs(direction @ self.rotation) @ self.size)


@dataclass(frozen=True, eq=False)
class Ellipsoid:
    """Solid ellipsoid with ``semi_axes`` along the columns of ``rotation``."""

    center: np.ndarray
    rotation: np.ndarray
    semi_axes: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        object.__setattr__(self, "rotation", _rotation(self.rotation, "rotation"))
        semi = _vec3(self.semi_axes, "semi_axes")
        if np.any(semi <= 0):
            raise ValueError(f"semi_axes must be positive, got {self.semi_axes!r}")
        object.__setattr__(self, "semi_axes", semi)

    def _roots(self, rays: Rays) -> tuple[np.ndarray, np.ndarray]:
        # (t d - c)^T M (t d - c) = 1 with M = R diag(1/s²) R^T: a quadratic in t whose
        # coefficients are quadratic / linear forms of d. NaN where the ray misses.
        rs = self.rotation / self.semi_axes
        m = rs @ rs.T
        c = self.center
        a = rays.quad(m)
        b = rays.lin(m @ c)
        cc = float(c @ m @ c) - 1.0
        with np.errstate(invalid="ignore", divide="ignore"):
            sq = np.sqrt(b * b - a * cc)
            return (b - sq) / a, (b + sq) / a

    def interval(self, rays: Rays) -> tuple[np.ndarray, np.ndarray]:
        """(entry, exit) ray parameters; NaN where the ray misses."""
        return self._roots(rays)

    def intersect(self, rays: Rays) -> np.ndarray:
        t = self._roots(rays)[0]
        return np.where(t > _EPS_T, t, np.inf)

    def transformed(self, pose: np.ndarray) -> Ellipsoid:
        rot = pose[:3, :3]
        return Ellipsoid(rot @ self.center + pose[:3, 3], rot @ self.rotation, self.semi_axes)

    def bounds(self) -> tuple[np.ndarray, float]:
        return self.center, float(np.max(self.semi_axes))

    def support(self, direction: np.ndarray) -> float:
        return float(
            self.center @ direction + np.linalg.norm((direction @ self.rotation) * self.semi_axes)
        )


@dataclass(frozen=True, eq=False)
class Plane:
    """Infinite plane through ``point`` with ``normal`` (the support, e.g. a table top)."""

    point: np.ndarray
    normal: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "point", _vec3(self.point, "point"))
        object.__setattr__(self, "normal", _unit(self.normal, "normal"))

    def intersect(self, rays: Rays) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            t = float(self.normal @ self.point) / rays.lin(self.normal)
        return np.where(t > _EPS_T, t, np.inf)

    def transformed(self, pose: np.ndarray) -> Plane:
        rot = pose[:3, :3]
        return Plane(rot @ self.point + pose[:3, 3], rot @ self.normal)

    def bounds(self) -> tuple[np.ndarray, float]:
        return self.point, np.inf

    def support(self, direction: np.ndarray) -> float:
        return np.inf


@dataclass(frozen=True, eq=False)
class ConvexPolyhedron:
    """Solid convex polyhedron given by its local vertices (a hexagonal prism, a tapered bar).

    The half-spaces ``n . p <= offset`` (local frame) are derived from the vertices' hull.
    """

    center: np.ndarray
    rotation: np.ndarray
    vertices: np.ndarray
    normals: np.ndarray = field(init=False, repr=False)
    offsets: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        from scipy.spatial import ConvexHull

        object.__setattr__(self, "center", _vec3(self.center, "center"))
        object.__setattr__(self, "rotation", _rotation(self.rotation, "rotation"))
        verts = np.asarray(self.vertices, dtype=np.float64)
        if verts.ndim != 2 or verts.shape[1] != 3 or len(verts) < 4:
            raise ValueError("vertices must be an (N>=4, 3) array")
        object.__setattr__(self, "vertices", verts)
        # Qhull gives one row per triangle; coplanar triangles repeat a face plane.
        eq = np.unique(np.round(ConvexHull(verts).equations, 12), axis=0)
        object.__setattr__(self, "normals", eq[:, :3])
        object.__setattr__(self, "offsets", -eq[:, 3])

    def intersect(self, rays: Rays) -> np.ndarray:
        # Generalised slab method: entering planes raise t_near, leaving planes lower t_far.
        ol = -(self.center @ self.rotation)
        t_near: np.ndarray = np.asarray(-np.inf)
        t_far: np.ndarray = np.asarray(np.inf)
        with np.errstate(invalid="ignore", divide="ignore"):
            for n, off in zip(self.normals, self.offsets, strict=True):
                denom = rays.lin(self.rotation @ n)
                num = float(off) - float(n @ ol)
                t = num / denom
                t_near = np.where(denom < 0, np.fmax(t_near, t), t_near)
                # A ray parallel to a face plane and outside it misses the solid.
                t_far = np.where(denom > 0, np.fmin(t_far, t), t_far)
                if num < 0:
                    t_far = np.where(denom == 0, -np.inf, t_far)
        return _entry(t_near, t_far)

    def transformed(self, pose: np.ndarray) -> ConvexPolyhedron:
        rot = pose[:3, :3]
        return ConvexPolyhedron(rot @ self.center + pose[:3, 3], rot @ self.rotation, self.vertices)

    def bounds(self) -> tuple[np.ndarray, float]:
        return self.center, float(np.max(np.linalg.norm(self.vertices, axis=1)))

    def support(self, direction: np.ndarray) -> float:
        return float(self.center @ direction + np.max(self.vertices @ (direction @ self.rotation)))


def _march_implicit(
    f_local: Callable[[np.ndarray], np.ndarray],
    center: np.ndarray,
    rotation: np.ndarray,
    bound: Cuboid | Ellipsoid,
    rays: Rays,
    steps: int,
) -> np.ndarray:
    """First root of an implicit surface (f <= 0 inside, local frame) along each ray: sample
    ``steps`` points across the convex ``bound``, then bisect the first sign change.

    A feature thinner than the chord / ``steps`` can be stepped over at grazing incidence.
    """
    shape = rays.shape
    t_near, t_far = bound.interval(rays)
    t_near = np.broadcast_to(t_near, shape).reshape(-1)
    t_far = np.broadcast_to(t_far, shape).reshape(-1)
    out = np.full(t_near.size, np.inf)
    hits = np.flatnonzero((t_near <= t_far) & (t_far > _EPS_T))
    if hits.size == 0:
        return out.reshape(shape)
    d = np.stack(
        [
            np.broadcast_to(np.asarray(c, dtype=np.float64), shape).reshape(-1)[hits]
            for c in (rays.dx, rays.dy, rays.dz)
        ],
        axis=-1,
    )
    t_in = np.maximum(t_near[hits], _EPS_T)
    frac = np.linspace(0.0, 1.0, steps)
    ts = t_in[:, None] + (t_far[hits] - t_in)[:, None] * frac[None, :]

    def f_at(t: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        return f_local((t[..., None] * dirs - center) @ rotation)

    inside = f_at(ts, d[:, None, :]) <= 0.0
    first = np.argmax(inside, axis=1)
    found = inside.any(axis=1)
    at_entry = np.flatnonzero(found & (first == 0))
    out[hits[at_entry]] = ts[at_entry, 0]
    rows = np.flatnonzero(found & (first > 0))
    lo = ts[rows, first[rows] - 1]
    hi = ts[rows, first[rows]]
    dk = d[rows]
    for _ in range(24):
        mid = 0.5 * (lo + hi)
        inner = f_at(mid, dk) <= 0.0
        hi = np.where(inner, mid, hi)
        lo = np.where(inner, lo, mid)
    out[hits[rows]] = hi
    return out.reshape(shape)


@dataclass(frozen=True, eq=False)
class _MarchedSolid:
    """A solid inside ``_f <= 0``, an implicit function of the local coordinates, with
    positive ``semi_axes``; rays are marched through an enclosing solid (``_shell``): slower
    than the closed-form solids."""

    center: np.ndarray
    rotation: np.ndarray
    semi_axes: np.ndarray
    steps: int = 48

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        object.__setattr__(self, "rotation", _rotation(self.rotation, "rotation"))
        semi = _vec3(self.semi_axes, "semi_axes")
        if np.any(semi <= 0):
            raise ValueError(f"semi_axes must be positive, got {self.semi_axes!r}")
        object.__setattr__(self, "semi_axes", semi)

    def _f(self, p: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _shell(self) -> Cuboid | Ellipsoid:
        raise NotImplementedError

    def intersect(self, rays: Rays) -> np.ndarray:
        return _march_implicit(self._f, self.center, self.rotation, self._shell(), rays, self.steps)

    def transformed(self, pose: np.ndarray) -> Self:
        rot = pose[:3, :3]
        return replace(self, center=rot @ self.center + pose[:3, 3], rotation=rot @ self.rotation)


@dataclass(frozen=True, eq=False, kw_only=True)
class Superellipsoid(_MarchedSolid):
    """|x/a|^p + |y/b|^p + |z/c|^p <= 1 (a bar of soap for p ≈ 4)."""

    exponent: float = 4.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.exponent < 2.0:
            raise ValueError(f"exponent must be >= 2 (convex), got {self.exponent}")

    def _f(self, p: np.ndarray) -> np.ndarray:
        e = self.exponent
        if e == int(e) and int(e) % 2 == 0:
            # Even integer powers by repeated products: much faster than a general pow.
            q2 = np.square(p / self.semi_axes)
            q = q2
            for _ in range(int(e) // 2 - 1):
                q = q * q2
        else:
            q = np.abs(p / self.semi_axes) ** e
        return np.sum(q, axis=-1) - 1.0

    def _shell(self) -> Cuboid:
        return Cuboid(self.center, self.rotation, 2.0 * self.semi_axes)  # its box

    def bounds(self) -> tuple[np.ndarray, float]:
        return self.center, float(np.linalg.norm(self.semi_axes)) * 1.001

    def support(self, direction: np.ndarray) -> float:
        # Exact along the principal axes, conservative (bounding box) elsewhere.
        return float(self.center @ direction + np.abs(direction @ self.rotation) @ self.semi_axes)


@dataclass(frozen=True, eq=False, kw_only=True)
class BumpyEllipsoid(_MarchedSolid):
    """An ellipsoid whose radius is modulated by smooth bumps (a potato): in scaled local
    coordinates q = p / semi_axes, inside when |q| <= 1 + amplitude * g(q/|q|), with
    g = sin(3 qx + 0.7) sin(2 qy + 1.9) + 0.5 sin(5 qz + 0.3)."""

    amplitude: float = 0.06

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0.0 <= self.amplitude < 0.5:
            raise ValueError(f"amplitude must be in [0, 0.5), got {self.amplitude}")

    def _f(self, p: np.ndarray) -> np.ndarray:
        q = p / self.semi_axes
        r = np.linalg.norm(q, axis=-1)
        u = q / np.maximum(r, 1e-12)[..., None]
        g = np.sin(3.0 * u[..., 0] + 0.7) * np.sin(2.0 * u[..., 1] + 1.9) + 0.5 * np.sin(
            5.0 * u[..., 2] + 0.3
        )
        return r - 1.0 - self.amplitude * g

    def _shell(self) -> Ellipsoid:
        # |g| <= 1.5, so the solid lies within the ellipsoid scaled by 1 + 1.5 amplitude.
        return Ellipsoid(self.center, self.rotation, self.semi_axes * (1.0 + 1.5 * self.amplitude))

    def bounds(self) -> tuple[np.ndarray, float]:
        return self.center, float(np.max(self.semi_axes)) * (1.0 + 1.5 * self.amplitude)

    def support(self, direction: np.ndarray) -> float:
        scaled = np.linalg.norm((direction @ self.rotation) * self.semi_axes)
        return float(self.center @ direction + scaled * (1.0 + 1.5 * self.amplitude))


# --------------------------------------------------------------------------- objects and truth


@dataclass(frozen=True, kw_only=True)
class ObjectTruth:
    """What a perfect reconstruction of the object would report from a given camera pose.

    ``center`` and ``axis`` are in the camera frame (metres; unit axis or None).
    ``wrist_angle_rad`` is the principal axis projected on the image plane (x right, y down),
    from +x toward +y, in [-pi/2, pi/2); None for a sphere, or when the axis is within ~6
    degrees of the optical axis. ``pierced`` says whether the optical axis meets the object,
    and ``pierce_depth_m`` where.
    """

    name: str
    shape: TruthShape
    grasp_width_m: float
    wrist_angle_rad: float | None
    center: tuple[float, float, float]
    axis: tuple[float, float, float] | None = None
    pierced: bool = False
    pierce_depth_m: float | None = None

    @property
    def grasp_width_mm(self) -> float:
        return 1000.0 * self.grasp_width_m

    @property
    def wrist_angle_deg(self) -> float | None:
        return None if self.wrist_angle_rad is None else float(np.degrees(self.wrist_angle_rad))


@dataclass(frozen=True, eq=False, kw_only=True)
class SceneObject:
    """A named solid (a union of primitives) and the grasp the paper would judge against.

    Ground truth rules: ``box`` set -> the cuboid rule (grasp width = the smaller extent of the
    face the optical axis pierces, principal axis = its longer edge); otherwise
    ``grasp_width_m`` is fixed and ``axis`` (world, None for a sphere) is the principal axis.
    ``center`` (world) is the aim point used by ``aim_pose``.
    """

    name: str
    parts: tuple[Primitive, ...]
    shape: TruthShape
    center: np.ndarray
    grasp_width_m: float | None = None
    axis: np.ndarray | None = None
    box: Cuboid | None = None
    note: str = ""

    def __post_init__(self) -> None:
        if not self.parts:
            raise ValueError("parts must not be empty")
        if self.shape not in ("sphere", "cylinder", "cuboid"):
            raise ValueError(f"shape must be sphere, cylinder or cuboid, got {self.shape!r}")
        object.__setattr__(self, "center", _vec3(self.center, "center"))
        if self.axis is not None:
            object.__setattr__(self, "axis", _unit(self.axis, "axis"))
        if self.box is None and self.grasp_width_m is None:
            raise ValueError("grasp_width_m is required unless box is given")

    def transformed(self, pose: np.ndarray) -> SceneObject:
        """The object moved by a rigid transform (world from object)."""
        pose = check_pose(pose, "pose")
        rot = pose[:3, :3]
        return replace(
            self,
            parts=tuple(p.transformed(pose) for p in self.parts),
            center=rot @ self.center + pose[:3, 3],
            axis=None if self.axis is None else rot @ self.axis,
            box=None if self.box is None else self.box.transformed(pose),
        )

    def translated(self, offset: Sequence[float]) -> SceneObject:
        return self.transformed(make_pose(None, offset))

    def lowest_z(self) -> float:
        down = np.array([0.0, 0.0, -1.0])
        return -max(p.support(down) for p in self.parts)

    def resting_on(self, z: float = 0.0) -> SceneObject:
        """The object translated vertically so that its lowest point touches height ``z``."""
        return self.translated((0.0, 0.0, z - self.lowest_z()))

    def bounds(self) -> tuple[np.ndarray, float]:
        centers = [p.bounds() for p in self.parts]
        radius = max(float(np.linalg.norm(c - self.center)) + r for c, r in centers)
        return self.center, radius

    def axis_depth(self, camera_pose: np.ndarray) -> float:
        """Depth at which the optical axis first meets the object (inf if it misses)."""
        cam_from_world = invert_pose(check_pose(camera_pose))
        axis = Rays.single((0.0, 0.0, 1.0))
        return min(float(p.transformed(cam_from_world).intersect(axis)[0]) for p in self.parts)

    def truth(self, camera_pose: np.ndarray) -> ObjectTruth:
        cam_from_world = invert_pose(check_pose(camera_pose))
        rot = cam_from_world[:3, :3]
        center = rot @ self.center + cam_from_world[:3, 3]
        depth = self.axis_depth(camera_pose)
        pierced = bool(np.isfinite(depth))
        if self.box is not None:
            width, axis = _pierced_face(self.box.transformed(cam_from_world))
        else:
            width = float(self.grasp_width_m)  # type: ignore[arg-type]
            axis = None if self.axis is None else rot @ self.axis
        angle = None
        if axis is not None and np.hypot(axis[0], axis[1]) >= _AXIS_ALONG_VIEW:
            angle = wrap_half_turn(float(np.arctan2(axis[1], axis[0])))
        return ObjectTruth(
            name=self.name,
            shape=self.shape,
            grasp_width_m=width,
            wrist_angle_rad=angle,
            center=(float(center[0]), float(center[1]), float(center[2])),
            axis=None if axis is None else (float(axis[0]), float(axis[1]), float(axis[2])),
            pierced=pierced,
            pierce_depth_m=depth if pierced else None,
        )


def _pierced_face(box_cam: Cuboid) -> tuple[float, np.ndarray]:
    """(smaller extent, longer edge direction) of the box face the optical axis enters.

    If the axis misses the box, the face turned most toward the camera stands in: the one
    whose slab the camera lies furthest outside of, relative to the half-size. A square face's
    principal axis is its first local axis.
    """
    t, face = box_cam.entered_face(Rays.single((0.0, 0.0, 1.0)))
    if np.isfinite(t[0]):
        k = int(face[0])
    else:
        cam_local = -(box_cam.center @ box_cam.rotation)
        k = int(np.argmax(np.abs(cam_local) / box_cam.size))
    i, j = [a for a in range(3) if a != k]
    long_edge = i if box_cam.size[i] >= box_cam.size[j] else j
    return float(min(box_cam.size[i], box_cam.size[j])), box_cam.rotation[:, long_edge].copy()


def sphere_object(name: str, center: Sequence[float], radius: float, note: str = "") -> SceneObject:
    return SceneObject(
        name=name,
        parts=(Sphere(np.asarray(center), radius),),
        shape="sphere",
        center=np.asarray(center, dtype=np.float64),
        grasp_width_m=2.0 * radius,
        note=note,
    )


def cylinder_object(
    name: str,
    center: Sequence[float],
    axis: Sequence[float],
    radius: float,
    length: float,
    note: str = "",
) -> SceneObject:
    cyl = Cylinder(np.asarray(center), np.asarray(axis), radius, length)
    return SceneObject(
        name=name,
        parts=(cyl,),
        shape="cylinder",
        center=cyl.center,
        grasp_width_m=2.0 * radius,
        axis=cyl.axis,
        note=note,
    )


def cuboid_object(
    name: str,
    center: Sequence[float],
    rotation: np.ndarray,
    size: Sequence[float],
    note: str = "",
) -> SceneObject:
    box = Cuboid(np.asarray(center), rotation, np.asarray(size))
    return SceneObject(
        name=name, parts=(box,), shape="cuboid", center=box.center, box=box, note=note
    )


# --------------------------------------------------------------------------- catalogues

_MM = 0.001
_X, _Y, _Z = np.eye(3)
_TILT_DEG = 30.0


def _tilt(side: Literal["left", "right"]) -> np.ndarray:
    """Rotation leaning an upright object's top toward -x (left) or +x (right), as seen by a
    viewer on the -y side looking along +y."""
    sign = -1.0 if side == "left" else 1.0
    return rotation_about(_Y, np.radians(sign * _TILT_DEG))


def functional_objects() -> dict[str, SceneObject]:
    """The paper's ten-object set (two spheres, four cylinders, four cuboids), resting on a
    table at z = 0 around the world origin. Sizes are invented within the paper's 35-85 mm
    grasp range; tilts are 30 degrees in the x-z plane (the viewer stands at -y).

    ==================== ================================ =====================================
    name                 size (mm)                        grasp seen from the front (-y side)
    ==================== ================================ =====================================
    sphere_small         diameter 40                      40
    sphere_large         diameter 70                      70
    cylinder_upright     diameter 60, length 120          60, wrist -90 deg (axis vertical)
    cylinder_lying       diameter 40, length 140, along x 40, wrist 0
    cylinder_tilt_left   diameter 75, length 110          75, wrist +60 deg
    cylinder_tilt_right  diameter 50, length 130          50, wrist -60 deg
    cuboid_upright       35 x 60 x 120 (x, y, z)          35 (front face 35 x 120), wrist -90
    cuboid_lying         150 x 70 x 40                    front 40 / from above 70, wrist 0
    cuboid_tilt_left     45 x 45 x 130                    45, wrist +60 deg
    cuboid_tilt_right    85 x 50 x 120                    85 (front face 85 x 120), wrist -60
    ==================== ================================ =====================================
    """
    up = np.eye(3)
    lying_x = rotation_about(_Y, np.pi / 2)  # local z (the long axis) along world x
    objs = [
        sphere_object("sphere_small", (0, 0, 0), 20 * _MM, "ball, 40 mm"),
        sphere_object("sphere_large", (0, 0, 0), 35 * _MM, "ball, 70 mm"),
        cylinder_object("cylinder_upright", (0, 0, 0), _Z, 30 * _MM, 120 * _MM, "can"),
        cylinder_object("cylinder_lying", (0, 0, 0), _X, 20 * _MM, 140 * _MM, "marker"),
        cylinder_object(
            "cylinder_tilt_left", (0, 0, 0), _tilt("left") @ _Z, 37.5 * _MM, 110 * _MM, "jar"
        ),
        cylinder_object(
            "cylinder_tilt_right", (0, 0, 0), _tilt("right") @ _Z, 25 * _MM, 130 * _MM, "bottle"
        ),
        cuboid_object("cuboid_upright", (0, 0, 0), up, np.array([35, 60, 120]) * _MM, "box"),
        cuboid_object(
            "cuboid_lying", (0, 0, 0), lying_x, np.array([40, 70, 150]) * _MM, "box, lying"
        ),
        cuboid_object(
            "cuboid_tilt_left", (0, 0, 0), _tilt("left"), np.array([45, 45, 130]) * _MM, "box"
        ),
        cuboid_object(
            "cuboid_tilt_right", (0, 0, 0), _tilt("right"), np.array([85, 50, 120]) * _MM, "box"
        ),
    ]
    return {o.name: o.resting_on(0.0) for o in objs}


def _union(
    name: str,
    parts: Sequence[Primitive],
    shape: TruthShape,
    center: Sequence[float],
    width_m: float,
    axis: Sequence[float] | None,
    note: str,
) -> SceneObject:
    return SceneObject(
        name=name,
        parts=tuple(parts),
        shape=shape,
        center=np.asarray(center, dtype=np.float64),
        grasp_width_m=width_m,
        axis=None if axis is None else np.asarray(axis, dtype=np.float64),
        note=note,
    )


def _hex_prism_vertices(across_flats: float, length: float) -> np.ndarray:
    # Hexagon in local x-y (flats facing +-y), prism along local z.
    r = across_flats / np.sqrt(3.0)
    ang = np.radians(np.arange(6) * 60.0)
    ring = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    return np.vstack([np.column_stack([ring, np.full(6, s * length / 2)]) for s in (-1.0, 1.0)])


def _tapered_bar_vertices(width0: float, width1: float, thickness: float, length: float):
    # Bar along local x, tapering in y from width0 (x = -L/2) to width1 (x = +L/2).
    pts = []
    for x, w in ((-length / 2, width0), (length / 2, width1)):
        for y in (-w / 2, w / 2):
            for z in (-thickness / 2, thickness / 2):
                pts.append((x, y, z))
    return np.asarray(pts)


def irregular_objects() -> dict[str, SceneObject]:
    """The paper's stress-test set, resting on a table at z = 0 around the world origin.

    Expected results (the paper judges size within ±20 mm, angle within ±10 degrees):

    =================== ============================================= ======== ====== =========
    name                built from                                    shape    width  axis
    =================== ============================================= ======== ====== =========
    hexagonal_prism     convex prism, 60 across flats, 150 long       cuboid   60     prism axis
    soap_bar            superellipsoid 90 x 60 x 30, exponent 4       cuboid   60     long side
    tv_remote           cuboid 180 x 50 x 20 + 12 button boxes        cuboid   50     long side
    horse_toy           ellipsoid torso 130 x 44 x 50, legs, head     cylinder 44     torso
    sweet_potato        bumpy ellipsoid 130 x 62 x 56                 cylinder 62     long axis
    banana              37 spheres along a 120 mm arc, 36 mm thick    cylinder 36     chord
    pear                sphere 64 + sphere 44 above it + stalk        sphere   64     -
    jar_cap             cylinder 60 diameter, 15 high, lying flat     cylinder 60     cap axis
    conic_mug           truncated cone 70 -> 90 diameter, 95 high     cylinder 80     cone axis
    frying_pan_handle   tapered bar 150 long, 25 -> 35 wide, 12 thick cuboid   30     handle
    =================== ============================================= ======== ====== =========

    The aim point (``center``) is the part one would grasp: the torso, the lower bulb of the
    pear, the middle of the banana and of the handle. The jar cap seen from above has its axis
    along the optical axis, hence no wrist angle; from the front its axis is vertical.
    """
    up = np.eye(3)
    lying = rotation_about(_Y, np.pi / 2)  # local z along world x
    objs: list[SceneObject] = []

    prism = ConvexPolyhedron(np.zeros(3), lying, _hex_prism_vertices(60 * _MM, 150 * _MM))
    objs.append(_union("hexagonal_prism", [prism], "cuboid", (0, 0, 0), 60 * _MM, _X, "prism box"))

    soap = Superellipsoid(np.zeros(3), up, np.array([45, 30, 15]) * _MM, exponent=4.0)
    objs.append(_union("soap_bar", [soap], "cuboid", (0, 0, 0), 60 * _MM, _X, "spherocuboid"))

    body = Cuboid(np.zeros(3), up, np.array([180, 50, 20]) * _MM)
    buttons: list[Primitive] = [
        Cuboid(np.array([x, y, 11.5]) * _MM, up, np.array([9, 9, 3]) * _MM)
        for x in (-60.0, -35.0, -10.0, 15.0)
        for y in (-13.0, 0.0, 13.0)
    ]
    objs.append(
        _union("tv_remote", [body, *buttons], "cuboid", (0, 0, 0), 50 * _MM, _X, "buttons on top")
    )

    torso = Ellipsoid(np.array([0, 0, 80]) * _MM, up, np.array([65, 22, 25]) * _MM)
    legs: list[Primitive] = [
        Cylinder(np.array([x, y, 30]) * _MM, _Z, 6 * _MM, 60 * _MM)
        for x in (-45.0, 45.0)
        for y in (-12.0, 12.0)
    ]
    neck = Cylinder(np.array([70, 0, 110]) * _MM, (0.6, 0, 0.8), 10 * _MM, 50 * _MM)
    head = Ellipsoid(
        np.array([88, 0, 135]) * _MM,
        rotation_about(_Y, np.radians(60)),
        np.array([12, 11, 25]) * _MM,
    )
    objs.append(
        _union(
            "horse_toy", [torso, *legs, neck, head], "cylinder", torso.center, 44 * _MM, _X, "torso"
        )
    )

    potato = BumpyEllipsoid(np.zeros(3), up, np.array([65, 31, 28]) * _MM, amplitude=0.06)
    objs.append(
        _union("sweet_potato", [potato], "cylinder", (0, 0, 0), 62 * _MM, _X, "irregular ellipsoid")
    )

    # Banana: an arc of radius 120 mm spanning 80 degrees in the x-z plane (ends up), radius
    # tapering from 18 mm at the middle to 9 mm at the tips.
    arc_r = 120 * _MM
    angles = np.radians(np.linspace(-40.0, 40.0, 37))
    balls: list[Primitive] = [
        Sphere(
            np.array([arc_r * np.sin(a), 0.0, arc_r * (1.0 - np.cos(a))]),
            (18.0 - 9.0 * (abs(a) / np.radians(40.0)) ** 2) * _MM,
        )
        for a in angles
    ]
    objs.append(_union("banana", balls, "cylinder", (0, 0, 0), 36 * _MM, _X, "curved cylinder"))

    bottom = Sphere(np.zeros(3), 32 * _MM)
    top = Sphere(np.array([0, 0, 38]) * _MM, 22 * _MM)
    stalk = Cylinder(np.array([0, 0, 66]) * _MM, _Z, 2 * _MM, 14 * _MM)
    objs.append(_union("pear", [bottom, top, stalk], "sphere", (0, 0, 0), 64 * _MM, None, "ovoid"))

    cap = Cylinder(np.zeros(3), _Z, 30 * _MM, 15 * _MM)
    objs.append(_union("jar_cap", [cap], "cylinder", (0, 0, 0), 60 * _MM, _Z, "disc, 15 mm high"))

    mug = Cone(np.zeros(3), _Z, 35 * _MM, 45 * _MM, 95 * _MM)
    objs.append(_union("conic_mug", [mug], "cylinder", (0, 0, 0), 80 * _MM, _Z, "conical"))

    handle = ConvexPolyhedron(
        np.zeros(3), up, _tapered_bar_vertices(25 * _MM, 35 * _MM, 12 * _MM, 150 * _MM)
    )
    objs.append(
        _union("frying_pan_handle", [handle], "cuboid", (0, 0, 0), 30 * _MM, _X, "tapered bar")
    )
    return {o.name: o.resting_on(0.0) for o in objs}


# --------------------------------------------------------------------------- scene and pose


@dataclass(frozen=True, eq=False)
class Scene:
    """Objects and an optional support plane (the table), all in the world frame."""

    objects: tuple[SceneObject, ...] = ()
    support: Plane | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "objects", tuple(self.objects))


def table(height_m: float = 0.0) -> Plane:
    """A horizontal support plane at ``height_m``."""
    return Plane(np.array([0.0, 0.0, height_m]), _Z)


def aim_pose(
    obj: SceneObject,
    distance_m: float,
    azimuth_rad: float = 0.0,
    elevation_rad: float = np.radians(20.0),
    roll_rad: float = 0.0,
    aim_point: Sequence[float] | None = None,
) -> np.ndarray:
    """Pose of a camera whose optical axis pierces ``obj`` through ``aim_point`` (default: the
    object's centre), with the pierced surface ``distance_m`` ahead.

    The camera sits on the side given by ``azimuth_rad`` (0: on the -y side looking along +y;
    positive turns it counter-clockwise seen from above) and ``elevation_rad`` above the
    horizontal, then turns by ``roll_rad`` about its optical axis.
    """
    distance_m = _positive(distance_m, "distance_m")
    target = obj.center if aim_point is None else _vec3(aim_point, "aim_point")
    back = np.array(
        [
            np.sin(azimuth_rad) * np.cos(elevation_rad),
            -np.cos(azimuth_rad) * np.cos(elevation_rad),
            np.sin(elevation_rad),
        ]
    )
    far = obj.bounds()[1] + 1.0
    probe = look_at(target + far * back, target)
    depth = obj.axis_depth(probe)
    surface = target + back * (far - depth) if np.isfinite(depth) else target
    pose = look_at(surface + distance_m * back, surface)
    if roll_rad:
        pose = pose @ make_pose(rotation_about(_Z, roll_rad))
    return pose


# --------------------------------------------------------------------------- rendering


@dataclass(frozen=True, kw_only=True)
class NoiseModel:
    """D435-like depth error model; every figure is a named parameter.

    - Range noise: Gaussian on z with RMS ``z**2 * subpixel_px / (fx * baseline_m)``
      (0.17 mm at 150 mm, 0.47 mm at 250 mm for fx = 213 px).
    - Flying pixels: a pixel whose disparity (fx B / z, what stereo matching measures)
      differs from a 4-neighbour's by more than ``flying_jump_px`` is on a depth edge; with
      ``flying_probability`` it takes a depth between its own and that neighbour's (mix
      uniform in ``flying_mix``). A plane, even at grazing view, has a disparity step well
      under a pixel per pixel, so only real discontinuities fly.
    - Holes: each pixel is dropped (0) with probability ``hole_fraction``.
    - Shadow: pixels whose point is hidden from the second imager, ``baseline_m`` along +x,
      are 0 (a band to the left of near objects).
    - Range: depths below ``min_range_m`` or above ``max_range_m`` are 0.
    Quantisation to the intrinsics' depth unit is always applied.
    """

    subpixel_px: float = 0.08
    baseline_m: float = 0.05
    range_noise: bool = True
    flying_jump_px: float = 2.0
    flying_probability: float = 0.5
    flying_mix: tuple[float, float] = (0.15, 0.85)
    hole_fraction: float = 0.003
    shadow: bool = True
    min_range_m: float = 0.10
    max_range_m: float = 4.0

    def __post_init__(self) -> None:
        for name in ("subpixel_px", "baseline_m", "flying_jump_px", "max_range_m"):
            _positive(getattr(self, name), name)
        for name in ("flying_probability", "hole_fraction"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value}")
        lo, hi = self.flying_mix
        if not 0.0 <= lo <= hi <= 1.0:
            raise ValueError(f"flying_mix must be 0 <= lo <= hi <= 1, got {self.flying_mix}")
        if not 0.0 <= self.min_range_m < self.max_range_m:
            raise ValueError("min_range_m must be in [0, max_range_m)")

    @classmethod
    def exact(cls, **overrides: object) -> NoiseModel:
        """No noise at all: only quantisation and the range limits remain."""
        base = dict(range_noise=False, flying_probability=0.0, hole_fraction=0.0, shadow=False)
        base.update(overrides)
        return cls(**base)  # type: ignore[arg-type]

    def range_rms_m(self, z_m: np.ndarray | float, fx: float) -> np.ndarray | float:
        return np.square(z_m) * (self.subpixel_px / (fx * self.baseline_m))


@dataclass(frozen=True, eq=False)
class _RayGrid:
    """Per-pixel rays of one intrinsics, computed once: x/z per column (1, W), y/z per row
    (H, 1) and |d|² per pixel (H, W)."""

    u: np.ndarray
    v: np.ndarray
    dd: np.ndarray

    def window(self, v0: int, v1: int, u0: int, u1: int) -> Rays:
        return Rays(self.u[:, u0:u1], self.v[v0:v1], 1.0, self.dd[v0:v1, u0:u1])


@lru_cache(maxsize=8)
def _ray_grid(intrinsics: Intrinsics, dtype: str) -> _RayGrid:
    xs, ys = intrinsics.pixel_rays()
    u = np.ascontiguousarray(xs[:1], dtype=dtype)
    v = np.ascontiguousarray(ys[:, :1], dtype=dtype)
    dd = (u * u + v * v + 1.0).astype(dtype)
    for arr in (u, v, dd):
        arr.setflags(write=False)
    return _RayGrid(u, v, dd)


@lru_cache(maxsize=1)
def _normal_quantiles() -> np.ndarray:
    """Standard normal quantiles at the centres of 65536 equal-probability bins.

    Indexing this table with uniform 16-bit integers draws a normal variate (truncated at
    ±4.3 sigma) several times faster than ``Generator.standard_normal`` on this machine.
    """
    from scipy.special import ndtri

    table = ndtri((np.arange(65536, dtype=np.float64) + 0.5) / 65536.0)
    table.setflags(write=False)
    return table


def _pixel_box(part: Primitive, intrinsics: Intrinsics) -> tuple[int, int, int, int] | None:
    """Conservative pixel rectangle (v0, v1, u0, u1) covering a primitive in the camera frame
    (from its axis-aligned bounding box); None if it is behind the camera or off the image."""
    h, w = intrinsics.height, intrinsics.width
    axes = np.eye(3)
    hi = np.array([part.support(e) for e in axes])
    lo = np.array([-part.support(-e) for e in axes])
    if hi[2] <= _EPS_T:
        return None
    if lo[2] <= 1e-3:
        return 0, h, 0, w
    # x/z over the box is extreme at its corners (z > 0 there).
    xs = (lo[0] / lo[2], lo[0] / hi[2], hi[0] / lo[2], hi[0] / hi[2])
    ys = (lo[1] / lo[2], lo[1] / hi[2], hi[1] / lo[2], hi[1] / hi[2])
    u0 = max(int(np.floor(intrinsics.ppx + intrinsics.fx * min(xs))), 0)
    u1 = min(int(np.ceil(intrinsics.ppx + intrinsics.fx * max(xs))) + 1, w)
    v0 = max(int(np.floor(intrinsics.ppy + intrinsics.fy * min(ys))), 0)
    v1 = min(int(np.ceil(intrinsics.ppy + intrinsics.fy * max(ys))) + 1, h)
    if u0 >= u1 or v0 >= v1:
        return None
    return v0, v1, u0, u1


def _render_exact(
    scene: Scene, intrinsics: Intrinsics, camera_pose: np.ndarray, dtype: str
) -> tuple[np.ndarray, tuple[int, int, int] | None]:
    """Exact depth and the (v0, v1, u1) extent of the objects' pixel boxes (None if none)."""
    cam_from_world = invert_pose(check_pose(camera_pose))
    grid = _ray_grid(intrinsics, dtype)
    full = grid.window(0, intrinsics.height, 0, intrinsics.width)
    if scene.support is not None:
        depth = scene.support.transformed(cam_from_world).intersect(full).astype(dtype, copy=False)
    else:
        depth = np.full((intrinsics.height, intrinsics.width), np.inf, dtype=dtype)
    extent: tuple[int, int, int] | None = None
    for obj in scene.objects:
        for part in obj.parts:
            moved = part.transformed(cam_from_world)
            box = _pixel_box(moved, intrinsics)
            if box is None:
                continue
            v0, v1, u0, u1 = box
            window = depth[v0:v1, u0:u1]
            np.minimum(window, moved.intersect(grid.window(v0, v1, u0, u1)), out=window)
            extent = (
                (v0, v1, u1)
                if extent is None
                else (min(extent[0], v0), max(extent[1], v1), max(extent[2], u1))
            )
    return depth, extent


def exact_depth(
    scene: Scene, intrinsics: Intrinsics, camera_pose: np.ndarray, dtype: str = "float64"
) -> np.ndarray:
    """Noise-free depth in metres, (H, W) of ``dtype``; inf where a ray hits nothing."""
    return _render_exact(scene, intrinsics, camera_pose, dtype)[0]


def _flying_pixels(
    z: np.ndarray, disparity: np.ndarray, noise: NoiseModel, rng: np.random.Generator
) -> None:
    """Blend pixels on a disparity edge toward their neighbour across it (z in place).

    Pairs with a missing end (disparity 0) are dropped on the short candidate list.
    """
    width = z.shape[1]
    flat = z.reshape(-1)
    disp = disparity.reshape(-1)
    jump = noise.flying_jump_px
    right = np.flatnonzero(np.abs(disp[:-1] - disp[1:]) > jump)
    right = right[right % width != width - 1]
    down = np.flatnonzero(np.abs(disp[:-width] - disp[width:]) > jump)
    p = np.concatenate([right, right + 1, down, down + width])
    q = np.concatenate([right + 1, right, down + width, down])
    keep = (disp[p] > 0) & (disp[q] > 0)
    p, q = p[keep], q[keep]
    if p.size == 0:
        return
    chosen = rng.random(p.size) < noise.flying_probability
    mix = rng.uniform(noise.flying_mix[0], noise.flying_mix[1], p.size)
    p, q, mix = p[chosen], q[chosen], mix[chosen].astype(z.dtype)
    source_p, source_q = flat[p], flat[q]
    flat[p] = source_p + mix * (source_q - source_p)


def _shadow_mask(disparity: np.ndarray) -> np.ndarray:
    """Pixels hidden from a second imager displaced by the baseline along +x.

    A point at column u with disparity d = f B / z appears in the second view at u - d.
    Along a row, a pixel is hidden when some pixel to its right lands further left in that
    view (it is nearer and covers it): a reverse running minimum per row.
    """
    cols = np.arange(disparity.shape[1], dtype=disparity.dtype)[None, :]
    seen_at = cols - disparity
    running = np.minimum.accumulate(seen_at[:, ::-1], axis=1)[:, ::-1]
    hidden = np.zeros(disparity.shape, dtype=bool)
    np.less(running[:, 1:], seen_at[:, :-1], out=hidden[:, :-1])
    return hidden


@lru_cache(maxsize=4)
def _range_noise_table(scale: float, dtype: str) -> np.ndarray:
    table = (_normal_quantiles() * scale).astype(dtype)
    table.setflags(write=False)
    return table


def _apply_noise(
    z: np.ndarray,
    intrinsics: Intrinsics,
    rng: np.random.Generator,
    noise: NoiseModel,
    shadow_extent: tuple[int, int, int] | None,
) -> np.ndarray:
    """Noise ``z`` (metres, inf = no return; modified in place) into uint16 depth units.

    rng draws, in this order: flying-pixel choices and mixes, range noise, holes.
    """
    hidden = None
    if noise.shadow or noise.flying_probability > 0:
        with np.errstate(divide="ignore"):
            disparity = (intrinsics.fx * noise.baseline_m) / z
        if noise.shadow and shadow_extent is not None:
            v0, v1, u1 = shadow_extent
            hidden = _shadow_mask(disparity[v0:v1, :u1])
        if noise.flying_probability > 0:
            _flying_pixels(z, disparity, noise, rng)
    if noise.range_noise:
        scale = noise.subpixel_px / (intrinsics.fx * noise.baseline_m)
        table = _range_noise_table(scale, str(z.dtype))
        g = table[rng.integers(0, 65536, size=z.shape, dtype=np.uint16)]
        with np.errstate(invalid="ignore"):
            g *= z
            g *= z
            z += g
    max_m = min(noise.max_range_m, np.iinfo(np.uint16).max * intrinsics.depth_scale)
    with np.errstate(invalid="ignore"):
        valid = (z >= noise.min_range_m) & (z <= max_m)
    if hidden is not None:
        valid[v0:v1, :u1] &= ~hidden
    units = np.multiply(z, 1.0 / intrinsics.depth_scale, out=z)
    np.rint(units, out=units)
    with np.errstate(invalid="ignore"):
        out = units.astype(np.uint16)  # NaN / inf cast to junk, zeroed just below
    out *= valid
    if noise.hole_fraction > 0:
        n_holes = int(rng.binomial(out.size, noise.hole_fraction))
        out.reshape(-1)[rng.choice(out.size, n_holes, replace=False)] = 0
    return out


def apply_noise(
    depth_m: np.ndarray,
    intrinsics: Intrinsics,
    rng: np.random.Generator,
    noise: NoiseModel = NoiseModel(),
) -> np.ndarray:
    """Turn an exact depth map (metres, inf = no return) into a D435-like uint16 frame."""
    depth = np.asarray(depth_m)
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth_m must have shape {(intrinsics.height, intrinsics.width)}, got {depth.shape}"
        )
    dtype = depth.dtype if depth.dtype in (np.float32, np.float64) else np.float64
    z = np.array(depth, dtype=dtype)
    return _apply_noise(z, intrinsics, rng, noise, (0, z.shape[0], z.shape[1]))


def render_depth(
    scene: Scene,
    intrinsics: Intrinsics,
    camera_pose: np.ndarray,
    rng: np.random.Generator,
    noise: NoiseModel = NoiseModel(),
) -> np.ndarray:
    """Render a D435-like depth frame: uint16 (H, W) in depth units, 0 = no data.

    ``camera_pose`` is the 4x4 world-from-camera transform (camera x right, y down, z forward).
    Geometry is computed in float32 (errors of a few micrometres, far below the depth unit).
    """
    z, extent = _render_exact(scene, intrinsics, camera_pose, "float32")
    return _apply_noise(z, intrinsics, rng, noise, extent)
