"""Line, circle and ellipse fits to the points of one scan line, by vectorised RANSAC.

A scan line gives an ``(N, 2)`` array in its own plane: ``s`` along the line and ``z`` depth,
in metres. The reconstructor fits all three models to each of the four lines and keeps the
one that explains the most points, so each fit returns its inlier mask and fraction.

Models follow scikit-image's fit models: one class per shape with a classmethod
``estimate(points)`` (least squares on all the points given) and ``residuals(points)``
(orthogonal distances, shape ``(N,)``). RANSAC departs from skimage's loop: it draws a
``(trials, k)`` index array from ``numpy.random.default_rng(seed)``, fits every minimal sample
at once in closed form (2-point lines, 3-point circumcircles, 5-point conics) and scores all
hypotheses against all points in one broadcast, then refits the best by least squares on its
inliers and recomputes the inliers once. Lines and circles are chosen by inlier count (ties:
lower residual sum); ellipses by MSAC's truncated quadratic cost, and their direct
least-squares refit is polished by orthogonal-distance Gauss-Newton (see :func:`fit_ellipse`
for why). Inlier semantics follow PCL's sample consensus models: a point is an inlier when
its distance is ``<= threshold``; ellipse distances are true orthogonal distances.

A degenerate input gives a falsy :class:`FailedFit` carrying ``.reason``, never an
exception; bad shapes or parameters raise ``ValueError`` naming the parameter.

Speed: with ~100 points a fit is dominated by numpy's per-call overhead (~1 us), not by
arithmetic, so the code below counts calls: scalar algebra runs on Python floats, and the
per-hypothesis work is a handful of array expressions over all hypotheses at once.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple, Protocol, Self, runtime_checkable

import numpy as np

__all__ = [
    "AXIS_LIMITS_M",
    "CIRCLE_TRIALS",
    "CONFIDENCE",
    "ELLIPSE_TRIALS",
    "LINE_TRIALS",
    "RADIUS_LIMITS_M",
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

# Trial budgets (min_trials, max_trials). A first chunk of min_trials hypotheses is always
# scored; the standard RANSAC bound at CONFIDENCE then says how many more are needed (up to
# max_trials), and they are scored as one more chunk. Clean scan lines stop after the first
# chunk; the maxima bound the time spent on lines the model does not describe.
LINE_TRIALS = (16, 100)
CIRCLE_TRIALS = (32, 200)
ELLIPSE_TRIALS = (128, 256)
# Ellipse hypotheses are scored by Sampson distance on an evenly strided subsample of at most
# this many points; the best few are then rescored on every point.
ELLIPSE_SCORE_POINTS = 32
ELLIPSE_TOP = 4
# Gauss-Newton steps of the geometric (orthogonal distance) polish of the ellipse refit. On
# partial arcs (40x20 mm, 10x40 mm) 1 step halves the direct fit's 3-5 mm shrink and recovers
# most of the lost inliers, 3 steps converge (~0.5 mm); each step costs ~40 us.
ELLIPSE_GN_STEPS = 3


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


def _coincide(spread2: float, n: int, mx: float, my: float) -> bool:
    """Whether points with squared spread ``spread2`` about their mean ``(mx, my)`` coincide
    up to round-off (the mean itself is only exact to ~1e-16 of the coordinates)."""
    return not spread2 > n * (1e-12 * (abs(mx) + abs(my))) ** 2 or not spread2 > 0.0


def _frozen(mask: np.ndarray) -> np.ndarray:
    mask.flags.writeable = False
    return mask


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
        return _line_distance(p[:, 0], p[:, 1], *self.params)


@dataclass(frozen=True)
class LineFit(LineModel, _FitMixin):
    """A line found by :func:`fit_line`, with its inlier mask ``(N,)`` and trial count."""

    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), compare=False)
    trials: int = 0


def _line_distance(
    x: np.ndarray, y: np.ndarray, px: float, py: float, dx: float, dy: float
) -> np.ndarray:
    return np.abs((x - px) * dy - (y - py) * dx)


def _line_lsq(x: np.ndarray, y: np.ndarray) -> LineModel | FailedFit:
    n = x.shape[0]
    if n < 2:
        return FailedFit(f"a line needs at least 2 points, got {n}")
    mx, my = float(x.sum()) / n, float(y.sum()) / n
    dx, dy = x - mx, y - my
    sxx, sxy, syy = float(dx @ dx), float(dx @ dy), float(dy @ dy)
    if _coincide(sxx + syy, n, mx, my):
        return FailedFit("line: all points coincide")
    # Principal axis of the 2x2 scatter matrix, in closed form.
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
        return _circle_distance(p[:, 0], p[:, 1], *self.params)


@dataclass(frozen=True)
class CircleFit(CircleModel, _FitMixin):
    """A circle found by :func:`fit_circle`, with its inlier mask ``(N,)`` and trial count."""

    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), compare=False)
    trials: int = 0


def _circle_distance(x: np.ndarray, y: np.ndarray, cx: float, cy: float, r: float) -> np.ndarray:
    return np.abs(np.hypot(x - cx, y - cy) - r)


_CIRCLE_GN_STEPS = 10


def _circle_lsq(x: np.ndarray, y: np.ndarray) -> CircleModel | FailedFit:
    n = x.shape[0]
    if n < 3:
        return FailedFit(f"a circle needs at least 3 points, got {n}")
    # Centre and scale so the normal equations are O(1) (skimage's habit).
    mx, my = float(x.sum()) / n, float(y.sum()) / n
    xs, ys = x - mx, y - my
    spread2 = float(xs @ xs + ys @ ys)
    if _coincide(spread2, n, mx, my):
        return FailedFit("circle: all points coincide")
    scale = math.sqrt(spread2 / n)
    inv = 1.0 / scale
    xs, ys = xs * inv, ys * inv
    # Kasa: x^2 + y^2 = a x + b y + c by linear least squares. On centred data the normal
    # equations split into a 2x2 system for (a, b), and c = mean(x^2 + y^2).
    zz = xs * xs + ys * ys
    sxx, sxy, syy = float(xs @ xs), float(xs @ ys), float(ys @ ys)
    sxz, syz = float(xs @ zz), float(ys @ zz)
    det = sxx * syy - sxy * sxy
    if det <= 1e-12 * (sxx + syy) ** 2:
        return FailedFit("circle: points are collinear or repeated")
    cx = 0.5 * (syy * sxz - sxy * syz) / det
    cy = 0.5 * (sxx * syz - sxy * sxz) / det
    # Gauss-Newton on the centre: residual_i = rho_i - mean(rho), Jacobian -(u_i - mean(u)),
    # u_i the unit vector from the centre to point i; normal equations (J'J) step = J' res.
    # With sum(res) = 0 and sum(u_i rho_i) = sum(p_i - c) = -n c (centred data), J'res and
    # J'J need only sum(rho), sum(u) and two dot products.
    for _ in range(_CIRCLE_GN_STEPS):
        dx, dy = xs - cx, ys - cy
        rho = np.hypot(dx, dy)
        if not rho.all():
            break
        ux, uy = dx / rho, dy / rho
        r = float(rho.sum()) / n
        mux, muy = float(ux.sum()) / n, float(uy.sum()) / n
        sxx, sxy = float(ux @ ux), float(ux @ uy)
        a11, a12, a22 = sxx - n * mux * mux, sxy - n * mux * muy, n - sxx - n * muy * muy
        b1, b2 = -n * (cx + r * mux), -n * (cy + r * muy)
        det = a11 * a22 - a12 * a12
        if not det > 0.0:
            break
        step_x = (a22 * b1 - a12 * b2) / det
        step_y = (a11 * b2 - a12 * b1) / det
        cx, cy = cx + step_x, cy + step_y
        # 1e-6 of the scale is ~1e-8 m: far below the depth noise.
        if step_x * step_x + step_y * step_y < 1e-12:
            break
    r = float(np.hypot(xs - cx, ys - cy).sum()) / n
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
    always yields an ellipse. At least 5 points, no 3 collinear. With ``geometric=True`` the
    direct fit is polished by Gauss-Newton on the orthogonal distances (the algebraic fit
    shrinks ellipses seen over a partial arc). ``residuals`` are the true orthogonal
    distances, not algebraic ones.

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
    def estimate(cls, points: np.ndarray, *, geometric: bool = False) -> EllipseModel | FailedFit:
        """Direct least-squares ellipse through ``points``, shape ``(N, 2)``, metres."""
        p = _as_points(points)
        found = _ellipse_lsq(p[:, 0], p[:, 1])
        if found and geometric:
            found = _ellipse_geometric(p[:, 0], p[:, 1], found) or found
        return found

    def residuals(self, points: np.ndarray) -> np.ndarray:
        """Orthogonal distances of ``points`` ``(N, 2)`` to the ellipse, shape ``(N,)``."""
        p = _as_points(points)
        return _ellipse_residuals(p[:, 0], p[:, 1], *self.params)


@dataclass(frozen=True)
class EllipseFit(EllipseModel, _FitMixin):
    """An ellipse found by :func:`fit_ellipse`, with its inlier mask ``(N,)`` and trial count."""

    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), compare=False)
    trials: int = 0


def _wrap_half_turn(angle: float) -> float:
    return (angle + math.pi / 2) % math.pi - math.pi / 2


def _conic_params(
    A: float, B: float, C: float, D: float, E: float, F: float
) -> tuple[float, float, float, float, float] | None:
    """``(cx, cy, a, b, theta)`` of the conic ``A x^2 + B xy + C y^2 + D x + E y + F = 0``,
    or None when it is not a real ellipse."""
    if A + C < 0.0:
        A, B, C, D, E, F = -A, -B, -C, -D, -E, -F
    det = 4.0 * A * C - B * B
    if not det > 0.0:
        return None
    cx = (B * E - 2.0 * C * D) / det
    cy = (B * D - 2.0 * A * E) / det
    f_center = F + 0.5 * (D * cx + E * cy)
    if not f_center < 0.0:
        return None
    # Eigenvalues of [[A, B/2], [B/2, C]]; the smaller one belongs to the major axis, and
    # 0.5 atan2(B, A - C) points along the larger one's eigenvector (the minor axis).
    mean, half = 0.5 * (A + C), 0.5 * math.hypot(A - C, B)
    a = math.sqrt(-f_center / (mean - half))
    b = math.sqrt(-f_center / (mean + half))
    theta = _wrap_half_turn(0.5 * math.atan2(B, A - C) + 0.5 * math.pi)
    return cx, cy, a, b, theta


def _ellipse_distance(
    u: np.ndarray, v: np.ndarray, a: float | np.ndarray, b: float | np.ndarray
) -> np.ndarray:
    """Orthogonal distance from ``(u, v)``, in the ellipse's frame, to ``u²/a² + v²/b² = 1``.

    ``a >= b > 0``; arrays broadcast. Eberly's formulation ("Distance from a point to an
    ellipse, an ellipsoid, or a hyperellipsoid", 2013): reflect into the first quadrant; the
    closest point is ``x = (r0 y0 / (s + r0), y1 / (s + 1))`` with ``r0 = (a/b)^2`` and ``s``
    the root of ``G(s) = (r0 z0 / (s + r0))^2 + (z1 / (s + 1))^2 - 1``, ``z = (y0/a, y1/b)``.
    Eberly bisects point by point; here Newton runs on all points at once, on
    ``phi(s) = (G + 1)^(-1/2) - 1``, which is concave and increasing (a power mean with
    exponent -2 of affine functions of ``s``) and exactly linear where one term dominates.
    Started at ``max(z1 - 1, r0 z0 - r0)``, where ``G >= 0``, Newton climbs monotonically to
    the root: it converges for every point, to round-off within 12 steps for axis ratios up
    to 20 (typically 5-7), and stops once every step is below 1e-12 relative. Points with
    ``v = 0`` use Eberly's closed form.
    """
    y0, y1 = np.abs(u), np.abs(v)
    r0 = (a / b) ** 2
    z0, z1 = y0 / a, y1 / b
    # On the major axis (v ~ 0) the iteration would meet the pole at s = -1: give those points
    # a harmless stand-in and use Eberly's closed form for them below.
    on_axis = z1 < 1e-9
    axis_points = bool(on_axis.any())
    if axis_points:
        z1 = np.where(on_axis, 1.0, z1)
    k0 = r0 * z0
    c0, c1 = k0 * k0, z1 * z1
    s = np.maximum(z1 - 1.0, k0 - r0)
    tol = 1e-12 * (1.0 + float(np.abs(s).max()))
    for _ in range(40):
        w0, w1 = s + r0, s + 1.0
        q0, q1 = c0 / (w0 * w0), c1 / (w1 * w1)
        total = q0 + q1
        step = total * (np.sqrt(total) - 1.0) / (q0 / w0 + q1 / w1)
        s += step
        if not np.abs(step).max() > tol:
            break
    # x - y without cancellation: x0 - y0 = -s y0 / (s + r0), x1 - y1 = -s y1 / (s + 1).
    d = np.abs(s) * np.hypot(y0 / (s + r0), y1 / (s + 1.0))
    if axis_points:
        # Inside the evolute the closest point leaves the axis.
        a2b2 = a * a - b * b
        inside = y0 * a < a2b2
        with np.errstate(all="ignore"):
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


def _eig3(m: list[list[float]]) -> list[tuple[float, list[float]]]:
    """Real eigenpairs of a 3x3 matrix with real spectrum (closed form, Python floats).

    ``numpy.linalg.eig`` costs ~25 us for a 3x3; this costs ~5 us.
    """
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m
    tr = m00 + m11 + m22
    minors = m00 * m11 - m01 * m10 + m00 * m22 - m02 * m20 + m11 * m22 - m12 * m21
    det = (m00 * (m11 * m22 - m12 * m21) - m01 * (m10 * m22 - m12 * m20)
           + m02 * (m10 * m21 - m11 * m20))  # fmt: skip
    # lambda^3 - tr lambda^2 + minors lambda - det = 0; lambda = y + tr/3 gives y^3 + p y + q.
    p = minors - tr * tr / 3.0
    q = -2.0 * tr**3 / 27.0 + tr * minors / 3.0 - det
    if p < 0.0:
        rad = math.sqrt(-p / 3.0)
        arg = max(-1.0, min(1.0, -q / (2.0 * rad**3)))
        phi = math.acos(arg) / 3.0
        roots = [tr / 3.0 + 2.0 * rad * math.cos(phi - 2.0 * math.pi * k / 3.0) for k in range(3)]
    else:  # triple root (up to round-off)
        roots = [tr / 3.0 + math.copysign(abs(q) ** (1.0 / 3.0), -q)] * 3
    pairs = []
    for lam in roots:
        r0 = (m00 - lam, m01, m02)
        r1 = (m10, m11 - lam, m12)
        r2 = (m20, m21, m22 - lam)
        # The eigenvector is orthogonal to every row of M - lambda I: take the largest of the
        # three cross products of row pairs.
        best, best_norm = [0.0, 0.0, 0.0], 0.0
        for u, w in ((r0, r1), (r0, r2), (r1, r2)):
            c = [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]]
            norm = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
            if norm > best_norm:
                best, best_norm = c, norm
        if best_norm > 0.0:
            scale = 1.0 / math.sqrt(best_norm)
            pairs.append((lam, [best[0] * scale, best[1] * scale, best[2] * scale]))
    return pairs


def _ellipse_lsq(x: np.ndarray, y: np.ndarray) -> EllipseModel | FailedFit:
    n = x.shape[0]
    if n < 5:
        return FailedFit(f"an ellipse needs at least 5 points, got {n}")
    # Centre and scale: the quartic moments in S1 span many orders of magnitude otherwise.
    mx, my = float(x.sum()) / n, float(y.sum()) / n
    xs, ys = x - mx, y - my
    spread2 = float(xs @ xs + ys @ ys)
    if _coincide(spread2, n, mx, my):
        return FailedFit("ellipse: all points coincide")
    scale = math.sqrt(spread2 / n)
    inv = 1.0 / scale
    xs, ys = xs * inv, ys * inv
    # Halir & Flusser 1998, Sec. 3: split the design matrix D = [D1 | D2] into its quadratic
    # part D1 = [x^2, xy, y^2] and linear part D2 = [x, y, 1], with scatter blocks
    # S1 = D1'D1, S2 = D1'D2, S3 = D2'D2.
    d1 = np.array([xs * xs, xs * ys, ys * ys])
    d2 = np.array([xs, ys, np.ones(n)])
    s1, s2, s3 = d1 @ d1.T, d1 @ d2.T, d2 @ d2.T
    # On centred, scaled data S3 = [[Sxx, Sxy, 0], [Sxy, Syy, 0], [0, 0, n]]: rank 3 unless
    # the points are collinear.
    s3_det = float(s3[0, 0] * s3[1, 1] - s3[0, 1] ** 2)
    if s3_det <= 1e-10 * float(s3[0, 0] + s3[1, 1]) ** 2:
        return FailedFit("ellipse: points are collinear")
    # The linear part follows from the quadratic one: a2 = T a1, T = -S3^-1 S2'. The reduced
    # scatter matrix is M = S1 + S2 T, and the constraint 4AC - B^2 = 1 reads a1' C1 a1 = 1
    # with C1 = [[0, 0, 2], [0, -1, 0], [2, 0, 0]]: solve C1^-1 M a1 = lambda a1.
    t = -np.linalg.solve(s3, s2.T)
    m = s1 + s2 @ t
    m = np.array([0.5 * m[2], -m[1], 0.5 * m[0]]).tolist()
    # Exactly one eigenvector has a1' C1 a1 = 4AC - B^2 > 0 (Fitzgibbon et al.); with
    # round-off on exact data pick the smallest |eigenvalue| among those that do.
    found = None
    for lam, a1 in _eig3(m):
        if 4.0 * a1[0] * a1[2] - a1[1] * a1[1] > 0.0 and (found is None or abs(lam) < found[0]):
            found = (abs(lam), a1)
    if found is None:
        return FailedFit("ellipse: no elliptic solution")
    a1 = found[1]
    a2 = (t @ np.array(a1)).tolist()
    params = _conic_params(*a1, *a2)
    if params is None:
        return FailedFit("ellipse: degenerate conic")
    cx, cy, a, b, theta = params
    return EllipseModel(
        center=(mx + scale * cx, my + scale * cy), axis_lengths=(scale * a, scale * b), theta=theta
    )


def _ellipse_geometric(
    x: np.ndarray, y: np.ndarray, start: EllipseModel, steps: int | None = None
) -> EllipseModel | None:
    """Polish an ellipse by Gauss-Newton on the orthogonal distances of ``x, y``.

    Minimises ``sum_i d_i^2`` over ``(cx, cy, a, b, theta)``, ``d_i`` the signed distance of
    point ``i`` along the normal at its closest point ``X(t_i) = c + R(theta) (a cos t_i,
    b sin t_i)``. Each step first moves every ``t_i`` by one Gauss-Newton step towards its
    closest point, then solves the 5x5 normal equations with the Jacobian ``-n_i . dX/dparam``
    (the tangential part vanishes at the closest point). The step is rejected if the cost
    rises; from the direct fit, 3 steps reach the optimum to ~0.05 mm on partial arcs.
    Returns None if the polish fails (it never makes the fit worse).
    """
    n = x.shape[0]
    if n < 5:
        return None
    steps = ELLIPSE_GN_STEPS if steps is None else steps
    (cx0, cy0), (a, b), theta = start.center, start.axis_lengths, start.theta
    # Work centred on the start's centre and scaled by its major axis.
    scale = a
    inv = 1.0 / scale
    xy = np.array([(x - cx0) * inv, (y - cy0) * inv])  # (2, N)
    p = [0.0, 0.0, 1.0, b * inv, theta]
    best_p, best_cost = p, math.inf
    c, s = math.cos(theta), math.sin(theta)
    u, v = np.array([[c, s], [-s, c]]) @ xy
    t = np.arctan2(p[2] * v, p[3] * u)
    for k in range(steps + 1):
        cx, cy, a, b, theta = p
        # First move each t_i by a Gauss-Newton step towards its closest point on the current
        # ellipse, r . X'(t) = 0 with X'(t) = (-a sin t, b cos t); then take the normal there.
        ct, st = np.cos(t), np.sin(t)
        bct, ast = b * ct, a * st
        t = t + (bct * (v - b * st) - ast * (u - a * ct)) / (bct * bct + ast * ast)
        ct, st = np.cos(t), np.sin(t)
        bct, ast = b * ct, a * st
        ru, rv = u - a * ct, v - b * st
        w = np.hypot(bct, ast)
        nu, nv = bct / w, ast / w  # unit normal at X(t), in the ellipse's frame
        d = nu * ru + nv * rv
        cost = float(d @ d)
        if not cost < best_cost:
            break
        best_p, best_cost = p, cost
        if k == steps:
            break
        # d(d)/d(centre) = -R(theta) n; d/da = -n_u cos t; d/db = -n_v sin t;
        # d/dtheta = n_u v - n_v u (the frame turns under the fixed point).
        c, s = math.cos(theta), math.sin(theta)
        jac = np.empty((5, n))
        jac[:2] = np.array([[-c, s], [-s, -c]]) @ np.array([nu, nv])
        jac[2], jac[3], jac[4] = -nu * ct, -nv * st, nu * v - nv * u
        h = jac @ jac.T
        # A little Levenberg damping: theta is unobservable on a circle (a = b).
        h.flat[::6] *= 1.0 + 1e-6
        h.flat[::6] += 1e-12 * float(h.trace())
        try:
            step = np.linalg.solve(h, -(jac @ d)).tolist()
        except np.linalg.LinAlgError:
            break
        p = [p[i] + step[i] for i in range(5)]
        if not (p[2] > 0.0 and p[3] > 0.0 and all(map(math.isfinite, p))):
            break
        c, s = math.cos(p[4]), math.sin(p[4])
        u, v = np.array([[c, s], [-s, c]]) @ (xy - np.array([[p[0]], [p[1]]]))
        if step[0] ** 2 + step[1] ** 2 + step[2] ** 2 + step[3] ** 2 + step[4] ** 2 < 1e-14:
            # Converged (1e-7 of the major axis): keep this step without another evaluation.
            best_p = p
            break
    if best_cost == math.inf:
        return None
    cx, cy, a, b, theta = best_p
    if b > a:
        a, b, theta = b, a, theta + 0.5 * math.pi
    return EllipseModel(
        center=(cx0 + scale * cx, cy0 + scale * cy),
        axis_lengths=(scale * a, scale * b),
        theta=_wrap_half_turn(theta),
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


def _check_trials(trials: tuple[int, int], confidence: float, name: str = "trials") -> None:
    lo, hi = trials
    if int(hi) != hi or hi < 1:
        raise ValueError(f"max_trials ({name}) must be a positive integer, got {hi}")
    if int(lo) != lo or lo < 1:
        raise ValueError(f"min_trials ({name}) must be a positive integer, got {lo}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be within (0, 1), got {confidence}")


def _draw_samples(rng: np.random.Generator, n: int, size: int, k: int) -> np.ndarray:
    """``(size, k)`` indices into ``range(n)``, distinct within each row.

    Floyd's algorithm, one column at a time for all rows: for j = n-k .. n-1 draw v uniform in
    [0, j] and take v, or j if v is already in the row. Every k-subset is equally likely (the
    order within a row is not uniform, which no model here cares about); no sorting.
    """
    v = (rng.random((size, k)) * (np.arange(n - k, n) + 1.0)).astype(np.intp)
    for col in range(1, k):
        j = n - k + col
        taken = v[:, :1] == v[:, col : col + 1] if col == 1 else (
            np.logical_or.reduce(v[:, :col] == v[:, col : col + 1], axis=1, keepdims=True))
        v[:, col : col + 1] = np.where(taken, j, v[:, col : col + 1])
    return v


def _trials_needed(n_inliers: int, n: int, k: int, confidence: float) -> float:
    """Standard RANSAC bound: trials for one all-inlier sample at the given confidence."""
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
# (inlier count, cost, parameters), or None if no sample in the chunk gave a valid hypothesis.
# Lines and circles rank by count, ties by cost = residual sum over the inliers; the ellipse
# ranks by cost alone, MSAC's truncated quadratic (see fit_ellipse). Counts may be on a fixed
# subsample (the ellipse's): the RANSAC bound then uses that subsample's size.
_Best = tuple[int, float, tuple[float, ...]]
_Scorer = Callable[[np.ndarray], _Best | None]


def _ransac(
    n: int,
    k: int,
    rng: np.random.Generator,
    trials: tuple[int, int],
    confidence: float,
    score_chunk: _Scorer,
    n_scored: int | None = None,
    by_cost: bool = False,
) -> tuple[_Best | None, int]:
    min_trials, max_trials = trials
    n_scored = n if n_scored is None else n_scored
    best: _Best | None = None
    done, needed = 0, float(max_trials)
    size = min(min_trials, max_trials)
    while size > 0:
        found = score_chunk(_draw_samples(rng, n, size, k))
        done += size
        if found is not None and (
            best is None
            or (by_cost and found[1] < best[1])
            or (not by_cost and (found[0], -found[1]) > (best[0], -best[1]))
        ):
            best = found
            needed = _trials_needed(best[0], n_scored, k, confidence)
        remaining = min(float(max_trials), needed) - done
        size = 0 if remaining <= 0 else min(max(math.ceil(remaining), min_trials),
                                            max_trials - done)  # fmt: skip
    return best, done


def _pick(
    counts: np.ndarray, residual_sums: Callable[[np.ndarray], np.ndarray]
) -> tuple[int, float] | None:
    """Row with the most inliers and its residual sum; ties go to the lowest residual sum,
    then the first row. None if no row has an inlier (every sample was degenerate)."""
    top = counts.max()
    if top == 0:
        return None
    tied = np.flatnonzero(counts == top)
    sums = residual_sums(tied)
    j = int(np.argmin(sums)) if tied.size > 1 else 0
    return int(tied[j]), float(sums[j])


class _Points:
    """A validated scan line, centred on its mean: every fit runs in centred coordinates."""

    __slots__ = ("_circle_basis", "_line_basis", "mean", "n", "points", "x", "y")

    def __init__(self, points: np.ndarray) -> None:
        self.points = _as_points(points)
        self.n = n = self.points.shape[0]
        mean = self.points.sum(axis=0) / n if n else np.zeros(2)
        self.mean = (float(mean[0]), float(mean[1]))
        centred = self.points - mean
        self.x = np.ascontiguousarray(centred[:, 0])
        self.y = np.ascontiguousarray(centred[:, 1])
        self._line_basis: np.ndarray | None = None
        self._circle_basis: np.ndarray | None = None

    def line_basis(self) -> np.ndarray:
        if self._line_basis is None:
            self._line_basis = np.array([self.x, self.y, np.ones(self.n)])
        return self._line_basis

    def circle_basis(self) -> np.ndarray:
        if self._circle_basis is None:
            x, y = self.x, self.y
            self._circle_basis = np.array([x, y, x * x + y * y, np.ones(self.n)])
        return self._circle_basis


def _none(n: int) -> np.ndarray:
    return _frozen(np.zeros(n, bool))


# --------------------------------------------------------------------------- fit_line


def _line_scorer(pts: _Points, threshold: float) -> _Scorer:
    x, y = pts.x, pts.y
    basis = pts.line_basis()  # (3, N): x, y, 1

    def score(idx: np.ndarray) -> _Best | None:
        x0, y0 = x[idx[:, 0]], y[idx[:, 0]]
        ex, ey = x[idx[:, 1]] - x0, y[idx[:, 1]] - y0
        # |e x (p - p0)| = |e| * distance, for every hypothesis and point in one product.
        coef = np.array([-ey, ex, ey * x0 - ex * y0])  # (3, T)
        length = np.hypot(ex, ey)
        # Repeated points (length 0) must count nothing.
        limit = np.where(length > 0.0, threshold * length, -1.0)
        dist = np.abs(coef.T @ basis)
        inl = dist <= limit[:, None]
        counts = inl.sum(axis=1)
        picked = _pick(counts, lambda rows: (dist[rows] * inl[rows]).sum(axis=1) / length[rows])
        if picked is None:
            return None
        i, total = picked
        li = float(length[i])
        return int(counts[i]), total, (float(coef[0, i]) / li, float(coef[1, i]) / li,
                                       float(coef[2, i]) / li)  # fmt: skip

    return score


def _fit_line(
    pts: _Points,
    threshold: float,
    rng: np.random.Generator,
    trials: tuple[int, int],
    confidence: float,
) -> LineFit | FailedFit:
    n = pts.n
    if n < 2:
        return FailedFit(f"a line needs at least 2 points, got {n}", _none(n))
    best, done = _ransac(n, 2, rng, trials, confidence, _line_scorer(pts, threshold))
    if best is None:
        return FailedFit("line: every sample was degenerate", _none(n), done)
    nx, ny, c = best[2]
    x, y = pts.x, pts.y
    inl = np.abs(nx * x + ny * y + c) <= threshold
    model = _line_lsq(x[inl], y[inl])
    if model:
        (px, py), (dx, dy) = model.origin, model.direction
    else:  # only if every inlier coincides, which two distinct inliers rule out
        px, py, dx, dy = -c * nx, -c * ny, ny, -nx
    px, py = px + pts.mean[0], py + pts.mean[1]
    inliers = _line_distance(pts.points[:, 0], pts.points[:, 1], px, py, dx, dy) <= threshold
    return LineFit(origin=(px, py), direction=(dx, dy), inliers=_frozen(inliers), trials=done)


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
        Passed to ``numpy.random.default_rng``; the same seed gives the same result.

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
    _check_trials((min_trials, max_trials), confidence)
    return _fit_line(pts, threshold, np.random.default_rng(seed), (min_trials, max_trials),
                     confidence)  # fmt: skip


# --------------------------------------------------------------------------- fit_circle


def _circle_scorer(pts: _Points, threshold: float, limits: tuple[float, float]) -> _Scorer:
    x, y = pts.x, pts.y
    basis = pts.circle_basis()  # (4, N): x, y, x^2 + y^2, 1
    r_lo = limits[0]
    lo2, hi2 = limits[0] ** 2, limits[1] ** 2
    unbounded = math.isinf(hi2)
    t2 = threshold * threshold
    ones = np.ones(0)

    def score(idx: np.ndarray) -> _Best | None:
        nonlocal ones
        if ones.shape[0] != idx.shape[0]:
            ones = np.ones(idx.shape[0])
        px, py = x[idx], y[idx]  # (T, 3)
        # Circumcentre relative to the first point; b, e the other two points' offsets.
        dx, dy = px[:, 1:] - px[:, :1], py[:, 1:] - py[:, :1]
        sq = dx * dx + dy * dy
        bx, ex, by, ey, bb, ee = dx[:, 0], dx[:, 1], dy[:, 0], dy[:, 1], sq[:, 0], sq[:, 1]
        cross = 2.0 * (bx * ey - by * ex)
        with np.errstate(all="ignore"):
            ux = (ey * bb - by * ee) / cross
            uy = (bx * ee - ex * bb) / cross
            r2 = ux * ux + uy * uy
            # Collinear or repeated points give cross ~ 0, so r2 huge, inf or nan: the radius
            # limits reject them (nan fails every comparison).
            ok = (r2 >= lo2) & (r2 <= hi2)
            if unbounded:
                ok &= np.abs(cross) > 1e-12 * (bb + ee)
            cx, cy, r = px[:, 0] + ux, py[:, 0] + uy, np.sqrt(r2)
            # Inlier iff (r - t)^2 <= rho^2 <= (r + t)^2, i.e. |rho^2 - mid| <= half: no sqrt
            # on the (T, N) array, and |p - c|^2 - mid = [-2cx, -2cy, 1, |c|^2 - mid] . basis.
            if r_lo >= threshold:  # then r - t >= 0 on every valid row
                mid, half = r2 + t2, 2.0 * threshold * r
            else:
                rlo, rhi = np.maximum(r - threshold, 0.0), r + threshold
                mid, half = 0.5 * (rlo * rlo + rhi * rhi), 0.5 * (rhi * rhi - rlo * rlo)
            half = np.where(ok, half, -1.0)
            coef = np.array([-2.0 * cx, -2.0 * cy, ones, cx * cx + cy * cy - mid])
            off = np.abs(coef.T @ basis)
        counts = (off <= half[:, None]).sum(axis=1)

        def residual_sums(rows: np.ndarray) -> np.ndarray:
            d = np.abs(np.hypot(x - cx[rows, None], y - cy[rows, None]) - r[rows, None])
            return np.where(d <= threshold, d, 0.0).sum(axis=1)

        picked = _pick(counts, residual_sums)
        if picked is None:
            return None
        i, total = picked
        return int(counts[i]), total, (float(cx[i]), float(cy[i]), float(r[i]))

    return score


def _fit_circle(
    pts: _Points,
    threshold: float,
    limits: tuple[float, float],
    rng: np.random.Generator,
    trials: tuple[int, int],
    confidence: float,
) -> CircleFit | FailedFit:
    n = pts.n
    if n < 3:
        return FailedFit(f"a circle needs at least 3 points, got {n}", _none(n))
    best, done = _ransac(n, 3, rng, trials, confidence, _circle_scorer(pts, threshold, limits))
    if best is None:
        return FailedFit("circle: no sample gave a circle within radius_limits", _none(n), done)
    cx, cy, r = best[2]
    inl = _circle_distance(pts.x, pts.y, cx, cy, r) <= threshold
    refit = _circle_lsq(pts.x[inl], pts.y[inl])
    # The refit may leave the radius limits (e.g. on a flat face); then keep the sample's.
    if refit and limits[0] <= refit.radius <= limits[1]:
        (cx, cy), r = refit.center, refit.radius
    cx, cy = cx + pts.mean[0], cy + pts.mean[1]
    inliers = _circle_distance(pts.points[:, 0], pts.points[:, 1], cx, cy, r) <= threshold
    return CircleFit(center=(cx, cy), radius=r, inliers=_frozen(inliers), trials=done)


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
    >>> abs(circle.radius - 0.02) < 5e-4, circle.inlier_fraction > 0.9
    (True, True)
    """
    pts = _Points(points)
    threshold = _check_threshold(threshold)
    limits = _check_limits(radius_limits, "radius_limits")
    _check_trials((min_trials, max_trials), confidence)
    return _fit_circle(pts, threshold, limits, np.random.default_rng(seed),
                       (min_trials, max_trials), confidence)  # fmt: skip


