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
inliers and recomputes the inliers once. The model-free part (argument checks, sampling, the
adaptive trial bound, the batch layout of scan lines, the loop) is :mod:`.ransac`; each model's
minimal fits, scorer and refit are here. Lines and circles are chosen by inlier count (ties:
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
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple, Protocol, Self, runtime_checkable

import numpy as np

from lpc_core.perception.ransac import (
    CONFIDENCE,
    Best,
    Scorer,
    Segments,
    as_points,
    check_limits,
    check_threshold,
    check_trials,
    checked,
    draw_samples,
    on_rows,
    pick_rows,
    ransac,
)

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
    "Segments",
    "fit_all",
    "fit_circle",
    "fit_circles",
    "fit_ellipse",
    "fit_ellipses",
    "fit_line",
    "fit_lines",
]

# The sampler under its name from before the RANSAC machinery had its own module.
_draw_samples = draw_samples

# The paper's limits for its scan lines, in metres. The fits are unbounded by default, as PCL's
# models are until limits are set; the reconstruction passes these.
RADIUS_LIMITS_M = (0.005, 0.05)
# Semi-axes of a cylinder's cross-section: the minor one is the radius (5-50 mm); the major
# one grows as the scan plane leans along the axis, and past ~100 mm the arc seen inside the
# 100 mm capture volume is indistinguishable from a line.
AXIS_LIMITS_M = (0.005, 0.10)

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


# One floating-point error state for a whole fit, set by its function (``_QUIET``): NaN and
# inf are how the scorers mark degenerate samples and padding, and a ``with np.errstate``
# block costs about 12 000 instructions, where the scorers, the refits and the distances below
# entered one about eight times a frame. The helpers they call run in their caller's state.
_QUIET = np.errstate(all="ignore")

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
        p = as_points(points)
        return _line_lsq(p[:, 0], p[:, 1])

    def residuals(self, points: np.ndarray) -> np.ndarray:
        """Orthogonal distances of ``points`` ``(N, 2)`` to the line, shape ``(N,)``, metres."""
        p = as_points(points)
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


def _line_from_moments(g: list[list[float]]) -> tuple[float, float, float, float] | None:
    """:func:`_line_lsq` from the moments ``[x, y, 1]' [x, y, 1]`` of the points (3x3, Python
    floats): ``(mx, my, ux, uy)``, or None when the points coincide."""
    (sxx, sxy, sx), (_, syy, sy), (_, _, n) = g
    if not n >= 2.0:
        return None
    mx, my = sx / n, sy / n
    # Central moments; the coordinates are centred on their segment, so the cancellation is
    # of the inliers' offset from it, not of the coordinates' magnitude.
    cxx, cxy, cyy = sxx - sx * mx, sxy - sx * my, syy - sy * my
    if _coincide(cxx + cyy, int(n), mx, my):
        return None
    phi = 0.5 * math.atan2(2.0 * cxy, cxx - cyy)
    ux, uy = math.cos(phi), math.sin(phi)
    if ux < 0.0 or (ux == 0.0 and uy < 0.0):
        ux, uy = -ux, -uy
    return mx, my, ux, uy


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
        p = as_points(points)
        return _circle_lsq(p[:, 0], p[:, 1])

    def residuals(self, points: np.ndarray) -> np.ndarray:
        """Orthogonal distances ``||p - c| - r|`` of ``points`` ``(N, 2)``, shape ``(N,)``."""
        p = as_points(points)
        return _circle_distance(p[:, 0], p[:, 1], *self.params)


@dataclass(frozen=True)
class CircleFit(CircleModel, _FitMixin):
    """A circle found by :func:`fit_circle`, with its inlier mask ``(N,)`` and trial count."""

    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), compare=False)
    trials: int = 0


def _circle_distance(x: np.ndarray, y: np.ndarray, cx: float, cy: float, r: float) -> np.ndarray:
    return np.abs(np.hypot(x - cx, y - cy) - r)


_CIRCLE_GN_STEPS = 10


def _normalised(
    x: np.ndarray, y: np.ndarray, k: int, shape: str
) -> tuple[np.ndarray, np.ndarray, float, float, float] | FailedFit:
    """``(xs, ys, mx, my, scale)``: the points centred on their mean ``(mx, my)`` and divided
    by their RMS radius ``scale``, so that normal equations stay O(1) (skimage's habit); a
    failure when there are fewer than ``k`` points or they coincide."""
    n = x.shape[0]
    if n < k:
        return FailedFit(f"{'an' if shape[0] in 'aeiou' else 'a'} {shape} needs at least {k} "
                         f"points, got {n}")  # fmt: skip
    mx, my = float(x.sum()) / n, float(y.sum()) / n
    xs, ys = x - mx, y - my
    spread2 = float(xs @ xs + ys @ ys)
    if _coincide(spread2, n, mx, my):
        return FailedFit(f"{shape}: all points coincide")
    scale = math.sqrt(spread2 / n)
    inv = 1.0 / scale
    return xs * inv, ys * inv, mx, my, scale


def _circle_lsq(x: np.ndarray, y: np.ndarray) -> CircleModel | FailedFit:
    found = _normalised(x, y, 3, "circle")
    if isinstance(found, FailedFit):
        return found
    xs, ys, mx, my, scale = found
    n = x.shape[0]
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


