"""Least-squares 3-D solids for the four-line method: sphere, cylinder and plane.

The laser method (``lpc_core.laser``) first fits 2-D models on each scan line, as the paper
does; the solids here then refine the 3-D object from the inliers of all four lines at once,
which is where the accuracy of the grasp width and wrist angle comes from. Each solid has the
same small surface as ``lpc_core.fit``'s models: a classmethod ``estimate`` and
``residuals(points) -> (N,)`` (orthogonal distances, metres). A degenerate estimate returns a
falsy ``FailedSolid`` carrying the reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, Self

import numpy as np


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


def orthonormal_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit vector ``axis`` to a right-handed basis."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = helper - (helper @ axis) * axis
    e1 /= np.sqrt(e1 @ e1)
    e2 = np.array([axis[1] * e1[2] - axis[2] * e1[1], axis[2] * e1[0] - axis[0] * e1[2],
                   axis[0] * e1[1] - axis[1] * e1[0]])  # fmt: skip
    return e1, e2


def fit_circle_2d(uv: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Algebraic (Kasa) circle through (N, 2) points: centre and radius, ``None`` if singular.

    Minimises sum((u - a)^2 + (v - b)^2 - r^2)^2, linear in (a, b, r^2 - a^2 - b^2); the
    points are centred and scaled first so the normal equations stay well conditioned.
    """
    mean = uv.mean(axis=0)
    d = uv - mean
    scale = float(np.sqrt(np.einsum("ij,ij->", d, d) / len(d)))
    if not np.isfinite(scale) or scale <= 0:
        return None
    d = d / scale
    a = np.column_stack([2 * d, np.ones(len(d))])
    ata = a.T @ a
    # Points centred and scaled to unit RMS: a tiny determinant means they are collinear.
    if abs(np.linalg.det(ata)) < 1e-9 * len(d) ** 3:
        return None
    sol = np.linalg.solve(ata, a.T @ np.einsum("ij,ij->i", d, d))
    r2 = sol[2] + sol[0] ** 2 + sol[1] ** 2
    if r2 <= 0:
        return None
    return mean + scale * sol[:2], float(scale * np.sqrt(r2))


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
        point = points.mean(axis=0)
        d = points - point
        values, vectors = np.linalg.eigh(d.T @ d)
        if values[1] <= 1e-12 * max(values[2], 1e-30):
            return FailedSolid("points are collinear")
        normal = vectors[:, 0]
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
        for _ in range(iterations):
            w = points - center
            rho = np.sqrt(np.einsum("ij,ij->i", w, w))
            if np.any(rho <= 0):
                return FailedSolid("a point sits on the centre")
            jac = np.empty((len(w), 4))
            jac[:, :3] = -w / rho[:, None]
            jac[:, 3] = -1.0
            try:
                step = np.linalg.solve(jac.T @ jac, jac.T @ (radius - rho))
            except np.linalg.LinAlgError:
                return FailedSolid("points do not fix a sphere")
            center = center + step[:3]
            radius += float(step[3])
            if abs(step).max() < 1e-7:
                break
        if not np.isfinite(radius) or radius <= 0:
            return FailedSolid("radius did not converge")
        return cls(center=center, radius=radius)

    def residuals(self, points: np.ndarray) -> np.ndarray:
        w = np.asarray(points, dtype=np.float64) - self.center
        return np.abs(np.sqrt((w * w).sum(axis=1)) - self.radius)


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
        d = np.asarray(axis, dtype=np.float64)
        norm = float(np.linalg.norm(d))
        if not np.isfinite(norm) or norm == 0:
            raise ValueError("axis must be a non-zero finite vector")
        d = d / norm
        basis = np.column_stack(orthonormal_basis(d))
        start = fit_circle_2d(points @ basis)
        if start is None:
            return FailedSolid("points are collinear across the axis")
        state = (basis @ start[0], d, basis, start[1])
        cost, jtj, jtr = _cylinder_normal_equations(points, *state)
        damping = 1e-4
        for _ in range(iterations):
            try:
                step = np.linalg.solve(jtj + damping * np.diag(np.diag(jtj)), -jtr)
            except np.linalg.LinAlgError:
                break
            c, d, basis, radius = state
            d_new = d + basis @ step[2:4]
            d_new /= np.sqrt(d_new @ d_new)
            new_state = (c + basis @ step[:2], d_new, _rotate_basis(basis, d_new), radius + step[4])
            new_cost, new_jtj, new_jtr = _cylinder_normal_equations(points, *new_state)
            if new_cost < cost:
                state, cost, jtj, jtr = new_state, new_cost, new_jtj, new_jtr
                damping = max(damping / 4, 1e-9)
                if abs(step).max() < 1e-6:
                    break
            else:
                damping *= 16
        c, d, _, radius = state
        if not np.isfinite(radius) or radius <= 0:
            return FailedSolid("radius did not converge")
        # Keep the axis point nearest the points' centroid along the axis: a readable centre.
        c = c + ((points.mean(axis=0) - c) @ d) * d
        return cls(point=c, axis=d, radius=float(radius), cost=cost)

    def residuals(self, points: np.ndarray) -> np.ndarray:
        w = np.asarray(points, dtype=np.float64) - self.point
        q = w - (w @ self.axis)[:, None] * self.axis
        return np.abs(np.sqrt(np.einsum("ij,ij->i", q, q)) - self.radius)