# --------------------------------------------------------------------------- fit_ellipse


def _five_point_conics(px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """Conics ``(6, T)`` through the 5 points of each row of ``px, py`` ``(T, 5)``.

    The conics through p1..p4 form the pencil spanned by the line pairs L12 L34 and
    L13 L24; the member through p5 is ``C2(p5) C1 - C1(p5) C2``. Closed form, no solve.
    Degenerate samples (three collinear points) give degenerate conics, rejected later.
    """
    i, j = [0, 2, 0, 1], [1, 3, 2, 3]  # lines L12, L34, L13, L24
    xi, yi, xj, yj = px[:, i], py[:, i], px[:, j], py[:, j]
    # Homogeneous line through two points: l = p_i x p_j, l0 x + l1 y + l2 = 0.
    l0, l1, l2 = yi - yj, xj - xi, xi * yj - xj * yi  # (T, 4)
    a0, a1, a2 = l0[:, 0::2], l1[:, 0::2], l2[:, 0::2]  # L12, L13
    b0, b1, b2 = l0[:, 1::2], l1[:, 1::2], l2[:, 1::2]  # L34, L24
    # Coefficients of the product of lines a and b.
    pair = np.array([
        a0 * b0, a0 * b1 + a1 * b0, a1 * b1, a0 * b2 + a2 * b0, a1 * b2 + a2 * b1, a2 * b2,
    ])  # (6, T, 2)
    x5, y5 = px[:, 4:], py[:, 4:]
    at5 = (a0 * x5 + a1 * y5 + a2) * (b0 * x5 + b1 * y5 + b2)  # (T, 2)
    return pair[:, :, 0] * at5[:, 1] - pair[:, :, 1] * at5[:, 0]


def _sampson_terms(conic: np.ndarray, mono: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``F^2`` and ``|grad F|^2`` ``(T, M)`` of conics ``(6, T)`` at points whose monomials
    ``[x^2, xy, y^2, x, y, 1]`` are ``mono`` ``(6, M)``.

    The Sampson distance ``|F| / |grad F|`` is the orthogonal distance to first order and is
    free of the conic's scale; the test ``F^2 <= t^2 |grad F|^2`` needs no sqrt or division.
    """
    A, B, C, D, E = conic[:5]
    f = conic.T @ mono
    lin = mono[3:]
    gx = np.array([2.0 * A, B, D]).T @ lin
    gy = np.array([B, 2.0 * C, E]).T @ lin
    return f * f, gx * gx + gy * gy


def _sampson_residual_sums(f2: np.ndarray, g2: np.ndarray, inl: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):
        return np.where(inl, np.sqrt(f2 / g2), 0.0).sum(axis=1)


def _ellipse_ok(conic: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Which conics ``(6, T)`` are real ellipses with semi-axes within ``[lo, hi]``."""
    A, B, C, D, E, F = conic
    with np.errstate(all="ignore"):
        det = 4.0 * A * C - B * B
        # F at the centre, F(c) = F - (C D^2 - B D E + A E^2) / det, times det.
        f_det = F * det - (C * D * D - B * D * E + A * E * E)
        m = A + C
        h = np.hypot(A - C, B)
        # Eigenvalues (m -+ h)/2 share m's sign when det = m^2 - h^2 > 0, and the semi-axes
        # are a^2 = -2 F(c) / (m - h), b^2 = -2 F(c) / (m + h) once the sign is m's.
        g = -2.0 * f_det * np.sign(m)  # = 2 |F(c)| det when the conic is a real ellipse
        am = np.abs(m)
        return (det > 0.0) & (g > 0.0) & (g >= lo * lo * det * (am + h)) & (
            g <= hi * hi * det * (am - h))


def _ellipse_scorer(
    x: np.ndarray, y: np.ndarray, threshold: float, limits: tuple[float, float]
) -> tuple[_Scorer, int]:
    """Scorer over normalised coordinates ``x, y``; also the number of points it counts on."""
    n = x.shape[0]
    stride = max(1, -(-n // ELLIPSE_SCORE_POINTS))
    xs, ys = x[::stride], y[::stride]
    mono = np.array([xs * xs, xs * ys, ys * ys, xs, ys, np.ones(xs.shape[0])])
    full: list[np.ndarray] = []  # every point's monomials, built on first need
    lo, hi = limits
    t2 = threshold * threshold

    def score(idx: np.ndarray) -> _Best | None:
        with np.errstate(all="ignore"):
            conic = _five_point_conics(x[idx], y[idx])
        ok = _ellipse_ok(conic, lo, hi)
        if not ok.any():
            return None
        conic = conic[:, ok]
        f2, g2 = _sampson_terms(conic, mono)
        with np.errstate(all="ignore"):
            ratio = f2 / g2
        inl = ratio <= t2
        cost = np.where(inl, ratio, t2).sum(axis=1)
        if stride > 1:
            top = np.argsort(cost, kind="stable")[:ELLIPSE_TOP]
            if not full:
                full.append(np.array([x * x, x * y, y * y, x, y, np.ones(n)]))
            conic = conic[:, top]
            f2, g2 = _sampson_terms(conic, full[0])
            with np.errstate(all="ignore"):
                ratio = f2 / g2
            inl = ratio <= t2
            cost = np.where(inl, ratio, t2).sum(axis=1) / stride
        i = int(np.argmin(cost))
        count = inl[i].sum() / stride
        if count == 0:
            return None
        # MSAC: rank by the truncated quadratic cost; report it as a negative "count" key.
        return int(count + 0.5), float(cost[i]), tuple(conic[:, i].tolist())

    return score, xs.shape[0]


def _fit_ellipse(
    pts: _Points,
    threshold: float,
    limits: tuple[float, float],
    rng: np.random.Generator,
    trials: tuple[int, int],
    confidence: float,
    geometric: bool,
) -> EllipseFit | FailedFit:
    n = pts.n
    if n < 5:
        return FailedFit(f"an ellipse needs at least 5 points, got {n}", _none(n))
    # Hypotheses live in the scan line's normalised frame (centred, RMS radius 1), so the
    # conic coefficients and Sampson terms stay O(1).
    scale = math.sqrt(float(pts.x @ pts.x + pts.y @ pts.y) / n)
    if not scale > 0.0:
        return FailedFit("ellipse: all points coincide", _none(n))
    inv = 1.0 / scale
    x, y = pts.x * inv, pts.y * inv
    t_n = threshold * inv
    lim_n = (limits[0] * inv, limits[1] * inv)
    score, n_scored = _ellipse_scorer(x, y, t_n, lim_n)
    best, done = _ransac(n, 5, rng, trials, confidence, score, n_scored, by_cost=True)
    if best is None:
        return FailedFit("ellipse: no sample gave an ellipse within axis_limits", _none(n), done)
    mono = np.array([x * x, x * y, y * y, x, y, np.ones(n)])
    f2, g2 = _sampson_terms(np.array(best[2])[:, None], mono)
    inl = f2[0] <= g2[0] * (t_n * t_n)
    found: EllipseModel | FailedFit = _ellipse_lsq(pts.x[inl], pts.y[inl])
    if found and geometric:
        found = _ellipse_geometric(pts.x[inl], pts.y[inl], found) or found
    if not (found and limits[0] <= found.axis_lengths[1] and found.axis_lengths[0] <= limits[1]):
        # The refit left the limits (or failed): keep the sample's ellipse.
        params = _conic_params(*best[2])
        if params is None:  # validated as an ellipse when drawn; round-off only
            return FailedFit("ellipse: degenerate conic", _none(n), done)
        cx, cy, a, b, theta = params
        found = EllipseModel(center=(cx * scale, cy * scale),
                             axis_lengths=(a * scale, b * scale), theta=theta)  # fmt: skip
    (cx, cy), axes, theta = found.center, found.axis_lengths, found.theta
    cx, cy = cx + pts.mean[0], cy + pts.mean[1]
    residuals = _ellipse_residuals(pts.points[:, 0], pts.points[:, 1], cx, cy, *axes, theta)
    return EllipseFit(center=(cx, cy), axis_lengths=axes, theta=theta,
                      inliers=_frozen(residuals <= threshold), trials=done)  # fmt: skip


def fit_ellipse(
    points: np.ndarray,
    threshold: float,
    *,
    axis_limits: tuple[float, float] = AXIS_LIMITS_M,
    max_trials: int = ELLIPSE_TRIALS[1],
    min_trials: int = ELLIPSE_TRIALS[0],
    confidence: float = CONFIDENCE,
    seed: int | np.random.Generator = 0,
    geometric: bool = True,
) -> EllipseFit | FailedFit:
    """RANSAC ellipse on one scan line: inliers are within ``threshold`` (orthogonal distance).

    Hypotheses are the conics through five points (closed form, all at once); those that are
    not ellipses, or whose semi-axes leave ``axis_limits`` (``low <= b <= a <= high``), are
    rejected. Hypotheses are scored with the Sampson distance ``d`` (the first-order
    orthogonal distance) on an evenly strided subsample of at most ``ELLIPSE_SCORE_POINTS``
    points, and the best ``ELLIPSE_TOP`` are rescored on every point. Unlike the line and the
    circle, the ellipse is chosen by MSAC's cost ``sum(min(d^2, threshold^2))`` rather than
    by inlier count: many ellipses fit a partial arc within the threshold, and the one with
    the most inliers is the one that also catches the most stray points, which then pull the
    refit by millimetres (MSAC halves the axis error with 20 % scattered outliers). The best
    is refitted by direct least squares on its inliers, then (``geometric=True``) polished by
    Gauss-Newton on the orthogonal distances, and kept if within the limits; the inliers are
    recomputed once with the true orthogonal distance.

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
    geometric : bool
        Polish the direct fit by orthogonal-distance least squares: on a partial arc the
        direct (algebraic) fit shrinks the ellipse by millimetres at this noise level.

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
    _check_trials((min_trials, max_trials), confidence)
    return _fit_ellipse(pts, threshold, limits, np.random.default_rng(seed),
                        (min_trials, max_trials), confidence, geometric)  # fmt: skip


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
    seed: int | np.random.Generator = 0,
    radius_limits: tuple[float, float] = RADIUS_LIMITS_M,
    axis_limits: tuple[float, float] = AXIS_LIMITS_M,
    confidence: float = CONFIDENCE,
    line_trials: tuple[int, int] = LINE_TRIALS,
    circle_trials: tuple[int, int] = CIRCLE_TRIALS,
    ellipse_trials: tuple[int, int] = ELLIPSE_TRIALS,
    geometric: bool = True,
) -> ScanLineFits:
    """Line, circle and ellipse on one scan line, sharing validation, centring and the RNG.

    ``*_trials`` are ``(min_trials, max_trials)`` pairs. One generator
    ``g = numpy.random.default_rng(seed)`` serves the three fits in turn, so the result equals
    ``fit_line(points, threshold, seed=g)``, then ``fit_circle(..., seed=g)``, then
    ``fit_ellipse(..., seed=g)`` with the same settings.
    """
    pts = _Points(points)
    threshold = _check_threshold(threshold)
    r_limits = _check_limits(radius_limits, "radius_limits")
    a_limits = _check_limits(axis_limits, "axis_limits")
    _check_trials(line_trials, confidence, "line_trials")
    _check_trials(circle_trials, confidence, "circle_trials")
    _check_trials(ellipse_trials, confidence, "ellipse_trials")
    rng = np.random.default_rng(seed)
    return ScanLineFits(
        line=_fit_line(pts, threshold, rng, line_trials, confidence),
        circle=_fit_circle(pts, threshold, r_limits, rng, circle_trials, confidence),
        ellipse=_fit_ellipse(pts, threshold, a_limits, rng, ellipse_trials, confidence, geometric),
    )