def _circle_kasa_batch(
    x: np.ndarray, y: np.ndarray, basis: np.ndarray, inl: np.ndarray
) -> list[tuple[float, float, float] | None]:
    """Kasa's circle on each row's points ``inl`` of ``x, y`` (L, W), all rows at once: the
    start of :func:`_circle_lsq` without its Gauss-Newton polish (radius: the mean distance
    to the centre). ``basis`` (L, 4, W) holds ``[x, y, x^2 + y^2, 1]``; the moments over the
    inliers come from one product and are centred on the inliers' mean in Python floats.
    ``(cx, cy, r)`` per row, None where degenerate."""
    d = np.where(inl[:, None, :], basis, 0.0)
    centres = []
    for g in (d @ d.transpose(0, 2, 1)).tolist():
        (sxx, sxy, sxz, sx), (_, syy, syz, sy), (_, _, _, sz), (_, _, _, m) = g
        if not m >= 3.0:
            centres.append((math.nan, math.nan))
            continue
        mx, my = sx / m, sy / m
        q = mx * mx + my * my
        # Moments of x' = x - mx, y' = y - my and z' = x'^2 + y'^2 from the raw ones.
        cxx, cxy, cyy = sxx - sx * mx, sxy - sx * my, syy - sy * my
        cxz = sxz - 2.0 * (mx * sxx + my * sxy) - mx * sz + 2.0 * m * mx * q
        cyz = syz - 2.0 * (mx * sxy + my * syy) - my * sz + 2.0 * m * my * q
        det = cxx * cyy - cxy * cxy
        if not det > 1e-12 * (cxx + cyy) ** 2:
            centres.append((math.nan, math.nan))
            continue
        centres.append((mx + 0.5 * (cyy * cxz - cxy * cyz) / det,
                        my + 0.5 * (cxx * cyz - cxy * cxz) / det))  # fmt: skip
    cx, cy = _columns(centres)
    dx, dy = x - cx, y - cy
    # Sums by add.reduce: ndarray.sum's Python wrapper costs more than these rows.
    rho = np.where(inl, np.sqrt(dx * dx + dy * dy), 0.0)
    r = np.add.reduce(rho, axis=1) / np.add.reduce(inl, axis=1)
    out: list[tuple[float, float, float] | None] = []
    for (cxk, cyk), rk in zip(centres, r.tolist(), strict=True):
        circle = (cxk, cyk, rk)
        out.append(circle if all(map(math.isfinite, circle)) else None)
    return out


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
        p = as_points(points)
        found = _ellipse_lsq(p[:, 0], p[:, 1])
        if found and geometric:
            found = _ellipse_geometric(p[:, 0], p[:, 1], found) or found
        return found

    def residuals(self, points: np.ndarray) -> np.ndarray:
        """Orthogonal distances of ``points`` ``(N, 2)`` to the ellipse, shape ``(N,)``."""
        p = as_points(points)
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
    to 20, and stops once every step is below 1e-12 relative. Since a Newton step on a
    concave function lands left of the root from either side, the step from ``s = 0`` is a
    valid start too; the larger of the two starts near points (the inliers) within the
    quadratic range, which saves about 3 steps. Points with ``v = 0`` use Eberly's closed
    form.
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
    total = z0 * z0 + c1  # G(0) + 1
    from_zero = total * (np.sqrt(total) - 1.0) / (z0 * z0 / r0 + c1)
    # fmax: from_zero is NaN at the centre, where the safe start alone is used.
    s = np.fmax(np.maximum(z1 - 1.0, k0 - r0), from_zero)
    # fmax ignores NaN: padded entries of a batch of scan lines neither set nor block the stop.
    tol = 1e-12 * (1.0 + float(np.fmax.reduce(np.abs(s), axis=None)))
    for _ in range(40):
        w0, w1 = s + r0, s + 1.0
        q0, q1 = c0 / (w0 * w0), c1 / (w1 * w1)
        total = q0 + q1
        step = total * (np.sqrt(total) - 1.0) / (q0 / w0 + q1 / w1)
        s += step
        if not np.fmax.reduce(np.abs(step), axis=None) > tol:
            break
    # x - y without cancellation: x0 - y0 = -s y0 / (s + r0), x1 - y1 = -s y1 / (s + 1).
    d = np.abs(s) * np.hypot(y0 / (s + r0), y1 / (s + 1.0))
    if axis_points:
        # Inside the evolute the closest point leaves the axis.
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
    with np.errstate(all="ignore"):
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
    # Centred and scaled: the quartic moments in S1 span many orders of magnitude otherwise.
    found = _normalised(x, y, 5, "ellipse")
    if isinstance(found, FailedFit):
        return found
    xs, ys, mx, my, scale = found
    n = x.shape[0]
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


