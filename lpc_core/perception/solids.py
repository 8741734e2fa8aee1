"""Least-squares 3-D solids for the four-line method: sphere, cylinder and plane.

The laser method (``laser``) first fits 2-D models on each scan line, as the paper
does; the solids here then refine the 3-D object from the inliers of all four lines at once,
which is where the accuracy of the grasp width and wrist angle comes from. Each solid has the
same small surface as ``lpc_core.perception.fit``'s models: a classmethod ``estimate`` and
``residuals(points) -> (N,)`` (orthogonal distances, metres). A degenerate estimate returns a
falsy ``FailedSolid`` carrying the reason.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, Self

import numpy as np
from scipy.linalg.lapack import dgesv as _dgesv


@dataclass(frozen=True)
class FailedSolid:
    """A degenerate estimate: falsy, with the reason."""

    reason: str

    def __bool__(self) -> bool:
        return False


class Solid(Protocol):
    def residuals(self, points: np.ndarray) -> np.ndarray: ...


def _as_points(points: np.ndarray, minimum: int) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points.shape}")
    if len(points) < minimum:
        raise ValueError(f"points must hold at least {minimum} rows, got {len(points)}")
    return points


def column_sums(points: np.ndarray) -> np.ndarray:
    """``points.sum(axis=0)`` of an (N >= 1, D) array of a few columns, to the bit.

    numpy's reduction adds the rows one after another, over an inner loop as long as a row;
    the running sum down the columns adds in the same order, at a third of the cost on
    (N, 3) points."""
    return np.add.accumulate(points, axis=0)[-1]


def squared_norms(d: np.ndarray) -> np.ndarray:
    """``(d * d).sum(axis=1)`` of (N, 3) vectors, to the bit: the same additions (x^2 + y^2,
    then + z^2) on the columns, at half the cost of numpy's reduction over 3-element rows."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return x * x + y * y + z * z


def orthonormal_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit vector ``axis`` to a right-handed basis."""
    e1, e2 = _basis(*(float(v) for v in axis))
    return np.array(e1), np.array(e2)


_Vec3 = tuple[float, float, float]


def _basis(ax: float, ay: float, az: float) -> tuple[_Vec3, _Vec3]:
    """:func:`orthonormal_basis` in Python floats."""
    hx, hy = (1.0, 0.0) if abs(ax) < 0.9 else (0.0, 1.0)
    dot = hx * ax + hy * ay
    e = (hx - dot * ax, hy - dot * ay, -dot * az)
    k = 1.0 / math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    e1 = (e[0] * k, e[1] * k, e[2] * k)
    return e1, (ay * e1[2] - az * e1[1], az * e1[0] - ax * e1[2], ax * e1[1] - ay * e1[0])


def fit_circle_2d(uv: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Algebraic (Kasa) circle through (N, 2) points: centre and radius, ``None`` if singular.

    Minimises sum((u - a)^2 + (v - b)^2 - r^2)^2, linear in (a, b, r^2 - a^2 - b^2); the
    points are centred and scaled first so the normal equations stay well conditioned.
    """
    found = _circle_2d(np.ascontiguousarray(uv.T))
    return None if found is None else (np.array(found[:2]), found[2])


