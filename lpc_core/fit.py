"""Line, circle and ellipse fits to the points of one scan line, by vectorised RANSAC.

A scan line gives an ``(N, 2)`` array in its own plane: ``s`` along the line and ``z`` depth,
in metres. The reconstructor fits all three models to each of the four lines and keeps the
one that explains the most points, so each fit returns its inlier mask and fraction.

Models follow scikit-image's fit models: one class per shape with a classmethod
``estimate(points)`` (least squares on all the points given) and ``residuals(points)``
(orthogonal distances, shape ``(N,)``). RANSAC departs from skimage's loop: it draws a
``(trials, k)`` index array from ``numpy.random.default_rng(seed)``, fits every minimal sample
at once in closed form and scores all hypotheses against all points in one broadcast, then
refits the best by least squares on its inliers. Inlier semantics follow PCL's sample
consensus models: a point is an inlier when its distance is ``<= threshold``.

A degenerate input gives a falsy :class:`FailedFit` carrying ``.reason``, never an
exception; bad shapes or parameters raise ``ValueError`` naming the parameter.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple, Protocol, Self, runtime_checkable

import numpy as np

__all__ = [
    "CircleFit",
    "CircleModel",
    "EllipseFit",
    "EllipseModel",
    "FailedFit",
    "FitModel",
    "LineFit",
    "LineModel",
    "ScanLineFits",
    "fit_all",
    "fit_circle",
    "fit_ellipse",
    "fit_line",
]

RADIUS_LIMITS_M = (0.005, 0.05)
# Semi-axes of a cylinder's cross-section: the minor one is the radius (5-50 mm); the major
# one grows as the scan plane leans along the axis, and past ~100 mm the arc seen inside the
# 100 mm capture volume is indistinguishable from a line.
AXIS_LIMITS_M = (0.005, 0.10)
CONFIDENCE = 0.99

# Trial budgets. A chunk of ``min_trials`` hypotheses is always scored; the standard RANSAC
# bound then decides how many more (up to ``max_trials``) are needed, and they are scored in
# one more chunk. The maxima are sized for the frame budget, not for the worst scan line.
LINE_TRIALS = (16, 100)
CIRCLE_TRIALS = (32, 200)
ELLIPSE_TRIALS = (64, 256)
# Ellipse hypotheses are ranked by Sampson distance on at most this many points, then the
# best few are scored by the true orthogonal distance on every point.
ELLIPSE_SCORE_POINTS = 64
ELLIPSE_TOP = 4
# Newton steps for the orthogonal distance to an ellipse; the iteration is monotone and
# quadratic near the root (see ``_ellipse_distance``), 8 steps reach ~1e-12 relative.
ELLIPSE_NEWTON_STEPS = 8


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class FailedFit:
    """A fit that produced no model: falsy, and says why.

    Like skimage's ``FailedEstimation``, but it also carries an all-False ``inliers`` mask and
    ``inlier_fraction == 0.0`` so callers ranking models need no special case.
    """

    reason: str
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), compare=False)
    trials: int = 0

    def __bool__(self) -> bool:
        return False

    @property
    def params(self) -> tuple[float, ...]:
        return ()

    @property
    def inlier_fraction(self) -> float:
        return 0.0

    @property
    def n_inliers(self) -> int:
        return 0


@runtime_checkable
class FitModel(Protocol):
    """What RANSAC needs from a 2-D model: estimate from ``(N, 2)`` points, then residuals."""

    min_points: ClassVar[int]

    @classmethod
    def estimate(cls, points: np.ndarray) -> Self | FailedFit: ...

    def residuals(self, points: np.ndarray) -> np.ndarray: ...

    @property
    def params(self) -> tuple[float, ...]: ...


class _FitMixin:
    """Inlier bookkeeping shared by the RANSAC results."""

    inliers: np.ndarray

    @property
    def n_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))

    @property
    def inlier_fraction(self) -> float:
        n = self.inliers.shape[0]
        return self.n_inliers / n if n else 0.0


def _as_points(points: np.ndarray, name: str = "points") -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite")
    return arr


# --------------------------------------------------------------------------- line


@dataclass(frozen=True)
class LineModel:
    """Line ``p = origin + t * direction`` with ``|direction| = 1``.

    Total least squares: minimises ``sum_i d_i**2``, ``d_i`` the orthogonal distance of point
    ``i`` to the line. At least 2 distinct points.

    Attributes
    ----------
    origin : (float, float)
        A point on the line (the centroid of the points fitted), metres.
    direction : (float, float)
        Unit direction, with a non-negative first component.

    Examples
    --------
    >>> t = np.linspace(-0.02, 0.02, 9)
    >>> points = np.column_stack([t, 0.2 + 0.5 * t])
    >>> line = LineModel.estimate(points)
    >>> np.round(line.params, 6).tolist()
    [0.0, 0.2, 0.894427, 0.447214]
    >>> bool(line.residuals(points).max() < 1e-12)
    True
    """

    origin: tuple[float, float]
    direction: tuple[float, float]
    min_points: ClassVar[int] = 2

    @property
    def params(self) -> tuple[float, float, float, float]:
        """``(px, py, dx, dy)``: a point on the line and its unit direction."""
        return (*self.origin, *self.direction)

    @classmethod
    def estimate(cls, points: np.ndarray) -> LineModel | FailedFit:
        """Total least squares line through ``points``, shape ``(N, 2)``, metres."""
        p = _as_points(points)
        return _line_lsq(p[:, 0], p[:, 1])

    def residuals(self, points: np.ndarray) -> np.ndarray:
        """Orthogonal distances of ``points`` ``(N, 2)`` to the line, shape ``(N,)``, metres."""
        p = _as_points(points)
        (px, py), (dx, dy) = self.origin, self.direction
        return np.abs((p[:, 0] - px) * dy - (p[:, 1] - py) * dx)


@dataclass(frozen=True)
class LineFit(LineModel, _FitMixin):
    """A line found by :func:`fit_line`, with its inlier mask ``(N,)`` and trial count."""

    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), compare=False)
    trials: int = 0


def _line_lsq(x: np.ndarray, y: np.ndarray) -> LineModel | FailedFit:
    n = x.shape[0]
    if n < 2:
        return FailedFit(f"a line needs at least 2 points, got {n}")
    mx, my = float(x.mean()), float(y.mean())
    dx, dy = x - mx, y - my
    sxx, sxy, syy = float(dx @ dx), float(dx @ dy), float(dy @ dy)
    if not sxx + syy > 0.0:
        return FailedFit("line: all points coincide")
    # Principal axis of the 2x2 scatter matrix in closed form.
    phi = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    ux, uy = math.cos(phi), math.sin(phi)
    if ux < 0.0 or (ux == 0.0 and uy < 0.0):
        ux, uy = -ux, -uy
    return LineModel(origin=(mx, my), direction=(ux, uy))


# --------------------------------------------------------------------------- circle


@dataclass(frozen=True)
class CircleModel:
    """Circle ``|p - center| = radius``.

    Geometric least squares: minimises ``sum_i (|p_i - center| - radius)**2`` by Gauss-Newton
    on the centre with the radius eliminated (for a fixed centre the best radius is the mean
    distance), started from Kasa's algebraic fit. At least 3 non-collinear points.

    Attributes
    ----------
    center : (float, float)
        Centre, metres.
    radius : float
        Radius, metres.

    Examples
    --------
    >>> t = np.linspace(0.3, 1.9, 12)
    >>> points = np.column_stack([0.01 + 0.02 * np.cos(t), 0.2 + 0.02 * np.sin(t)])
    >>> circle = CircleModel.estimate(points)
    >>> np.round(circle.params, 9).tolist()
    [0.01, 0.2, 0.02]
    """

    center: tuple[float, float]
    radius: float
    min_points: ClassVar[int] = 3

    @property
    def params(self) -> tuple[float, float, float]:
        """``(cx, cy, r)``."""
        return (*self.center, self.radius)

    @classmethod
    def estimate(cls, points: np.ndarray) -> CircleModel | FailedFit:
        """Geometric least-squares circle through ``points``, shape ``(N, 2)``, metres."""
        p = _as_points(points)
        return _circle_lsq(p[:, 0], p[:, 1])

    def residuals(self, points: np.ndarray) -> np.ndarray:
        """Orthogonal distances ``||p - c| - r|`` of ``points`` ``(N, 2)``, shape ``(N,)``."""
        p = _as_points(points)
        cx, cy = self.center
        return np.abs(np.hypot(p[:, 0] - cx, p[:, 1] - cy) - self.radius)


@dataclass(frozen=True)
class CircleFit(CircleModel, _FitMixin):
    """A circle found by :func:`fit_circle`, with its inlier mask ``(N,)`` and trial count."""

    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), compare=False)
    trials: int = 0


_GN_STEPS = 20


def _circle_lsq(x: np.ndarray, y: np.ndarray) -> CircleModel | FailedFit:
    n = x.shape[0]
    if n < 3:
        return FailedFit(f"a circle needs at least 3 points, got {n}")
    # Centre and scale so the normal equations are O(1) (skimage's habit).
    mx, my = float(x.mean()), float(y.mean())
    xs, ys = x - mx, y - my
    scale = math.sqrt(float(xs @ xs + ys @ ys) / n)
    if not scale > 0.0:
        return FailedFit("circle: all points coincide")
    xs, ys = xs / scale, ys / scale
    # Kasa: x^2 + y^2 = a x + b y + c, linear least squares. On centred data the normal
    # equations split into a 2x2 system for (a, b) and c = mean(x^2 + y^2).
    zz = xs * xs + ys * ys
    sxx, sxy, syy = float(xs @ xs), float(xs @ ys), float(ys @ ys)
    sxz, syz = float(xs @ zz), float(ys @ zz)
    det = sxx * syy - sxy * sxy
    if det <= 1e-12 * (sxx + syy) ** 2:
        return FailedFit("circle: points are collinear or repeated")
    cx = 0.5 * (syy * sxz - sxy * syz) / det
    cy = 0.5 * (sxx * syz - sxy * sxz) / det
    # Gauss-Newton on the centre; residual_i = rho_i - mean(rho), Jacobian -(u_i - mean(u)),
    # u_i the unit vector from the centre to point i.
    cost, base_x, base_y, step_x, step_y = math.inf, cx, cy, 0.0, 0.0
    for _ in range(_GN_STEPS):
        dx, dy = xs - cx, ys - cy
        rho = np.hypot(dx, dy)
        if not rho.all():
            break
        res = rho - rho.mean()
        new_cost = float(res @ res)
        if new_cost > cost:
            # Overshoot (rare: Kasa starts close on arcs of 90 degrees or more): halve the step.
            step_x, step_y = 0.5 * step_x, 0.5 * step_y
            cx, cy = base_x + step_x, base_y + step_y
            if step_x * step_x + step_y * step_y < 1e-24:
                cx, cy = base_x, base_y
                break
            continue
        cost, base_x, base_y = new_cost, cx, cy
        ux, uy = dx / rho, dy / rho
        jx, jy = ux - ux.mean(), uy - uy.mean()
        a11, a12, a22 = float(jx @ jx), float(jx @ jy), float(jy @ jy)
        b1, b2 = float(jx @ res), float(jy @ res)
        det = a11 * a22 - a12 * a12
        if not det > 0.0:
            break
        step_x = (a22 * b1 - a12 * b2) / det
        step_y = (a11 * b2 - a12 * b1) / det
        cx, cy = cx + step_x, cy + step_y
        if step_x * step_x + step_y * step_y < 1e-24:
            break
    r = float(np.hypot(xs - cx, ys - cy).mean())
    cx, cy, r = mx + scale * cx, my + scale * cy, scale * r
    if not (math.isfinite(cx) and math.isfinite(cy) and math.isfinite(r)):
        return FailedFit("circle: least squares did not converge")
    return CircleModel(center=(cx, cy), radius=r)


# --------------------------------------------------------------------------- ellipse


@dataclass(frozen=True)
class EllipseModel:
    """Ellipse ``(u / a)**2 + (v / b)**2 = 1``, ``(u, v)`` the point in the ellipse's frame.

    ``u = (x - cx) cos(theta) + (y - cy) sin(theta)``, ``v = -(x - cx) sin(theta) +
    (y - cy) cos(theta)``, ``a >= b`` the semi-axes and ``theta`` the angle of the major axis,
    in ``[-pi/2, pi/2)``.

    Direct least squares (Fitzgibbon, Pilu and Fisher 1999) in Halir and Flusser's numerically
    stable form: minimises the algebraic distance ``sum_i F(p_i)**2`` of the conic
    ``F(x, y) = A x^2 + B xy + C y^2 + D x + E y + F`` subject to ``4AC - B^2 = 1``, which
    always yields an ellipse. At least 5 points, no 3 collinear. ``residuals`` are the true
    orthogonal distances, not algebraic ones.

    Attributes
    ----------
    center : (float, float)
        Centre, metres.
    axis_lengths : (float, float)
        Semi-axes ``(a, b)``, ``a >= b``, metres.
    theta : float
        Angle of the major axis from the first coordinate axis, radians, in ``[-pi/2, pi/2)``.

    Examples
    --------
    >>> t = np.linspace(0.0, 2.0, 15)
    >>> a, b, th = 0.03, 0.02, 0.4
    >>> u, v = a * np.cos(t), b * np.sin(t)
    >>> points = np.column_stack([0.01 + u * np.cos(th) - v * np.sin(th),
    ...                           0.2 + u * np.sin(th) + v * np.cos(th)])
    >>> ellipse = EllipseModel.estimate(points)
    >>> np.round(ellipse.params, 9).tolist()
    [0.01, 0.2, 0.03, 0.02, 0.4]
    """

    center: tuple[float, float]
    axis_lengths: tuple[float, float]
    theta: float
    min_points: ClassVar[int] = 5

    @property
    def params(self) -> tuple[float, float, float, float, float]:
        """``(cx, cy, a, b, theta)``."""
        return (*self.center, *self.axis_lengths, self.theta)

    @classmethod
    def estimate(cls, points: np.ndarray) -> EllipseModel | FailedFit:
        """Direct least-squares ellipse through ``points``, shape ``(N, 2)``, metres."""
        p = _as_points(points)
        return _ellipse_lsq(p[:, 0], p[:, 1])

    def residuals(self, points: np.ndarray) -> np.ndarray:
        """Orthogonal distances of ``points`` ``(N, 2)`` to the ellipse, shape ``(N,)``."""
        p = _as_points(points)
        return _ellipse_residuals(p[:, 0], p[:, 1], *self.params)


@dataclass(frozen=True)
class EllipseFit(EllipseModel, _FitMixin):
    """An ellipse found by :func:`fit_ellipse`, with its inlier mask ``(N,)`` and trial count."""

    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), compare=False)
    trials: int = 0


def _wrap_half_turn(angle: np.ndarray | float) -> np.ndarray | float:
    return (angle + np.pi / 2) % np.pi - np.pi / 2


def _conic_to_ellipse(
    A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, E: np.ndarray, F: np.ndarray
) -> tuple[np.ndarray, ...]:
    """Centre, semi-axes and major-axis angle of conics; ``ok`` is False where not an ellipse.

    Vectorised over any shape; invalid entries hold NaN or garbage and must be masked.
    """
    with np.errstate(all="ignore"):
        # Make the quadratic form positive definite where it is definite at all.
        sign = np.where(A + C < 0.0, -1.0, 1.0)
        A, B, C, D, E, F = (sign * c for c in (A, B, C, D, E, F))
        det = 4.0 * A * C - B * B
        cx = (B * E - 2.0 * C * D) / det
        cy = (B * D - 2.0 * A * E) / det
        f_center = F + 0.5 * (D * cx + E * cy)  # F(center)
        mean = 0.5 * (A + C)
        half = np.hypot(0.5 * (A - C), 0.5 * B)
        # Eigenvalues of [[A, B/2], [B/2, C]]; the smaller one belongs to the major axis.
        a = np.sqrt(-f_center / (mean - half))
        b = np.sqrt(-f_center / (mean + half))
        # 0.5 * atan2(B, A - C) points along the larger eigenvalue's eigenvector (minor axis).
        theta = _wrap_half_turn(0.5 * np.arctan2(B, A - C) + 0.5 * np.pi)
        ok = (det > 0.0) & (f_center < 0.0) & np.isfinite(a) & np.isfinite(b) & (b > 0.0)
    return cx, cy, a, b, theta, ok


def _ellipse_to_conic(
    cx: np.ndarray, cy: np.ndarray, a: np.ndarray, b: np.ndarray, theta: np.ndarray
) -> np.ndarray:
    """Conic coefficients ``(6, ...)`` of ellipses, scaled so ``F(center) = -1``."""
    c, s = np.cos(theta), np.sin(theta)
    ia, ib = 1.0 / (a * a), 1.0 / (b * b)
    A = c * c * ia + s * s * ib
    B = 2.0 * c * s * (ia - ib)
    C = s * s * ia + c * c * ib
    D = -2.0 * A * cx - B * cy
    E = -B * cx - 2.0 * C * cy
    F = A * cx * cx + B * cx * cy + C * cy * cy - 1.0
    return np.stack([A, B, C, D, E, F])


def _ellipse_distance(
    u: np.ndarray, v: np.ndarray, a: np.ndarray | float, b: np.ndarray | float
) -> np.ndarray:
    """Orthogonal distance from ``(u, v)``, in the ellipse's frame, to ``u²/a² + v²/b² = 1``.

    ``a >= b > 0``; arrays broadcast. Eberly's formulation ("Distance from a point to an
    ellipse", 2013): reflect into the first quadrant; the closest point is
    ``x = (r0 y0 / (s + r0), y1 / (s + 1))`` with ``r0 = (a/b)^2`` and ``s`` the root of
    ``G(s) = (r0 z0 / (s + r0))^2 + (z1 / (s + 1))^2 - 1``, ``z = (y0/a, y1/b)``. Eberly
    bisects; here a fixed number of Newton steps on ``phi(s) = (G + 1)^(-1/2) - 1`` runs on all
    points at once. ``phi`` is concave and increasing (a power mean with exponent -2 of
    affine functions), so Newton started left of the root, at
    ``max(z1 - 1, r0 z0 - r0)`` where ``G >= 0``, climbs monotonically to it; and ``phi`` is
    exactly linear when one term dominates, so there is no slow phase near the poles.
    """
    y0, y1 = np.abs(u), np.abs(v)
    r0 = (a / b) ** 2
    z0, z1 = y0 / a, y1 / b
    c0, c1 = (r0 * z0) ** 2, z1 * z1
    s = np.maximum(z1 - 1.0, r0 * z0 - r0)
    with np.errstate(all="ignore"):
        for _ in range(ELLIPSE_NEWTON_STEPS):
            w0, w1 = s + r0, s + 1.0
            q0, q1 = c0 / (w0 * w0), c1 / (w1 * w1)
            total = q0 + q1
            s = s + total * (np.sqrt(total) - 1.0) / (q0 / w0 + q1 / w1)
        # x - y without cancellation: x0 - y0 = -s y0 / (s + r0), x1 - y1 = -s y1 / (s + 1).
        d = np.abs(s) * np.hypot(y0 / (s + r0), y1 / (s + 1.0))
        # On the major axis (v ~ 0) the iteration meets the pole at s = -1: Eberly's closed
        # form. Inside the evolute the closest point leaves the axis.
        on_axis = z1 < 1e-9
        if np.any(on_axis):
            a2b2 = a * a - b * b
            inside = y0 * a < a2b2
            x0 = a * a * y0 / np.where(inside, a2b2, 1.0)
            x1 = b * np.sqrt(np.maximum(1.0 - (x0 / a) ** 2, 0.0))
            d_axis = np.where(inside, np.hypot(x0 - y0, x1), np.abs(y0 - a))
            d = np.where(on_axis, d_axis, d)
    return d


def _ellipse_residuals(
    x: np.ndarray, y: np.ndarray, cx: float, cy: float, a: float, b: float, theta: float
) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    dx, dy = x - cx, y - cy
    return _ellipse_distance(dx * c + dy * s, dy * c - dx * s, a, b)


def _ellipse_lsq(x: np.ndarray, y: np.ndarray) -> EllipseModel | FailedFit:
    n = x.shape[0]
    if n < 5:
        return FailedFit(f"an ellipse needs at least 5 points, got {n}")
    # Centre and scale: the quartic moments in S1 span many orders of magnitude otherwise.
    mx, my = float(x.mean()), float(y.mean())
    xs, ys = x - mx, y - my
    scale = math.sqrt(float(xs @ xs + ys @ ys) / n)
    if not scale > 0.0:
        return FailedFit("ellipse: all points coincide")
    xs, ys = xs / scale, ys / scale
    # Halir & Flusser 1998, Sec. 3: split the design matrix D = [D1 | D2] into its quadratic
    # part D1 = [x^2, xy, y^2] and linear part D2 = [x, y, 1], with scatter blocks
    # S1 = D1'D1, S2 = D1'D2, S3 = D2'D2.
    d1 = np.stack([xs * xs, xs * ys, ys * ys])
    d2 = np.stack([xs, ys, np.ones_like(xs)])
    s1, s2, s3 = d1 @ d1.T, d1 @ d2.T, d2 @ d2.T
    if np.linalg.cond(s3) > 1e12:
        return FailedFit("ellipse: points are collinear")
    # a2 = T a1 with T = -S3^-1 S2' (linear part from the quadratic part), and the reduced
    # scatter matrix M = S1 + S2 T; the constraint 4AC - B^2 = 1 is a1' C1 a1 = 1 with
    # C1 = [[0, 0, 2], [0, -1, 0], [2, 0, 0]], so solve the 3x3 eigenproblem C1^-1 M a1 = l a1.
    t = -np.linalg.solve(s3, s2.T)
    m = s1 + s2 @ t
    m = np.stack([0.5 * m[2], -m[1], 0.5 * m[0]])
    eigval, eigvec = np.linalg.eig(m)
    eigvec = np.real(eigvec)
    # Exactly one eigenvector satisfies a1' C1 a1 = 4AC - B^2 > 0 (Fitzgibbon et al.); with
    # round-off on exact data pick the one with the smallest |eigenvalue| among them.
    cond = 4.0 * eigvec[0] * eigvec[2] - eigvec[1] ** 2
    good = np.flatnonzero(cond > 0.0)
    if good.size == 0:
        return FailedFit("ellipse: no elliptic solution")
    a1 = eigvec[:, good[np.argmin(np.abs(eigval[good]))]]
    a2 = t @ a1
    cx, cy, a, b, theta, ok = _conic_to_ellipse(*a1, *a2)
    if not ok:
        return FailedFit("ellipse: degenerate conic")
    return EllipseModel(
        center=(mx + scale * float(cx), my + scale * float(cy)),
        axis_lengths=(scale * float(a), scale * float(b)),
        theta=float(theta),
    )


# --------------------------------------------------------------------------- RANSAC core


def _check_threshold(threshold: float) -> float:
    t = float(threshold)
    if not (math.isfinite(t) and t > 0.0):
        raise ValueError(f"threshold must be a finite positive distance in metres, got {threshold}")
    return t


def _check_limits(limits: tuple[float, float], name: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in limits)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (low, high) in metres, got {limits!r}") from None
    if not (math.isfinite(lo) and 0.0 <= lo < hi) or math.isnan(hi):
        raise ValueError(f"{name} must satisfy 0 <= low < high, got {limits!r}")
    return lo, hi


def _check_trials(min_trials: int, max_trials: int, confidence: float) -> None:
    if int(max_trials) != max_trials or max_trials < 1:
        raise ValueError(f"max_trials must be a positive integer, got {max_trials}")
    if int(min_trials) != min_trials or min_trials < 1:
        raise ValueError(f"min_trials must be a positive integer, got {min_trials}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be within (0, 1), got {confidence}")


def _draw_samples(rng: np.random.Generator, n: int, size: int, k: int) -> np.ndarray:
    """``(size, k)`` indices into ``range(n)``, distinct within each row."""
    # Column j is drawn from the n - j indices not yet used in its row: take the v-th unused
    # index by stepping v past every earlier pick it reaches, smallest first.
    idx = rng.integers(0, n - np.arange(k), size=(size, k))
    for j in range(1, k):
        v = idx[:, j]
        earlier = np.sort(idx[:, :j], axis=1) if j > 1 else idx[:, :1]
        for c in range(j):
            v += v >= earlier[:, c]
    return idx


def _trials_needed(n_inliers: int, n: int, k: int, confidence: float) -> float:
    """Standard RANSAC bound: trials for one all-inlier sample with the given confidence."""
    # Exact probability of an all-inlier sample without replacement (matters for small n).
    p = 1.0
    for i in range(k):
        p *= max(n_inliers - i, 0) / (n - i)
    if p >= 1.0:
        return 0.0
    if p <= 0.0:
        return math.inf
    return math.log(1.0 - confidence) / math.log1p(-p)


# A chunk scorer takes the (T, k) sample indices and returns the chunk's best hypothesis as
# (inlier count, residual sum over its inliers, parameter tuple), or None if no sample in the
# chunk gave a valid hypothesis.
_Scorer = Callable[[np.ndarray], tuple[int, float, tuple[float, ...]] | None]


def _ransac(
    n: int,
    k: int,
    seed: int | np.random.Generator,
    min_trials: int,
    max_trials: int,
    confidence: float,
    score_chunk: _Scorer,
) -> tuple[tuple[int, float, tuple[float, ...]] | None, int]:
    rng = np.random.default_rng(seed)
    best: tuple[int, float, tuple[float, ...]] | None = None
    done, needed = 0, float(max_trials)
    size = min(min_trials, max_trials)
    while size > 0:
        found = score_chunk(_draw_samples(rng, n, size, k))
        done += size
        if found is not None and (
            best is None or found[0] > best[0] or (found[0] == best[0] and found[1] < best[1])
        ):
            best = found
            needed = _trials_needed(best[0], n, k, confidence)
        remaining = min(max_trials, needed) - done
        size = (
            0
            if remaining <= 0
            else int(min(max(math.ceil(remaining), min_trials), max_trials - done))
        )
    return best, done


def _best_of(counts: np.ndarray, residual_sums: Callable[[np.ndarray], np.ndarray]) -> int:
    """Row with the most inliers; ties go to the lowest residual sum, then the first row."""
    top = counts.max()
    tied = np.flatnonzero(counts == top)
    if tied.size == 1:
        return int(tied[0])
    return int(tied[np.argmin(residual_sums(tied))])


class _Points:
    """A validated scan line, centred on its mean (all fitting runs in centred coordinates)."""

    __slots__ = ("mean", "n", "points", "x", "y")

    def __init__(self, points: np.ndarray) -> None:
        self.points = _as_points(points)
        self.n = self.points.shape[0]
        self.mean = self.points.mean(axis=0) if self.n else np.zeros(2)
        centred = self.points - self.mean
        self.x = np.ascontiguousarray(centred[:, 0])
        self.y = np.ascontiguousarray(centred[:, 1])


# --------------------------------------------------------------------------- fit_line


def _line_scorer(pts: _Points, threshold: float) -> _Scorer:
    x, y = pts.x, pts.y
    basis = np.stack([x, y, np.ones_like(x)])  # (3, N)

    def score(idx: np.ndarray) -> tuple[int, float, tuple[float, ...]] | None:
        x0, y0 = x[idx[:, 0]], y[idx[:, 0]]
        ex, ey = x[idx[:, 1]] - x0, y[idx[:, 1]] - y0
        length = np.hypot(ex, ey)
        ok = length > 0.0
        if not ok.any():
            return None
        nx, ny = -ey[ok] / length[ok], ex[ok] / length[ok]
        # Signed distance n . p - n . p0 for every hypothesis and point in one product.
        coef = np.stack([nx, ny, -(nx * x0[ok] + ny * y0[ok])], axis=1)
        dist = np.abs(coef @ basis)
        inl = dist <= threshold
        counts = inl.sum(axis=1)
        i = _best_of(counts, lambda rows: (dist[rows] * inl[rows]).sum(axis=1))
        sum_res = float(dist[i][inl[i]].sum())
        return int(counts[i]), sum_res, (float(nx[i]), float(ny[i]), float(coef[i, 2]))

    return score


def _fit_line(
    pts: _Points,
    threshold: float,
    seed: int | np.random.Generator,
    min_trials: int,
    max_trials: int,
    confidence: float,
) -> LineFit | FailedFit:
    n = pts.n
    if n < 2:
        return FailedFit(f"a line needs at least 2 points, got {n}", np.zeros(n, bool))
    best, trials = _ransac(
        n, 2, seed, min_trials, max_trials, confidence, _line_scorer(pts, threshold)
    )
    if best is None:
        return FailedFit("line: every sample was degenerate", np.zeros(n, bool), trials)
    nx, ny, c = best[2]
    inl = np.abs(nx * pts.x + ny * pts.y + c) <= threshold
    model = _line_lsq(pts.x[inl], pts.y[inl])
    if not model:
        # Only if every inlier coincides; keep the sample's line.
        model = LineModel(origin=(-c * nx, -c * ny), direction=(ny, -nx))
    (px, py), direction = model.origin, model.direction
    origin = (px + float(pts.mean[0]), py + float(pts.mean[1]))
    fitted = LineModel(origin=origin, direction=direction)
    inliers = fitted.residuals(pts.points) <= threshold
    return LineFit(origin=origin, direction=direction, inliers=inliers, trials=trials)


def fit_line(
    points: np.ndarray,
    threshold: float,
    *,
    max_trials: int = LINE_TRIALS[1],
    min_trials: int = LINE_TRIALS[0],
    confidence: float = CONFIDENCE,
    seed: int | np.random.Generator = 0,
) -> LineFit | FailedFit:
    """RANSAC line on one scan line: inliers are points within ``threshold`` of the line.

    Hypotheses are lines through two distinct points, all scored at once; the best by inlier
    count (ties: lower residual sum) is refitted by total least squares on its inliers, and
    the inliers are recomputed once.

    Parameters
    ----------
    points : (N, 2) array
        The scan line's points in its plane, metres.
    threshold : float
        Inlier distance, metres (``distance <= threshold``).
    max_trials, min_trials : int
        At least ``min_trials`` samples are scored, then as many as the standard bound asks
        for at ``confidence``, never more than ``max_trials``.
    seed : int or numpy.random.Generator
        Seeds ``numpy.random.default_rng``; the same seed gives the same result.

    Returns
    -------
    LineFit or FailedFit
        The line with ``inliers`` (``(N,)`` bool) and ``inlier_fraction``, or a falsy failure
        with ``reason``.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> s = np.linspace(-0.04, 0.04, 60)
    >>> points = np.column_stack([s, 0.2 + 0.1 * s + rng.normal(0, 3e-4, s.size)])
    >>> points[::10, 1] += 0.01  # outliers
    >>> line = fit_line(points, 0.001)
    >>> round(line.inlier_fraction, 2), round(line.direction[1] / line.direction[0], 2)
    (0.9, 0.1)
    """
    pts = _Points(points)
    threshold = _check_threshold(threshold)
    _check_trials(min_trials, max_trials, confidence)
    return _fit_line(pts, threshold, seed, min_trials, max_trials, confidence)


# --------------------------------------------------------------------------- fit_circle


def _circle_scorer(pts: _Points, threshold: float, limits: tuple[float, float]) -> _Scorer:
    x, y = pts.x, pts.y
    # |p - c|^2 = |p|^2 - 2 c.p + |c|^2 for all hypotheses and points as one product.
    basis = np.stack([x, y, x * x + y * y, np.ones_like(x)])  # (4, N)
    r_lo, r_hi = limits

    def score(idx: np.ndarray) -> tuple[int, float, tuple[float, ...]] | None:
        x0, y0 = x[idx[:, 0]], y[idx[:, 0]]
        bx, by = x[idx[:, 1]] - x0, y[idx[:, 1]] - y0
        ex, ey = x[idx[:, 2]] - x0, y[idx[:, 2]] - y0
        bb, ee = bx * bx + by * by, ex * ex + ey * ey
        cross = 2.0 * (bx * ey - by * ex)
        with np.errstate(all="ignore"):
            # Circumcentre relative to the first point.
            ux = (ey * bb - by * ee) / cross
            uy = (bx * ee - ex * bb) / cross
        r = np.hypot(ux, uy)
        # Collinear or repeated points give cross == 0 (r inf or nan): rejected here too.
        ok = (np.abs(cross) > 1e-12 * (bb + ee)) & (r >= r_lo) & (r <= r_hi)
        if not ok.any():
            return None
        cx, cy, r = x0[ok] + ux[ok], y0[ok] + uy[ok], r[ok]
        # Inlier iff (r - t)^2 <= rho^2 <= (r + t)^2, i.e. |rho^2 - mid| <= half: no sqrt.
        lo2 = np.maximum(r - threshold, 0.0) ** 2
        hi2 = (r + threshold) ** 2
        mid, half = 0.5 * (lo2 + hi2), 0.5 * (hi2 - lo2)
        coef = np.stack([-2.0 * cx, -2.0 * cy, np.ones_like(cx), cx * cx + cy * cy - mid], axis=1)
        off = np.abs(coef @ basis)
        counts = (off <= half[:, None]).sum(axis=1)

        def residual_sums(rows: np.ndarray) -> np.ndarray:
            d = np.abs(np.hypot(x - cx[rows, None], y - cy[rows, None]) - r[rows, None])
            return np.where(d <= threshold, d, 0.0).sum(axis=1)

        i = _best_of(counts, residual_sums)
        return (
            int(counts[i]),
            float(residual_sums(np.array([i]))[0]),
            (float(cx[i]), float(cy[i]), float(r[i])),
        )

    return score


def _fit_circle(
    pts: _Points,
    threshold: float,
    limits: tuple[float, float],
    seed: int | np.random.Generator,
    min_trials: int,
    max_trials: int,
    confidence: float,
) -> CircleFit | FailedFit:
    n = pts.n
    if n < 3:
        return FailedFit(f"a circle needs at least 3 points, got {n}", np.zeros(n, bool))
    best, trials = _ransac(
        n, 3, seed, min_trials, max_trials, confidence, _circle_scorer(pts, threshold, limits)
    )
    if best is None:
        return FailedFit(
            "circle: no sample gave a circle within radius_limits", np.zeros(n, bool), trials
        )
    cx, cy, r = best[2]
    inl = np.abs(np.hypot(pts.x - cx, pts.y - cy) - r) <= threshold
    refit = _circle_lsq(pts.x[inl], pts.y[inl])
    # The refit may leave the radius limits (e.g. a flat face); then keep the sample's circle.
    if refit and limits[0] <= refit.radius <= limits[1]:
        (cx, cy), r = refit.center, refit.radius
    center = (cx + float(pts.mean[0]), cy + float(pts.mean[1]))
    inliers = CircleModel(center=center, radius=r).residuals(pts.points) <= threshold
    return CircleFit(center=center, radius=r, inliers=inliers, trials=trials)


def fit_circle(
    points: np.ndarray,
    threshold: float,
    *,
    radius_limits: tuple[float, float] = RADIUS_LIMITS_M,
    max_trials: int = CIRCLE_TRIALS[1],
    min_trials: int = CIRCLE_TRIALS[0],
    confidence: float = CONFIDENCE,
    seed: int | np.random.Generator = 0,
) -> CircleFit | FailedFit:
    """RANSAC circle on one scan line: inliers are points within ``threshold`` of the circle.

    Hypotheses are circumcircles of three points (closed form, all at once); collinear or
    repeated samples and radii outside ``radius_limits`` are rejected. The best by inlier
    count (ties: lower residual sum) is refitted by geometric least squares on its inliers
    (kept only if the radius stays within the limits) and the inliers recomputed once.

    Parameters
    ----------
    points : (N, 2) array
        The scan line's points in its plane, metres.
    threshold : float
        Inlier distance, metres (``distance <= threshold``).
    radius_limits : (float, float)
        Accepted radii ``(low, high)``, metres; PCL's 5-50 mm by default.
    max_trials, min_trials, confidence, seed
        As for :func:`fit_line`.

    Returns
    -------
    CircleFit or FailedFit

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> t = np.linspace(np.pi + 0.5, 2 * np.pi - 0.5, 80)  # the near side, seen from z = 0
    >>> points = np.column_stack([0.02 * np.cos(t), 0.2 + 0.02 * np.sin(t)])
    >>> points += rng.normal(0, 3e-4, points.shape)
    >>> circle = fit_circle(points, 0.001)
    >>> round(circle.radius * 1000, 1), circle.inlier_fraction > 0.9
    (20.0, True)
    """
    pts = _Points(points)
    threshold = _check_threshold(threshold)
    limits = _check_limits(radius_limits, "radius_limits")
    _check_trials(min_trials, max_trials, confidence)
    return _fit_circle(pts, threshold, limits, seed, min_trials, max_trials, confidence)


# --------------------------------------------------------------------------- fit_ellipse


def _five_point_conics(px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """Conics ``(6, T)`` through the 5 points of each row of ``px, py`` ``(T, 5)``.

    The conics through p1..p4 form the pencil spanned by the line pairs L12 L34 and
    L13 L24; the member through p5 is ``C2(p5) C1 - C1(p5) C2``. Closed form, no solve.
    """
    i, j = [0, 2, 0, 1], [1, 3, 2, 3]  # lines L12, L34, L13, L24
    xi, yi, xj, yj = px[:, i], py[:, i], px[:, j], py[:, j]
    # Homogeneous line through two points: l = p_i x p_j, l0 x + l1 y + l2 = 0.
    l0, l1, l2 = yi - yj, xj - xi, xi * yj - xj * yi  # (T, 4)
    # Conic of the product of lines l and m.
    a0, a1, a2 = l0[:, 0::2], l1[:, 0::2], l2[:, 0::2]  # L12, L13
    b0, b1, b2 = l0[:, 1::2], l1[:, 1::2], l2[:, 1::2]  # L34, L24
    pair = np.stack(
        [
            a0 * b0,
            a0 * b1 + a1 * b0,
            a1 * b1,
            a0 * b2 + a2 * b0,
            a1 * b2 + a2 * b1,
            a2 * b2,
        ]
    )  # (6, T, 2)
    x5, y5 = px[:, 4:5], py[:, 4:5]
    at5 = (a0 * x5 + a1 * y5 + a2) * (b0 * x5 + b1 * y5 + b2)  # (T, 2)
    return pair[:, :, 0] * at5[:, 1] - pair[:, :, 1] * at5[:, 0]


def _ellipse_scorer(
    pts: _Points, threshold: float, limits: tuple[float, float], scale: float
) -> _Scorer:
    # Work in the scan line's normalised frame (centred, RMS radius 1): conic coefficients
    # and Sampson distances stay O(1).
    x, y = pts.x / scale, pts.y / scale
    t_n = threshold / scale
    lo, hi = limits[0] / scale, limits[1] / scale
    n = x.shape[0]
    # Sampson pre-scoring on an evenly strided subsample, to bound the (T x N) work.
    sub = slice(None, None, max(1, -(-n // ELLIPSE_SCORE_POINTS)))
    xs, ys = x[sub], y[sub]
    mono = np.stack([xs * xs, xs * ys, ys * ys, xs, ys, np.ones_like(xs)])  # (6, M)
    lin = mono[3:]  # (3, M): x, y, 1

    def score(idx: np.ndarray) -> tuple[int, float, tuple[float, ...]] | None:
        px, py = x[idx], y[idx]  # (T, 5)
        # Per-sample centring and scaling keeps the pencil well conditioned.
        mx, my = px.mean(axis=1, keepdims=True), py.mean(axis=1, keepdims=True)
        px, py = px - mx, py - my
        sc = np.sqrt((px * px + py * py).mean(axis=1, keepdims=True))
        with np.errstate(all="ignore"):
            px, py = px / sc, py / sc
            conic = _five_point_conics(px, py)
            cx, cy, a, b, theta, ok = _conic_to_ellipse(*conic)
        sc, mx, my = sc[:, 0], mx[:, 0], my[:, 0]
        a, b = a * sc, b * sc
        ok &= (b >= lo) & (a <= hi)
        if not ok.any():
            return None
        cx, cy = (mx + sc * cx)[ok], (my + sc * cy)[ok]
        a, b, theta = a[ok], b[ok], theta[ok]
        # Sampson distance |F| / |grad F| <= t, as F^2 <= t^2 |grad F|^2 (no sqrt, no divide).
        coef = _ellipse_to_conic(cx, cy, a, b, theta)  # (6, V)
        f = coef.T @ mono
        A, B, C, D, E = coef[:5]
        grad = np.concatenate([np.stack([2 * A, B, D], 1), np.stack([B, 2 * C, E], 1)]) @ lin
        v = cx.shape[0]
        gx, gy = grad[:v], grad[v:]
        counts = (f * f <= t_n * t_n * (gx * gx + gy * gy)).sum(axis=1)
        # True orthogonal distances on every point for the best few.
        top = np.argsort(-counts, kind="stable")[:ELLIPSE_TOP]
        c, s = np.cos(theta[top])[:, None], np.sin(theta[top])[:, None]
        dx, dy = x - cx[top, None], y - cy[top, None]
        d = _ellipse_distance(dx * c + dy * s, dy * c - dx * s, a[top, None], b[top, None])
        inl = d <= t_n
        true_counts = inl.sum(axis=1)
        i = _best_of(true_counts, lambda rows: np.where(inl[rows], d[rows], 0.0).sum(axis=1))
        j = top[i]
        return (
            int(true_counts[i]),
            float(d[i][inl[i]].sum()),
            (float(cx[j]), float(cy[j]), float(a[j]), float(b[j]), float(theta[j])),
        )

    return score


def _fit_ellipse(
    pts: _Points,
    threshold: float,
    limits: tuple[float, float],
    seed: int | np.random.Generator,
    min_trials: int,
    max_trials: int,
    confidence: float,
) -> EllipseFit | FailedFit:
    n = pts.n
    if n < 5:
        return FailedFit(f"an ellipse needs at least 5 points, got {n}", np.zeros(n, bool))
    scale = math.sqrt(float(pts.x @ pts.x + pts.y @ pts.y) / n)
    if not scale > 0.0:
        return FailedFit("ellipse: all points coincide", np.zeros(n, bool))
    best, trials = _ransac(
        n,
        5,
        seed,
        min_trials,
        max_trials,
        confidence,
        _ellipse_scorer(pts, threshold, limits, scale),
    )
    if best is None:
        return FailedFit(
            "ellipse: no sample gave an ellipse within axis_limits", np.zeros(n, bool), trials
        )
    cx, cy, a, b, theta = best[2]
    params = (cx * scale, cy * scale, a * scale, b * scale, theta)
    inl = _ellipse_residuals(pts.x, pts.y, *params) <= threshold
    refit = _ellipse_lsq(pts.x[inl], pts.y[inl])
    # Keep the sample's ellipse if the refit leaves the axis limits.
    if refit and limits[0] <= refit.axis_lengths[1] and refit.axis_lengths[0] <= limits[1]:
        params = refit.params
    cx, cy, a, b, theta = params
    center = (cx + float(pts.mean[0]), cy + float(pts.mean[1]))
    model = EllipseModel(center=center, axis_lengths=(a, b), theta=theta)
    inliers = model.residuals(pts.points) <= threshold
    return EllipseFit(
        center=center, axis_lengths=(a, b), theta=theta, inliers=inliers, trials=trials
    )


def fit_ellipse(
    points: np.ndarray,
    threshold: float,
    *,
    axis_limits: tuple[float, float] = AXIS_LIMITS_M,
    max_trials: int = ELLIPSE_TRIALS[1],
    min_trials: int = ELLIPSE_TRIALS[0],
    confidence: float = CONFIDENCE,
    seed: int | np.random.Generator = 0,
) -> EllipseFit | FailedFit:
    """RANSAC ellipse on one scan line: inliers are within ``threshold`` (orthogonal distance).

    Hypotheses are the conics through five points (closed form, all at once); those that are
    not ellipses, or whose semi-axes leave ``axis_limits`` (``low <= b <= a <= high``), are
    rejected. All hypotheses are ranked by the Sampson distance (first-order orthogonal
    distance) on a subsample of at most ``ELLIPSE_SCORE_POINTS`` points; the best
    ``ELLIPSE_TOP`` are then scored by the true orthogonal distance on every point. The best
    (ties: lower residual sum) is refitted by direct least squares on its inliers (kept only
    within the limits) and the inliers recomputed once with the true distance.

    Parameters
    ----------
    points : (N, 2) array
        The scan line's points in its plane, metres.
    threshold : float
        Inlier distance, metres (``distance <= threshold``).
    axis_limits : (float, float)
        Accepted semi-axes ``(low, high)``, metres.
    max_trials, min_trials, confidence, seed
        As for :func:`fit_line`.

    Returns
    -------
    EllipseFit or FailedFit

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> t = np.linspace(3.3, 6.1, 90)
    >>> a, b, th = 0.035, 0.02, 0.2
    >>> u, v = a * np.cos(t), b * np.sin(t)
    >>> points = np.column_stack([u * np.cos(th) - v * np.sin(th),
    ...                           0.2 + u * np.sin(th) + v * np.cos(th)])
    >>> points += rng.normal(0, 2e-4, points.shape)
    >>> ellipse = fit_ellipse(points, 0.001)
    >>> [round(1000 * v) for v in ellipse.axis_lengths], ellipse.inlier_fraction > 0.95
    ([35, 20], True)
    """
    pts = _Points(points)
    threshold = _check_threshold(threshold)
    limits = _check_limits(axis_limits, "axis_limits")
    _check_trials(min_trials, max_trials, confidence)
    return _fit_ellipse(pts, threshold, limits, seed, min_trials, max_trials, confidence)


# --------------------------------------------------------------------------- fit_all


class ScanLineFits(NamedTuple):
    """The three models fitted to one scan line."""

    line: LineFit | FailedFit
    circle: CircleFit | FailedFit
    ellipse: EllipseFit | FailedFit


def fit_all(
    points: np.ndarray,
    threshold: float,
    *,
    seed: int = 0,
    radius_limits: tuple[float, float] = RADIUS_LIMITS_M,
    axis_limits: tuple[float, float] = AXIS_LIMITS_M,
    confidence: float = CONFIDENCE,
    line_trials: tuple[int, int] = LINE_TRIALS,
    circle_trials: tuple[int, int] = CIRCLE_TRIALS,
    ellipse_trials: tuple[int, int] = ELLIPSE_TRIALS,
) -> ScanLineFits:
    """Line, circle and ellipse on one scan line, validating and centring the points once.

    Identical to calling :func:`fit_line`, :func:`fit_circle` and :func:`fit_ellipse` with the
    same ``seed`` (each model draws from its own ``default_rng(seed)``). ``*_trials`` are
    ``(min_trials, max_trials)`` pairs.
    """
    pts = _Points(points)
    threshold = _check_threshold(threshold)
    r_limits = _check_limits(radius_limits, "radius_limits")
    a_limits = _check_limits(axis_limits, "axis_limits")
    for lo_hi in (line_trials, circle_trials, ellipse_trials):
        _check_trials(lo_hi[0], lo_hi[1], confidence)
    return ScanLineFits(
        line=_fit_line(pts, threshold, seed, *line_trials, confidence),
        circle=_fit_circle(pts, threshold, r_limits, seed, *circle_trials, confidence),
        ellipse=_fit_ellipse(pts, threshold, a_limits, seed, *ellipse_trials, confidence),
    )