def _ellipse_direct_batch(
    mono: np.ndarray, inl: np.ndarray, scale: list[float]
) -> list[EllipseModel | FailedFit]:
    """:func:`_ellipse_lsq` on each row's points ``inl`` (L, W), all rows at once.

    ``mono`` (L, 6, W) holds the monomials ``[x^2, xy, y^2, x, y, 1]`` of each row's points in
    a frame centred on the row and scaled by ``scale`` to RMS radius 1 (``_EllipseFrame``), so
    the scatter matrix of every row comes from one product and stays O(1); the 3x3 blocks and
    eigenproblems are solved in Python floats. Models are returned in the centred frame,
    metres (multiplied back by ``scale``).
    """
    d = np.where(inl[:, None, :], mono, 0.0)
    out: list[EllipseModel | FailedFit] = []
    for g, sk in zip((d @ d.transpose(0, 2, 1)).tolist(), scale, strict=True):
        m = g[5][5]
        if m < 5:
            out.append(FailedFit(f"an ellipse needs at least 5 points, got {m:.0f}"))
            continue
        # Halir & Flusser's blocks of D'D, D = [x^2, xy, y^2 | x, y, 1]: S1 = D1'D1,
        # S2 = D1'D2, S3 = D2'D2 = [[Sxx, Sxy, Sx], [Sxy, Syy, Sy], [Sx, Sy, m]].
        s1 = [row[:3] for row in g[:3]]
        s2 = [row[3:] for row in g[:3]]
        (sxx, sxy, sx), (_, syy, sy), _ = (row[3:] for row in g[3:])
        mx, my = sx / m, sy / m
        cxx, cxy, cyy = sxx - sx * mx, sxy - sx * my, syy - sy * my
        if _coincide(cxx + cyy, int(m), mx, my):
            out.append(FailedFit("ellipse: all points coincide"))
            continue
        # Collinear points make S3 singular (the centred 2x2 block, scale-free test).
        if cxx * cyy - cxy * cxy <= 1e-10 * (cxx + cyy) ** 2:
            out.append(FailedFit("ellipse: points are collinear"))
            continue
        # T = -S3^-1 S2' (a2 = T a1) by the adjugate of the symmetric S3.
        a11, a12, a13, a22, a23, a33 = sxx, sxy, sx, syy, sy, m
        c11, c12, c13 = a22 * a33 - a23 * a23, a13 * a23 - a12 * a33, a12 * a23 - a13 * a22
        c22, c23, c33 = a11 * a33 - a13 * a13, a12 * a13 - a11 * a23, a11 * a22 - a12 * a12
        det = a11 * c11 + a12 * c12 + a13 * c13
        adj = ((c11, c12, c13), (c12, c22, c23), (c13, c23, c33))
        # t[i][j] = -(S3^-1 S2')[i][j] = -sum_k adj[i][k] S2[j][k] / det
        t = [[-(ai[0] * s2j[0] + ai[1] * s2j[1] + ai[2] * s2j[2]) / det for s2j in s2]
             for ai in adj]  # fmt: skip
        # Reduced scatter M = S1 + S2 T; the constraint 4AC - B^2 = 1 as C1^-1 M.
        mr = [[s1[i][j] + s2[i][0] * t[0][j] + s2[i][1] * t[1][j] + s2[i][2] * t[2][j]
               for j in range(3)] for i in range(3)]  # fmt: skip
        found = None
        for lam, a1 in _eig3([[0.5 * v for v in mr[2]], [-v for v in mr[1]],
                              [0.5 * v for v in mr[0]]]):  # fmt: skip
            if 4.0 * a1[0] * a1[2] - a1[1] * a1[1] > 0.0 and (found is None or abs(lam) < found[0]):
                found = (abs(lam), a1)
        if found is None:
            out.append(FailedFit("ellipse: no elliptic solution"))
            continue
        a1 = found[1]
        a2 = [t[i][0] * a1[0] + t[i][1] * a1[1] + t[i][2] * a1[2] for i in range(3)]
        params = _conic_params(*a1, *a2)
        if params is None:
            out.append(FailedFit("ellipse: degenerate conic"))
            continue
        cx, cy, a, b, theta = params
        out.append(EllipseModel(center=(sk * cx, sk * cy), axis_lengths=(sk * a, sk * b),
                                theta=theta))  # fmt: skip
    return out


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


def _none(n: int) -> np.ndarray:
    return _frozen(np.zeros(n, bool))


# A model whose best sample has fewer than GOAL_SLACK x the inliers the caller asked for
# (min_inliers) is not refitted: the refit on a sample's inliers gains a few points, not
# the many that would be missing. The ellipse's count is on its scoring subsample and its
# sample is picked by cost, not count: its refit was seen to gain a fifth, so it has more room.
GOAL_SLACK = 0.85
ELLIPSE_GOAL_SLACK = 0.6


def _short(count: float, goal: float, n: int, trials: int) -> FailedFit:
    return FailedFit(f"not refitted: the best sample has {count:.0f} inliers, the caller needs "
                     f"{goal:.0f}", _none(n), trials)  # fmt: skip


def _too_few(n: list[int], k: int, what: str) -> list[Any]:
    """A failure for each line with fewer than ``k`` points, None (to be filled) elsewhere."""
    return [
        FailedFit(f"{what} needs at least {k} points, got {m}", _none(m)) if m < k else None
        for m in n
    ]


def _column(values: list[float]) -> np.ndarray:
    return np.array(values, dtype=np.float64)[:, None]


def _columns(rows: Iterable[Sequence[float]]) -> tuple[np.ndarray, ...]:
    """Per-line parameter tuples as one ``(L, 1)`` column per parameter (views of one array:
    one conversion instead of one per parameter)."""
    columns = np.array(list(rows), dtype=np.float64).T[:, :, None]
    # Indexed, not iterated: iterating an array ends on a formatted IndexError.
    return tuple(columns[k] for k in range(columns.shape[0]))


def _best_columns(best: list[Best | None], width: int) -> tuple[np.ndarray, ...]:
    """Each line's best sample's parameters as ``(L, 1)`` columns, NaN where it has none."""
    nan = (math.nan,) * width
    return _columns(b[2] if b else nan for b in best)


# --------------------------------------------------------------------------- fit_line


def _line_scorer(seg: Segments, threshold: float) -> Scorer:
    basis_all = seg.basis("line")  # (L, 3, W): x, y, 1

    def score(idx: np.ndarray, rows: np.ndarray | None) -> list[Best | None]:
        (basis,) = on_rows(rows, basis_all)
        # Both points' coordinates in one gather, p[axis (x, y), point, line, trial].
        p = basis.take(idx.transpose(2, 0, 1) + seg.gather_offsets("line", idx.shape[0]))
        x0, y0, x1, y1 = p[0, 0], p[1, 0], p[0, 1], p[1, 1]
        # The line through p0 and p1, (y0 - y1, x1 - x0, x0 y1 - x1 y0) = (-e_y, e_x, e x p0):
        # |e x (p - p0)| = |e| * distance, for every hypothesis and point in one product.
        a, b = y0 - y1, x1 - x0
        length = np.hypot(a, b)
        # Unit normals, so the product below is the distance itself and the test is against a
        # scalar; repeated points (length 0) give NaN, which is never an inlier. Each divided
        # on its contiguous (L, T) block into its column: dividing the (L, T, 3) array by the
        # lengths broadcast them three elements at a time.
        coef = np.empty((*x0.shape, 3))
        np.divide(a, length, out=coef[:, :, 0])
        np.divide(b, length, out=coef[:, :, 1])
        c = x0 * y1
        c -= x1 * y0
        np.divide(c, length, out=coef[:, :, 2])
        dist = coef @ basis  # (L, T, W); NaN on padding, never an inlier
        np.abs(dist, out=dist)
        inl = dist <= threshold

        def residual_sums(rl: np.ndarray, rt: np.ndarray) -> np.ndarray:
            return np.add.reduce(np.where(inl[rl, rt], dist[rl, rt], 0.0), axis=1)

        picks = pick_rows(inl, residual_sums)
        r, i = np.arange(len(picks)), np.array([t for t, _, _ in picks])
        params = coef[r, i].tolist()
        return [
            None if c == 0 else (c, total, tuple(p))
            for (_, c, total), p in zip(picks, params, strict=True)
        ]

    return score