def _circle_2d(rows: np.ndarray) -> tuple[float, float, float] | None:
    """:func:`fit_circle_2d` of the points as contiguous rows (2, N): centre and radius in
    Python floats."""
    n = rows.shape[1]
    # np.add.reduce: ndarray.sum's own reduction, without its Python wrapper.
    mu, mv = (np.add.reduce(rows, axis=1) / n).tolist()
    # (u, v, u^2 + v^2) about the mean as contiguous rows (3, N), row by row (no broadcast).
    d = np.empty((3, n))
    np.subtract(rows[0], mu, out=d[0])
    np.subtract(rows[1], mv, out=d[1])
    np.add(d[0] * d[0], d[1] * d[1], out=d[2])
    scale2 = float(np.add.reduce(d[2])) / n
    if not (math.isfinite(scale2) and scale2 > 0):
        return None
    # The normal equations of [2u, 2v, 1] . sol = u^2 + v^2 on the points scaled to unit RMS,
    # from the moments of (u, v, u^2 + v^2) in one product (scaled afterwards, in floats).
    (guu, guv, guz), (_, gvv, gvz), (_, _, _) = (d @ d.T).tolist()
    su, sv, sz = np.add.reduce(d, axis=1).tolist()
    k1, k2 = 1.0 / math.sqrt(scale2), 1.0 / scale2
    guu, guv, gvv, su, sv = guu * k2, guv * k2, gvv * k2, su * k1, sv * k1
    guz, gvz, sz = guz * k1 * k2, gvz * k1 * k2, sz * k2
    ata = ((4 * guu, 4 * guv, 2 * su), (4 * guv, 4 * gvv, 2 * sv), (2 * su, 2 * sv, float(n)))
    # Points centred and scaled to unit RMS: a tiny determinant means they are collinear.
    sol = _solve3(ata, (2 * guz, 2 * gvz, sz), 1e-9 * n**3)
    if sol is None:
        return None
    r2 = sol[2] + sol[0] ** 2 + sol[1] ** 2
    if not r2 > 0:
        return None
    scale = math.sqrt(scale2)
    return mu + scale * sol[0], mv + scale * sol[1], scale * math.sqrt(r2)


_Row3 = tuple[float, float, float]


def _solve3(
    m: tuple[_Row3, _Row3, _Row3], b: _Row3, min_det: float
) -> tuple[float, float, float] | None:
    """``m x = b`` for a 3x3 system by Cramer's rule, in Python floats (a tenth of what
    ``numpy.linalg.solve`` costs at this size); None when ``|det m| < min_det``."""
    (a11, a12, a13), (a21, a22, a23), (a31, a32, a33) = m
    c11, c12, c13 = a22 * a33 - a23 * a32, a23 * a31 - a21 * a33, a21 * a32 - a22 * a31
    det = a11 * c11 + a12 * c12 + a13 * c13
    if not abs(det) >= min_det:
        return None
    b1, b2, b3 = b
    x1 = b1 * c11 + a12 * (a23 * b3 - b2 * a33) + a13 * (b2 * a32 - a22 * b3)
    x2 = a11 * (b2 * a33 - a23 * b3) + b1 * c12 + a13 * (a21 * b3 - b2 * a31)
    x3 = a11 * (a22 * b3 - b2 * a32) + a12 * (b2 * a31 - a21 * b3) + b1 * c13
    return x1 / det, x2 / det, x3 / det


def _solve(a: np.ndarray, b: np.ndarray) -> list[float]:
    """``numpy.linalg.solve(a, b)`` as Python floats; ``LinAlgError`` for a singular system.

    LAPACK's ``dgesv`` through SciPy's public wrapper, which numpy's ``solve`` calls too (LU
    with partial pivoting, the same bits: every one of 200 000 random 4x4 and 5x5 normal
    equations, and every solve of the live recording's frames): 1.8 us a call where numpy's
    checks, its error state and its result wrapping make 12.5 us. Sphere and cylinder fits
    solve five to ten of these a frame. A singular ``a`` (an exact zero pivot: ``info > 0``)
    raises as numpy's does."""
    _, _, x, info = _dgesv(a, b)
    if info != 0:
        raise np.linalg.LinAlgError("Singular matrix")
    return x.tolist()


def _smallest_eigenvector(m: list[list[float]]) -> list[float] | None:
    """Unit eigenvector of the smallest eigenvalue of a symmetric positive semi-definite 3x3
    matrix, in closed form (Python floats: a tenth of ``numpy.linalg.eigh`` at this size);
    None when the middle eigenvalue is below 1e-12 of the largest (rank one or zero).

    Eigenvalues by Smith's trigonometric formula (1961); the eigenvector is orthogonal to
    the rows of M - lambda I: the largest cross product of two of them.
    """
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = m
    q = (a00 + a11 + a22) / 3.0
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1) / 6.0)
    if not p > 0.0:
        return None if not q > 0.0 else [1.0, 0.0, 0.0]  # zero, or a multiple of I
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
           + a02 * (a01 * a12 - b11 * a02)) / (p * p * p)  # fmt: skip
    phi = math.acos(max(-1.0, min(1.0, 0.5 * det))) / 3.0
    largest = q + 2.0 * p * math.cos(phi)
    smallest = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    middle = 3.0 * q - largest - smallest
    if middle <= 1e-12 * max(largest, 1e-30):
        return None
    r0 = (a00 - smallest, a01, a02)
    r1 = (a01, a11 - smallest, a12)
    r2 = (a02, a12, a22 - smallest)
    best, best_norm = (0.0, 0.0, 0.0), 0.0
    for u, w in ((r0, r1), (r0, r2), (r1, r2)):
        c = (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])
        norm = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
        if norm > best_norm:
            best, best_norm = c, norm
    if not best_norm > 0.0:
        return None
    k = 1.0 / math.sqrt(best_norm)
    return [best[0] * k, best[1] * k, best[2] * k]