def _rotate_basis(basis: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Re-orthonormalise the previous basis against the new axis (no branch, continuous)."""
    e1 = basis[:, 0] - (basis[:, 0] @ d) * d
    e1 /= math.sqrt(e1 @ e1)
    out = np.empty((3, 2))
    out[:, 0] = e1
    out[0, 1] = d[1] * e1[2] - d[2] * e1[1]
    out[1, 1] = d[2] * e1[0] - d[0] * e1[2]
    out[2, 1] = d[0] * e1[1] - d[1] * e1[0]
    return out


def _cylinder_normal_equations(
    points: np.ndarray, c: np.ndarray, d: np.ndarray, basis: np.ndarray, radius: float
) -> tuple[float, np.ndarray, np.ndarray]:
    """Cost, J^T J and J^T r of the orthogonal residuals |q| - r.

    For c += basis @ (u, v) and d += basis @ (a, b) (the basis spans the plane across d), the
    Jacobian rows are (-n.e1, -n.e2, -t n.e1, -t n.e2, -1), with n the unit radial direction
    and t the position along the axis.
    """
    w = points - c
    t = w @ d
    # The radial part of w in the basis across the axis: (w . e1, w . e2).
    qb = w @ basis
    rho = np.sqrt(np.einsum("ij,ij->i", qb, qb))
    res = rho - radius
    jac = np.empty((len(points), 5))
    np.divide(qb, -np.maximum(rho, 1e-12)[:, None], out=jac[:, :2])
    np.multiply(jac[:, :2], t[:, None], out=jac[:, 2:4])
    jac[:, 4] = -1.0
    return float(res @ res), jac.T @ jac, jac.T @ res


def best_cylinder_axis(
    points: np.ndarray, directions: np.ndarray, threshold: float
) -> tuple[np.ndarray, int]:
    """Among unit ``directions`` (K, 3), the one whose projected points fit a circle best.

    For every direction at once: project the points on the plane across it, fit an algebraic
    circle, count points within ``threshold`` of it. Returns the direction and its count. Used
    to seed ``CylinderSolid.estimate`` when the seed points give no principal direction.
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


__all__ = [
    "CylinderSolid",
    "FailedSolid",
    "PlaneSolid",
    "Solid",
    "SphereSolid",
    "best_cylinder_axis",
    "fit_circle_2d",
    "hemisphere_directions",
    "orthonormal_basis",
]