@_QUIET
def _fit_lines(
    seg: Segments,
    threshold: float,
    rng: np.random.Generator,
    trials: tuple[int, int],
    confidence: float,
    goals: Sequence[float] | None = None,
) -> list[LineFit | FailedFit]:
    out: list[Any] = _too_few(seg.n, 2, "a line")
    rows = [r for r, m in enumerate(seg.n) if m >= 2]
    best, done = ransac(seg.n, rows, 2, rng, trials, confidence,
                         _line_scorer(seg, threshold), seg.n, goals=goals)  # fmt: skip
    found = [r for r in rows if best[r] is not None]
    for r in rows:
        if best[r] is None:
            out[r] = FailedFit("line: every sample was degenerate", _none(seg.n[r]), done[r])
    if not found:
        return out
    nx, ny, c = _best_columns(best, 3)
    x, y = seg.x, seg.y
    inl = np.abs(nx * x + ny * y + c) <= threshold
    # Total least squares on each line's inliers, every line from one product: the moments
    # [x, y, 1] x [x, y, 1] over the inliers (padding is never an inlier).
    d = np.where(inl[:, None, :], seg.basis("line"), 0.0)  # (L, 3, W)
    moments = (d @ d.transpose(0, 2, 1)).tolist()
    line = [(math.nan,) * 4] * seg.count
    for r in found:
        model = _line_from_moments(moments[r])
        if model is not None:
            px, py, ux, uy = model
        else:  # only if every inlier coincides, which two distinct inliers rule out
            a, b, cc = best[r][2]
            px, py, ux, uy = -cc * a, -cc * b, b, -a
        line[r] = (px + seg.mean[r][0], py + seg.mean[r][1], ux, uy)
    px, py, ux, uy = _columns(line)
    inliers = _line_distance(seg.ox, seg.oy, px, py, ux, uy) <= threshold
    for r in found:
        p = line[r]
        out[r] = LineFit(origin=(p[0], p[1]), direction=(p[2], p[3]),
                         inliers=_frozen(inliers[r, : seg.n[r]]), trials=done[r])  # fmt: skip
    return out


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
    return fit_lines([points], threshold, max_trials=max_trials, min_trials=min_trials,
                     confidence=confidence, seed=seed)[0]  # fmt: skip


def fit_lines(
    segments: Segments | Sequence[np.ndarray],
    threshold: float,
    *,
    max_trials: int = LINE_TRIALS[1],
    min_trials: int = LINE_TRIALS[0],
    confidence: float = CONFIDENCE,
    seed: int | np.random.Generator = 0,
    min_inliers: Sequence[float] | None = None,
) -> list[LineFit | FailedFit]:
    """:func:`fit_line` on several scan lines at once, one result per line.

    Every line draws its samples from the one generator ``default_rng(seed)``, so a line's
    result depends on which lines share the call (each is as good a RANSAC as alone).
    ``min_inliers`` (one per line, optional) is the inlier count below which the caller has no
    use for a line's model: the adaptive budget then stops once such a model, if it existed,
    would have been drawn at ``confidence`` (see ``ransac``).
    """
    trials = (min_trials, max_trials)
    seg, threshold, goals = checked(segments, threshold, trials, confidence, min_inliers)
    return _fit_lines(seg, threshold, np.random.default_rng(seed), trials, confidence, goals)


# --------------------------------------------------------------------------- fit_circle


def _circle_scorer(seg: Segments, threshold: float, limits: tuple[float, float]) -> Scorer:
    basis_all = seg.basis("circle")  # (L, 4, W): x, y, x^2 + y^2, 1
    r_lo = limits[0]
    lo2, hi2 = limits[0] ** 2, limits[1] ** 2
    unbounded = math.isinf(hi2)
    t2 = threshold * threshold

    def score(idx: np.ndarray, rows: np.ndarray | None) -> list[Best | None]:
        (basis,) = on_rows(rows, basis_all)
        # The samples' coordinates in one gather, p[axis (x, y), point, line, trial]: (L, T)
        # blocks on the leading axes keep every operation below on contiguous rows (numpy's
        # strided views of small arrays cost more than the calls they save).
        p = basis.take(idx.transpose(2, 0, 1) + seg.gather_offsets("circle", idx.shape[0]))
        # Circumcentre relative to the first point; b, e the other two points' offsets:
        # d = [[bx, ex], [by, ey]], sq = [bb, ee] their squared lengths.
        d = p[:, 1:] - p[:, :1]
        dd = d * d
        sq = dd[0] + dd[1]
        # Indexed, not unpacked: iterating an array ends on a formatted IndexError.
        bx, ex, by, ey = d[0, 0], d[0, 1], d[1, 0], d[1, 1]
        bb, ee = sq[0], sq[1]
        cross = 2.0 * (bx * ey - by * ex)
        # [[by ee, ey bb], [bx ee, ex bb]], flattened: the centre's numerators are its middle
        # pair less its outer pair, (ey bb - by ee, bx ee - ex bb).
        m = (d[::-1] * sq[::-1]).reshape(4, *cross.shape)
        u = m[1:3] - m[::3]
        u /= cross  # (ux, uy)
        uu = u * u
        r2 = uu[0] + uu[1]
        # Collinear or repeated points give cross ~ 0, so r2 huge, inf or nan: the radius
        # limits reject them (nan fails every comparison).
        ok = (r2 >= lo2) & (r2 <= hi2)
        if unbounded:
            ok &= np.abs(cross) > 1e-12 * (bb + ee)
        c, r = p[:, 0] + u, np.sqrt(r2)
        cx, cy = c[0], c[1]
        # Inlier iff (r - t)^2 <= rho^2 <= (r + t)^2, i.e. |rho^2 - mid| <= half: no sqrt
        # for the test, and rho^2 - mid = [-2cx, -2cy, 1, |c|^2 - mid] . basis.
        if r_lo >= threshold:  # then r - t >= 0 on every valid row
            mid, half = r2 + t2, 2.0 * threshold * r
        else:
            rlo, rhi = np.maximum(r - threshold, 0.0), r + threshold
            mid, half = 0.5 * (rlo * rlo + rhi * rhi), 0.5 * (rhi * rhi - rlo * rlo)
        # [-2cx, -2cy, 1, |c|^2 - mid] / half: the test is then |product| <= 1 against a
        # scalar; rejected hypotheses get NaN, which is never an inlier.
        scale = np.where(ok, 1.0 / half, np.nan)
        coef = np.empty((*cx.shape, 4))
        minus_two_scale = -2.0 * scale
        np.multiply(cx, minus_two_scale, out=coef[:, :, 0])
        np.multiply(cy, minus_two_scale, out=coef[:, :, 1])
        coef[:, :, 2] = scale
        cc = c * c
        np.multiply(cc[0] + cc[1] - mid, scale, out=coef[:, :, 3])
        q = coef @ basis  # (L, T, W): (rho^2 - mid) / half, NaN on padding
        inl = np.abs(q) <= 1.0

        def residual_sums(rl: np.ndarray, rt: np.ndarray) -> np.ndarray:
            # |rho - r| over the inliers, rho = sqrt(q half + mid).
            rho2 = q[rl, rt] * half[rl, rt, None] + mid[rl, rt, None]
            d = np.abs(np.sqrt(np.maximum(rho2, 0.0)) - r[rl, rt, None])
            return np.add.reduce(np.where(inl[rl, rt], d, 0.0), axis=1)

        picks = pick_rows(inl, residual_sums)
        k, i = np.arange(len(picks)), np.array([t for t, _, _ in picks])
        params = zip(cx[k, i].tolist(), cy[k, i].tolist(), r[k, i].tolist(), strict=True)
        return [
            None if c == 0 else (c, total, tuple(p))
            for (_, c, total), p in zip(picks, params, strict=True)
        ]

    return score