# --------------------------------------------------------------------------- plane


@dataclass(frozen=True, kw_only=True)
class PlaneSolid:
    """Plane n . (p - point) = 0 with unit ``normal`` facing the camera (n_z <= 0 side).

    Total least squares (smallest principal axis of the points); at least 3 points.
    """

    point: np.ndarray
    normal: np.ndarray

    @classmethod
    def estimate(cls, points: np.ndarray) -> Self | FailedSolid:
        points = _as_points(points, 3)
        point = column_sums(points) / len(points)
        d = points - point
        found = _smallest_eigenvector((d.T @ d).tolist())
        if found is None:
            return FailedSolid("points are collinear")
        normal = np.array(found)
        # Face the camera at the origin: the normal points from the plane toward the sensor.
        if normal @ point > 0:
            normal = -normal
        return cls(point=point, normal=normal)

    def residuals(self, points: np.ndarray) -> np.ndarray:
        return np.abs((np.asarray(points, dtype=np.float64) - self.point) @ self.normal)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Orthogonal projection of (N, 3) points onto the plane."""
        d = (points - self.point) @ self.normal
        return points - d[:, None] * self.normal


# --------------------------------------------------------------------------- sphere


@dataclass(frozen=True, kw_only=True)
class SphereSolid:
    """Sphere |p - center| = radius.

    ``estimate`` minimises sum(|p - c| - r)^2 by Gauss-Newton from the algebraic solution of
    |p|^2 = 2 c . p + (r^2 - |c|^2) (or from ``init``); at least 4 points.
    """

    center: np.ndarray
    radius: float

    @classmethod
    def estimate(
        cls,
        points: np.ndarray,
        *,
        init: tuple[np.ndarray, float] | None = None,
        iterations: int = 4,
    ) -> Self | FailedSolid:
        points = _as_points(points, 4)
        if init is None:
            mean = points.mean(axis=0)
            d = points - mean
            scale = float(np.sqrt((d * d).sum(axis=1).mean()))
            if scale <= 0:
                return FailedSolid("points coincide")
            d /= scale
            a = np.column_stack([2 * d, np.ones(len(d))])
            ata = a.T @ a
            if np.linalg.cond(ata) > 1e12:
                return FailedSolid("points are coplanar")
            sol = np.linalg.solve(ata, a.T @ (d * d).sum(axis=1))
            r2 = sol[3] + sol[:3] @ sol[:3]
            if r2 <= 0:
                return FailedSolid("no real sphere through the points")
            center, radius = mean + scale * sol[:3], float(scale * np.sqrt(r2))
        else:
            center, radius = np.asarray(init[0], dtype=np.float64), float(init[1])
        # [-J | r] as rows (5, N): J'J and -J'r from one product, on contiguous rows (a
        # third of the cost of the columns of an (N, 5) array). Negating J and r flips the
        # sign of every product with them and none of their sums' bits: J'J and J'r come out
        # as from J and -r, without negating the radial directions (a numpy call a pass).
        rows = np.ascontiguousarray(points.T)
        x, y, z = rows[0], rows[1], rows[2]
        aug = np.empty((5, len(points)))
        aug[3] = 1.0
        w, squares, jacobian, residual = np.empty(rows.shape), np.empty(rows.shape), aug[:3], aug[4]
        wx, wy, wz, sx, sy, sz = w[0], w[1], w[2], squares[0], squares[1], squares[2]
        c = center.tolist()
        for _ in range(iterations):
            # Row by row with Python floats, and the squares summed as x^2 + y^2, then z^2
            # (the order of the rows' reduction): a frame fits up to ten spheres of two to
            # four passes, and numpy's broadcasting and reductions cost more than their
            # arithmetic here.
            np.subtract(x, c[0], out=wx)
            np.subtract(y, c[1], out=wy)
            np.subtract(z, c[2], out=wz)
            np.multiply(w, w, out=squares)
            rho = np.add(sx, sy)
            rho += sz
            np.sqrt(rho, out=rho)
            if not np.minimum.reduce(rho) > 0:  # rho.min() without its Python wrapper
                return FailedSolid("a point sits on the centre")
            np.divide(w, rho, out=jacobian)
            np.subtract(rho, radius, out=residual)
            normal = aug @ aug.T
            try:
                step = _solve(normal[:4, :4], normal[:4, 4])
            except np.linalg.LinAlgError:
                return FailedSolid("points do not fix a sphere")
            c = [c[0] + step[0], c[1] + step[1], c[2] + step[2]]
            radius += step[3]
            # As numpy's max would, a NaN step does not stop the iteration.
            s0, s1, s2, s3 = step
            if abs(s0) < 1e-7 and abs(s1) < 1e-7 and abs(s2) < 1e-7 and abs(s3) < 1e-7:
                break
        if not math.isfinite(radius) or radius <= 0:
            return FailedSolid("radius did not converge")
        return cls(center=np.array(c), radius=radius)

    def residuals(self, points: np.ndarray) -> np.ndarray:
        # Column by column with Python floats: an (N, 3) array less a 3-vector is broadcast
        # by numpy three elements at a time; the same differences, squares and sums as
        # squared_norms of that array (x^2 + y^2, then + z^2).
        p = np.asarray(points, dtype=np.float64)
        cx, cy, cz = self.center.tolist()
        x, y, z = p[:, 0] - cx, p[:, 1] - cy, p[:, 2] - cz
        x *= x
        y *= y
        z *= z
        x += y
        x += z
        np.sqrt(x, out=x)
        x -= self.radius
        return np.abs(x, out=x)

    def silhouette_distance(self, points: np.ndarray) -> np.ndarray:
        """View angle (radians) from each point's ray, seen from the camera at the origin, in
        to the sphere's silhouette: positive inside it, negative beyond (where no point of
        the sphere can be seen). Times the focal length in pixels, the distance in pixels."""
        return silhouette_distance(points, self.center, self.radius)


# --------------------------------------------------------------------------- cylinder


@dataclass(frozen=True, kw_only=True)
class CylinderSolid:
    """Cylinder |(p - point) - ((p - point) . axis) axis| = radius, ``axis`` a unit vector.

    ``estimate`` minimises the sum of squared orthogonal distances over the axis direction
    (2 parameters), the axis position (2) and the radius (1) by Levenberg-Marquardt, from an
    axis direction guess; the start circle comes from the points projected along that guess.
    At least 5 points.
    """

    point: np.ndarray
    axis: np.ndarray
    radius: float
    cost: float = 0.0

    @classmethod
    def estimate(
        cls, points: np.ndarray, axis: np.ndarray, *, iterations: int = 6
    ) -> Self | FailedSolid:
        points = _as_points(points, 5)
        d = [float(v) for v in np.asarray(axis, dtype=np.float64).reshape(-1)]
        norm = math.sqrt(sum(v * v for v in d)) if len(d) == 3 else math.nan
        if not math.isfinite(norm) or norm == 0:
            raise ValueError("axis must be a non-zero finite vector")
        d = [v / norm for v in d]
        e1, e2 = _basis(*d)
        # Coordinates as rows (3, N): each pass of the normal equations then works on
        # contiguous rows, a third cheaper than on the columns of (N, 3).
        rows = np.ascontiguousarray(points.T)
        start = _circle_2d(np.array([e1, e2]) @ rows)
        if start is None:
            return FailedSolid("points are collinear across the axis")
        u, v, r0 = start
        # The state (centre, axis, basis across it, radius) is kept in Python floats: each
        # Levenberg-Marquardt step is a handful of 3-vectors besides the normal equations.
        state = ([u * a + v * b for a, b in zip(e1, e2, strict=True)], d, e1, e2, r0)
        aug = np.empty((6, rows.shape[1]))
        aug[4] = 1.0
        cost, jtj, rhs = _cylinder_normal_equations(rows, *state, aug)
        damping = 1e-4
        for _ in range(iterations):
            h = jtj.copy()
            # + damping * diag(J'J): Marquardt's scaling, on the diagonal as a view of the copy.
            diagonal = h.reshape(25)[::6]
            diagonal *= 1.0 + damping
            try:
                s0, s1, s2, s3, s4 = _solve(h, rhs)
            except np.linalg.LinAlgError:
                break
            (cx, cy, cz), (dx, dy, dz), (ax, ay, az), (bx, by, bz), radius = state
            # Component by component, not comprehensions: each of those is a function call,
            # and a frame takes two to four steps of one to three cylinders.
            dx, dy, dz = dx + ax * s2 + bx * s3, dy + ay * s2 + by * s3, dz + az * s2 + bz * s3
            k = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
            dx, dy, dz = dx * k, dy * k, dz * k
            # Re-orthonormalise the previous basis against the new axis (continuous, no branch).
            dot = ax * dx + ay * dy + az * dz
            fx, fy, fz = ax - dot * dx, ay - dot * dy, az - dot * dz
            k = 1.0 / math.sqrt(fx * fx + fy * fy + fz * fz)
            fx, fy, fz = fx * k, fy * k, fz * k
            f2 = (dy * fz - dz * fy, dz * fx - dx * fz, dx * fy - dy * fx)
            cn = (cx + ax * s0 + bx * s1, cy + ay * s0 + by * s1, cz + az * s0 + bz * s1)
            new_state = (cn, (dx, dy, dz), (fx, fy, fz), f2, radius + s4)
            new_cost, new_jtj, new_rhs = _cylinder_normal_equations(rows, *new_state, aug)
            if new_cost < cost:
                state, cost, jtj, rhs = new_state, new_cost, new_jtj, new_rhs
                damping = max(damping / 4, 1e-9)
                if max(abs(s0), abs(s1), abs(s2), abs(s3), abs(s4)) < 1e-6:
                    break
            else:
                damping *= 16
        c, d, _, _, radius = state
        if not math.isfinite(radius) or radius <= 0:
            return FailedSolid("radius did not converge")
        # Keep the axis point nearest the points' centroid along the axis: a readable centre.
        mean = (column_sums(points) / len(points)).tolist()
        along = sum((mean[i] - c[i]) * d[i] for i in range(3))
        point = np.array([c[i] + along * d[i] for i in range(3)])
        return cls(point=point, axis=np.array(d), radius=float(radius), cost=cost)

    def residuals(self, points: np.ndarray) -> np.ndarray:
        return np.abs(self.offsets(points))

    def offsets(self, points: np.ndarray) -> np.ndarray:
        """Each point's distance across the axis less the radius: positive outside."""
        w = np.asarray(points, dtype=np.float64) - self.point
        # The part across the axis column by column (no (N, 3) outer product to broadcast).
        q = _off_axis(w, w @ self.axis, self.axis)
        return np.sqrt(einsum_norms(q)) - self.radius

    def silhouette_distance(self, points: np.ndarray) -> np.ndarray:
        """View angle (radians) from each point's ray in to the cylinder's silhouette (its two
        outermost generators as seen from the origin): positive inside, negative beyond.

        Measured in the cross-section through the point (across the axis), then scaled by
        the point's distance across the axis over its range: the angle it subtends in view.
        """
        return silhouette_distance(points, self.point, self.radius, self.axis)