@_QUIET
def _fit_circles(
    seg: Segments,
    threshold: float,
    limits: tuple[float, float],
    rng: np.random.Generator,
    trials: tuple[int, int],
    confidence: float,
    goals: Sequence[float] | None = None,
    geometric: bool = True,
) -> list[CircleFit | FailedFit]:
    out: list[Any] = _too_few(seg.n, 3, "a circle")
    rows = [r for r, m in enumerate(seg.n) if m >= 3]
    best, done = ransac(seg.n, rows, 3, rng, trials, confidence,
                         _circle_scorer(seg, threshold, limits), seg.n, goals=goals)  # fmt: skip
    for r in rows:
        if best[r] is None:
            out[r] = FailedFit("circle: no sample gave a circle within radius_limits",
                               _none(seg.n[r]), done[r])  # fmt: skip
        elif goals is not None and best[r][0] < goals[r] * GOAL_SLACK:
            out[r] = _short(best[r][0], goals[r], seg.n[r], done[r])
    found = [r for r in rows if out[r] is None]
    if not found:
        return out
    cx, cy, rad = _best_columns(best, 3)
    x, y = seg.x, seg.y
    inl = _circle_distance(x, y, cx, cy, rad) <= threshold
    if geometric:
        xi, yi, ends = x[inl], y[inl], np.cumsum(inl.sum(axis=1)).tolist()
        refits: list[tuple[float, float, float] | None] = []
        for r in range(seg.count):
            lo = ends[r - 1] if r else 0
            refit = _circle_lsq(xi[lo : ends[r]], yi[lo : ends[r]]) if r in found else None
            refits.append((*refit.center, refit.radius) if refit else None)
    else:
        refits = _circle_kasa_batch(x, y, seg.basis("circle"), inl)
    circle = [(math.nan,) * 3] * seg.count
    for r in found:
        cxr, cyr, rr = best[r][2]
        refit = refits[r]
        # The refit may leave the radius limits (e.g. on a flat face); then keep the sample's.
        if refit is not None and limits[0] <= refit[2] <= limits[1]:
            cxr, cyr, rr = refit
        circle[r] = (cxr + seg.mean[r][0], cyr + seg.mean[r][1], rr)
    cx, cy, rad = _columns(circle)
    inliers = _circle_distance(seg.ox, seg.oy, cx, cy, rad) <= threshold
    for r in found:
        c = circle[r]
        out[r] = CircleFit(center=(c[0], c[1]), radius=c[2],
                           inliers=_frozen(inliers[r, : seg.n[r]]), trials=done[r])  # fmt: skip
    return out