def silhouette_distance(
    points: np.ndarray, centre: np.ndarray, radius: float, axis: np.ndarray | None = None
) -> np.ndarray:
    """View angle (radians) from each of the (N, 3) points' rays, seen from the camera at the
    origin, in to the silhouette of the sphere (``axis`` None) or of the cylinder along
    ``axis`` through ``centre``: positive inside it, negative beyond, where no point of the
    solid can be seen. Times the focal length in pixels, a distance in pixels.

    For a sphere, asin(r / |c|) less the angle between the point and the centre. For a
    cylinder, the same in the cross-section through the point (across the axis), scaled by
    the point's distance across the axis over its range: the angle that subtends in view. A
    camera inside the solid sees no silhouette: every point is then infinitely far inside.
    """
    p = np.asarray(points, dtype=np.float64)
    c = np.asarray(centre, dtype=np.float64)
    if axis is None:
        return _tangent_angle(p, c, radius)
    a = np.asarray(axis, dtype=np.float64)
    across = np.empty(p.shape)
    for k, qk in enumerate(_off_axis(p, p @ a, a)):
        across[:, k] = qk
    angle = _tangent_angle(across, c - (c @ a) * a, radius)
    return angle * np.sqrt(einsum_norms(across) / einsum_norms(p))


def _off_axis(
    w: np.ndarray, along: np.ndarray, axis: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The columns of ``w - along[:, None] * axis`` for (N, 3) ``w``, ``along`` (N,) and a
    3-vector ``axis``: the same products and differences, each column on its own (numpy's
    broadcast of the (N, 3) outer product costs more than the three columns)."""
    ax, ay, az = axis.tolist()
    qx, qy, qz = along * ax, along * ay, along * az
    np.subtract(w[:, 0], qx, out=qx)
    np.subtract(w[:, 1], qy, out=qy)
    np.subtract(w[:, 2], qz, out=qz)
    return qx, qy, qz


def einsum_norms(q: np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """``np.einsum("ij,ij->i", q, q)`` of (N, 3) vectors with contiguous rows (or the three
    columns of such an array), to the bit, on whole columns at a third of its cost. Over
    contiguous rows einsum adds a row's three squares as (x^2 + z^2) + y^2 (its unrolled sum
    of products; the same on 2.8 million random rows); over strided ones (a transposed
    array) it adds them in turn, and float32 rows as (x^2 + y^2) + z^2, so those are left
    to it."""
    if isinstance(q, np.ndarray):
        if q.strides[1] != q.itemsize or q.dtype != np.float64:
            return np.einsum("ij,ij->i", q, q)
        q = q[:, 0], q[:, 1], q[:, 2]
    x, y, z = q
    out = x * x
    out += z * z
    out += y * y
    return out


def fattening_trim_m(
    face_normal_z: float,
    side_normal: np.ndarray,
    depth_m: float,
    fattening_rad: float,
    counted_m: float,
) -> float:
    """How far an occluding side of a plane face moves back in for an edge fattening of
    ``fattening_rad`` (an angle in view), both methods' trim.

    On the face the angle spans ``depth_m`` times it over the in-image part of the side's
    normal ``side_normal`` (3-D, in the face's plane). The fattened pixels keep the edge's
    depth, so on a face turned away they part from it, and only the part within ``counted_m``
    of the face was counted as the face's and widened it.
    """
    lateral = max(math.hypot(side_normal[0], side_normal[1]), 1e-6)
    rise = abs(face_normal_z) * depth_m * fattening_rad * abs(side_normal[2]) / lateral
    counted = min(1.0, counted_m / rise) if rise > 0 else 1.0
    return counted * depth_m * fattening_rad / lateral


def _tangent_angle(points: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Angle at the origin from each point in to the tangents from the origin to the ball of
    ``radius`` about ``centre``."""
    d = math.sqrt(float(centre @ centre))
    if not d > radius:
        return np.full(len(points), np.inf)
    half = math.asin(radius / d)
    # points x centre, column by column as np.cross computes it (same bits, without its
    # moveaxis and dtype checks, which cost more than the arithmetic on a frame's points).
    cx, cy, cz = centre.tolist()
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    cross = y * cz, z * cx, x * cy
    np.subtract(cross[0], z * cy, out=cross[0])
    np.subtract(cross[1], x * cz, out=cross[1])
    np.subtract(cross[2], y * cx, out=cross[2])
    off = np.arctan2(np.sqrt(einsum_norms(cross)), points @ centre)
    return half - off


def _cylinder_normal_equations(
    rows: np.ndarray,
    c: Sequence[float],
    d: Sequence[float],
    e1: _Vec3,
    e2: _Vec3,
    radius: float,
    aug: np.ndarray,
) -> tuple[float, np.ndarray, np.ndarray]:
    """Cost, J^T J and -J^T r of the orthogonal residuals |q| - r of the points ``rows``
    (3, N): the cost and the two sides of the Gauss-Newton step J^T J s = -J^T r.

    For c += e1 u + e2 v and d += e1 a + e2 b (e1, e2 span the plane across d), the Jacobian
    rows are (-n.e1, -n.e2, -t n.e1, -t n.e2, -1), with n the unit radial direction and t the
    position along the axis. ``aug`` is a (6, N) workspace whose row 4 holds 1.0 (the
    caller's, kept over the passes of one fit).
    """
    # (t, w . e1, w . e2) for every point in one product, as rows.
    m = np.array([d, e1, e2])
    proj = m @ rows
    proj -= (m @ np.array(c))[:, None]
    t, qb = proj[0], proj[1:]
    # |q| from both squares in one product (the same sums as qb[0]^2 + qb[1]^2), rooted in
    # place: numpy's per-call cost outweighs the arithmetic at a frame's few hundred points.
    rho = qb * qb
    rho = np.add(rho[0], rho[1])
    np.sqrt(rho, out=rho)
    # [-J | r] as rows (r taken before rho is clamped in place): J'J, -J'r and r'r from one
    # product. Negating J flips the sign of every product with it and of their sums, exactly:
    # the right-hand side comes out negated, without negating the radial directions or J'r
    # (a numpy call each).
    np.subtract(rho, radius, out=aug[5])
    np.divide(qb, np.maximum(rho, 1e-12, out=rho), out=aug[:2])
    np.multiply(aug[:2], t, out=aug[2:4])
    normal = aug @ aug.T
    return float(normal[5, 5]), normal[:5, :5], normal[:5, 5]


def best_cylinder_axis(
    points: np.ndarray,
    directions: np.ndarray,
    threshold: float,
    radius_limits: tuple[float, float] | None = None,
) -> tuple[np.ndarray, int]:
    """Among unit ``directions`` (K, 3), the one whose projected points fit a circle best.

    For every direction at once: project the points on the plane across it, fit an algebraic
    circle, count points within ``threshold`` of it. Returns the direction and its count. Used
    to seed ``CylinderSolid.estimate`` when the seed points give no principal direction.
    With ``radius_limits`` (min, max), a direction whose circle lies outside them counts 0.
    """
    points = _as_points(points, 5)
    directions = np.asarray(directions, dtype=np.float64)
    helper = np.where(np.abs(directions[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = helper - (helper * directions).sum(axis=1, keepdims=True) * directions
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(directions, e1)
    centred = points - points.mean(axis=0)
    scale = float(np.sqrt((centred * centred).sum(axis=1).mean())) or 1.0
    centred = centred / scale
    u = centred @ e1.T  # (N, K)
    v = centred @ e2.T
    z = u * u + v * v
    n = len(points)
    # Normal equations of the Kasa fit, one 3x3 system per direction.
    suu, svv, suv = (u * u).sum(0), (v * v).sum(0), (u * v).sum(0)
    su, sv = u.sum(0), v.sum(0)
    ata = np.empty((len(directions), 3, 3))
    ata[:, 0, 0], ata[:, 0, 1], ata[:, 0, 2] = 4 * suu, 4 * suv, 2 * su
    ata[:, 1, 0], ata[:, 1, 1], ata[:, 1, 2] = 4 * suv, 4 * svv, 2 * sv
    ata[:, 2, 0], ata[:, 2, 1], ata[:, 2, 2] = 2 * su, 2 * sv, n
    atb = np.stack([2 * (u * z).sum(0), 2 * (v * z).sum(0), z.sum(0)], axis=1)
    ata += np.eye(3) * 1e-12
    sol = np.linalg.solve(ata, atb[:, :, None])[:, :, 0]
    r2 = sol[:, 2] + sol[:, 0] ** 2 + sol[:, 1] ** 2
    r = np.sqrt(np.maximum(r2, 0.0))
    rho = np.sqrt((u - sol[:, 0]) ** 2 + (v - sol[:, 1]) ** 2)
    counts = (np.abs(rho - r) <= threshold / scale).sum(axis=0)
    if radius_limits is not None:
        lo, hi = radius_limits
        counts = np.where((r * scale >= lo) & (r * scale <= hi), counts, 0)
    best = int(np.argmax(counts))
    return directions[best], int(counts[best])


def hemisphere_directions(count: int) -> np.ndarray:
    """About ``count`` unit vectors spread evenly over the half-sphere z >= 0 (Fibonacci)."""
    if count < 1:
        raise ValueError(f"count must be positive, got {count}")
    i = np.arange(count) + 0.5
    z = 1.0 - i / count  # (0, 1]: an axis and its reverse are the same axis
    r = np.sqrt(1.0 - z * z)
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def resting_width(
    points: np.ndarray,
    support: PlaneSolid,
    centre: np.ndarray,
    radius: float,
    axis: np.ndarray | None = None,
    *,
    gap_ratio: float,
    float_ratio: float,
    max_tilt_rad: float,
    tolerance_m: float,
    radius_limits_m: tuple[float, float],
) -> float | None:
    """The width of a round fitted again to ``points`` touching ``support``, when it rests on
    it; ``None`` when it does not, or when the fit fails or leaves ``radius_limits_m``.

    The round is a sphere (``centre``, ``radius``), or a cylinder whose ``axis`` passes through
    ``centre``. It rests on the support when its surface sinks into the plane by at most
    ``gap_ratio`` of its radius (no solid does: the fit is wrong), or stands off it by at most
    ``float_ratio`` of it, or by up to ``gap_ratio`` while ``points`` spread across the plane
    wider than its diameter (too narrow a fit; a ball held 15 mm before a wall, fitted right,
    keeps its own fit), and, a cylinder, when its axis also runs along the plane within
    ``max_tilt_rad``. A fit already within ``tolerance_m`` of the plane keeps its own width
    (``None``): the contact would move it by less than the fit's own noise, and an arched
    object (a banana) stands that much above the table it touches.

    The refit is least squares of the orthogonal distances by Gauss-Newton over the centre's
    place on the plane (2 for a sphere, 1 across a cylinder's axis) and the radius, the centre
    standing the radius above the plane. On a short arc a free fit's radius trades against its
    centre's depth; the contact removes that freedom.
    """
    n = support.normal
    if axis is not None and abs(float(n @ axis)) > math.sin(max_tilt_rad):
        return None
    height = float((centre - support.point) @ n)
    gap = height - radius
    if not tolerance_m < abs(gap) <= gap_ratio * radius:
        return None
    points = _as_points(points, 4)
    if axis is not None:
        along = axis - (axis @ n) * n
        across = np.cross(n, along / math.sqrt(float(along @ along)))
        basis = np.array([across, n])
    else:
        e1, e2 = orthonormal_basis(n)
        basis = np.array([e1, e2, n])
    coords = (points - support.point) @ basis.T  # on the plane (1 or 2), then the height
    if gap > float_ratio * radius:
        # Standing well off the plane: only a fit narrower than its own points spread across
        # the plane is wrong enough to be moved onto it.
        spread = float(np.ptp(coords[:, :-1], axis=0).max())
        if spread <= 2 * (radius + tolerance_m):
            return None
    x = (centre - support.point) @ basis.T
    x[-1] = radius
    for _ in range(10):
        offsets = coords - x  # the centre is x itself: its height is the radius
        dist = np.sqrt(np.add.reduce(offsets * offsets, axis=1))
        if not np.all(dist > 0):
            return None
        jacobian = offsets / -dist[:, None]
        jacobian[:, -1] -= 1.0
        step = np.linalg.lstsq(jacobian, x[-1] - dist, rcond=None)[0]
        x = x + step
        if not np.all(np.isfinite(x)):
            return None
        if float(np.abs(step).max()) < 1e-7:
            break
    lo, hi = radius_limits_m
    return 2 * float(x[-1]) if lo <= x[-1] <= hi else None


__all__ = [
    "CylinderSolid",
    "FailedSolid",
    "PlaneSolid",
    "Solid",
    "SphereSolid",
    "best_cylinder_axis",
    "column_sums",
    "fit_circle_2d",
    "hemisphere_directions",
    "orthonormal_basis",
    "resting_width",
    "silhouette_distance",
    "squared_norms",
]