def fit_circle(
    points: np.ndarray,
    threshold: float,
    *,
    radius_limits: tuple[float, float] | None = None,
    max_trials: int = CIRCLE_TRIALS[1],
    min_trials: int = CIRCLE_TRIALS[0],
    confidence: float = CONFIDENCE,
    seed: int | np.random.Generator = 0,
    geometric: bool = True,
) -> CircleFit | FailedFit:
    """RANSAC circle on one scan line: inliers are points within ``threshold`` of the circle.

    Hypotheses are circumcircles of three points (closed form, all at once); collinear or
    repeated samples and radii outside ``radius_limits`` are rejected. The best by inlier
    count (ties: lower residual sum) is refitted by geometric least squares on its inliers
    (kept only if the radius stays within the limits) and the inliers recomputed once.
    With ``geometric=False`` the refit is Kasa's algebraic circle alone (the radius the mean
    distance to its centre), which is biased on a partial arc by a few tenths of a mm.

    Parameters
    ----------
    points, threshold
        As for :func:`fit_line`.
    radius_limits : (float, float) or None
        Accepted radii ``(low, high)``, metres. None (the default) accepts any radius, as PCL's
        circle model does until limits are set; the paper's scan lines use
        ``RADIUS_LIMITS_M`` (5-50 mm).
    max_trials, min_trials, confidence, seed
        As for :func:`fit_line`.
    geometric : bool
        Polish the refit by Gauss-Newton on the orthogonal distances.

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
    return fit_circles([points], threshold, radius_limits=radius_limits, max_trials=max_trials,
                       min_trials=min_trials, confidence=confidence, seed=seed,
                       geometric=geometric)[0]  # fmt: skip


def fit_circles(
    segments: Segments | Sequence[np.ndarray],
    threshold: float,
    *,
    radius_limits: tuple[float, float] | None = None,
    max_trials: int = CIRCLE_TRIALS[1],
    min_trials: int = CIRCLE_TRIALS[0],
    confidence: float = CONFIDENCE,
    seed: int | np.random.Generator = 0,
    geometric: bool = True,
    min_inliers: Sequence[float] | None = None,
) -> list[CircleFit | FailedFit]:
    """:func:`fit_circle` on several scan lines at once, one result per line (see
    :func:`fit_lines`, also for ``min_inliers``)."""
    trials = (min_trials, max_trials)
    seg, threshold, goals = checked(segments, threshold, trials, confidence, min_inliers)
    limits = check_limits(radius_limits, "radius_limits")
    rng = np.random.default_rng(seed)
    return _fit_circles(seg, threshold, limits, rng, trials, confidence, goals, geometric)


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
    pair = np.array(
        [
            a0 * b0,
            a0 * b1 + a1 * b0,
            a1 * b1,
            a0 * b2 + a2 * b0,
            a1 * b2 + a2 * b1,
            a2 * b2,
        ]
    )  # (6, T, 2)
    x5, y5 = px[:, 4:], py[:, 4:]
    at5 = (a0 * x5 + a1 * y5 + a2) * (b0 * x5 + b1 * y5 + b2)  # (T, 2)
    return pair[:, :, 0] * at5[:, 1] - pair[:, :, 1] * at5[:, 0]


def _sampson_ratio(conic: np.ndarray, mono: np.ndarray) -> np.ndarray:
    """``F^2 / (t^2 |grad F|^2)`` ``(L, T, M)`` of conics ``(L, T, 6)`` at points whose
    monomials are ``mono`` ``(3, L, 6, M)`` (see ``_monomials``; ``t`` is each line's
    threshold): a point is a Sampson inlier when this is ``<= 1``.

    The Sampson distance ``|F| / |grad F|`` is the orthogonal distance to first order and is
    free of the conic's scale. NaN where the gradient vanishes or the point is padding.
    """
    f, gx, gy = np.matmul(conic, mono)  # F, t dF/dx, t dF/dy: three contiguous blocks
    np.multiply(f, f, out=f)
    np.multiply(gx, gx, out=gx)
    np.multiply(gy, gy, out=gy)
    np.add(gx, gy, out=gx)
    return np.divide(f, gx, out=f)


def _monomials(x: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``(3, L, 6, M)`` monomials of points ``x, y`` ``(L, M)``: those of ``F``
    (``[x^2, xy, y^2, x, y, 1]``), of ``t dF/dx`` (``t [2x, y, 0, 1, 0, 0]``) and of
    ``t dF/dy`` (``t [0, x, 2y, 0, 1, 0]``), ``t`` ``(L, 1)`` each line's threshold."""
    count, m = x.shape
    out = np.zeros((3, count, 6, m))
    f, gx, gy = out
    np.multiply(x, x, out=f[:, 0])
    np.multiply(x, y, out=f[:, 1])
    np.multiply(y, y, out=f[:, 2])
    f[:, 3], f[:, 4], f[:, 5] = x, y, 1.0
    tx, ty = t * x, t * y
    np.multiply(tx, 2.0, out=gx[:, 0])
    gx[:, 1], gx[:, 3] = ty, t
    np.multiply(ty, 2.0, out=gy[:, 2])
    gy[:, 1], gy[:, 4] = tx, t
    return out


def _ellipse_ok(conic: np.ndarray, lo: float | np.ndarray, hi: float | np.ndarray) -> np.ndarray:
    """Which conics ``(6, ...)`` are real ellipses with semi-axes within ``[lo, hi]``."""
    A, B, C, D, E, F = conic
    det = 4.0 * A * C - B * B
    # F at the centre, F(c) = F - (C D^2 - B D E + A E^2) / det, times det.
    f_det = F * det - (C * D * D - B * D * E + A * E * E)
    m = A + C
    h = np.hypot(A - C, B)
    # Eigenvalues (m -+ h)/2 share m's sign when det = m^2 - h^2 > 0, and the semi-axes
    # are a^2 = -2 F(c) / (m - h), b^2 = -2 F(c) / (m + h) once the sign is m's.
    g = -2.0 * f_det * np.sign(m)  # = 2 |F(c)| det when the conic is a real ellipse
    am = np.abs(m)
    return (
        (det > 0.0) & (g > 0.0) & (g >= lo * lo * det * (am + h)) & (g <= hi * hi * det * (am - h))
    )


class _EllipseFrame:
    """The rows' points in each line's normalised frame (centred, RMS radius 1), so conic
    coefficients and Sampson terms stay O(1), with the strided subsample hypotheses are
    first scored on."""

    def __init__(self, seg: Segments, rows: list[int], spread: list[float], threshold: float,
                 limits: tuple[float, float]) -> None:  # fmt: skip
        self.seg = sub = seg.take(rows) if len(rows) != seg.count else seg
        self.scale = scale = [math.sqrt(s / m) for s, m in zip(spread, sub.n, strict=True)]
        inv = _column([1.0 / v for v in scale])
        self.x, self.y = sub.x * inv, sub.y * inv
        self.t = threshold * inv  # (L, 1)
        self.lo, self.hi = limits[0] * inv, limits[1] * inv
        self.stride = stride = [max(1, -(-m // ELLIPSE_SCORE_POINTS)) for m in sub.n]
        self.n_scored = [-(-m // s) for m, s in zip(sub.n, stride, strict=True)]
        j = np.arange(ELLIPSE_SCORE_POINTS)
        picks = np.where(j < np.array(self.n_scored)[:, None], j * np.array(stride)[:, None],
                         sub.width - 1)  # fmt: skip
        picks += (np.arange(sub.count) * sub.width)[:, None]
        self.mono_sub = _monomials(self.x.ravel()[picks], self.y.ravel()[picks], self.t)
        self.pad_sub = _column([ELLIPSE_SCORE_POINTS - m for m in self.n_scored])
        self.pad = _column([sub.width - m for m in sub.n])
        self.stride_col = _column([float(s) for s in stride])
        self._mono_full: np.ndarray | None = None
        self._ones: dict[tuple[int, ...], np.ndarray] = {}

    def mono_full(self) -> np.ndarray:
        if self._mono_full is None:
            self._mono_full = _monomials(self.x, self.y, self.t)
        return self._mono_full

    def truncated_sums(self, ratio: np.ndarray) -> np.ndarray:
        """MSAC's ``sum(min(ratio, 1))`` over the last axis; NaN (padding, a vanishing
        gradient) counts 1, an outlier. ``fmin`` against an array and a product with ones
        are three times cheaper here than against a scalar and ``sum``."""
        shape = ratio.shape
        if shape not in self._ones:
            self._ones[shape] = np.ones(shape)
        return np.fmin(ratio, self._ones[shape], out=ratio) @ self._ones[shape][0, 0]


def _ellipse_scorer(frame: _EllipseFrame) -> Scorer:
    """Hypotheses scored by MSAC's cost on the subsample; each line's best ``ELLIPSE_TOP``
    are rescored on every point."""

    def score(idx: np.ndarray, rows: np.ndarray | None) -> list[Best | None]:
        f = frame
        x, y, lo, hi, pad_sub, pad, stride = on_rows(
            rows, f.x, f.y, f.lo, f.hi, f.pad_sub, f.pad, f.stride_col
        )
        sub, full = f.mono_sub, f.mono_full()
        if rows is not None:  # the monomials hold the lines on their second axis
            sub, full = sub[:, rows], full[:, rows]
        count, trials = idx.shape[0], idx.shape[1]
        g = (idx + f.seg.offsets(count)).reshape(-1, 5)
        conic = _five_point_conics(x.ravel()[g], y.ravel()[g]).reshape(6, count, trials)
        ok = _ellipse_ok(conic, lo, hi)  # (L, T)
        conic = np.ascontiguousarray(conic.transpose(1, 2, 0))  # (L, T, 6)
        # MSAC's truncated cost, in units of each line's threshold squared; padding adds 1 to
        # every hypothesis: take it off.
        cost = f.truncated_sums(_sampson_ratio(conic, sub)) - pad_sub
        cost = np.where(ok, cost, np.inf)
        top = np.argsort(cost, axis=1, kind="stable")[:, :ELLIPSE_TOP]
        rows_ = np.arange(count)[:, None]
        conic, ok = conic[rows_, top], ok[rows_, top]  # (L, TOP, 6), (L, TOP)
        ratio = _sampson_ratio(conic, full)
        inl = ratio <= 1.0
        cost = (f.truncated_sums(ratio) - pad) / stride
        cost = np.where(ok, cost, np.inf)
        i = cost.argmin(axis=1)
        k = np.arange(count)
        counts = (inl[k, i].sum(axis=1) / stride[:, 0]).tolist()
        costs, params = cost[k, i].tolist(), conic[k, i].tolist()
        # MSAC: rank by the truncated quadratic cost; the count (in subsample points) only
        # feeds the RANSAC bound.
        return [
            None if c == math.inf or m == 0 else (int(m + 0.5), c, tuple(p))
            for m, c, p in zip(counts, costs, params, strict=True)
        ]

    return score


@_QUIET
def _fit_ellipses(
    seg: Segments,
    threshold: float,
    limits: tuple[float, float],
    rng: np.random.Generator,
    trials: tuple[int, int],
    confidence: float,
    geometric: bool,
    goals: Sequence[float] | None = None,
) -> list[EllipseFit | FailedFit]:
    out: list[Any] = _too_few(seg.n, 5, "an ellipse")
    spread = np.where(seg.valid, seg.x * seg.x + seg.y * seg.y, 0.0).sum(axis=1).tolist()
    rows = []
    for r, m in enumerate(seg.n):
        if m < 5:
            continue
        if spread[r] > 0.0 and math.isfinite(spread[r]):
            rows.append(r)
        else:
            out[r] = FailedFit("ellipse: all points coincide", _none(m))
    if not rows:
        return out
    frame = _EllipseFrame(seg, rows, [spread[r] for r in rows], threshold, limits)
    sub = frame.seg
    # Goals count scored points, a subsample of each line.
    scored = None if goals is None else [
        goals[r] * m / seg.n[r] for r, m in zip(rows, frame.n_scored, strict=True)]  # fmt: skip
    best, done = ransac(sub.n, list(range(sub.count)), 5, rng, trials, confidence,
                         _ellipse_scorer(frame), frame.n_scored, by_cost=True,
                         goals=scored)  # fmt: skip
    # A line whose best sample falls short of its goal gets no refit: the caller has no use
    # for it (and when every line falls short, there is nothing to refit).
    short = [
        b is not None and goals is not None and b[0] < scored[k] * ELLIPSE_GOAL_SLACK
        for k, b in enumerate(best)
    ]
    if all(b is None or sh for b, sh in zip(best, short, strict=True)):
        for k, r in enumerate(rows):
            out[r] = (FailedFit("ellipse: no sample gave an ellipse within axis_limits",
                                _none(seg.n[r]), done[k]) if best[k] is None
                      else _short(best[k][0] * seg.n[r] / frame.n_scored[k], goals[r],
                                  seg.n[r], done[k]))  # fmt: skip
        return out
    nan6 = (math.nan,) * 6
    conics = np.array([b[2] if b and not sh else nan6
                       for b, sh in zip(best, short, strict=True)])[:, None, :]  # fmt: skip
    inl = _sampson_ratio(conics, frame.mono_full())[:, 0] <= 1.0
    if geometric:
        xi, yi, ends = sub.x[inl], sub.y[inl], np.cumsum(inl.sum(axis=1)).tolist()
        refits: list[EllipseModel | FailedFit] = []
        for k in range(sub.count):
            lo = ends[k - 1] if k else 0
            x, y = xi[lo : ends[k]], yi[lo : ends[k]]
            model: EllipseModel | FailedFit = _ellipse_lsq(x, y)
            refits.append((_ellipse_geometric(x, y, model) or model) if model else model)
    else:
        refits = _ellipse_direct_batch(frame.mono_full()[0], inl, frame.scale)
    found = []
    for k, r in enumerate(rows):
        if best[k] is None:
            out[r] = FailedFit("ellipse: no sample gave an ellipse within axis_limits",
                               _none(seg.n[r]), done[k])  # fmt: skip
            continue
        if short[k]:
            out[r] = _short(best[k][0] * seg.n[r] / frame.n_scored[k], goals[r], seg.n[r],
                            done[k])  # fmt: skip
            continue
        model = refits[k]
        if not (model and limits[0] <= model.axis_lengths[1]
                and model.axis_lengths[0] <= limits[1]):  # fmt: skip
            # The refit left the limits (or failed): keep the sample's ellipse.
            params = _conic_params(*best[k][2])
            if params is None:  # validated as an ellipse when drawn; round-off only
                out[r] = FailedFit("ellipse: degenerate conic", _none(seg.n[r]), done[k])
                continue
            cx, cy, a, b, theta = params
            scale = frame.scale[k]
            model = EllipseModel(center=(cx * scale, cy * scale),
                                 axis_lengths=(a * scale, b * scale), theta=theta)  # fmt: skip
        (cx, cy), (a, b), theta = model.center, model.axis_lengths, model.theta
        mx, my = sub.mean[k]
        found.append((k, r, (cx + mx, cy + my, a, b, theta, math.cos(theta), math.sin(theta))))
    if not found:
        return out
    keep = [k for k, _, _ in found]
    cx, cy, a, b, _, c, s = _columns(p for _, _, p in found)
    ox, oy = sub.ox[keep], sub.oy[keep]
    dx, dy = ox - cx, oy - cy
    residuals = _ellipse_distance(dx * c + dy * s, dy * c - dx * s, a, b)
    inliers = residuals <= threshold
    for j, (k, r, p) in enumerate(found):
        out[r] = EllipseFit(center=(p[0], p[1]), axis_lengths=(p[2], p[3]), theta=p[4],
                            inliers=_frozen(inliers[j, : seg.n[r]]), trials=done[k])  # fmt: skip
    return out


def fit_ellipse(
    points: np.ndarray,
    threshold: float,
    *,
    axis_limits: tuple[float, float] | None = None,
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
    points, threshold
        As for :func:`fit_line`.
    axis_limits : (float, float) or None
        Accepted semi-axes ``(low, high)``, metres. None (the default) accepts any ellipse, as
        PCL's ellipse model does; the paper's scan lines use ``AXIS_LIMITS_M`` (5-100 mm).
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
    return fit_ellipses([points], threshold, axis_limits=axis_limits, max_trials=max_trials,
                        min_trials=min_trials, confidence=confidence, seed=seed,
                        geometric=geometric)[0]  # fmt: skip


def fit_ellipses(
    segments: Segments | Sequence[np.ndarray],
    threshold: float,
    *,
    axis_limits: tuple[float, float] | None = None,
    max_trials: int = ELLIPSE_TRIALS[1],
    min_trials: int = ELLIPSE_TRIALS[0],
    confidence: float = CONFIDENCE,
    seed: int | np.random.Generator = 0,
    geometric: bool = True,
    min_inliers: Sequence[float] | None = None,
) -> list[EllipseFit | FailedFit]:
    """:func:`fit_ellipse` on several scan lines at once, one result per line (see
    :func:`fit_lines`, also for ``min_inliers``).
    """
    trials = (min_trials, max_trials)
    seg, threshold, goals = checked(segments, threshold, trials, confidence, min_inliers)
    limits = check_limits(axis_limits, "axis_limits")
    rng = np.random.default_rng(seed)
    return _fit_ellipses(seg, threshold, limits, rng, trials, confidence, geometric, goals)


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
    radius_limits: tuple[float, float] | None = None,
    axis_limits: tuple[float, float] | None = None,
    confidence: float = CONFIDENCE,
    line_trials: tuple[int, int] = LINE_TRIALS,
    circle_trials: tuple[int, int] = CIRCLE_TRIALS,
    ellipse_trials: tuple[int, int] = ELLIPSE_TRIALS,
    geometric: bool = True,
) -> ScanLineFits:
    """Line, circle and ellipse on one scan line, sharing validation, centring and the RNG.

    ``*_trials`` are ``(min_trials, max_trials)`` pairs; the limits, as for
    :func:`fit_circle` and :func:`fit_ellipse`, are unbounded by default. One generator
    ``g = numpy.random.default_rng(seed)`` serves the three fits in turn, so the result equals
    ``fit_line(points, threshold, seed=g)``, then ``fit_circle(..., seed=g)``, then
    ``fit_ellipse(..., seed=g)`` with the same settings.
    """
    seg = Segments([points])
    threshold = check_threshold(threshold)
    r_limits = check_limits(radius_limits, "radius_limits")
    a_limits = check_limits(axis_limits, "axis_limits")
    check_trials(line_trials, confidence, "line_trials")
    check_trials(circle_trials, confidence, "circle_trials")
    check_trials(ellipse_trials, confidence, "ellipse_trials")
    rng = np.random.default_rng(seed)
    line = _fit_lines(seg, threshold, rng, line_trials, confidence)
    circle = _fit_circles(seg, threshold, r_limits, rng, circle_trials, confidence)
    ellipse = _fit_ellipses(seg, threshold, a_limits, rng, ellipse_trials, confidence, geometric)
    return ScanLineFits(line[0], circle[0], ellipse[0])
