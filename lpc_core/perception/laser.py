"""The four-line method: shape, grasp width and wrist angle from four scan lines.

This is the paper's "Reconstruction of 3-D Objects Using Laser Scanners" (reference/paper.tex,
Methods): on each scan line, taken in its own plane as (s, z) with s = x cos(phi) + y sin(phi),
fit a circle, a line and an ellipse by RANSAC and keep the best by inlier fraction; a sphere
comes from the circle centres, a cylinder or a cuboid from the eight seed points (the extreme
inliers of the four lines) projected on the longitudinal or face plane, sorted around the star,
and Algorithm 1 (``principal_direction``) finds the principal direction.

``LaserParams(variant="paper")`` runs the method as the paper describes it (with departure 1,
which both variants share). The default ``variant="lpc"`` keeps the structure and departs where
the paper is weak:

1. Each line keeps only the segment the optical axis pierces (split at jumps of more than
   ``segment_gap_m``), and a model counts by the run of its inliers through that point (short
   gaps and bumps in front of a face allowed), so a table, a side face or a neighbouring object
   in the capture volume does not win the line. Across a crease the line is fitted once more
   on the points the first line left out.
2. The shape is not decided by counting 2-D models (a partial elliptic arc is fitted by a circle
   within 1 mm, which is why the paper's per-frame cylinder and cuboid accuracy was 95% and 89%)
   but by fitting a plane, a sphere and a cylinder in 3-D to the runs of all four lines, started
   from the 2-D results (sphere from the circle centres; cylinder axis from lines fitted by a
   line model, from Algorithm 1, and from a coarse search over axis directions when those fail),
   fewest parameters first: a richer solid must explain more of the runs by a margin.
3. Sphere and cylinder diameters are 2 x the radius of the 3-D least-squares fit, not the
   distance from a centre to one extreme point. This is what fixes the narrow cylinder (the
   paper measured a 40 mm cylinder as 60 mm).
4. A cuboid's seeds are the ends of each line's run on the face plane. Algorithm 1's straightest
   triple is one candidate direction among the directions through two seeds and a 1-degree
   grid; the chosen one puts the uncut seeds on the sides of the seeds' bounding rectangle, and
   is refined by total least squares over the seeds on each side (a square-ish face has two
   seeds per edge; a face larger than the capture volume may have one). Seeds move half a sample
   outward along their line (``edge_extension``): the last inlier lies up to a sample inside the
   edge. The width counts the object past the face's edges while its surface falls away (a
   prism's next face, a rounded edge), and a face whose seeds lie on a circle is a disc (a lid
   seen from above: a short cylinder along the face normal, the paper's failure case).
5. With ``lazy_fits``, a richer 2-D model is not fitted on a line that a simpler one already
   covers so well that the richer could not win it.
"""

from __future__ import annotations

import bisect
import copy
import functools
import itertools
import math
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal, NamedTuple, Protocol

import numpy as np
from numpy.linalg import _umath_linalg

from lpc_core.perception import fit
from lpc_core.perception.cloud import (
    SCAN_LINE_SUPPORT,
    CloudParams,
    SupportHypotheses,
    find_support,
    support_hypotheses,
)
from lpc_core.perception.reconstruction import LineSummary, Reconstruction, median, wrap_half_turn
from lpc_core.perception.scans import residual_correlation
from lpc_core.perception.solids import (
    CylinderSolid,
    PlaneSolid,
    SphereSolid,
    best_cylinder_axis,
    column_sums,
    einsum_norms,
    fattening_trim_m,
    fit_circle_2d,
    hemisphere_directions,
    orthonormal_basis,
    resting_width,
    squared_norms,
)

MODELS = ("line", "circle", "ellipse")


class ScanLinesLike(Protocol):
    """What the method reads from ``lpc_core.perception.scans.ScanLines``; and, where they
    carry it, ``past_ends_m`` (read with ``getattr``: scan lines without it, as recorded
    before it was measured, size a box's window trim as a whole window)."""

    @property
    def angles_rad(self) -> Any: ...

    @property
    def points(self) -> Any: ...


@dataclass(frozen=True, kw_only=True)
class LaserParams:
    """Every threshold of the four-line method, in SI units.

    The 2-D fit settings are the paper's (PCL RANSAC, 1 mm, radius 5-50 mm); the paper ran
    1000 iterations, here each model's ``(min, max)`` trials follow ``fit``'s adaptive
    budget, since the pierced segment is nearly outlier-free. The circle and ellipse start
    from smaller first chunks than ``fit``'s defaults (16 and 32 samples, not 32 and 128), and
    the ellipse stops at 128, not 256: their refit on the inliers, not the best of many
    samples, sets the model, and a richer model's budget also stops once a model that could
    win the line would have been drawn. The circle keeps its 200: on a cylinder lying beside
    a box, 100 made the frame fail for one seed in six instead of one in thirty.
    """

    variant: Literal["lpc", "paper"] = "lpc"
    # 2-D fits on each scan line.
    threshold_m: float = 0.001
    radius_limits_m: tuple[float, float] = fit.RADIUS_LIMITS_M
    axis_limits_m: tuple[float, float] = fit.AXIS_LIMITS_M
    line_trials: tuple[int, int] = fit.LINE_TRIALS
    circle_trials: tuple[int, int] = (16, 200)
    ellipse_trials: tuple[int, int] = (32, 128)
    lazy_fits: bool = True
    # Polish each line's circle and ellipse refit by Gauss-Newton on orthogonal distances
    # (``fit``'s default). The shape and grasp come from the 3-D solids, so by default
    # it is skipped: on ``lpc bench accuracy`` it changed no figure and cost ~1 ms a frame.
    geometric_2d: bool = False
    min_points_per_line: int = 10
    # A richer 2-D model (circle over line, ellipse over circle) must beat a simpler one by this
    # much inlier fraction on its line.
    model_margin: float = 0.05
    # The pierced segment: consecutive points farther apart than this break a line, and the
    # segment kept must reach within ``pierce_tolerance_m`` of the optical axis (s = 0).
    segment_gap_m: float = 0.008
    pierce_tolerance_m: float = 0.006
    max_outlier_run: int = 3
    run_gap_m: float = 0.015
    # Seeds and Algorithm 1.
    alpha_max_rad: float = math.radians(10.0)
    capture_half_width_m: float = 0.05
    capture_z_m: tuple[float, float] = (0.15, 0.25)
    crop_margin_m: float = 0.0015
    edge_extension: float = 0.5
    # 3-D solids and the decision.
    solid_threshold_m: float = 0.0015
    cylinder_margin: float = 0.10  # the cylinder must explain this much more than the sphere
    cuboid_margin: float = 0.02  # a plane wins ties within this margin (fewest parameters)
    sphere_depth_ratio: float = 0.5  # centre beyond the nearest inlier by >= ratio x radius
    min_solid_fraction: float = 0.6
    # A lying disc found where a face won must explain the runs within this much of the face
    # (see _decide): a disc's band is flat across its middle only, a box's face all across.
    # The jar cap's discs came within 0.16 of their faces, a box's disc 0.36 short of it.
    disc_face_margin: float = 0.25
    axis_grid: int = 96
    max_axis_guesses: int = 2
    cylinder_points: int = 160
    edge_tolerance_m: float = 0.0015
    # When two or more seeds lie off the sides their best direction gives them, the direction
    # is chosen again within this wider tolerance, or by every seed's least-squares fit to its
    # nearest side (see _scattered_direction): a stereo matcher scatters the seeds by its
    # fattening. 0 turns both off.
    scattered_edge_tolerance_m: float = 0.003
    # A cuboid's width includes the object past the face's edges while the surface falls away
    # steeper than ``bevel_min_rad`` (or within ``bevel_free_depth_m`` of the edge).
    bevels: bool = True
    bevel_min_rad: float = math.radians(20.0)
    bevel_free_depth_m: float = 0.003
    # A face whose uncut seeds lie on a circle (RMS <= disc_max_rms_m, at least disc_min_seeds)
    # better than on a rectangle is a disc: a short cylinder along the face normal.
    disc_min_seeds: int = 6
    disc_max_rms_m: float = 0.0012
    # An axis within ~6 degrees of the optical axis has no wrist angle (as the simulator's truth).
    axis_along_view: float = 0.1
    axis_grid_points: int = 120
    axis_good_fraction: float = 0.9
    cylinder_iterations: int = 3
    # A sphere's or cylinder's width comes from the points at least this many pixels inside
    # its silhouette. A matching window straddling an occluding edge corrupts depth on both
    # sides of it: half the window beyond (fattening) and half inside (the rim pulled toward
    # the front), 2 x 3 px for a 7 x 7 window; on a curved surface those pixels hold a wide
    # arc and leaving them out costs only points. 0 fits all the inliers. The pixel's angle
    # comes from the lines' sample spacing unless ``pixel_rad`` (1 / fx) is given.
    silhouette_margin_px: float = 6.0
    pixel_rad: float | None = None
    # Fattening only ever widens a fit, and the rim pins the radius far better than the cap
    # under 1 mm depth steps: the fit on all inliers stands unless its diameter exceeds the
    # camera-facing fit's by more than this.
    silhouette_tolerance_m: float = 0.0015
    # A round is also refitted without the plateaus ending its lines' segments (a matcher's
    # fattening past the silhouette); that fit stands when narrower by more than
    # silhouette_tolerance_m (see _without_end_plateaus).
    end_plateaus: bool = True
    # A round resting on the support (the table the scan lines cross beside it) is fitted
    # again touching it: a sphere, or a cylinder lying along the plane (within
    # rest_max_tilt_rad), whose fitted surface sinks into the plane by at most rest_gap_ratio
    # of its radius or stands off it by at most rest_float_ratio (a ball may stand before a
    # wall). On a short arc a free fit's radius trades against its centre's depth (a matcher's
    # staircase: 40 mm cylinders fitted 27-54 mm); the contact pins it (see _resting_width).
    # rest_gap_ratio 0 turns it off.
    rest_gap_ratio: float = 0.7
    rest_float_ratio: float = 0.25
    rest_max_tilt_rad: float = math.radians(10.0)
    # A matcher pulls a curved surface toward the camera well inside its silhouette, not only
    # at the rim: on SGBM 7-9 and BM 9 cylinders the samples lie 1.0-1.5 mm outside the true
    # surface 3-4 px inside it, 0.3-0.4 mm at 8-11 px, none past 11 px; lpc's noise model
    # shows none. A fit on the whole arc comes out too flat, 5-8 mm too wide. Where the
    # samples within 4 px of the silhouette they show bow out of that fit by rim_bow_m
    # (median), a cylinder is refitted on those at least rim_bias_px inside it (see
    # _rim_free). The inner arc is noisier: where the whole arc's fit holds (the rotation
    # suite's 75 mm cylinder, rims bowing 0.4-1.0 mm) a lower gate costs, a higher one gives
    # up the upright can. Cylinder width MAE, SGBM 7 (SGBM 9), mm: functional upright 4.8
    # (8.5) before, 3.3 (5.0) at 0.4 mm, 3.4 (7.9) at 0.8, 5.0 (8.5) at 1.2; rotation 75 mm
    # 2.70 (3.28), 3.47 (3.89), 2.98 (3.72), 2.77 (3.49); 40 mm 2.07 (2.10), 2.30 (2.35),
    # 2.04 (2.15), 2.03 (2.07). rim_bias_px 0 turns it off.
    rim_bias_px: float = 9.0
    rim_bow_m: float = 0.0008
    # A cuboid face's seed at an occluding edge moves in by this many pixels (samples along
    # its line): the fattening of a matching window of 2 x edge_fattening_px + 1 pixels, 3
    # for a 7 x 7 window. Fixed, it cost lpc's own noise model, which does not fatten, cuboid
    # widths 0.8 -> 3.0 mm and clutter angles 1.8 -> 7.4 deg at 3 px (lpc bench accuracy
    # --quick). See _collect_seeds.
    edge_fattening_px: float = 0.0
    # With edge_fattening_px 0, each frame's fattening is measured where its face runs show
    # it, and ends where it does not show take the frame's median (see _fattening).
    measure_fattening: bool = True
    # Where no face run shows it (a face seen square-on: the fattened pixels copy each row's
    # edge depth and lie on the face's own plane), a frame whose scan lines' residuals are
    # correlated between neighbours like a matcher's (scans.residual_correlation at least
    # ``window_correlation_gate``) takes ``window_fattening_px``, a 7 x 7 window's; lpc's
    # noise model reads at most 0.22, SGBM 0.36-0.38 on average, BM 0.12-0.13 (the gate
    # passes 87-96% of SGBM frames, 11-15% of BM's). The correlation does not size the
    # fattening (the same at SGBM blocks 5, 7 and 9): it only tells that there is one.
    # 0 turns it off.
    window_fattening_px: float = 3.0
    # The same gate tells the matcher's frames to the silhouette bound and to balls' fits
    # (see _matched); 0 turns all of them off.
    window_correlation_gate: float = 0.25
    # A frame whose residuals are correlated at least this much (short of the gate above)
    # came from a matching window too, whose smoothness does not carry: where no face run
    # shows the fattening, it takes ``hole_fattening_px`` (see _weak_gate). 0 turns it off.
    weak_correlation_gate: float = 0.15
    # Where the scans carry the depth past the lines' ends, an occluding edge's side takes
    # that window's fattening in proportion to the depth jump behind the edge, the whole
    # window at ``far_background_ratio`` of the edge's depth, up to ``far_window_shares``
    # windows (and those where no depth lies behind it within ``background_reach_px``; see
    # _window_shares): a matcher fattens an edge by more the further its background lies.
    # The 40 mm bar lying on the table (the table 0.15-0.26 of its depth behind) came out
    # 37.0 mm at SGBM 7 with the whole window on every side, 39.2 so; the four boxes of the
    # functional suite, their far sides under-trimmed, 3.1 -> 2.8 mm (SGBM 7), 4.5 -> 4.3
    # (SGBM 9). 0.35 is the full cloud's far_background_ratio (CloudParams).
    far_background_ratio: float = 0.35
    far_window_shares: float = 1.5
    background_reach_px: float = 30.0
    # Where no face run shows the fattening and the residuals are not correlated like SGBM's,
    # a frame whose image holds no depth past an occluding edge facing +x (``_hole_past_edge``:
    # a block matcher's, whose fattening neither shows) takes ``hole_fattening_px``, a 5 x 5
    # window's, each side its share of it as above but at most one window: without a
    # smoothness term the matcher fattens an edge by about half its window whatever lies
    # behind, and its missing depth there tells no far background. Cuboid width MAE, BM 5 / 7 /
    # 9 (held-out BM 11), mm: 3.05 / 3.78 / 4.56 (4.79) before, 2.73 / 2.21 / 2.28 (3.19) so;
    # with shares up to 1.5 windows 3.37 / 2.53 / 2.05 (2.71); a 7 x 7 window's (3 px) 3.44 /
    # 2.32 / 1.79 (2.54). 0 turns it off.
    hole_fattening_px: float = 2.0
    # The paper's rule, as its authors' code applies it (``variant="paper"``): on each line an
    # ellipse must beat the circle by this much inlier fraction (the text says "twice").
    paper_ellipse_margin: float = 0.25

    def __post_init__(self) -> None:
        if self.variant not in ("lpc", "paper"):
            raise ValueError(f"variant must be 'lpc' or 'paper', got {self.variant!r}")
        positive = (
            "threshold_m",
            "min_points_per_line",
            "segment_gap_m",
            "pierce_tolerance_m",
            "run_gap_m",
            "alpha_max_rad",
            "capture_half_width_m",
            "solid_threshold_m",
            "axis_grid",
            "axis_grid_points",
            "cylinder_iterations",
            "max_axis_guesses",
            "cylinder_points",
            "edge_tolerance_m",
            "bevel_min_rad",
            "disc_min_seeds",
            "disc_max_rms_m",
            "axis_along_view",
            "far_background_ratio",
            "background_reach_px",
        )
        for name in positive:
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be positive, got {value}")
        for name in ("radius_limits_m", "axis_limits_m"):
            lo, hi = getattr(self, name)
            if not 0 < lo < hi:
                raise ValueError(f"{name} must satisfy 0 < min < max, got {(lo, hi)}")
        zlo, zhi = self.capture_z_m
        if not 0 < zlo < zhi:
            raise ValueError(f"capture_z_m must satisfy 0 < near < far, got {(zlo, zhi)}")
        if self.min_points_per_line < 5:
            raise ValueError(f"min_points_per_line must be >= 5, got {self.min_points_per_line}")
        for name in (
            "model_margin",
            "cylinder_margin",
            "cuboid_margin",
            "disc_face_margin",
            "crop_margin_m",
            "edge_extension",
            "sphere_depth_ratio",
            "paper_ellipse_margin",
            "bevel_free_depth_m",
            "max_outlier_run",
            "silhouette_margin_px",
            "edge_fattening_px",
            "silhouette_tolerance_m",
            "scattered_edge_tolerance_m",
            "rest_gap_ratio",
            "rest_float_ratio",
            "rest_max_tilt_rad",
            "rim_bias_px",
            "rim_bow_m",
            "window_fattening_px",
            "hole_fattening_px",
            "far_window_shares",
        ):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.pixel_rad is not None and not (
            math.isfinite(self.pixel_rad) and self.pixel_rad > 0
        ):
            raise ValueError(f"pixel_rad must be positive, got {self.pixel_rad}")
        for name in ("min_solid_fraction", "axis_good_fraction"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")


# --------------------------------------------------------------------------- Algorithm 1


def principal_direction(
    seeds: np.ndarray,
    alpha_max_rad: float = math.radians(10.0),
    *,
    pick: Literal["first", "straightest"] = "first",
) -> np.ndarray | None:
    """Algorithm 1: a principal direction from seed points sorted around the star.

    At each seed S_i (cyclically), if the angle between the inbound vector S_i - S_{i-1} and
    the outbound vector S_{i+1} - S_i is at most ``alpha_max_rad``, S_{i+1} - S_{i-1} is a
    principal direction. ``pick="first"`` returns the first such i as the paper's loop does;
    ``"straightest"`` the one with the smallest angle. ``None`` when no seed qualifies.

    Parameters
    ----------
    seeds : (N, D) array, N >= 3
        Seed points in order around the star (2-D plane coordinates or 3-D).
    """
    seeds = np.asarray(seeds, dtype=np.float64)
    if seeds.ndim != 2 or len(seeds) < 3:
        raise ValueError(f"seeds must have shape (N >= 3, D), got {seeds.shape}")
    previous = np.roll(seeds, 1, axis=0)
    following = np.roll(seeds, -1, axis=0)
    inbound = seeds - previous
    outbound = following - seeds
    n_in = np.linalg.norm(inbound, axis=1)
    n_out = np.linalg.norm(outbound, axis=1)
    scale = max(float(np.linalg.norm(seeds - seeds.mean(axis=0), axis=1).max()), 1e-12)
    valid = (n_in > 1e-6 * scale) & (n_out > 1e-6 * scale)
    cos = np.einsum("ij,ij->i", inbound, outbound) / np.where(valid, n_in * n_out, 1.0)
    angle = np.where(valid, np.arccos(np.clip(cos, -1.0, 1.0)), np.inf)
    hits = np.flatnonzero(angle <= alpha_max_rad)
    if len(hits) == 0:
        return None
    i = int(hits[0]) if pick == "first" else int(hits[np.argmin(angle[hits])])
    return following[i] - previous[i]


def sort_around(points2d: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Indices ordering (N, 2) points counter-clockwise (x right, y down: clockwise on screen)
    around ``origin``."""
    d = points2d - origin
    return np.argsort(np.arctan2(d[:, 1], d[:, 0]), kind="stable")


def sphere_from_circles(
    angles_rad: np.ndarray, centres_sz: np.ndarray, extreme_points: np.ndarray
) -> tuple[np.ndarray, float] | None:
    """The paper's sphere: centre from the circle centres, radius to the extreme points.

    The centre of the circle cut on the plane at angle phi is the sphere centre projected on
    that plane, so its z is the sphere's z and s_c = cx cos(phi) + cy sin(phi). With two or more
    planes, (cx, cy) is their least-squares solution and z their mean; the radius is the mean
    distance from the centre to the extreme points (the paper takes one of them).
    """
    angles = np.asarray(angles_rad, dtype=np.float64).reshape(-1).tolist()
    centres = np.asarray(centres_sz, dtype=np.float64).reshape(-1, 2).tolist()
    if len(angles) < 2:
        return None
    # Least squares over the planes, by the 2x2 normal equations (a few planes: Python floats).
    cs = [(math.cos(a), math.sin(a)) for a in angles]
    scc = sum(c * c for c, _ in cs)
    scs = sum(c * s for c, s in cs)
    sss = sum(s * s for _, s in cs)
    det = scc * sss - scs * scs
    # All planes (nearly) the same: the centre is not fixed across them.
    if not det > 1e-10 * (scc + sss) ** 2:
        return None
    bc = sum(c * sz[0] for (c, _), sz in zip(cs, centres, strict=True))
    bs = sum(s * sz[0] for (_, s), sz in zip(cs, centres, strict=True))
    z = sum(sz[1] for sz in centres) / len(centres)
    cx, cy = (sss * bc - scs * bs) / det, (scc * bs - scs * bc) / det
    # Mean distance to the extreme points (a few: Python floats).
    extremes = np.asarray(extreme_points, dtype=np.float64).reshape(-1, 3).tolist()
    radius = math.fsum(math.dist(p, (cx, cy, z)) for p in extremes) / len(extremes)
    return np.array([cx, cy, z]), radius


# --------------------------------------------------------------------------- one scan line


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


_NO_POINTS = _read_only(np.empty((0, 3)))
_NO_SZ = _read_only(np.empty((0, 2)))
_EMPTY_RUN = _read_only(np.empty(0, dtype=np.intp))


@dataclass
class LineModels:
    """One scan line as the method sees it: the pierced ``points`` (segment, (N, 3)) and their
    plane coordinates ``sz``, the three ``fits``, the chosen ``model``, the ``run`` of its
    inliers through the optical axis, and a ``reason`` when the line is unusable."""

    index: int
    angle: float
    total: int
    reason: str = ""
    # Empty until the line is prepared: shared read-only arrays, replaced, never written.
    points: np.ndarray = field(default_factory=lambda: _NO_POINTS)  # pierced segment
    sz: np.ndarray = field(default_factory=lambda: _NO_SZ)
    fits: dict[str, Any] = field(default_factory=dict)
    model: str = "none"
    run: np.ndarray = field(default_factory=lambda: _EMPTY_RUN)
    # The line's samples before and after its pierced segment (what the object stands on).
    beyond: tuple[np.ndarray, ...] = ()
    # Median change of s/z between neighbouring samples of the run (``step``), computed when
    # first asked for: only a cuboid's seeds use it.
    _step: float | None = field(default=None, repr=False)
    # The segment's end plateaus (``_end_plateaus``) with the ``sz`` they were read from.
    _end_plateaus: tuple[np.ndarray, tuple[int, int]] | None = field(
        default=None, init=False, repr=False, compare=False
    )

    @property
    def step(self) -> float:
        """Median change of s/z between neighbouring samples of the chosen model's run."""
        if self._step is None:
            self._step = _median_step(self.sz.take(self.run, axis=0)) if not self.reason else 0.0
        return self._step

    @property
    def label(self) -> str:
        return f"line {self.index} ({math.degrees(self.angle):.0f} deg)"

    @property
    def direction(self) -> np.ndarray:
        return np.array([math.cos(self.angle), math.sin(self.angle), 0.0])

    def summary(self) -> LineSummary:
        chosen = self.fits.get(self.model)
        return LineSummary(
            angle_deg=math.degrees(self.angle),
            model=self.model,
            params=tuple(map(float, chosen.params)) if chosen else (),
            inlier_fraction=float(chosen.inlier_fraction) if chosen else 0.0,
            n_points=len(self.points),
        )

    def seeds(self) -> np.ndarray:
        """The extreme inliers: first and last point of the pierced run, shape (2, 3)."""
        return self.points.take((self.run[0], self.run[-1]), axis=0)


def _runs(
    inliers: np.ndarray,
    points: np.ndarray,
    params: LaserParams,
    front: np.ndarray | Callable[[], np.ndarray | None] | None = None,
) -> list[np.ndarray]:
    """Runs of inlier indices. A run ends at more than ``max_outlier_run`` outliers in a row or
    a jump of ``segment_gap_m``, except over a bump: outliers all in ``front`` of the model
    (toward the camera; a remote's buttons) spanning at most ``run_gap_m``. ``front`` may be
    a function giving that mask: it is called only when some run would end.

    ``points`` is a segment (``_prepare_lines``): neighbours lie within ``segment_gap_m``, so
    only inliers with outliers between them can end a run, and only those are measured.
    """
    idx = inliers.nonzero()[0]
    if len(idx) < 2:
        return [idx] if len(idx) else []
    if idx.item(-1) - idx.item(0) == len(idx) - 1:
        return [idx]  # no outlier between the inliers (most lines' runs): no gap to measure
    skip = (idx[1:] - idx[:-1] > 1).nonzero()[0]
    # The inliers either side of each gap, and their squared distance, in Python floats:
    # a line has a few gaps, and numpy's calls on arrays that short cost more than the sums
    # (the same sums as squared_norms, in the same order). Both ends' points in one gather.
    gaps, inlying = skip.tolist(), idx.tolist()
    before, after = [inlying[at] for at in gaps], [inlying[at + 1] for at in gaps]
    ends = points.take(before + after, axis=0).tolist()
    longest, gap2 = params.max_outlier_run + 1, params.segment_gap_m**2
    split = []  # (position in idx, inlier before, inlier after, squared distance)
    for at, i, j, p, q in zip(gaps, before, after, ends, ends[len(gaps) :], strict=False):
        dx, dy, dz = q[0] - p[0], q[1] - p[1], q[2] - p[2]
        dist2 = dx * dx + dy * dy + dz * dz
        if j - i > longest or dist2 > gap2:
            split.append((at, i, j, dist2))
    if not split:
        return [idx]
    if callable(front):
        front = front()
    if front is None:
        breaks = [at for at, _, _, _ in split]
    else:
        # behind[j]: points up to j that are not in front; none between two inliers is a bump.
        behind = np.cumsum(~front).tolist()
        limit = params.run_gap_m**2
        breaks = [
            at for at, i, j, dist2 in split if not (behind[j - 1] == behind[i] and dist2 <= limit)
        ]
    bounds = [0, *(b + 1 for b in breaks), len(idx)]
    return [idx[a:b] for a, b in itertools.pairwise(bounds)]


def _front(model: str, fitted: Any, sz: np.ndarray) -> np.ndarray | None:
    """The points nearer the camera than the model: in front of a line (smaller z), outside a
    circle. A stereo matcher's window pulls a curved surface's depth toward the camera over a
    few samples (its staircase, the fattening at a crease or a hole): on a circle as on a
    face, such a bump does not end the run (the SGBM 5 jar lost its circles to a 2 mm bump
    of four samples where the axis pierced it, and came out a box)."""
    if model == "circle":
        cs, cz, r = fitted.params[:3]
        return np.hypot(sz[:, 0] - cs, sz[:, 1] - cz) > r
    if model != "line":
        return None
    px, py, dx, dy = fitted.params
    normal = np.array([dy, -dx])
    if normal[1] > 0:
        normal = -normal  # toward the camera: decreasing z
    return (sz - (px, py)) @ normal > 0


def _pierced_run(runs: list[np.ndarray], s: np.ndarray, params: LaserParams) -> np.ndarray:
    """The run reaching the optical axis (s = 0), or an empty array."""
    tol = params.pierce_tolerance_m
    for run in runs:
        # Python numbers, not numpy scalars: the same sums, at a fraction of their cost.
        if s.item(run.item(0)) - tol <= 0.0 <= s.item(run.item(-1)) + tol:
            return run
    return _EMPTY_RUN


def _hole(before: np.ndarray, after: np.ndarray, params: LaserParams) -> bool:
    """Whether the gap between two (s, z) samples of a line is a hole, not an edge: the
    samples between them are missing (a matcher's failed windows: dim or dotless patches, a
    block matcher's texture check) while the surface goes on, at most ``run_gap_m`` across
    and rising or falling no more than it runs across (45 degrees). An occluding edge or the
    shadow band beside it changes depth far faster than that."""
    ds = abs(float(after[0] - before[0]))
    return ds <= params.run_gap_m and abs(float(after[1] - before[1])) <= ds


def _across_holes(
    runs: list[np.ndarray], run: np.ndarray, sz: np.ndarray, params: LaserParams
) -> np.ndarray:
    """The pierced ``run`` joined with the runs beside it that only a hole parts from it
    (at most ``max_outlier_run`` outliers between them, ``_hole`` across): the gap's
    distance ended it, and holes make a gap long without any sample leaving the model.
    Only a run too short to count is joined, so a line without holes keeps its run."""
    at = next(i for i, r in enumerate(runs) if r is run)
    lo = hi = at
    while lo > 0 and _joins(runs[lo - 1][-1], runs[lo][0], sz, params):
        lo -= 1
    while hi + 1 < len(runs) and _joins(runs[hi][-1], runs[hi + 1][0], sz, params):
        hi += 1
    return run if lo == hi else np.concatenate(runs[lo : hi + 1])


def _joins(i: int, j: int, sz: np.ndarray, params: LaserParams) -> bool:
    return j - i - 1 <= params.max_outlier_run and _hole(sz[i], sz[j], params)


def _choose_model(runs: dict[str, np.ndarray], n: int, margin: float, ellipse_margin: float) -> str:
    """The model whose pierced run covers most of the segment; a richer model (circle over
    line, ellipse over circle) must cover more by its margin."""
    # Plain locals, not a dict of fractions: this runs for every line and model a frame.
    get = runs.get
    line = len(get("line", _EMPTY_RUN)) / n
    circle = len(get("circle", _EMPTY_RUN)) / n
    ellipse = len(get("ellipse", _EMPTY_RUN)) / n
    best, top = "line", line
    if circle > line + margin:
        best, top = "circle", circle
    if ellipse > top + (ellipse_margin if best == "circle" else margin):
        best, top = "ellipse", ellipse
    return best if top > 0 else "none"


def _fit_batch(
    model: str,
    segments: fit.Segments,
    params: LaserParams,
    rng: np.random.Generator,
    goals: list[float] | None = None,
) -> list[Any]:
    """One model fitted to several lines' segments at once."""
    thr = params.threshold_m
    if model == "line":
        lo, hi = params.line_trials
        return fit.fit_lines(segments, thr, min_trials=lo, max_trials=hi, seed=rng,
                             min_inliers=goals)  # fmt: skip
    if model == "circle":
        lo, hi = params.circle_trials
        return fit.fit_circles(
            segments, thr, radius_limits=params.radius_limits_m, min_trials=lo, max_trials=hi,
            seed=rng, min_inliers=goals, geometric=params.geometric_2d,
        )  # fmt: skip
    lo, hi = params.ellipse_trials
    return fit.fit_ellipses(
        segments, thr, axis_limits=params.axis_limits_m, min_trials=lo, max_trials=hi,
        seed=rng, min_inliers=goals, geometric=params.geometric_2d,
    )  # fmt: skip


def _second_lines(
    lines: list[LineModels], params: LaserParams, rng: np.random.Generator
) -> list[Any]:
    """For each line, a line fitted to the points its first line left out, with inliers over
    the whole segment (None where too few points are left)."""
    rest = [~ln.fits["line"].inliers for ln in lines]
    rows = [k for k, r in enumerate(rest) if np.count_nonzero(r) >= params.min_points_per_line]
    out: list[Any] = [None] * len(lines)
    if not rows:
        return out
    segments = fit.Segments([lines[k].sz.compress(rest[k], axis=0) for k in rows], validated=True)
    for k, found in zip(rows, _fit_batch("line", segments, params, rng), strict=True):
        if found:
            out[k] = replace(found, inliers=found.residuals(lines[k].sz) <= params.threshold_m)
    return out


def _prepare_lines(
    angles: list[float],
    raw: list[np.ndarray],
    params: LaserParams,
    joined: np.ndarray | None = None,
    across: frozenset[int] = frozenset(),
) -> list[LineModels]:
    """Each line's points sorted along it, in its plane as (s, z), and the segment the optical
    axis pierces (split at jumps of more than ``segment_gap_m``), or the reason it has none.
    All lines in one pass over their concatenated points (``joined``: ``raw`` concatenated,
    where the caller has it). The lines whose index is in ``across`` take every hole beside
    their pierced segment, however many points it holds (see ``analyse_lines``)."""
    need = params.min_points_per_line
    lines = [
        LineModels(index=i, angle=a, total=len(p))
        for i, (a, p) in enumerate(zip(angles, raw, strict=True))
    ]
    ok = []
    for line in lines:
        if line.total < need:
            line.reason = f"too few points on {line.label}: {line.total} < {need}"
        else:
            ok.append(line)
    if not ok:
        return lines
    counts = [line.total for line in ok]
    if joined is not None and len(ok) == len(lines):
        points = joined
    else:
        points = np.concatenate([raw[line.index] for line in ok])
    c = np.array([math.cos(line.angle) for line in ok]).repeat(counts)
    s_ = np.array([math.sin(line.angle) for line in ok]).repeat(counts)
    s = points[:, 0] * c + points[:, 1] * s_
    # Scan lines usually arrive sorted along themselves (``scans`` cuts them so): then the sort
    # is a check. Descending steps at the joins between lines do not count.
    descending = s[1:] < s[:-1]
    descending[[end - 1 for end in itertools.accumulate(counts[:-1])]] = False
    if descending.any():
        order = np.lexsort((s, np.repeat(np.arange(len(ok)), counts)))
        points, s = points[order], s[order]
    sz = np.empty((len(s), 2))
    sz[:, 0], sz[:, 1] = s, points[:, 2]
    d = points[1:] - points[:-1]
    breaks = (squared_norms(d) > params.segment_gap_m**2).nonzero()[0].tolist()
    stop = 0
    line_bounds = []
    for n in counts:
        start, stop = stop, stop + n
        inside = breaks[bisect.bisect_left(breaks, start) : bisect.bisect_left(breaks, stop - 1)]
        line_bounds.append([start, *(b + 1 for b in inside), stop])
    # s at every segment's first and last point, in one gather.
    at = [i for bounds in line_bounds for k in range(len(bounds) - 1)
          for i in (bounds[k], bounds[k + 1] - 1)]  # fmt: skip
    s_at = iter(s[at].tolist())
    for line, bounds in zip(ok, line_bounds, strict=True):
        best, distance = 0, math.inf
        for k in range(len(bounds) - 1):
            lo, hi = next(s_at), next(s_at)
            d_k = max(lo, -hi, 0.0)  # 0 if it spans s = 0
            if d_k < distance:
                best, distance = k, d_k
        if distance > params.pierce_tolerance_m:
            line.reason = f"the optical axis misses the object on {line.label}"
            continue
        a, b = bounds[best], bounds[best + 1]
        if distance > 0:
            a, b = _across_pierced_hole(bounds, best, sz, params)
        joins = line.index in across
        if b - a < need or joins:
            # Holes (a matcher's failures) may have split or thinned the pierced stretch.
            # Segment k is bounds[k]:bounds[k + 1]; first and last are those a and b bound.
            first, last = bounds.index(a), bounds.index(b) - 1
            while first > 0 and (b - a < need or joins) and _hole(sz[a - 1], sz[a], params):
                first -= 1
                a = bounds[first]
            while (
                last + 2 < len(bounds)
                and (b - a < need or joins)
                and _hole(sz[b - 1], sz[b], params)
            ):
                last += 1
                b = bounds[last + 1]
        if b - a < need:
            line.reason = f"too few points on {line.label}: {b - a} < {need} on the object"
            continue
        line.points, line.sz = points[a:b], sz[a:b]
        line.beyond = (points[bounds[0] : a], points[b : bounds[-1]])
    return lines


def _across_pierced_hole(
    bounds: list[int], best: int, sz: np.ndarray, params: LaserParams
) -> tuple[int, int]:
    """The pierced segment ``bounds[best]:bounds[best + 1]``, which ends short of the optical
    axis, joined with its neighbour beyond the axis where only a hole parts them (``_hole``):
    the axis pierces the hole, so the surface it pierces is the one on both sides of it, not
    the nearer side alone (the jar cap from the front under BM 9 and BM 7 with uniqueness 5,
    trial 0 frame 0: a 10 mm hole from 3 mm left of the axis to 7 mm right of it left the
    horizontal line the band's left half, 22 mm of a 60 mm arc that a line holds within the
    threshold, and every line straight: a box 8-11 mm wide, 62-70 degrees off)."""
    a, b = bounds[best], bounds[best + 1]
    if sz[b - 1, 0] < 0.0 and best + 2 < len(bounds) and _hole(sz[b - 1], sz[b], params):
        return a, bounds[best + 2]
    if sz[a, 0] > 0.0 and best > 0 and _hole(sz[a - 1], sz[a], params):
        return bounds[best - 1], b
    return a, b


_COVERED = "not fitted: a simpler model covers the line"
_STRAIGHT = "not fitted: the line is straight pieces"
# One shared (immutable, empty-masked) failure of each: a fitted frame marks three or four of
# its lines' models so, and a FailedFit costs more to build than the rest of the marking.
_COVERED_FIT, _STRAIGHT_FIT = fit.FailedFit(_COVERED), fit.FailedFit(_STRAIGHT)


def _fit_lines_models(
    lines: list[LineModels], params: LaserParams, rng: np.random.Generator
) -> None:
    """Fit the 2-D models to every line's segment, one model at a time for all lines at once,
    then choose each line's model and its pierced run.

    A model counts by the run of its inliers that reaches the optical axis: a table or a side
    face next to the object may hold more inliers, but it is not what the axis pierces. Models
    are fitted simplest first; with ``lazy_fits`` a richer one is not fitted on a line once a
    simpler one's run covers so much of the segment that the richer could not win.
    """
    need = params.min_points_per_line
    paper = params.variant == "paper"
    lazy = params.lazy_fits and not paper
    segments = fit.Segments([ln.sz for ln in lines], validated=True)
    all_runs: list[dict[str, list[np.ndarray]]] = [{} for _ in lines]
    pierced: list[dict[str, np.ndarray]] = [{} for _ in lines]
    ellipse_margin = params.paper_ellipse_margin if paper else params.model_margin
    for model in MODELS:
        if model == "circle" and lazy and _straight_pieces(lines, pierced, params):
            # Every line is a straight run through the axis with straight pieces beside it
            # (a box's faces, a face and the table): no circle or ellipse is fitted.
            for k, ln in enumerate(lines):
                n = len(ln.points)
                covered = len(pierced[k]["line"]) >= n * (1.0 - params.model_margin)
                why = _COVERED_FIT if covered else _STRAIGHT_FIT
                for richer in ("circle", "ellipse"):
                    ln.fits[richer] = why
                    all_runs[k][richer], pierced[k][richer] = [], _EMPTY_RUN
            break
        rows, goals = [], []
        for k, ln in enumerate(lines):
            n = len(ln.points)
            # The inliers a richer model needs to win the line: more than the best simpler
            # model's pierced run, by the margin (its own run is at most its inliers).
            goal = 0.0
            if model != "line":
                simpler = _choose_model(pierced[k], n, params.model_margin, ellipse_margin)
                if simpler != "none":
                    margin = ellipse_margin if simpler == "circle" else params.model_margin
                    goal = len(pierced[k][simpler]) + margin * n
            full = n * (1.0 - params.model_margin)
            if lazy and any(len(r) >= full for r in pierced[k].values()):
                ln.fits[model] = _COVERED_FIT
                all_runs[k][model], pierced[k][model] = [], _EMPTY_RUN
            else:
                rows.append(k)
                goals.append(goal)
        if not rows:
            continue
        batch = segments if len(rows) == len(lines) else segments.take(rows)
        found_all = _fit_batch(model, batch, params, rng, goals if lazy else None)
        for k, found in zip(rows, found_all, strict=True):
            ln = lines[k]
            ln.fits[model] = found
            front = functools.partial(_front, model, found, ln.sz)
            runs = _runs(found.inliers, ln.points, params, front) if found else []
            all_runs[k][model] = runs
            pierced[k][model] = _pierced_run(runs, ln.sz[:, 0], params)
            if 0 < len(pierced[k][model]) < need:
                pierced[k][model] = _across_holes(runs, pierced[k][model], ln.sz, params)
        if model == "line":
            # Across a crease (a box's front and top faces, or a face and the table) RANSAC's
            # line may lie on the other side: look once more among the points it left out.
            short = [k for k in rows if len(pierced[k]["line"]) < need and lines[k].fits["line"]]
            if short:
                seconds = _second_lines([lines[k] for k in short], params, rng)
                for k, second in zip(short, seconds, strict=True):
                    if second is None:
                        continue
                    ln = lines[k]
                    front = functools.partial(_front, "line", second, ln.sz)
                    runs = _runs(second.inliers, ln.points, params, front)
                    run = _pierced_run(runs, ln.sz[:, 0], params)
                    if len(run) > len(pierced[k]["line"]):
                        ln.fits["line"], all_runs[k]["line"], pierced[k]["line"] = second, runs, run
    if not paper:
        _second_circles(lines, all_runs, pierced, params, rng, ellipse_margin)
    for k, ln in enumerate(lines):
        _choose(ln, all_runs[k], pierced[k], params, ellipse_margin)
    if not paper and all(ln.model == "line" for ln in lines):
        _flattened_crests(lines, pierced, params)


# How many circles _second_circles fits to the points the earlier ones left out.
_SECOND_CIRCLES = 3


def _second_circles(
    lines: list[LineModels],
    all_runs: list[dict[str, list[np.ndarray]]],
    pierced: list[dict[str, np.ndarray]],
    params: LaserParams,
    rng: np.random.Generator,
    ellipse_margin: float,
) -> None:
    """A line whose chosen model's run through the axis holds fewer than
    ``min_points_per_line`` points (``_choose`` would take the longest run anywhere) tries
    circles on the points its circles so far left out, up to ``_SECOND_CIRCLES`` of them,
    and keeps the first that bulges toward the camera with a run through the axis that
    holds that many.

    A segment runs on without a jump from a round into a surface beside it wherever the
    round's far flank falls into a trough in front of that surface (a 40 mm ball beside a
    steep face rising toward the camera, the line at 45 degrees: SGBM 7 on a 47 mm baseline,
    trial 0 frame 2, and 3-way SGBM 7 in twice the room light, trial 0 frame 3). The surface
    holds more samples than the ball's arc, so RANSAC's circle lies concave along the slope
    and the ball's flattened crest, the model chosen by the runs through the axis held 9 of
    74 samples, and the line took the longest run anywhere: the slope's, 44-68 mm off the
    axis, and the frame had no shape. The arc the axis pierces is among the points that
    circle left out, or the next one (the trough's own concave circle). A round seen from
    the camera bulges toward it, so only a convex circle counts (its centre beyond its run's
    samples). Only such lines: where the chosen run through the axis holds enough points it
    is the object's; and these fits draw from the generator after every other fit, so no
    other line moves.
    """
    need = params.min_points_per_line
    margin = params.model_margin
    for k, ln in enumerate(lines):
        first = ln.fits.get("circle")
        chosen = _choose_model(pierced[k], len(ln.points), margin, ellipse_margin)
        if not first or len(pierced[k].get(chosen, _EMPTY_RUN)) >= need:
            continue
        if _near_axis(_longest_run(all_runs[k])[1], ln.sz[:, 0], params.run_gap_m):
            # The axis pierces beside a crease, on its smaller side, and the longest run is
            # the face past it (_choose): an upright conic mug's side along the line at 90
            # degrees under BM 9 with a texture threshold of 8, trial 1 frame 1, 43 samples
            # from 1.5 mm off the axis; a circle there took 13 samples of the rim.
            continue
        rest = ~first.inliers
        for _ in range(_SECOND_CIRCLES):
            if np.count_nonzero(rest) < need:
                break
            segment = fit.Segments([ln.sz.compress(rest, axis=0)], validated=True)
            found = _fit_batch("circle", segment, params, rng)[0]
            if not found:
                break
            inliers = found.residuals(ln.sz) <= params.threshold_m
            second = replace(found, inliers=inliers)
            runs = _runs(
                inliers, ln.points, params, functools.partial(_front, "circle", second, ln.sz)
            )
            run = _pierced_run(runs, ln.sz[:, 0], params)
            if 0 < len(run) < need:
                run = _across_holes(runs, run, ln.sz, params)
            if len(run) >= need and found.params[1] > float(ln.sz[run, 1].max()):
                ln.fits["circle"], all_runs[k]["circle"], pierced[k]["circle"] = second, runs, run
                break
            rest &= ~inliers


def _longest_run(runs: dict[str, list[np.ndarray]]) -> tuple[str, np.ndarray]:
    """The longest run of any model and that model (the first of equals), or "none" and an
    empty run."""
    longest = [(m, max(r, key=len)) for m, r in runs.items() if r]
    return max(longest, key=lambda mr: len(mr[1])) if longest else ("none", _EMPTY_RUN)


def _near_axis(run: np.ndarray, s: np.ndarray, reach: float) -> bool:
    """Whether ``run`` comes within ``reach`` of the optical axis (s = 0) along its line."""
    if not len(run):
        return False
    lo, hi = s.item(run.item(0)), s.item(run.item(-1))
    return max(lo, -hi, 0.0) <= reach


def _flattened_crests(
    lines: list[LineModels], pierced: list[dict[str, np.ndarray]], params: LaserParams
) -> None:
    """Every line chose its straight run, so a plane holds the runs and the frame will be a
    box's face (or a disc): no solid competes. A line that one convex circle within the radius
    limits holds, flanks and all, better than its straight run by the margin a circle needs to
    win is an arc whose crest the matcher flattened: it takes the run of its curved model
    (the circle's or the ellipse's, whichever is longer) through the axis.

    A block matcher locks disparities to whole pixels, so a round's crest comes out a tread
    about a disparity step deep (1-2 mm at 20 cm), 1-1.5 mm behind the arc through its flanks.
    The tread is straight and ends the arc's own run, so the straight run, over the tread and
    a flank, wins the line by a few samples (BM 9, the 60 mm can, trial 1 frame 1: 26 against
    23 of 49, where one circle holds 41; all four lines straight, the can came out a 37 mm
    box). A box's face and the crease beside it are not held so: a circle does not turn a
    crease, and one within the limits sags off a flat face within a few centimetres.

    Only where every line is straight: there the straight runs alone decide the shape. Where
    some line is curved the solids compete on every run already, and the same swap on the
    sweep's frames moved their widths both ways (the 40 mm cylinder under SGBM 9 at roll 90:
    2.7 and 5.7 mm narrower), for no shape.
    """
    need = params.min_points_per_line
    for k, ln in enumerate(lines):
        if ln.reason:
            continue
        curved = max(("circle", "ellipse"), key=lambda m: len(pierced[k].get(m, _EMPTY_RUN)))
        run = pierced[k].get(curved, _EMPTY_RUN)
        n = len(ln.points)
        if len(run) >= need and _arc_holds(
            ln.sz, len(pierced[k]["line"]) + params.model_margin * n, params
        ):
            ln.model, ln.run = curved, run


def _straight_pieces(
    lines: list[LineModels], pierced: list[dict[str, np.ndarray]], params: LaserParams
) -> bool:
    """Whether every line is its line model's pierced run plus, on either side of it, points
    that one straight line holds within ``threshold_m`` (fewer than three always do), or two
    that meet in a concave corner (a side face, then the table it stands on).

    A polyhedron's scan lines look like this (a face through the axis, then the next face or
    the table); a circle or an ellipse could then win a line only by following a crease, which
    neither does. On a sphere or a cylinder the sides of a line run curve away, and they bulge
    toward the camera (convex), so no concave corner stands in for the curve: at least one line
    fails, and every model is fitted as usual.

    Short sides prove nothing, though: over a few millimetres any arc is straight within the
    threshold. Where a stereo matcher loses a small ball's rim (its grazing, steep part) and
    smooths its cap flat, every line is a flat run and two short sides, straight pieces, and
    the ball was taken for a box or a disc (BM 7: 5 of 10 frames of the 40 mm ball). So a line
    whose whole segment one convex circle holds better than its line model, by the margin a
    circle needs to win the line, is not straight pieces (``_arc_holds``).
    """
    thr = params.threshold_m
    for k, ln in enumerate(lines):
        n, run = len(ln.sz), pierced[k].get("line", _EMPTY_RUN)
        if len(run) >= n * (1.0 - params.model_margin):
            continue
        if not len(run):
            return False
        for side in (ln.sz[: run[0]], ln.sz[run[-1] + 1 :]):
            if not (_straight(side, thr) or _concave_corner(side, thr)):
                return False
        if _arc_holds(ln.sz, len(run) + params.model_margin * n, params):
            return False
    return True


def _arc_holds(sz: np.ndarray, need: float, params: LaserParams) -> bool:
    """Whether one circle, bulging toward the camera with a radius within the limits, holds
    more than ``need`` of the (s, z) points within ``threshold_m``: the algebraic circle
    through all of them, then once more through its inliers (a fattened tail or a table's
    first samples pull the first fit off). Two small solves, not a RANSAC fit."""
    lo, hi = params.radius_limits_m
    thr = params.threshold_m
    keep = np.ones(len(sz), dtype=bool)
    for _ in range(2):
        if np.count_nonzero(keep) < 3:
            return False
        got = fit_circle_2d(sz.compress(keep, axis=0))
        if got is None:
            return False
        (cs, cz), radius = got
        inliers = np.abs(np.hypot(sz[:, 0] - cs, sz[:, 1] - cz) - radius) <= thr
        convex = cz > float(sz[:, 1].max())
        if convex and lo <= radius <= hi and np.count_nonzero(inliers) > need:
            return True
        keep = inliers
    return False


def _straight(sz: np.ndarray, threshold: float) -> bool:
    """Whether one line holds the (m, 2) points within ``threshold`` (total least squares:
    the normal is the minor axis of the 2x2 scatter matrix)."""
    m = len(sz)
    if m < 3:
        return True
    d = sz - column_sums(sz) / m
    (sxx, sxy), (_, syy) = (d.T @ d).tolist()
    phi = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    off = np.abs(d @ np.array([-math.sin(phi), math.cos(phi)]))
    return bool(np.maximum.reduce(off) <= threshold)  # off.max() without its Python wrapper


_CONCAVE_SIN = math.sin(math.radians(15.0))


def _concave_corner(sz: np.ndarray, threshold: float) -> bool:
    """Whether the (m, 2) points (s, z), in order of s, are two straight pieces that turn
    away from the camera by more than 15 degrees where they meet, at the point farthest from
    the chord through the ends (Douglas and Peucker's split)."""
    if len(sz) < 4:
        return False
    (s0, z0), (s1, z1) = sz[0].tolist(), sz[-1].tolist()
    # Distance to the chord, up to its length: |(p - p0) x (p1 - p0)|.
    k = int(np.abs((sz[:, 0] - s0) * (z1 - z0) - (sz[:, 1] - z0) * (s1 - s0)).argmax())
    if not 2 <= k <= len(sz) - 2:
        return False
    (a0, b0), (ak, bk) = (s0, z0), sz[k].tolist()
    u = (ak - a0, bk - b0)
    v = (s1 - ak, z1 - bk)
    # z(s) concave at the corner: the slope falls, u x v < 0 (a convex bulge turns the other way).
    turn = (u[0] * v[1] - u[1] * v[0]) / (math.hypot(*u) * math.hypot(*v))
    return (
        turn < -_CONCAVE_SIN and _straight(sz[: k + 1], threshold) and _straight(sz[k:], threshold)
    )


def _choose(
    line: LineModels,
    all_runs: dict[str, list[np.ndarray]],
    pierced: dict[str, np.ndarray],
    params: LaserParams,
    ellipse_margin: float,
) -> None:
    need = params.min_points_per_line
    line.model = _choose_model(pierced, len(line.points), params.model_margin, ellipse_margin)
    if line.model != "none" and len(pierced[line.model]) >= need:
        line.run = pierced[line.model]
    else:
        # The axis pierces near a crease, on its smaller side: keep the longest run there is.
        line.model, line.run = _longest_run(all_runs)
        if line.model == "none":
            line.reason = f"no 2-D model fits {line.label}"
            return
    if len(line.run) < need and _across_holes_count(line, params) < need:
        line.reason = f"too few inliers on {line.label}: {len(line.run)} < {need}"


def _across_holes_count(line: LineModels, params: LaserParams) -> int:
    """How many samples ``line.run`` would hold without the matcher's holes in it: its
    inliers, and for each hole between two neighbouring samples of the segment inside the
    run (``_hole``: the surface goes on across it), the samples the line's median spacing
    along s would have put there.

    A block matcher's texture check drops every window with too few dots, so across a small
    round the segment comes in clumps: BM 5 with a texture threshold of 15, the 40 mm ball,
    trial 0 frame 0, the line at 45 degrees kept 13 samples where the other lines kept 19-30,
    and a circle within 0.5 mm of the ball's radius held 9 of them over 21 mm of its arc
    (three holes of 3-6 mm): 9 < 10 left the frame without a shape. ``min_points_per_line``
    asks how much of the line its model holds; a hole holds no sample against the model.
    Only for a run that would be short (frames that had no shape), and on the sweep only
    block matchers' holes did so: that ball, and the jar cap on three BM 5 settings (its shape
    right on 3, 2 and 1 more of its 20 frames). Every other line's count is its inliers."""
    run, s = line.run, line.sz[:, 0]
    if len(run) < 2:
        return len(run)
    lo, hi = run.item(0), run.item(-1)
    gaps = np.diff(s[lo : hi + 1])
    step = float(np.median(np.diff(s)))
    if not step > 0.0:
        return len(run)
    missing = 0
    for k in (gaps > 1.5 * step).nonzero()[0].tolist():
        if _hole(line.sz[lo + k], line.sz[lo + k + 1], params):
            missing += round(gaps.item(k) / step) - 1
    return len(run) + missing


def _median_step(sz: np.ndarray) -> float:
    """Median change of s/z between neighbouring samples (``np.median`` without its
    overhead: sort, then the middle one or two)."""
    if len(sz) < 2:
        return 0.0
    q = sz[:, 0] / sz[:, 1]
    d = np.abs(q[1:] - q[:-1])
    d.sort()
    m = len(d)
    return float(d[m // 2]) if m % 2 else float((d[m // 2 - 1] + d[m // 2]) / 2)


# --------------------------------------------------------------------------- seeds


@dataclass(frozen=True)
class _Seeds:
    points: np.ndarray  # (K, 3)
    cropped: np.ndarray  # (K,) bool: at the capture volume's edge, not the object's
    occluding: np.ndarray | None = None  # (K,) bool: its run ends where its segment does
    reach: np.ndarray | None = None  # (K,) m: cut, the face ending within this past it; else 0
    # (K, 3): cut with a reach, where its line leaves the face past it (the scans'
    # edge_past_m); zeros elsewhere: for the direction only (_with_face_edges)
    edges: np.ndarray | None = None
    # (K,) the share of the window's trim each uncut seed's place took (its run ended at the
    # face's edge with a far background behind it): for the direction only
    fattened: np.ndarray | None = None
    # (K,) bool: its run stops short of its segment's end, the segment falling away behind
    # the face past it toward a far background (_receding_ends): see _consistent_sides
    receding: np.ndarray | None = None
    # (K,) bool: past its run's end its segment comes back onto the face's plane (_resuming_ends):
    # the face goes on there, past an excursion or a hole's border; see _consistent_sides
    resuming: np.ndarray | None = None
    # (K,) the share of the window's trim an uncut seed at no occluding edge took, its run
    # ending on a ramp down to a near background (_stepped_ends): see _consistent_sides
    stepped: np.ndarray | None = None


# A face's run that stops at most _RAMP_SAMPLES samples short of its segment's end, those
# samples all behind the face by more than _RAMP_BEHIND_M and within _CREASE_OFF_M of it (no
# next face), ends at an occluding edge as one reaching its segment's end does: a matcher's
# fattening ramps down from the face's depth to the background's over the last pixels, and
# the segment ends where the drop passes the segment's threshold. Such seeds lay 4-14 mm past
# the true side on the box tilted left (SGBM 7 dots 0.04), and not being occluding, their
# side kept its fattening. The ramp's samples, left out of the run, took their part of the
# fattening with them: the seed takes the rest of the frame's trim (BM 7 and 9 put such
# seeds on the lying box's true sides, and the whole trim made it 3 mm narrow). A background
# less than far_background_ratio of the edge's depth behind it fattens it little: those
# ends stay.
_RAMP_SAMPLES = 2
_RAMP_BEHIND_M = 0.0003
# A run stopping at most this many samples short of its segment's end on a ramp down to a
# near background takes its share of that step's fattening (_stepped_ends).
_STEPPED_SAMPLES = 6
# The share of the window's trim a run takes that stops short of its segment's end with a far
# background behind the segment, at no occluding edge (see _stopped_shares).
_STOPPED_SHARE = 0.5


def _ramp_ends(
    lines: list[LineModels], face: PlaneSolid, past: list[list[float]], params: LaserParams
) -> list[int]:
    """Per face run end (two a line, as ``_collect_seeds`` orders the seeds): how many samples
    short of its segment's end its run stops on a fattening ramp down to a far background
    (``_far_behind``), 0 where it does not."""
    toward = -1.0 if float(face.point @ face.normal) > 0 else 1.0  # the camera's side
    far = _far_behind(lines, past, params)
    out = []
    for i, line in enumerate(lines):
        run = line.run
        for k in (0, 1):
            ramp = line.points[: run[0]] if k == 0 else line.points[run[-1] + 1 :]
            if not 0 < len(ramp) <= _RAMP_SAMPLES:
                out.append(0)
                continue
            off = ((ramp - face.point) @ face.normal * toward).tolist()
            if min(off) < -_CREASE_OFF_M or max(off) >= -_RAMP_BEHIND_M:
                out.append(0)
                continue
            out.append(len(ramp) if far[2 * i + k] else 0)
    return out


def _behind_ends(lines: list[LineModels], past: list[list[float]]) -> list[tuple[float, float]]:
    """Per face run end (two a line): its depth and the background's behind it (the line's
    samples ``beyond`` its segment, else the scans' depth ``past`` its end; 0: none)."""
    out = []
    for line in lines:
        run = line.run
        for k in (0, 1):
            z = float(line.points[run[0] if k == 0 else run[-1], 2])
            beyond = line.beyond[k] if line.beyond else _NO_POINTS
            if len(beyond):
                behind = median((beyond[-4:, 2] if k == 0 else beyond[:4, 2]).tolist())
            else:
                behind = past[line.index][k] if line.index < len(past) else 0.0
            out.append((z, behind))
    return out


def _far_behind(
    lines: list[LineModels], past: list[list[float]], params: LaserParams
) -> list[bool]:
    """Per face run end (two a line): whether the background behind it lies more than
    far_background_ratio of the end's depth behind it (``_behind_ends``; none: far)."""
    ratio = params.far_background_ratio
    return [b == 0.0 or b - z > ratio * z for z, b in _behind_ends(lines, past)]


def _stepped_ends(
    lines: list[LineModels], face: PlaneSolid, past: list[list[float]], params: LaserParams
) -> list[float]:
    """Per face run end (two a line, as ``_collect_seeds`` orders the seeds): the share of
    the window's fattening taken by a run facing -x in the image that stops short of its
    segment's end on at most ``_STEPPED_SAMPLES`` samples, all behind the face, with a near
    background behind them (``_far_behind`` false; nearer than the run's end: none):
    ``jump / (far_background_ratio z)`` as ``_window_shares`` sizes an occluding edge's, the
    jump from the run's end to the background past its segment; 0 elsewhere.

    A window matcher ramps the disparity down from the face's to a near background's (the
    table beside a tilted box) over the window's reach, and the run ends where the ramp leaves
    the face's plane: its end took the fattening of an edge with that step behind it, less than
    a far background's, and most on the side facing -x, where the band the left image sees
    and the right one does not takes the face's disparity. Without a share such seeds kept it
    all: on the box tilted left at SGBM 7 they lay about 3 mm past that side and set its
    median. Cuboid width MAE over the 64 study settings 2.950 -> 2.929 mm (better by 0.05 or
    more on 14, worse on 4: SGBM 3 2.45 -> 2.51, 3way7-a 2.50 -> 2.58, sg5-s150 2.16 ->
    2.22, 3way7-shot 2.28 -> 2.33, where that side lay inside already), the box tilted left
    3.79 -> 3.73; on every side, and as an occluding edge (its small share turning a side's
    far vote), worse on 2 settings of 14 studied and the TV remote worse on 5 of 12."""
    toward = -1.0 if float(face.point @ face.normal) > 0 else 1.0  # the camera's side
    ratio = params.far_background_ratio
    depths = _behind_ends(lines, past)
    out = []
    for i, line in enumerate(lines):
        run, cos = line.run, math.cos(line.angle)
        for k in (0, 1):
            ramp = line.points[: run[0]] if k == 0 else line.points[run[-1] + 1 :]
            z, behind = depths[2 * i + k]
            leftward = (cos if k else -cos) < -_RIGHTWARD_COS  # the end faces -x in the image
            if not (leftward and 0 < len(ramp) <= _STEPPED_SAMPLES and z < behind <= z + ratio * z):
                out.append(0.0)
                continue
            off = (ramp - face.point) @ face.normal * toward
            out.append((behind / z - 1.0) / ratio if float(off.max()) < 0 else 0.0)
    return out


def _stopped_shares(seeds: _Seeds, far: np.ndarray, stepped: np.ndarray) -> np.ndarray:
    """The ``stepped`` shares (per seed, see ``_stepped_ends``) with ``_STOPPED_SHARE`` for
    each uncut seed at no occluding edge and no near step whose run stops short of its
    segment's end with the background far behind the segment (``far``, per seed, see
    ``_far_behind``), its segment staying off the face's plane past it (not
    ``seeds.resuming``): for its side's median only, as a near step's share.

    Past an occluding edge a matcher fills the band the left image sees and the right one does
    not with the face's disparity, and a semi-global one's paths carry it there sliding a
    step at a time, so the band's depth drifts off the face's plane: the run leaves the plane
    somewhere inside the band, short of the jump at the segment's end, and its end took part
    of the window's fattening where an occluding seed at the jump took it all. Untrimmed, such
    seeds set their side's median out: over the stereo sweep's 84 studied settings' boxes
    (functional suite, 2 trials x 5 frames) they lay a median 0.45 of the window's trim past
    the true side at SGBM (0.9-1.2 on the upright box's sides, 0.4-0.9 on the tilted ones'),
    0.0 at BM, and their distance did not fall with the samples left past the run (so no
    share of the rest, as ``_ramp_ends`` gives). Four-line cuboid width MAE 2.697 -> 2.656 mm
    (33 settings better by 0.05 mm, 6 worse by 0.05-0.12 mm: BM 5, SGBM 3, SGBM 5 with dense
    even dots, SGBM 5 3-way supersampled, two projector rigs, where both sides lay inside
    already); the upright box 2.917 -> 2.848, tilted left 3.603 -> 3.503, the lying box 1.081
    -> 1.086 (its sides face up and down in the image: _across_rows leaves them little trim).
    A whole window: 2.638, but 15 worse; three quarters 2.644, 10 worse."""
    res = seeds.resuming if seeds.resuming is not None else np.zeros(len(far), dtype=bool)
    stopped = far & ~seeds.cropped & (seeds.occluding <= 0) & ~res & (stepped <= 0)
    return np.where(stopped, _STOPPED_SHARE, stepped)


def _receding_ends(
    lines: list[LineModels], face: PlaneSolid, past: list[list[float]], params: LaserParams
) -> list[bool]:
    """Per face run end (two a line, as ``_collect_seeds`` orders the seeds): whether its run
    stops short of its segment's end where the segment's next sample lies behind the face
    and the background past the segment lies far behind (``_far_behind``): the segment falls
    away from the face toward the background, as a matcher's ramp from the face's disparity
    down to the background's does, not up in front of it (a fattened plateau at the edge's
    depth in front of a face turned away, where the plateau, not the ramp, ends the run)."""
    toward = -1.0 if float(face.point @ face.normal) > 0 else 1.0  # the camera's side
    far = _far_behind(lines, past, params)
    out = []
    for i, line in enumerate(lines):
        run, last = line.run, len(line.points) - 1
        for k, end in enumerate((int(run[0]), int(run[-1]))):
            if end == last * k:
                out.append(False)
                continue
            nxt = line.points[end + (1 if k else -1)]
            out.append(far[2 * i + k] and float((nxt - face.point) @ face.normal) * toward < 0)
    return out


def _resuming_ends(lines: list[LineModels], face: PlaneSolid, params: LaserParams) -> list[bool]:
    """Per face run end (two a line, as ``_collect_seeds`` orders the seeds): whether
    ``max_outlier_run`` samples or more of its segment past the run's end lie within
    ``solid_threshold_m`` of the face's plane: the face goes on past that end (an excursion
    or a hole's border inside it), where a segment that stays off the plane past it (a
    fattened plateau, a ramp down to the background) ends with the face."""
    tol, need = params.solid_threshold_m, params.max_outlier_run
    out = []
    for line in lines:
        run = line.run
        for k in (0, 1):
            past = line.points[: run[0]] if k == 0 else line.points[run[-1] + 1 :]
            on = np.abs((past - face.point) @ face.normal) <= tol
            out.append(int(np.count_nonzero(on)) >= need)
    return out


def _collect_seeds(
    lines: list[LineModels],
    params: LaserParams,
    *,
    extend: bool,
    face: PlaneSolid | None = None,
    past: list[list[float]] | None = None,
    pixel_rad: float = 0.0,
    edges: list[list[list[float]]] | None = None,
) -> _Seeds:
    """The seed points, two per line; with ``extend``, each moved outward along its scan line
    by ``edge_extension`` samples (the last inlier lies up to one sample inside the edge).

    With a ``face``, a seed whose line's data stops near the capture volume's side counts as
    cut where the depth ``past`` the line's ends (``past_ends_m``; ``pixel_rad``, the angle
    of a pixel) shows the face going on (``_face_goes_on``). A seed at an occluding edge (its
    run ends where its segment does: the depth jumps away or the data stops) is moved in by
    ``edge_fattening_px`` as well, onto
    the face's plane: stereo matching gives the foreground's depth to the background pixels
    within about half its window of the edge, and on a flat face those fattened pixels lie
    on the face's own plane, so nothing in the line itself tells them apart. With a ``face``
    and ``past``, an uncut seed whose run ends on the segment falling away toward a far
    background is flagged ``receding`` (``_receding_ends``). A seed cut where the face ends
    within its reach keeps where its line leaves the face past it (``edges``, the scans'
    ``edge_past_m``) as its ``edges`` entry.
    """
    # In samples: a sample is a pixel along x or y, as far as a window's half reaches.
    trim = params.edge_fattening_px if face is not None else 0.0
    pts, cropped, occludes, reach = [], [], [], []
    face_edges: list[list[float]] = []
    hw, margin = params.capture_half_width_m, params.crop_margin_m
    zlo, zhi = params.capture_z_m
    for line in lines:
        run = line.run
        # The two ends and their neighbours along the run, as Python floats (a handful of
        # scalars: numpy indexing would cost more than the arithmetic).
        ends = line.points.take((run[0], run[-1]), axis=0).tolist()
        # The segment's own ends, where a face's run stops within _CROP_SLACK samples of them
        # and they stay near the face.
        line_ends: list[list[float] | None] = [None, None]
        if face is not None:
            last = len(line.points) - 1
            for k, (r, e) in enumerate(((int(run[0]), 0), (int(run[-1]), last))):
                if 0 < abs(r - e) <= _CROP_SLACK:
                    q = line.points[e]
                    if abs(float((q - face.point) @ face.normal)) <= _CROP_OFF_FACE_M:
                        line_ends[k] = q.tolist()
        ends_sz = (
            line.sz.take((run[0], run[1], run[-1], run[-2]), axis=0).tolist()
            if len(run) > 1
            else None
        )
        c, s_ = math.cos(line.angle), math.sin(line.angle)
        for k, sign in ((0, -1.0), (1, 1.0)):
            p = ends[k]
            at_crop = any(
                max(abs(e[0]), abs(e[1])) >= hw - margin
                or e[2] <= zlo + margin
                or e[2] >= zhi - margin
                for e in (p, line_ends[k])
                if e is not None
            )
            occluding = run[-k] == (len(line.points) - 1) * k  # run[0] == 0 or run[-1] == last
            ends_within = 0.0
            if (
                occluding
                and face is not None
                and past is not None
                and line.index < len(past)
                and not (line.beyond and len(line.beyond[k]))
            ):
                if not at_crop:
                    at_crop = _face_goes_on(p, c, s_, sign, past[line.index][k], face, params,
                                            pixel_rad, line.step)  # fmt: skip
                elif max(abs(p[0]), abs(p[1])) >= hw - margin:
                    ends_within = _face_ends_past(p, c, s_, sign, past[line.index][k], face,
                                                  pixel_rad)  # fmt: skip
            if extend and not at_crop and trim > 0 and occluding and line.step > 0:
                q = (p[0] * c + p[1] * s_) / p[2]
                q += sign * (params.edge_extension - trim) * line.step
                p = _on_plane(p, (q * c, q * s_, 1.0), face)  # type: ignore[arg-type]
            elif extend and not at_crop and params.edge_extension > 0 and line.step > 0:
                q = (p[0] * c + p[1] * s_) / p[2]
                if ends_sz is not None:
                    p = _extend_seed(p, ends_sz[2 * k], ends_sz[2 * k + 1], c, s_,
                                     q + sign * params.edge_extension * line.step)  # fmt: skip
            pts.append(p)
            cropped.append(at_crop)
            occludes.append(bool(occluding))
            reach.append(ends_within)
            edge = (
                edges[line.index][k]
                if ends_within > 0 and edges is not None and line.index < len(edges)
                else _NO_EDGE
            )
            face_edges.append(edge if edge[2] > 0.0 else _NO_EDGE)
    receding = None
    if face is not None and past is not None:
        ends = _receding_ends(lines, face, past, params)
        receding = np.array(ends, dtype=bool) & ~np.array(cropped, dtype=bool)
    return _Seeds(
        points=np.array(pts),
        cropped=np.array(cropped, dtype=bool),
        occluding=np.array(occludes, dtype=bool),
        reach=np.array(reach),
        edges=np.array(face_edges) if any(e[2] > 0.0 for e in face_edges) else None,
        receding=receding,
        resuming=None if face is None else np.array(_resuming_ends(lines, face, params)),
    )


_NO_EDGE = [0.0, 0.0, 0.0]


# A face's run that stops this many samples short of its segment's end at the capture
# volume's edge is cut there too: a matcher's last sample may leave the face (1.5 mm behind it
# on the box tilted left at SGBM 7, trial 0 frame 3), ending the run a sample inside the edge
# and past crop_margin_m; that seed, on no side, turned the box's axis 7.5 degrees (0.7 cut).
# Two samples cost lpc's noise model: a clutter box's edge rounding off two samples short of
# the capture volume's edge was cut, and its axis turned 0.4 -> 1.8 degrees.
_CROP_SLACK = 1
# ... when that sample lies within this of the face's plane (1.5 mm at SGBM 7): those a real
# edge ends the run before lie further (5-8 mm behind on the golden grasp replay's box).
_CROP_OFF_FACE_M = 0.003


# A seed where its line's data stops (no sample past it in the capture volume) within this
# many samples of the capture volume's side is cut when the depth past the line's end
# (scans.past_line_ends, 8-30 px past it: its middle here) lies within _PAST_ON_FACE_M of the
# face's plane: the face goes on, and the matcher's holes, not an edge, ended the data (BM 5,
# the box tilted right, trial 1 frame 3: its line along x stopped 2 mm short of the side, and
# that seed, on no side, turned the box 16 degrees; 2.9 cut).
_EDGE_REACH_SAMPLES = 2.0
_PAST_MIDDLE_PX = 19.0
_PAST_ON_FACE_M = 0.003


def _face_goes_on(
    end: list[float],
    c: float,
    s_: float,
    sign: float,
    behind: float,
    face: PlaneSolid,
    params: LaserParams,
    pixel_rad: float,
    step: float,
) -> bool:
    """Whether the seed ``end``, where its line's data stops, lies at the capture volume's
    edge: within _EDGE_REACH_SAMPLES samples (``step``) of its side, and the depth ``behind``
    past the line's end (``sign``: which end, along the line's direction ``c, s_``) on the
    face's plane, as the face going on outside the capture volume would put it."""
    if behind <= 0.0 or pixel_rad <= 0.0 or step <= 0.0:
        return False
    hw = params.capture_half_width_m - params.crop_margin_m
    if max(abs(end[0]), abs(end[1])) < hw - _EDGE_REACH_SAMPLES * step * end[2]:
        return False
    # Past a line's end with depth (checked above), no reach means the depth is on the face.
    return _face_ends_past(end, c, s_, sign, behind, face, pixel_rad) == 0.0


def _face_ends_past(
    end: list[float],
    c: float,
    s_: float,
    sign: float,
    behind: float,
    face: PlaneSolid,
    pixel_rad: float,
) -> float:
    """How far past the seed ``end``, cut at the capture volume's side, the face ends: when
    the depth ``behind`` past the line's end (``sign``: which end, along the line's direction
    ``c, s_``) lies off the face's plane by more than _PAST_ON_FACE_M (a background, or the
    next face past a crease), more than half of the window 8-30 px past the end is off the
    face, so its edge lies within _PAST_MIDDLE_PX pixels of the seed along the line (no
    farther across its side); 0 when the depth is missing or on the face."""
    if behind <= 0.0 or pixel_rad <= 0.0:
        return 0.0
    q = (end[0] * c + end[1] * s_) / end[2] + sign * _PAST_MIDDLE_PX * pixel_rad
    on = _on_plane(end, (q * c, q * s_, 1.0), face)
    if abs(on[2] - behind) <= _PAST_ON_FACE_M:
        return 0.0
    return _PAST_MIDDLE_PX * pixel_rad * end[2]


def _on_plane(end: list[float], ray: tuple[float, float, float], plane: PlaneSolid) -> list[float]:
    """Where the ray from the camera along ``ray`` meets ``plane`` (``end`` when it runs
    along the plane)."""
    n, p0 = plane.normal.tolist(), plane.point.tolist()
    along = n[0] * ray[0] + n[1] * ray[1] + n[2] * ray[2]
    if abs(along) < 1e-9:
        return end
    t = (n[0] * p0[0] + n[1] * p0[1] + n[2] * p0[2]) / along
    return [t * ray[0], t * ray[1], t * ray[2]]


def _extend_seed(
    end: list[float], sz0: list[float], sz1: list[float], c: float, s_: float, q: float
) -> list[float]:
    """The point on the ray s/z = q, on the straight line through the run's end ``sz0`` and
    its neighbour ``sz1`` (plane coordinates); ``end`` (3-D) when the ray misses it."""
    (s0, z0), (s1, z1) = sz0, sz1
    ds, dz = s1 - s0, z1 - z0
    denom = ds - q * dz
    if abs(denom) < 1e-12:
        return end
    t = (q * z0 - s0) / denom
    if not math.isfinite(t) or abs(t) > 2.0:
        return end
    s, z = s0 + t * ds, z0 + t * dz
    return [s * c, s * s_, z]


def _face_frame(plane: PlaneSolid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Origin (where the optical axis pierces the plane) and an in-plane basis."""
    n = plane.normal
    if abs(n[2]) > 1e-6:
        origin = np.array([0.0, 0.0, (plane.point @ n) / n[2]])
    else:
        origin = plane.point.copy()
    e1, e2 = orthonormal_basis(n)
    return origin, e1, e2


def _perp(u: np.ndarray) -> np.ndarray:
    return u[..., ::-1] * _TURN


_TURN = np.array([-1.0, 1.0])  # (x, y) -> (-y, x): a quarter turn


def _edge_direction(
    uv: np.ndarray, cropped: np.ndarray, tol: float, reach: np.ndarray | None = None
) -> np.ndarray | None:
    """The rectangle orientation that puts the object's seeds on the sides of the seeds' box.

    The face (cut by the capture volume) holds every seed, and the seeds not cut by the
    capture volume lie on its edges. A direction scores the uncut seeds on a side of the
    bounding rectangle of all seeds in its frame (the true one puts them all there), then
    those on sides holding two or more (a lone extreme seed is on some side for any
    direction). Directions through two uncut seeds are tried first and refined by least
    squares; when none scores best (one seed per edge, a face larger than the capture volume),
    the answer is the middle of the widest span of best-scoring directions on a 1-degree grid.

    With one uncut seed a side, every direction over a span of up to 60 degrees puts each on
    a side, and that span's middle was 20-30 degrees off where the face's diagonal runs along
    a scan line (the box tilted right, 85 mm wide against the capture volume's 100 mm). A
    seed cut at the capture volume's side where the face ends within ``reach`` past it (its
    entry, 0 for none: ``_face_ends_past``) then has its side pass within that reach: among
    directions the uncut seeds score alike, those keeping more such seeds near a side win.
    """
    valid = uv.compress(~cropped, axis=0)
    if len(valid) < 2:
        return None
    i, j = _pairs(len(valid))
    pairs = valid[j] - valid[i]
    lengths = np.sqrt(np.einsum("ij,ij->i", pairs, pairs))
    pairs = pairs[lengths > 2 * tol] / lengths[lengths > 2 * tol, None]
    grid = _ANGLE_GRID
    dirs = np.concatenate([pairs, grid])
    on, shared, area = _rectangle_scores(uv, ~cropped, dirs, tol)
    if reach is not None and reach.any():
        near, _, _ = _rectangle_scores(uv, reach > 0, dirs, reach[:, None])
    else:
        near = np.zeros_like(on)
    best = np.lexsort((area, -near, -shared, -on))[0]
    if best < len(pairs):
        refined = _refine_direction(valid, pairs[best], tol)
        r_on, r_shared = _rectangle_score(uv.tolist(), (~cropped).tolist(), refined.tolist(), tol)
        return refined if (r_on, r_shared) >= (on[best], shared[best]) else pairs[best]
    k = len(pairs)
    top = (on[k:] == on[best]) & (shared[k:] == shared[best]) & (near[k:] == near[best])
    return grid[_widest_run_middle(top)]


def _scattered_direction(
    uv: np.ndarray,
    cropped: np.ndarray,
    direction: np.ndarray,
    tol: float,
    wide: float,
    *,
    best_fit: bool = True,
) -> np.ndarray:
    """``direction``, or when two or more uncut seeds lie off every side it gives them (by
    more than ``tol``), a direction that lets every seed vote: the one chosen within the wider
    tolerance ``wide`` if it puts every uncut seed on a side, else the least-squares fit of
    each uncut seed to its nearest side (``_pooled_sides_direction``) if it leaves as many
    seeds within ``tol`` of a side as ``direction`` does.

    A stereo matcher moves a seed at an occluding edge by its fattening, which varies along
    the edge (0-14 px at SGBM 7, sd 4 px), and one at a crease by up to 3 px; the count within
    1.5 mm then picks among near-ties, by chance, a direction through two seeds that happen to
    line up (a narrow face's side seeds lie about 40 px apart: 4 px turns such a direction by
    6 degrees). Where the background is far and dim the scatter exceeds any tolerance; pooled
    over every seed of all sides it averages out (given each seed's true side, such a fit put
    the upright box's axis 1.8 degrees off on average at SGBM 7, against 5.2 for the count). A
    matcher's hole that ends a run inside the face gives a seed no side holds, which would
    pull that fit: it must not lose seeds the count holds. A sensor without a matching
    window leaves at most one seed off (a bevel, a corner) on all but about 1 % of faces."""
    valid = (~cropped).tolist()
    pts = uv.tolist()
    need = sum(valid)
    on, _ = _rectangle_score(pts, valid, direction.tolist(), tol)
    if on >= need:
        return direction
    if on == need - 1:
        on_wide, _ = _rectangle_score(pts, valid, direction.tolist(), wide)
        if on_wide >= need:
            return direction
    best = _best_pooled_fit(uv, cropped, direction) if best_fit else None
    if best is not None:
        return best
    if on == need - 1:
        # A lone seed off the sides is a bevel or a corner under lpc's noise model, but a
        # matcher moves every seed at an occluding edge by its own fattening: with few uncut
        # seeds (a face larger than the capture volume leaves four), the count then holds
        # three of them by chance along a direction 5-14 degrees off (the lying box at SGBM 9),
        # and leaves the fourth beyond any scatter, where the pooled fit, 0.2-2.6 degrees off,
        # holds them all within the wider tolerance.
        pooled = _pooled_sides_direction(uv, cropped, direction)
        pooled_wide, _ = _rectangle_score(pts, valid, pooled.tolist(), wide)
        return pooled if pooled_wide >= need else direction
    wider = _edge_direction(uv, cropped, wide)
    if wider is not None:
        on_wide, _ = _rectangle_score(pts, valid, wider.tolist(), wide)
        if on_wide >= need:
            return wider
    pooled = _pooled_sides_direction(uv, cropped, direction)
    on_pooled, _ = _rectangle_score(pts, valid, pooled.tolist(), tol)
    return pooled if on_pooled >= on else direction


def _best_pooled_fit(
    uv: np.ndarray, cropped: np.ndarray, direction: np.ndarray
) -> np.ndarray | None:
    """The pooled fit (``_pooled_sides_direction``) that leaves the uncut seeds nearest the
    sides of their bounding rectangle (root mean square), started from ``direction`` and from
    every ``_POOLED_STARTS`` degrees, if it leaves them nearer than ``direction`` does;
    None as well when ``direction`` leaves an uncut seed deeper inside than
    ``_INSIDE_SIDES`` of the face's width (a hole ended its run: no rectangle fits).

    The fit assigns each seed to its nearest side along the direction it starts from: from
    a direction 10-20 degrees off, the seeds near a corner go to the wrong side, and the fit
    stays near it (the upright box at SGBM 7, whose count turned 12-19 degrees off by
    seeds moved by 2-12 px)."""
    pts = uv.tolist()
    valid = (~cropped).tolist()
    uncut = [q for q, ok in zip(pts, valid, strict=True) if ok]
    d = direction.tolist()
    norm = math.hypot(d[0], d[1])
    u = (d[0] / norm, d[1] / norm)
    m = _min_area_direction(uv)
    width = min(float(np.ptp(uv @ m)), float(np.ptp(uv @ _perp(m))))
    if _rectangle_residual(uncut, u) > _INSIDE_SIDES * width:
        return None
    best, best_rms = None, _sides_rms(pts, valid, u)
    for start in [direction, *_POOLED_START_DIRECTIONS]:
        fit = _pooled_sides_direction(uv, cropped, start, passes=6)
        rms = _sides_rms(pts, valid, (float(fit[0]), float(fit[1])))
        if rms < best_rms:
            best, best_rms = fit, rms
    return best


def _sides_rms(pts: list[list[float]], valid: list[bool], u: tuple[float, float]) -> float:
    """Root mean square distance of the ``valid`` (uncut) seeds among ``pts`` to the nearest
    side of the bounding rectangle of all ``pts`` along the unit direction ``u``."""
    near = [min(d) ** 2 for d, ok in zip(_side_distances(pts, u), valid, strict=True) if ok]
    return math.sqrt(sum(near) / len(near))


_POOLED_STARTS = 10.0
_POOLED_START_DIRECTIONS = [
    np.array([math.cos(math.radians(a)), math.sin(math.radians(a))])
    for a in np.arange(0.0, 90.0, _POOLED_STARTS)
]


def _pooled_sides_direction(
    uv: np.ndarray, cropped: np.ndarray, direction: np.ndarray, passes: int = 3
) -> np.ndarray:
    """Total least squares of the rectangle's direction over every uncut seed, each on the
    nearest side of the seeds' bounding rectangle along the current direction (the sides
    across it turned by 90 degrees), from ``direction``; the sides are assigned again after
    each fit, at most ``passes`` times. In Python floats: a handful of seeds."""
    pts = uv.tolist()
    uncut = [not c for c in cropped.tolist()]
    dx, dy = direction.tolist()
    norm = math.hypot(dx, dy)
    ux, uy = dx / norm, dy / norm
    sides: list[int] = []
    for _ in range(passes):
        nearest = [
            d.index(min(d)) if ok else -1
            for d, ok in zip(_side_distances(pts, (ux, uy)), uncut, strict=True)
        ]
        if nearest == sides:
            break
        sides = nearest
        # Sides 0 and 1 run across u: turned by 90 degrees they vote for it.
        groups = [([p for p, s in zip(pts, sides, strict=True) if s == k], k < 2) for k in range(4)]
        sxx, sxy, syy, _ = _sides_scatter(groups)
        if sxx + syy == 0:
            break
        ux, uy = _principal_axis(sxx, sxy, syy, (ux, uy))
    return np.array([ux, uy])


def _widest_run_middle(flags: np.ndarray) -> int:
    """Index of the middle of the longest circular run of True in ``flags``."""
    n = len(flags)
    if flags.all():
        return 0
    start = int(np.argmin(flags))  # a False: unroll the circle there
    rolled = np.roll(flags, -start)
    padded = np.concatenate([[False], rolled, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    begins, ends = edges[::2], edges[1::2]
    k = int(np.argmax(ends - begins))
    return (start + (begins[k] + ends[k] - 1) // 2) % n


_ANGLE_GRID = np.column_stack(
    [np.cos(np.radians(np.arange(180.0))), np.sin(np.radians(np.arange(180.0)))]
)


def _rectangle_scores(
    uv: np.ndarray, valid: np.ndarray, dirs: np.ndarray, tol: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per direction: uncut seeds on a side of all seeds' box, those on shared sides, area
    (``tol`` a scalar, or a column: one per seed)."""
    k = len(dirs)
    # Coordinates along each direction and across it, side by side: (seeds, 2K).
    c = uv @ np.concatenate([dirs, _perp(dirs)]).T
    lo, hi = c.min(axis=0), c.max(axis=0)
    valid = valid[:, None]
    low, high = (c - lo <= tol) & valid, (hi - c <= tol) & valid
    n_low, n_high = low.sum(axis=0), high.sum(axis=0)
    shared = np.where(n_low >= 2, n_low, 0) + np.where(n_high >= 2, n_high, 0)
    on = low | high
    span = hi - lo
    return (on[:, :k] | on[:, k:]).sum(axis=0), shared[:k] + shared[k:], span[:k] * span[k:]


def _rectangle_score(
    uv: list[list[float]], valid: list[bool], u: list[float], tol: float
) -> tuple[int, int]:
    """``_rectangle_scores`` for one direction ``u``, in Python floats (a few seeds)."""
    ux, uy = u
    on = [False] * len(uv)
    shared = 0
    for c in ([x * ux + y * uy for x, y in uv], [y * ux - x * uy for x, y in uv]):
        lo, hi = min(c), max(c)
        for side in ([v - lo <= tol for v in c], [hi - v <= tol for v in c]):
            side = [f and ok for f, ok in zip(side, valid, strict=True)]
            on = [a or b for a, b in zip(on, side, strict=True)]
            n = sum(side)
            shared += n if n >= 2 else 0
    return sum(on), shared


def _refine_direction(uv: np.ndarray, direction: np.ndarray, tol: float) -> np.ndarray:
    """Total least squares of the edge direction: the seeds on each side of the rectangle
    (two or more) vote for it, those on the sides across it turned by 90 degrees. In Python
    floats: a few seeds, and the principal axis of a 2x2 scatter matrix in closed form."""
    dx, dy = direction.tolist()
    norm = math.hypot(dx, dy)
    ux, uy = dx / norm, dy / norm
    pts = uv.tolist()
    a = [x * ux + y * uy for x, y in pts]
    b = [y * ux - x * uy for x, y in pts]  # along _perp(u) = (-uy, ux)
    groups = []
    for c, turn in ((b, False), (a, True)):
        lo, hi = min(c), max(c)
        for side in ([v - lo <= tol for v in c], [hi - v <= tol for v in c]):
            groups.append(([p for p, f in zip(pts, side, strict=True) if f], turn))
    sxx, sxy, syy, voted = _sides_scatter(groups)
    if not voted:
        return np.array([ux, uy])
    return np.array(_principal_axis(sxx, sxy, syy, (ux, uy)))


def _sides_scatter(
    groups: list[tuple[list[list[float]], bool]],
) -> tuple[float, float, float, int]:
    """The 2x2 scatter sums of seeds grouped by the rectangle side they lie on, each group
    about its own mean, those of a group marked ``turn`` (a side across the direction) turned
    by 90 degrees so that they vote for it too; and how many groups voted (two seeds or more).
    In Python floats: a handful of seeds."""
    sxx = sxy = syy = 0.0
    voted = 0
    for members, turn in groups:
        if len(members) < 2:
            continue
        voted += 1
        mx = sum(p[0] for p in members) / len(members)
        my = sum(p[1] for p in members) / len(members)
        for x, y in members:
            cx, cy = (-(y - my), x - mx) if turn else (x - mx, y - my)
            sxx, sxy, syy = sxx + cx * cx, sxy + cx * cy, syy + cy * cy
    return sxx, sxy, syy, voted


def _principal_axis(
    sxx: float, sxy: float, syy: float, u: tuple[float, float]
) -> tuple[float, float]:
    """The larger eigenvalue's unit eigenvector of ``[[sxx, sxy], [sxy, syy]]`` in closed form,
    on the side of ``u``."""
    phi = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    rx, ry = math.cos(phi), math.sin(phi)
    return (rx, ry) if rx * u[0] + ry * u[1] >= 0 else (-rx, -ry)


def _min_area_direction(uv: np.ndarray) -> np.ndarray:
    """Direction of the minimum-area bounding rectangle over the edges between neighbours."""
    edges = np.roll(uv, -1, axis=0) - uv
    lengths = np.linalg.norm(edges, axis=1)
    edges = edges[lengths > 1e-9] / lengths[lengths > 1e-9, None]
    if len(edges) == 0:
        return np.array([1.0, 0.0])
    a, b = uv @ edges.T, uv @ _perp(edges).T
    return edges[int(np.argmin(np.ptp(a, axis=0) * np.ptp(b, axis=0)))]


def _seeds_direction(
    uv: np.ndarray,
    cropped: np.ndarray,
    reach: np.ndarray | None,
    params: LaserParams,
    *,
    fattened: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The rectangle direction the seeds ``uv`` (in the face's plane, sorted around it) give,
    and the one the disc test weighs (the count's, without the best pooled fit).

    Where the count gives no direction, or one that leaves a seed deep inside its sides
    (``_unless_rounded``), the minimum-area rectangle's stands; with ``fattened`` (a
    matcher's fattening measured in the frame), the best pooled fit from it
    (``_best_pooled_fit``) where that holds the uncut seeds nearer the sides. The
    minimum-area rectangle follows the seeds' outline: two of its corners lie on seeds, its
    direction runs along the line between two of them, and a matcher moves each occluding
    seed by its own fattening (0-14 px at SGBM 7) or smears one far past its side (the
    upright box under SGBM without texture: 25 mm), which turns that line; the pooled fit
    lets every seed vote (the upright box's angle 2.42 -> 2.29 degrees over the 39 study
    settings; the laser angle of ten settings 0.01-0.34 degrees better, of five at most
    0.02 worse)."""
    tol = params.edge_tolerance_m
    uncut = [p for p, c in zip(uv.tolist(), cropped.tolist(), strict=True) if not c]
    direction = _edge_direction(uv, cropped, tol, reach)
    wide = params.scattered_edge_tolerance_m
    # The disc test weighs the circle against the rectangle the count chose (its
    # direction without the best pooled fit, which only turns a rectangle's axis): a
    # disc's seeds fit some rectangle, and the best of them would hide the disc.
    classic = direction
    if direction is not None and wide > tol:
        count = direction
        direction = _scattered_direction(uv, cropped, count, tol, wide)
        classic = _scattered_direction(uv, cropped, count, tol, wide, best_fit=False)
    if direction is None or classic is None:
        direction = classic = _min_area_direction(uv)
        outline = True
    else:
        turned = classic is not direction
        counted = direction
        direction = _unless_rounded(uv, uncut, direction)
        classic = _unless_rounded(uv, uncut, classic) if turned else direction
        outline = direction is not counted
    if fattened and outline:
        pooled = _best_pooled_fit(uv, cropped, direction)
        if pooled is not None:
            direction = pooled
    return direction, classic


# A fattened seed moves back along its line by at most this share of its run's length.
_UNFATTEN_MAX_RUN = 0.3
# The trims move seeds by a window and a half at most (2-3 mm across a face tens of mm wide):
# a trimmed count farther than this from the seeds' own picked another rectangle (the soap
# bar's rounded face at SGBM 5, uniqueness 15: 5.0 -> 42.2 degrees off).
_UNFATTEN_MAX_TURN_DEG = 20.0


def _turn_deg(u: np.ndarray, v: np.ndarray) -> float:
    """How far the rectangle along ``v`` is turned from the one along ``u`` (0-45 degrees:
    a rectangle's direction and the one across it are the same rectangle)."""
    cos = abs(float(u @ v)) / float(np.linalg.norm(u) * np.linalg.norm(v))
    sin = abs(float(u[0] * v[1] - u[1] * v[0])) / float(np.linalg.norm(u) * np.linalg.norm(v))
    return math.degrees(math.atan2(min(cos, sin), max(cos, sin)))


def _unfattened_seeds(seeds: _Seeds, trim_rad: float) -> np.ndarray:
    """The seeds with each uncut fattened one moved back toward its line's other end by its
    share (``fattened``) of the window's fattening ``trim_rad`` (an angle: its depth times it
    on the face, at most _UNFATTEN_MAX_RUN of the run)."""
    pts = seeds.points.copy()
    share = seeds.fattened
    if share is None:
        return pts
    partner = np.arange(len(pts)) ^ 1
    partner = np.minimum(partner, len(pts) - 1)
    run = seeds.points[partner] - seeds.points
    length = np.linalg.norm(run, axis=1)
    move = (share > 0) & ~seeds.cropped & (length > 1e-9)
    step = np.minimum(share * trim_rad * seeds.points[:, 2], _UNFATTEN_MAX_RUN * length)
    safe = np.where(length > 1e-9, length, 1.0)
    pts += np.where(move[:, None], run * (step / safe)[:, None], 0.0)
    return pts


def _with_face_edges(
    uv: np.ndarray, cropped: np.ndarray, reach: np.ndarray | None, edge_uv: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The seeds ``uv`` (in the face's plane, sorted around it) with where the cut lines
    leave the face (``edge_uv``, the seeds' ``edges`` in the plane) as uncut seeds, sorted
    around it again; their ``cropped`` flags and ``reach``.

    A face filling the capture volume (the 85 mm box tilted right) keeps about one uncut
    seed a side, and the count's directions then tie over some 20 degrees; past a seed cut
    at the capture volume's side, the pixel where its line leaves the face lies on the
    face's side, as an uncut seed's end does (fattened as much: the matcher carries the
    face's depth past its edge there too). From the scene's truth, that point for every such
    seed of the three upright and tilted boxes over the 69 studied stereo settings would
    take their in-plane direction error 2.99 -> 2.45 degrees; the scans' reading gives 2.46
    (used as the tie-break's tolerance instead, the exact reach made it worse: h40ang2)."""
    if edge_uv is None or not len(edge_uv):
        return uv, cropped, reach
    joined = np.concatenate([uv, edge_uv])
    order = sort_around(joined, np.zeros(2))
    flags = np.concatenate([cropped, np.zeros(len(edge_uv), dtype=bool)])[order]
    if reach is None:
        return joined[order], flags, None
    return joined[order], flags, np.concatenate([reach, np.zeros(len(edge_uv))])[order]


def _edges_onto_uncut_sides(
    uv: np.ndarray, cropped: np.ndarray, edge_uv: np.ndarray, direction: np.ndarray
) -> np.ndarray:
    """The edge points ``edge_uv``, each moved in onto any side of the seeds' own rectangle
    (along ``direction`` and across it) that an uncut seed settles and that it lies past.

    An uncut seed's end already lies at its side's fattened edge; a cut line's point past
    it stands in for such an end, so it cannot lie further out on that side. One that does
    was read where a matcher carried the face's depth on along the line past the edge:
    where the depth stays on the face's straight line up to a hole running out of the walk,
    the hole begins 6-12 px past the true edge (median 8, growing with the window: 5 px at
    SGBM 3, 11 at SGBM 11), against 3 px where the depth leaves the line (the upright and
    tilted boxes over stop 41's 69 settings). Such a point still says how far along that
    side the face reaches, so it is moved in onto the side, not dropped: dropping the ones
    more than 3 mm out turned on whether a point lay 3.1 or 2.9 mm past (SGBM 7, the box
    tilted left, trial 1 frame 1: 1.4 or 4.0 degrees); moved in, the four-line angle over
    the 74 studied settings went 1.734 -> 1.688 degrees (46 settings better, 24 worse).
    Past a side only cut seeds settle, the face goes on beyond the capture volume, and the
    point is what it is for."""
    u = direction / np.linalg.norm(direction)
    axes = np.array([u, [-u[1], u[0]]]).T
    c, ce = uv @ axes, edge_uv @ axes
    for axis in range(2):
        low, high = int(np.argmin(c[:, axis])), int(np.argmax(c[:, axis]))
        if not cropped[low]:
            ce[:, axis] = np.maximum(ce[:, axis], c[low, axis])
        if not cropped[high]:
            ce[:, axis] = np.minimum(ce[:, axis], c[high, axis])
    return ce @ axes.T


def _counted_direction(
    uv: np.ndarray,
    cropped: np.ndarray,
    reach: np.ndarray | None,
    edge_uv: np.ndarray | None,
    params: LaserParams,
    fattened: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``_seeds_direction`` of the seeds ``uv``, run again with the edge points ``edge_uv``
    (where the cut lines leave the face) kept as uncut seeds once moved onto the seeds' own
    sides (``_edges_onto_uncut_sides``: the seeds' own direction only places those sides);
    and the edge points as moved (None without any)."""
    direction, classic = _seeds_direction(uv, cropped, reach, params, fattened=fattened)
    if edge_uv is None or not len(edge_uv):
        return direction, classic, edge_uv
    moved = _edges_onto_uncut_sides(uv, cropped, edge_uv, direction)
    direction, classic = _seeds_direction(
        *_with_face_edges(uv, cropped, reach, moved), params, fattened=fattened
    )
    return direction, classic, moved


def _unit(direction: np.ndarray) -> tuple[float, float]:
    """``direction`` (2-D) as a unit tuple of Python floats."""
    dx, dy = direction.tolist()
    norm = math.hypot(dx, dy)
    return dx / norm, dy / norm


@dataclass(frozen=True)
class _Face:
    width: float
    axis: np.ndarray  # principal axis, 3-D unit
    centre: np.ndarray
    rectangle_residual: float  # largest distance of an uncut seed to its rectangle side
    disc: tuple[np.ndarray, float, float] | None  # centre (3-D), radius, RMS of a circle fit


def _face_geometry(
    plane: PlaneSolid,
    seeds: _Seeds,
    params: LaserParams,
    *,
    paper: bool,
    beyond: np.ndarray | None = None,
    smeared: bool = False,
    trim_px: float = 0.0,
    pixel_rad: float = 0.0,
) -> _Face | str:
    """Grasp width, principal axis (3-D, unit) and centre of a face or longitudinal plane.

    The seeds are projected on the plane and sorted around the star. The paper's variant takes
    Algorithm 1's first direction and measures the seeds across it. Otherwise the direction is
    the one putting the seeds on the sides of a rectangle (Algorithm 1's straightest triple is
    among the candidates), refined by least squares; the principal axis is the longer extent
    and the width the extent across it, over all seeds (seeds cut by the capture volume lie
    inside the face) and the points ``beyond`` the face's edges that belong to the object.
    """
    origin, e1, e2 = _face_frame(plane)
    to_plane = np.array([e1, e2]).T
    uv = (seeds.points - origin) @ to_plane
    order = sort_around(uv, np.zeros(2))
    uv, cropped = uv.take(order, axis=0), seeds.cropped[order]
    disc = None
    # The seeds (and points beyond the edges) are a handful: Python floats from here on.
    pts = uv.tolist()
    uncut = [p for p, c in zip(pts, cropped.tolist(), strict=True) if not c]
    if paper:
        direction = principal_direction(uv, params.alpha_max_rad, pick="first")
        if direction is None:
            return "no principal direction: no three seed points are collinear"
        classic = direction
        pts_all = pts
    else:
        reach = None if seeds.reach is None else seeds.reach[order]
        fattened = trim_px > 0 and pixel_rad > 0
        edge_uv = None
        # Only with a measured window fattening: the edge point stands in for an uncut
        # seed's fattened end; with none (lpc's own noise model) the cut seeds settle it.
        if fattened and seeds.edges is not None:
            found = seeds.edges[:, 2] > 0
            edge_uv = (plane.project(seeds.edges[found]) - origin) @ to_plane
        direction, classic, moved = _counted_direction(
            uv, cropped, reach, edge_uv, params, fattened
        )
        valid = (~cropped).tolist()
        tol = params.edge_tolerance_m
        score = _rectangle_score(pts, valid, direction.tolist(), tol)
        t_uv = None
        if fattened and seeds.fattened is not None:
            trimmed = _unfattened_seeds(seeds, trim_px * pixel_rad).take(order, axis=0)
            t_uv = (trimmed - origin) @ to_plane
        if score[0] < sum(valid) and t_uv is not None:
            # Seeds off every side the count gives them: each occluding seed takes back the
            # fattening it took (its share of the window's trim) along its line, and the
            # count runs again. A side's seeds with different backgrounds behind them are
            # moved out by different amounts, which turns it. Kept where the trimmed seeds fit
            # a rectangle at least as well: a wrong share (a far background that did not
            # fatten there) spreads them instead.
            # The trimmed seeds with the edge points, then without them: the edge points were
            # moved in onto the untrimmed seeds' sides, which the trim moves in, so with them
            # the trimmed count can lose a side's seed it holds alone (SGBM 7, the box tilted
            # left, trial 1 frame 0: 3 -> 2 seeds, and the untrimmed direction stood 5.0
            # degrees off, 0.8 mm narrow; 1.1 degrees and 0.2 mm with the trimmed seeds' own
            # count).
            tries = [_with_face_edges(t_uv, cropped, reach, moved)]
            if moved is not None and len(moved):
                tries.append((t_uv, cropped, reach))
            for t_seeds in tries:
                t_direction, t_classic = _seeds_direction(*t_seeds, params, fattened=fattened)
                if _rectangle_score(t_uv.tolist(), valid, t_direction.tolist(), tol) >= score and (
                    _turn_deg(direction, t_direction) <= _UNFATTEN_MAX_TURN_DEG
                ):
                    direction, classic = t_direction, t_classic
                    break
        if t_uv is not None:
            # A seed lies past its side by the fattening its background gave it (over the
            # studied settings' boxes: 0.0 mm with no share of the window's trim, 1.1 with
            # half, 2.7 with one, 4.1 with one and a half, median), and the count at 1.5 mm
            # over seeds scattered that much picks, by chance, a direction through two that
            # line up (BM 9 at P2 x 4, the upright box, trial 1 frame 3: 6.5 degrees off).
            # The trimmed seeds' own count (the edge points moved onto their sides) is kept
            # where the trimmed seeds lie nearer its rectangle's sides than that direction's,
            # by root mean square: no seed crossing a tolerance flips the choice. Within
            # _UNFATTEN_MAX_TURN_DEG, as the trim above: past it the count found another
            # rectangle (without the bound, the upright box without texture, trial 0 frame
            # 0: 0.0 -> 24.7 degrees). The four-line angle over the 79 studied settings:
            # 1.696 -> 1.641 degrees (60 settings better, 19 worse).
            t_direction, t_classic, _ = _counted_direction(
                t_uv, cropped, reach, edge_uv, params, fattened
            )
            t_pts = t_uv.tolist()
            if _turn_deg(direction, t_direction) <= _UNFATTEN_MAX_TURN_DEG and _sides_rms(
                t_pts, valid, _unit(t_direction)
            ) < _sides_rms(t_pts, valid, _unit(direction)):
                direction, classic = t_direction, t_classic
        pts_all = pts
        if beyond is not None and len(beyond):
            pts_all = pts + ((beyond - origin) @ to_plane).tolist()
    dx, dy = direction.tolist()
    norm = math.hypot(dx, dy)
    ux, uy = dx / norm, dy / norm
    # Coordinates along u and along _perp(u) = (-uy, ux).
    a = [x * ux + y * uy for x, y in pts_all]
    b = [y * ux - x * uy for x, y in pts_all]
    alo, ahi, blo, bhi = min(a), max(a), min(b), max(b)
    if not paper and trim_px > 0 and pixel_rad > 0 and seeds.occluding is not None:
        settled = [False] * 4
        z_face = float(plane.point[2])
        trims = tuple(
            fattening_trim_m(
                plane.normal[2],
                n2[0] * e1 + n2[1] * e2,
                z_face,
                trim_px * pixel_rad,
                params.solid_threshold_m,
            )
            * _across_rows(plane, n2[0] * e1 + n2[1] * e2)
            for n2 in ((ux, uy), (-uy, ux))
        )
        alo, ahi, blo, bhi = _trimmed_sides(
            plane, (e1, e2), (ux, uy), uv, cropped, seeds.occluding[order],
            _consistent_sides(
                pts, cropped.tolist(), (seeds.occluding[order] > 0).tolist(), (ux, uy), a, b,
                # Points beyond the edges: bevels or further faces there, no occluding edge
                # (a hexagonal prism lost 3-5 mm at SGBM 7 dots 0.04 and BM 5 without this);
                # so too a walk past an edge dropped as the fattening's smear (the box tilted
                # left at SGBM 3 lost 26 mm once it let a hole's seed stand for its side).
                _OUTLYING_TRIMS * trim_px * pixel_rad * float(plane.point[2])
                if len(pts_all) == len(pts) and not smeared else math.inf,
                _OUTLYING_TRIMS * trim_px * pixel_rad * float(plane.point[2]),
                seeds.occluding[order].tolist(), trims, settled,  # type: ignore[arg-type]
                _occlusion_sides(plane, (e1, e2), (ux, uy)),
                None if seeds.receding is None else seeds.receding[order].tolist(),
                None if seeds.resuming is None else seeds.resuming[order].tolist(),
                None if seeds.stepped is None else seeds.stepped[order].tolist(),
            ),
            trim_px * pixel_rad, params, settled,
        )  # fmt: skip
    elif (
        not paper
        and params.edge_fattening_px == 0
        and pixel_rad > 0
        and seeds.occluding is not None
        and len(pts_all) == len(pts)
        and not smeared
    ):
        # Not where a fixed edge_fattening_px moved the seeds in already. Points beyond the
        # edges: bevels or further faces there (the hexagonal prism's seeds lie on no
        # rectangle's sides: on lpc's noise model it lost 2-6 mm), or a smear dropped there:
        # as in _consistent_sides, no seed is an outlier then.
        alo, ahi, blo, bhi = _straight_sides(
            pts, cropped.tolist(), (seeds.occluding[order] > 0).tolist(), a, b,
            (alo, ahi, blo, bhi), (ux, uy),
            _STRAIGHT_SIDE_SAMPLES * pixel_rad * float(plane.point[2]),
        )  # fmt: skip
    if paper:
        principal, width = (ux, uy), bhi - blo
    else:
        if ahi - alo >= bhi - blo:
            principal, width = (ux, uy), bhi - blo
        else:
            principal, width = (-uy, ux), ahi - alo
        if len(uncut) >= params.disc_min_seeds:
            circle = fit_circle_2d(np.array(uncut))
            if circle is not None:
                (cu, cv), radius = circle[0].tolist(), circle[1]
                sq = [(math.hypot(x - cu, y - cv) - radius) ** 2 for x, y in uncut]
                rms = math.sqrt(sum(sq) / len(sq))
                disc = (origin + cu * e1 + cv * e2, radius, rms)
    residual = 0.0
    if uncut:
        cx, cy = (ux, uy) if paper else classic.tolist()
        norm = math.hypot(cx, cy)
        residual = _rectangle_residual(uncut, (cx / norm, cy / norm))
    a_mid, b_mid = (alo + ahi) / 2, (blo + bhi) / 2
    centre = origin + (a_mid * ux - b_mid * uy) * e1 + (a_mid * uy + b_mid * ux) * e2
    axis = principal[0] * e1 + principal[1] * e2
    return _Face(width, axis / math.sqrt(axis @ axis), centre, residual, disc)


# Where the scan lines run on past a face's crease (no occluding edge) onto the next face,
# the two faces' planes meet along the box's edge: fitted to each face's interior, they put
# the edge where no matcher's fattening moves it (the seeds at the sides scatter by 0-14 px
# along their lines at SGBM 7). The next face's samples: past each crease seed, those more
# than _CREASE_OFF_M behind the face's plane (or in front of it: the table), up to
# _CREASE_REACH_M from the seed along the line, past at least _CREASE_MIN_LINES seeds (two
# let one noisy piece tilt the plane: an upright box with the table in view, its crease
# 0.2-4.3 degrees off square on lpc's noise model); their plane within _CREASE_RMS_M (one
# face, not two), spread _CREASE_SPREAD_M across, at least _CREASE_MIN_DEG to the face.
_CREASE_OFF_M = 0.003
_CREASE_REACH_M = 0.03
_CREASE_MIN_SAMPLES = 4
_CREASE_MIN_LINES = 3
_CREASE_RMS_M = 0.001
_CREASE_SPREAD_M = 0.003
_CREASE_MIN_DEG = 30.0
# The crease turns the face's direction by at most this: further, it is not the edge the
# rectangle's sides follow (a bevel, or the seeds' rectangle is another face's).
_CREASE_TURN_DEG = 10.0


def _crease_direction(
    lines: list[LineModels], plane: PlaneSolid, seeds: _Seeds
) -> np.ndarray | None:
    """The direction (3-D, unit) where the face ``plane`` meets the next face, fitted to the
    samples the face's ``lines`` have past their crease seeds (not cut, not occluding): those
    behind the face's plane (the box's next face), else those in front of it (the table the
    face stands on); None when fewer than three line ends see a single such plane."""
    if seeds.occluding is None:
        return None
    behind: list[np.ndarray] = []
    before: list[np.ndarray] = []
    for i, line in enumerate(lines):
        run = line.run
        for k in (0, 1):
            j = 2 * i + k
            if j >= len(seeds.points) or seeds.cropped[j] or seeds.occluding[j] > 0:
                continue
            past = line.points[: run[0]][::-1] if k == 0 else line.points[run[-1] + 1 :]
            if len(past) == 0:
                continue
            start = line.points[run[0] if k == 0 else run[-1]]
            reach = np.sqrt(((past - start) ** 2).sum(axis=1)) <= _CREASE_REACH_M
            height = (past - plane.point) @ plane.normal
            for pieces, off in (
                (behind, height < -_CREASE_OFF_M),
                (before, height > _CREASE_OFF_M),
            ):
                piece = past[reach & off]
                if len(piece) >= _CREASE_MIN_SAMPLES:
                    pieces.append(piece)
    for pieces in (behind, before):
        if len(pieces) < _CREASE_MIN_LINES:
            continue
        pts = np.concatenate(pieces)
        _, sv, vt = np.linalg.svd(pts - pts.mean(axis=0), full_matrices=False)
        n = math.sqrt(len(pts))
        if sv[2] / n > _CREASE_RMS_M or sv[1] / n < _CREASE_SPREAD_M:
            continue
        normal = vt[2]
        if abs(float(normal @ plane.normal)) > math.cos(math.radians(_CREASE_MIN_DEG)):
            continue
        edge = np.cross(plane.normal, normal)
        return edge / math.sqrt(edge @ edge)
    return None


def _along_crease(axis: np.ndarray, crease: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The face's principal ``axis`` turned within its plane (``normal``) onto the crease or
    the direction across it, whichever it lies nearer, unless that turns it by more than
    _CREASE_TURN_DEG."""
    across = np.cross(normal, crease)
    target = crease if abs(axis @ crease) >= abs(axis @ across) else across
    if target @ axis < 0:
        target = -target
    if target @ axis < math.cos(math.radians(_CREASE_TURN_DEG)):
        return axis
    return target


def _consistent_sides(
    seeds: list[list[float]],
    cropped: list[bool],
    occluding: list[bool],
    u: tuple[float, float],
    a: list[float],
    b: list[float],
    apart_m: float,
    cut_apart_m: float,
    shares: list[float] | None = None,
    trims: tuple[float, float] = (0.0, 0.0),
    settled: list[bool] | None = None,
    occlusion: list[bool] | None = None,
    receding: list[bool] | None = None,
    resuming: list[bool] | None = None,
    stepped: list[float] | None = None,
) -> tuple[float, float, float, float]:
    """The rectangle's sides ``(alo, ahi, blo, bhi)`` along the unit direction ``u`` where a
    matcher fattened the edges: each side through the farthest uncut seed nearest it once the
    seeds lying more than ``apart_m`` beyond every other seed of that side are dropped, one
    at a time (two seeds or more; a side keeps one). Points beyond the face's edges (``a`` and
    ``b`` hold the seeds' coordinates, then those points') still extend it; seeds cut by the
    capture volume bound only the sides with fewer than two uncut seeds, and a side with one
    at an ``occluding`` edge only where none of them lies more than ``cut_apart_m`` beyond it
    (a fattened run may reach the capture volume past the edge: the tilted box at SGBM 9 was
    21 mm wide so). Seeds at a corner count on both its sides (``_corner_seeds``).

    With ``settled`` (four flags, set here for the sides placed so), ``shares`` (each seed's
    share of the window's trim, 0 at no occluding edge) and ``trims`` (a whole window's trim
    across the sides along ``u``, then across ``u``): a side of two uncut seeds or more half
    of whose occluding seeds or more take a whole window or more (``_FAR_EDGES``: the
    background lies far behind the side) goes through the median of its seeds' edges, each
    seed's own trim taken off, its outliers beyond dropped as above and a seed at no
    occluding edge lying more than ``_HOLE_APART`` times ``apart_m`` inside the farthest
    left out (a hole's border, inside the face). Those sides are trimmed already:
    ``_trimmed_sides`` leaves them. So too a side facing the occlusion side (``occlusion``,
    four flags, ``_occlusion_sides``) with one edge or more taking a whole window, through the
    median of its occluding seeds' edges alone. A seed with a ``stepped`` share (its run
    ending on a ramp down to a near background, ``_stepped_ends``) enters such a median with
    that share of the trim taken off, and counts as no occluding edge otherwise.

    A window matcher fattens an occluding edge by an amount that varies along it: at SGBM 7
    the cuboids' seeds lay 0.95 mm past the true side on the nearest, 3.1 on the median and
    5.4 on the farthest seed of a side (mean over cuboid_upright and cuboid_tilt_left), up to
    15 mm, and the trim of a 7 x 7 window's fattening (2.5-3 mm a side) left the widths 5.7
    mm too wide. A seed that lies so far beyond the others carries more fattening than any
    window explains. The median of each side would have gone further (cuboid widths 4.0 ->
    3.4 mm over the eight matcher settings, against 3.6 here), but where the fattening is
    smaller than the trim, as on the 40 mm bar lying on the table (its background is near),
    every side moved in cost width: the bar lost 1.6 mm (36.9 -> 35.3 at SGBM 7). Where the
    background lies far behind, the trim sizes the fattening of the median seed, not the
    farthest: the upright box at SGBM 7 (the room behind its sides, one and a half windows
    a side) had its sides' seeds 3.5-5 px past the true side, their farthest up to 7 px,
    and the side through the farthest kept 1-4 px of it (width MAE 3.5 mm over 10 frames,
    2.3 through the median). Where it lies near (the bar, the table 0.15-0.26 of its depth
    behind, 0.5-0.7 of a window a side) its median seed lies on the true side: the share
    over-trims it (the bar 2.2 mm too narrow at SGBM 7 through the median, 0.7 so)."""
    n = len(seeds)
    out = [min(a), max(a), min(b), max(b)]
    # Per side: each seed's coordinate across it, positive outward (sides 0 and 2 face the
    # negative way), its edge there once its own share of the trim is taken off, its share.
    groups: list[list[tuple[float, float, float]]] = [[], [], [], []]
    cut_groups: list[list[float]] = [[], [], [], []]
    edge = [False] * 4  # the side's uncut seeds include one at an occluding edge
    members: list[list[int]] = [[], [], [], []]  # the side's uncut seeds
    dists = _side_distances(seeds, u)
    share = shares if shares is not None else [0.0] * n
    recede = receding if receding is not None else [False] * n
    step = stepped if stepped is not None else [0.0] * n

    def across(k: int, side: int) -> tuple[float, float, float]:
        c = _outward(a, b, k, side)
        w = share[k]
        if w == 0 and recede[k] and occlusion is not None and occlusion[side]:
            # Facing the occlusion side, a run ending where its segment falls away toward a
            # far background took the fill and the fattening as an occluding one did: a
            # whole window (see _occlusion_sides).
            w = 1.0
        if w == 0 and step[k] > 0:
            # A run ending on a ramp down to a near background (_stepped_ends): its edge less
            # that step's share of the window, for the side's median; no occluding edge for
            # the side's far vote, which a near background's small share would turn.
            return c, c - step[k] * trims[side // 2], 0.0
        return c, c - w * trims[side // 2], w

    for k, (d, cut, occludes) in enumerate(zip(dists, cropped, occluding, strict=True)):
        side = d.index(min(d))
        if cut:
            cut_groups[side].append(across(k, side)[0])
        else:
            groups[side].append(across(k, side))
            members[side].append(k)
        edge[side] |= occludes and not cut
    for k, side in _corner_seeds(dists, cropped, a, b):
        groups[side].append(across(k, side))
        members[side].append(k)
    for side, outward in enumerate(groups):
        cut = cut_groups[side]
        with_cut = False
        fill = _row_fill(side, members, occlusion, resuming)
        if len(outward) == 1 and cut and (edge[side] or fill):
            # One uncut seed, at an occluding edge (or where the face ends on a side facing
            # the occlusion side, _row_fill): the side's cut seeds bound it too, unless
            # one lies more than cut_apart_m beyond it, a run fattened past the edge to the
            # capture volume (the box tilted left at SGBM 9, trial 1 frames 0 and 1: a cut
            # seed 21.6 mm past the true side, the side's one uncut seed 6.4 and 7.5 mm, the
            # width 18-19 mm too wide). Points beyond the face's edges do not stand for such
            # a run: it keeps the face's plane, and they leave it. A run ending elsewhere (a
            # hole, a bump) is no edge and bounds nothing: the box tilted right at BM 5,
            # trial 0 frame 2, had its one uncut seed 35 mm inside the side so.
            near = [c for c in cut if c - outward[0][0] <= cut_apart_m]
            if len(near) == len(cut):
                continue
            outward = outward + [(c, c, 1.0) for c in near]
            with_cut = True
        elif len(outward) < 2:
            continue
        # Half its edges or more take a whole window or more: the background lies far behind
        # the side, and one end with something nearer behind it (the table under a tilted
        # box) fattens no less (see _FAR_EDGES).
        edges = [w for _, _, w in outward if w > 0]
        far = not with_cut and sum(w >= 1.0 for w in edges) >= _FAR_EDGES * len(edges)
        # Facing the occlusion side with something far behind: the band's fill varies along
        # the side, and only the occluding seeds' edges stand for it (see _occlusion_sides).
        filled = (
            not far
            and not with_cut
            and occlusion is not None
            and occlusion[side]
            and any(w >= 1.0 for w in edges)
        )
        far |= filled
        outward.sort(reverse=True)
        while len(outward) > 1 and _beyond_seed(outward[0], outward[1], far) > apart_m:
            outward.pop(0)
        sign = -1.0 if side % 2 == 0 else 1.0
        beyond = [sign * c for c in (a[n:] if side < 2 else b[n:])]
        if settled is not None and far:
            # The side through the median of its seeds' edges, each seed's own trim taken
            # off; a hole's seed (at no occluding edge) far inside the others is no edge.
            inside = outward[0][0] - _HOLE_APART * apart_m
            ed = sorted(e for c, e, w in outward if w > 0 or (c >= inside and not filled))
            m = len(ed)
            if m >= _SIDE_MEDIAN_SEEDS:
                mid = ed[m // 2] if m % 2 else 0.5 * (ed[m // 2 - 1] + ed[m // 2])
                if not beyond or mid >= max(beyond):
                    out[side] = sign * mid
                    settled[side] = True
                    continue
        out[side] = sign * max([outward[0][0], *beyond])
    return out[0], out[1], out[2], out[3]


# A side whose in-image normal heads within acos(_ROW_FULL_COS) (37 degrees) of the image's x
# axis takes the whole window trim; further from it, the share |cos| / _ROW_FULL_COS (see
# _across_rows).
_ROW_FULL_COS = 0.8


def _across_rows(plane: PlaneSolid, normal: np.ndarray) -> float:
    """The share of the window's trim a side takes, from the direction of its outward
    ``normal`` (3-D, in the face's plane) in the image at the face's point: 1 within
    acos(``_ROW_FULL_COS``) of the image's x axis, else its |cos| to x over ``_ROW_FULL_COS``.

    A stereo matcher searches along the image rows (the epipolar lines): the band it fills
    past an occluding edge (the strip only one imager sees, and the window's fattening over
    it) runs along the rows, and moves a side out across itself by the band's width times the
    x part of the side's in-image normal; a side along the rows (facing up or down in the
    image) has no such strip. The window trims (``window_fattening_px``, the runs' plateaus,
    each edge's share) were sized on sides facing near x: the upright and tilted boxes' width
    sides, |cos| 0.8 or more on nearly every frame, their uncut occluding seeds 3.1, 4.0 and
    1.3 mm past the true side (upright, tilted left, right; mean over the stereo sweep's 79
    studied settings). The lying box's width sides (its front face's top and bottom edges,
    |cos| 0.2-0.6) had theirs 0.5 mm past, whatever lay behind them, and the whole trim
    (1.6-3.7 mm) left its side facing up 1.7 mm inside on trial 1. Four-line cuboid width MAE
    over those settings (functional boxes, 2 trials x 5 frames) 2.794 -> 2.728 mm (33 better
    by 0.05 mm, none worse; the lying box 1.335 -> 1.070, 51 settings better, 4 worse).
    Trimmed by |cos| alone, the tilted boxes' sides lost the trim they need: 2.753 (32
    worse); no trim below |cos| 0.5 and the whole one above: 2.722 (7 worse). The irregular
    objects, seen from above, moved with it: hexagonal prism 6.87 -> 6.16 mm (77 settings
    better by 0.05 mm, 1 worse), soap bar 8.43 -> 8.19 (66 / 0), frying-pan handle 2.21 ->
    1.98 (48 / 22), TV remote 3.00 -> 2.94 (42 / 29)."""
    x, y, z = plane.point.tolist()
    nx, ny, nz = normal.tolist()
    # The normal's direction in the image: the derivative of the projection along it.
    dx, dy = nx / z - x * nz / (z * z), ny / z - y * nz / (z * z)
    return min(1.0, abs(dx) / (_ROW_FULL_COS * math.hypot(dx, dy)))


def _occlusion_sides(
    plane: PlaneSolid, basis: tuple[np.ndarray, np.ndarray], u: tuple[float, float]
) -> list[bool]:
    """Per side of the rectangle along the unit direction ``u`` (in the face's ``basis``;
    ``alo, ahi, blo, bhi`` as ``_consistent_sides`` orders them): whether its outward normal
    heads within 60 degrees of -x in the image at the face's point.

    The second imager sits along +x: past a near object's side facing -x lies the band of
    background the left image shows and the right one cannot, as wide as the disparity step
    (see ``_occlusion_side_fill``). A matcher with no left-right check, or one that keeps
    what a semi-global smoothness carried there, fills part of that band with the face's
    disparity, as far as each row's paths took it: the side's seeds lie out by the window's
    fattening and the fill, which varies along the side, and the farthest of them takes the
    most. Where one of the side's edges or more takes a whole window (something far behind
    it, a wide band), ``_consistent_sides`` draws such a side through the median of its
    occluding seeds' edges, as a side with the background far behind, and leaves out the
    seeds at no occluding edge (a hole, a bump, a run ending inside the band short of its
    segment's end: no edge of the side). Through the farthest seed, the functional boxes'
    sides facing -x lay 5.2-8.2 mm out (mean before the trim; SGBM 5 at uniqueness 15, SGBM 9
    3-way, HH 9 without the left-right check, SGBM 7 at half the signal and at P1 x 3, P2 x
    6), against 1.8-5.2 on their sides facing +x. Cuboid width MAE over the 44 study settings
    2.892 -> 2.880 mm (HH 7 at P2 x 4 4.50 -> 4.32, four times the room light 3.22 -> 3.05,
    soft9 3.22 -> 3.09, base40 3.50 -> 3.38; base55 1.73 -> 1.78, 3way9-dark 3.64 -> 3.71).
    With only the table near behind the side (a narrow band) too: 2.869, but the 40 mm bar
    lying on the table (rotation suite, SGBM 7, six rolls) -0.7 -> -1.5 mm, its median seed
    over-trimmed by its share (see ``_consistent_sides``). Without the gate and with the seeds
    at no occluding edge kept as on a far side: 2.845 and the TV remote 2.81 -> 2.89 (its
    buttons' seeds drew its side in: 8.6-9.4 mm narrow on a frame each at SGBM 9, HH, 3-way
    and proj35, 0.3-3.4 before).

    A run on such a side that stops short of its segment's end, the segment falling away
    behind the face toward a far background past it (``_Seeds.receding``), ended in the band
    too: the fill and the ramp down from it, the run's end on the face's plane as far out as
    an occluding seed's (median 3.5 px past the true side over 27 settings, against 1.0 on
    sides facing +x). It counts as an occluding seed taking a whole window there. Without it such
    a side of receding seeds alone kept the farthest, untrimmed (proj15's upright box, trial
    0 frame 3: 12.8 -> 4.8 mm too wide). Cuboid width MAE over the 54 study settings 3.000
    -> 2.950 mm (better by 0.05 or more on 19, worse on 4: HH 2.05 -> 2.22, SGBM 3 2.34 ->
    2.45, BM 5 at 30 % texture 2.45 -> 2.54, base55 1.78 -> 1.83, where such seeds lay
    0-1 px out). Without the falling-away gate (a run ended by a plateau rising in front of a
    face turned away, 1-2 px inside the side at SGBM 7 and HH): 2.904, worse on 11; so on
    every side too: 2.878, worse on 21."""
    e1, e2 = basis
    ux, uy = u
    x, y, z = plane.point.tolist()
    out = []
    for n2x, n2y in ((-ux, -uy), (ux, uy), (uy, -ux), (-uy, ux)):
        nx, ny, nz = (n2x * e1 + n2y * e2).tolist()
        # The normal's direction in the image: the derivative of the projection along it.
        dx, dy = nx / z - x * nz / (z * z), ny / z - y * nz / (z * z)
        out.append(dx < -_RIGHTWARD_COS * math.hypot(dx, dy))
    return out


def _row_fill(
    side: int,
    members: list[list[int]],
    occlusion: list[bool] | None,
    resuming: list[bool] | None,
) -> bool:
    """Whether the one uncut seed of ``side`` (``members``: each side's uncut seeds) marks
    where the face ends on a side facing the occlusion side (``occlusion``, four flags, see
    ``_occlusion_sides``), its segment not coming back onto the face's plane past it
    (``resuming``, per seed; see ``_resuming_ends``): ``_consistent_sides`` then drops the
    side's cut seeds lying more than ``cut_apart_m`` beyond it, as for a seed at an occluding
    edge.

    A semi-global matcher carries the face's disparity along the image rows into the band
    past a side facing -x that only the left imager sees (see ``_occlusion_sides``), and a row
    may carry it to the capture volume's side: the line along the rows is then cut there,
    its seed 22-24 mm past the true side (the box tilted left, trial 1: frame 1 at SGBM 7, P1
    x 3, P2 x 6; frame 0 at SGBM 5, uniqueness 15, and at SGBM 9, P2 x 3; frame 4 at SGBM 7
    3-way), while the side's one uncut seed, its run ended by a plateau 1.6-2.2 mm off the
    face's plane or a ramp down behind it, lay 3.5-10 mm past it. A seed whose segment comes
    back onto the plane past it ended at an excursion inside the face, no edge (HH 9 under an
    uneven light, the box tilted right, trial 1 frame 4: 36.6 mm inside the side, its cut
    seeds on the true side; the width 30 mm narrow without that check). Cuboid-branch width
    MAE over the 59 study settings (functional boxes, two trials) 2.981 -> 2.954 mm: SGBM 7
    3-way 2.80 -> 2.28, SGBM 5 at uniqueness 15 4.57 -> 4.17, P1 x 3, P2 x 6 7.00 -> 6.64, P2
    x 3 7.91 -> 7.61; none worse by 0.05 mm, the hexagonal prism, soap bar and TV remote as
    they were."""
    if occlusion is None or resuming is None or not occlusion[side] or len(members[side]) != 1:
        return False
    return not resuming[members[side][0]]


def _beyond_seed(
    seed: tuple[float, float, float], inner: tuple[float, float, float], far: bool
) -> float:
    """How far ``seed`` lies beyond ``inner`` across their side (each ``(coordinate, edge,
    share)`` as ``_consistent_sides`` groups them): on a ``far`` side between their edges
    where both lie at occluding edges, else between the seeds.

    Each seed at an occluding edge fattened by its own share of the window: one with the
    background nearer behind it (a smaller share) lies inside one with it far behind by the
    difference, and is no outlier for that. Compared as seeds, the upright box at BM 5 (trial
    0 frame 0) dropped a seed of a whole window 3.7 mm beyond one of 0.38 of it (2.65 mm
    between their edges, 3.2 apart allowed), then that one, and drew its side through a
    hole's seed 4 mm inside: 7.4 mm narrow, 1.3 through the median of the two edges. A seed
    at no occluding edge took no fattening and is compared as it lies: an occluding seed
    beyond a crease's by more than ``apart_m`` fattened more than its share says (SGBM 7, a
    45 mm baseline, 70 % of the signal; the box tilted left, trial 1 frame 2: 6.8 mm beyond,
    3.7 between the edges; 1.7 mm over through the crease's seed, 6.7 through the median)."""
    c, e, w = seed
    ci, ei, wi = inner
    return e - ei if far and w > 0 and wi > 0 else c - ci


def _straight_sides(
    seeds: list[list[float]],
    cropped: list[bool],
    occluding: list[bool],
    a: list[float],
    b: list[float],
    sides: tuple[float, float, float, float],
    u: tuple[float, float],
    apart_m: float,
) -> tuple[float, float, float, float]:
    """The rectangle's sides ``(alo, ahi, blo, bhi)`` (``sides`` as the seeds bound them,
    along the unit direction ``u``; ``a`` and ``b`` hold each seed's coordinates) where no
    fattening was measured: on a side holding ``_STRAIGHT_SIDE_SEEDS`` uncut seeds or more,
    the seed at an occluding edge lying more than ``apart_m`` beyond every other seed of the
    side is dropped, one at a time, and the side goes through the farthest seed left.

    A straight edge puts its seeds on one line: each lies within a sample of it (the last
    inlier up to a sample inside, moved half a sample out). A block matcher whose fattening
    neither the plateau nor the residual correlation shows (BM: its fattened pixels follow
    the face's slope, its residuals hardly correlate) fattens an edge by an amount that
    varies along it, and the side through the farthest seed takes the most of it: the
    upright box's sides at BM 7 lay 2.3-4.9 mm out, through a seed more than 2 px beyond the
    side's others on 29 % of the boxes' sides (BM 5-9: 29-39 %); on lpc's noise model, which
    does not fatten, 0 of 64 (at most 1.8 px), and the rule changed none of the 2950 frames
    of ``lpc bench accuracy --quick --trials 5``. Three seeds at least: of two, the nearer
    may be a hole's, eaten into the face (BM 5, the box tilted right: seeds 1.5-3.5 mm
    inside its side)."""
    groups: list[list[tuple[float, int]]] = [[], [], [], []]
    dists = _side_distances(seeds, u)
    for k, (d, cut) in enumerate(zip(dists, cropped, strict=True)):
        if cut:
            continue
        side = d.index(min(d))
        groups[side].append((_outward(a, b, k, side), k))
    for k, side in _corner_seeds(dists, cropped, a, b):
        groups[side].append((_outward(a, b, k, side), k))
    dropped: list[set[int]] = [set(), set(), set(), set()]
    for side, outward in enumerate(groups):
        if len(outward) < _STRAIGHT_SIDE_SEEDS:
            continue
        outward.sort(reverse=True)
        while (
            len(outward) > 1
            and occluding[outward[0][1]]
            and outward[0][0] - outward[1][0] > apart_m
        ):
            dropped[side].add(outward.pop(0)[1])
    if not any(dropped):
        return sides
    # A seed dropped from one side still bounds the others (a corner seed, see _corner_seeds).
    out = list(sides)
    for side, gone in enumerate(dropped):
        if gone:
            coords = [x for k, x in enumerate(a if side < 2 else b) if k not in gone]
            out[side] = min(coords) if side % 2 == 0 else max(coords)
    return out[0], out[1], out[2], out[3]


def _corner_seeds(
    dists: list[tuple[float, float, float, float]],
    cropped: list[bool],
    a: list[float],
    b: list[float],
) -> list[tuple[int, int]]:
    """The seeds that also stand on a side next to their own, as ``(seed, side)``: an uncut
    seed alone on its side (the nearest of the four, ``dists`` as ``_side_distances`` gives
    them), where the nearer of the two sides across it holds two uncut seeds or more and the
    seed lies beyond one of them at least.

    Such a seed lies at a corner: its line left the face near where two sides meet, and only
    fattening along the line (which moves it out across both) tells which side it crossed. The
    upright box shows no top side (its tall face runs past the capture volume), so a diagonal
    line's seed near the top of a side was the top side's one seed and counted for no side of
    the width: at SGBM 7 (trial 1 frame 0) its side was drawn through a seed 1.1 mm past the
    true side once one 14.6 mm past was dropped, and trimmed to 3.6 mm inside, the corner seed
    4.6 mm past left out; at BM 9 (trial 1 frame 2) the corner seed 5.7 mm past bounded the
    side alone, its side's two others 0.8 mm inside and 1.0 past."""
    nearest = [d.index(min(d)) for d in dists]
    uncut = [k for k, cut in enumerate(cropped) if not cut]
    count = [sum(1 for k in uncut if nearest[k] == side) for side in range(4)]
    out = []
    for k in uncut:
        side = nearest[k]
        if count[side] != 1:
            continue
        lo, hi = (2, 3) if side < 2 else (0, 1)
        other = lo if dists[k][lo] <= dists[k][hi] else hi
        if count[other] < 2:
            continue
        mine = _outward(a, b, k, other)
        if any(mine > _outward(a, b, j, other) for j in uncut if nearest[j] == other):
            out.append((k, other))
    return out


def _trimmed_sides(
    plane: PlaneSolid,
    basis: tuple[np.ndarray, np.ndarray],
    u: tuple[float, float],
    uv: np.ndarray,
    cropped: np.ndarray,
    occluding: np.ndarray,
    sides: tuple[float, float, float, float],
    trim_rad: float,
    params: LaserParams,
    settled: list[bool] | None = None,
) -> tuple[float, float, float, float]:
    """The rectangle's sides ``(alo, ahi, blo, bhi)`` (along ``u`` and across it), each side
    that an occluding seed lies on moved in by the fattening ``trim_rad`` (an angle): a
    fattened edge moves the whole side out across the edge, so the side moves back, not each
    seed along its own line (which would turn the rectangle). On the face the angle spans its
    depth times it over the in-image part of the side's normal; and the fattened pixels keep
    the edge's depth, so on a face turned away only those within ``solid_threshold_m`` of it
    (the run's inliers) widened it. Sides ``settled`` (``_consistent_sides``) stay."""
    ux, uy = u
    e1, e2 = basis
    z = float(plane.point[2])
    a = uv @ np.array([ux, uy])
    b = uv @ np.array([-uy, ux])
    out = list(sides)
    tol = params.edge_tolerance_m
    for k, (coords, normal2) in enumerate(((a, (ux, uy)), (b, (-uy, ux)))):
        normal = normal2[0] * e1 + normal2[1] * e2
        trim = fattening_trim_m(plane.normal[2], normal, z, trim_rad, params.solid_threshold_m)
        trim *= _across_rows(plane, normal)
        lo, hi = out[2 * k], out[2 * k + 1]
        on_lo = (coords - lo <= tol) & ~cropped
        on_hi = (hi - coords <= tol) & ~cropped
        if on_lo.any() and not (settled and settled[2 * k]):
            lo += trim * float(occluding[on_lo].max())
        if on_hi.any() and not (settled and settled[2 * k + 1]):
            hi -= trim * float(occluding[on_hi].max())
        if hi < lo:
            lo = hi = (lo + hi) / 2
        out[2 * k], out[2 * k + 1] = lo, hi
    return out[0], out[1], out[2], out[3]


def _window_shares(
    lines: list[LineModels], past_ends_m: Any, pixel_rad: float, params: LaserParams
) -> list[float]:
    """Per face run end (two a line, as ``_collect_seeds`` orders the seeds): the share of
    the window's fattening (``window_fattening_px``) its side takes, from the depth jump
    behind its edge: ``jump / (far_background_ratio z)``, at most ``far_window_shares``.

    Behind the end: past the run's segment, the median depth of the line's own samples within
    ``background_reach_px``; where none lies that near, the line's data stopped there: the
    scans' depth past the line's end (``past_ends_m``) when the segment is the line's last,
    else nothing in the capture volume. No depth there at all takes the largest share; a
    segment ending at something no further than its end (a hole in the face) keeps the whole
    window, as does an end that is no occluding edge (it is not trimmed)."""
    ratio, cap = params.far_background_ratio, params.far_window_shares
    reach = params.background_reach_px * pixel_rad
    past = np.asarray(past_ends_m, dtype=np.float64).tolist()
    out = []
    for ln in lines:
        run, last = ln.run, len(ln.points) - 1
        c, s_ = math.cos(ln.angle), math.sin(ln.angle)
        for k, end in enumerate((int(run[0]), int(run[-1]))):
            if end != last * k:
                out.append(1.0)
                continue
            x, y, z = ln.points[end].tolist()
            beyond = ln.beyond[k] if ln.beyond else _NO_POINTS
            if len(beyond):
                q = (beyond[:, 0] * c + beyond[:, 1] * s_) / beyond[:, 2]
                near = np.abs(q - (x * c + y * s_) / z) <= reach
                behind = float(np.median(beyond[near, 2])) if near.any() else 0.0
            else:
                behind = past[ln.index][k] if ln.index < len(past) else 0.0
            if behind == 0.0:
                out.append(cap)
            elif behind <= z:
                out.append(1.0)
            else:
                out.append(min((behind / z - 1.0) / ratio, cap))
    return out


def _hole_past_edge(lines: list[LineModels], past: list[list[float]]) -> bool:
    """Whether a face run ends at an occluding edge facing +x in the image (its line heading
    within 60 degrees of it) where the image holds no depth past the line's end (``past``:
    ``past_ends_m`` as a list, 0 where none).

    The second imager sits along +x: the pixels it cannot see, the shadow band where a depth
    image has none, lie on the other side of a near object, to its left. Past an edge facing
    right the background is seen by both imagers, and lpc's noise model gives it depth (no
    such hole on its 40 functional, 56 irregular and 60 rotation cuboid-branch frames, 2
    trials). A block matcher leaves none there on most of its frames that showed no
    fattening (the functional cuboids, 2 trials, BM 5 / 7 / 9: 26 of 33, 25 of 33, 22 of 27;
    SGBM 7 and 9: 0 of 2). A nearer neighbour to the right casts its own shadow band past the
    edge: lpc's noise model shows such a hole on 39 of the 500 clutter frames of ``lpc bench
    accuracy --quick --trials 5`` (its clutter cuboid width MAE 0.8 -> 1.0 mm, none of the
    default --quick's frames)."""
    for ln in lines:
        run, last = ln.run, len(ln.points) - 1
        if ln.index >= len(past):
            continue
        c = math.cos(ln.angle)
        for k, end in enumerate((int(run[0]), int(run[-1]))):
            # The run's first end faces -x along the line, its last +x.
            if end == last * k and (c if k else -c) > _RIGHTWARD_COS and past[ln.index][k] == 0:
                return True
    return False


# A line heading within 60 degrees of +x (see _hole_past_edge).
_RIGHTWARD_COS = 0.5


def _unless_rounded(uv: np.ndarray, uncut: list[list[float]], direction: np.ndarray) -> np.ndarray:
    """``direction``, or the minimum-area rectangle's around the seeds ``uv`` when the best
    rectangle along ``direction`` leaves an uncut seed farther inside its sides than
    ``_INSIDE_SIDES`` of the face's width (the smaller extent of that minimum-area rectangle)
    and the minimum-area rectangle holds the uncut seeds closer to its sides.

    Such a face is no rectangle with its seeds on its sides, and the count of seeds on sides
    that chose ``direction`` measured nothing: a rounded face (the soap bar, a
    superellipsoid, whose lines leave the plane along a rounded outline) or seeds moved off
    the edges by holes and fattening put few seeds within ``edge_tolerance_m`` of any
    rectangle's sides, and which direction scores best is chance. The soap bar's wrist angle
    was 29-51 deg off on one or two frames in ten (SGBM 7 and 9, BM 7), its angle SD over 15
    deg, where the minimum-area rectangle, which follows the outline's elongation, was within
    5 deg. lpc's noise model leaves seeds at most 0.15 of the width inside (the soap bar)."""
    if len(uncut) < 3:
        return direction
    d = direction.tolist()
    norm = math.hypot(d[0], d[1])
    residual = _rectangle_residual(uncut, (d[0] / norm, d[1] / norm))
    m = _min_area_direction(uv)
    width = min(float(np.ptp(uv @ m)), float(np.ptp(uv @ _perp(m))))
    if residual <= _INSIDE_SIDES * width:
        return direction
    mx, my = m.tolist()
    return m if _rectangle_residual(uncut, (mx, my)) < residual else direction


def _outward(a: list[float], b: list[float], k: int, side: int) -> float:
    """Seed ``k``'s coordinate across the rectangle's ``side`` (0, 1 along ``a``; 2, 3 along
    ``b``), positive outward: sides 0 and 2 face the negative way."""
    return (-1.0 if side % 2 == 0 else 1.0) * (a[k] if side < 2 else b[k])


def _side_distances(
    pts: list[list[float]], u: tuple[float, float]
) -> list[tuple[float, float, float, float]]:
    """Each point's distances to the four sides of the points' bounding rectangle along the
    unit direction ``u``: the two across ``u``, then the two along it."""
    ux, uy = u
    a = [x * ux + y * uy for x, y in pts]
    b = [y * ux - x * uy for x, y in pts]
    alo, ahi, blo, bhi = min(a), max(a), min(b), max(b)
    return [(p - alo, ahi - p, q - blo, bhi - q) for p, q in zip(a, b, strict=True)]


def _rectangle_residual(pts: list[list[float]], u: tuple[float, float]) -> float:
    """Largest distance of the points ``pts`` to the nearest side of their bounding rectangle
    along the unit direction ``u``."""
    return max(min(d) for d in _side_distances(pts, u))


def _beyond_edges(
    lines: list[LineModels], plane: PlaneSolid, params: LaserParams
) -> tuple[np.ndarray, bool]:
    """Points of the object past the face's edges: from each end of a line's run, outward
    through its segment, while the surface falls away from the face (a bevel, a rounded edge,
    a prism's next face) and before it turns parallel to the face again (a table). A walk
    that reaches the segment's end stops ``edge_fattening_px`` short of it: that end is an
    occluding edge (see ``_collect_seeds``). A walk no longer than that fattening wherever it
    ends shows no surface: a window matcher smears the step from a box's edge down to the
    table behind it over about its window, and the smear falls away like a bevel (the box
    tilted left at SGBM 7, trial 0 frame 0: a point 8.9 mm past the true side, the width 9.4
    mm too wide). Longer walks keep their length: they follow a surface that is there (the
    soap bar's rounded edges; trimming every walk cost its median width 1.4-2.7 mm at SGBM
    5-9 and the hexagonal prism's 0.3-1.8 mm, for 0.1 mm on the functional boxes). Also
    returned: whether such a walk was dropped (something fell away past an edge there). A walk
    along the image's rows that keeps the edge's depth is dropped too, whatever its length
    (``_keeps_depth``): it is the matcher's fill, not a surface; so is one heading -x that
    falls away where the line's other end does not (``_occlusion_side_fill``)."""
    trim = params.edge_fattening_px  # in samples, as in _collect_seeds
    out = []
    smeared = False
    n = plane.normal
    slope, free = math.tan(params.bevel_min_rad), params.bevel_free_depth_m
    for line in lines:
        pts = line.points
        first, last, m = int(line.run[0]), int(line.run[-1]), len(pts)
        if first == 0 and last == m - 1:
            continue
        h = (pts - plane.point) @ n  # > 0: in front of the face
        moves = pts[1:] - pts[:-1]
        rise = h[1:] - h[:-1]  # rise[i]: from point i to i + 1
        run = np.sqrt(np.maximum(einsum_norms(moves) - rise * rise, 0.0))
        below = h <= params.solid_threshold_m
        along_x = abs(math.cos(line.angle)) > _ALONG_ROW_COS
        # Steps a walk may take: none across a row's gap wider than the fattening (_row_gap).
        steps = ~_row_gaps(line.sz, line.step, trim) if along_x and trim > 0 else None
        walks: list[tuple[np.ndarray, bool]] = []  # each walk's end, and whether it is fill
        # An end walks past the edge, before the trim, is no fill and falls gently (a side
        # rounding off, not the step down to what lies behind).
        falls = False
        if last < m - 1:
            # Walking right from the run's last point: step i reaches point i + 1.
            ok = below[last + 1 :] & (
                (-rise[last:] >= slope * run[last:]) | (h[last] - h[last + 1 :] <= free)
            )
            if steps is not None:
                ok &= steps[last:]
            bad = (~ok).nonzero()[0]
            k = int(bad[0]) if len(bad) else len(ok)
            if (
                k > 0
                and along_x
                and _keeps_depth(pts[last : last + k + 1, 2], h[last : last + k + 1], params)
            ):
                k = 0
            fill = (
                k > 0
                and trim > 0
                and _occlusion_side_fill(math.cos(line.angle), h[last], h[last + k], params)
            )
            falls |= k > 0 and not fill and h[last] - h[last + k] <= free
            if k > 0 and trim > 0:
                q = line.sz[last : last + k + 1, 0] / line.sz[last : last + k + 1, 1]
                short = int(np.count_nonzero(q <= q[-1] - trim * line.step)) - 1
                if last + k == m - 1 or short <= 0:
                    smeared |= last + k < m - 1
                    k = short
            if k > 0:
                walks.append((pts[last + k], fill))
        if first > 0:
            # Walking left from the run's first point: step i reaches point first - 1 - i.
            ok = below[:first] & (
                (rise[:first] >= slope * run[:first]) | (h[first] - h[:first] <= free)
            )
            if steps is not None:
                ok &= steps[:first]
            bad = (~ok).nonzero()[0]
            k = first - 1 - int(bad[-1]) if len(bad) else first
            if (
                k > 0
                and along_x
                and _keeps_depth(
                    pts[first - k : first + 1, 2][::-1], h[first - k : first + 1][::-1], params
                )
            ):
                k = 0
            fill = (
                k > 0
                and trim > 0
                and _occlusion_side_fill(-math.cos(line.angle), h[first], h[first - k], params)
            )
            falls |= k > 0 and not fill and h[first] - h[first - k] <= free
            if k > 0 and trim > 0:
                q = line.sz[first - k : first + 1, 0] / line.sz[first - k : first + 1, 1]
                short = int(np.count_nonzero(q >= q[0] + trim * line.step)) - 1
                if first - k == 0 or short <= 0:
                    smeared |= first - k > 0
                    k = short
            if k > 0:
                walks.append((pts[first - k], fill))
        # A walk that is no fill at the line's other end, if only within the fattening's trim
        # there: the object falls away on both sides (its own rounded or bevelled sides), and
        # the fill-like one is kept too (see _occlusion_side_fill).
        falls |= any(not is_fill for _, is_fill in walks)
        out.extend(end for end, is_fill in walks if falls or not is_fill)
    return (plane.project(np.array(out)) if out else np.empty((0, 3))), smeared


def _row_gaps(sz: np.ndarray, step: float, trim: float) -> np.ndarray:
    """Per step between neighbouring samples of a line heading along the image's rows (s, z
    ``sz``, ``step`` of s/z a sample apart): whether it crosses a gap of more than ``trim``
    samples with no depth, the frame's fattening (``_beyond_edges`` walks no step across one).

    A matcher searches along the rows: a row's pixels it left without a match past a face's
    edge, more of them than its window's reach fills, are the disparity step's band where
    the two images do not match, not a surface, and what lies past that band is the fill it
    carried on beyond it, not more of the object. SGBM 5, the box tilted left, trial 0 frame
    2: past the side facing +x the row line's walk fell 1.9 mm over one sample, crossed 5
    samples without depth and went on 2.5 mm further behind: kept as a bevel, the box came
    out 7.1 mm too wide, 0.2 with the walk stopped at the gap. Only along the rows: on the
    vertical and diagonal lines a block matcher's holes lie on the hexagonal prism's steep
    next face (BM 5, trial 1: -8.4 -> -19.9 mm had the walks stopped at them; its width MAE
    11.0 -> 12.7 mm, 3.1 -> 3.9 at hh5-dim). Cuboid width MAE (the cuboid branch, 59 study
    settings) 2.954 -> 2.936, 5 better by 0.05 mm or more (sgbm5-u15 4.17 -> 3.74), none
    worse; the TV remote, soap bar and hexagonal prism none moved by 0.3 mm."""
    q = sz[:, 0] / sz[:, 1]
    return np.abs(q[1:] - q[:-1]) > (trim + 1.5) * step


# A line heading within 30 degrees of the image's x, the baseline (see _keeps_depth).
_ALONG_ROW_COS = math.cos(math.radians(30.0))


def _keeps_depth(z: np.ndarray, h: np.ndarray, params: LaserParams) -> bool:
    """Whether a walk past a face's edge (depths ``z`` and heights ``h`` in front of the face,
    from the edge's sample outward along a line heading within 30 degrees of the image's x)
    stays within ``solid_threshold_m`` of the edge's depth all along while the face turns
    away from it, ending more than that behind the face: a semi-global matcher's smoothness
    carries the face's disparity into the background past a box's side along the image rows
    (the baseline), where no real match pulls it away, and that fill, at the edge's depth,
    falls away from a face turned away like a bevel. A bevel or a rounded edge turns away
    from the face and its depth moves with it (on a face square to the view, a rounded edge
    starts at the edge's depth, but stays on the face's plane there). Only along the rows: on
    the diagonal lines the soap bar's rounded edges kept the edge's depth (quantised to a
    millimetre) for 4-7 samples, and dropping them cost its width 0.3-0.8 mm at SGBM 7, BM 7
    and half the signal. Dropping the rows' fill: the box tilted left at half the signal 7.8
    -> 7.1 mm (trial 1 frame 1: 17.3 -> 11.0 mm wide)."""
    tol = params.solid_threshold_m
    return len(z) > 1 and bool(np.all(np.abs(z[1:] - z[0]) <= tol)) and h[0] - h[-1] > tol


def _occlusion_side_fill(
    heading_x: float, h_edge: float, h_end: float, params: LaserParams
) -> bool:
    """Whether a walk past a face's edge (``_beyond_edges``), heading ``heading_x`` along the
    image's x (the cosine of its direction there), from a height ``h_edge`` in front of the
    face to ``h_end``, may be a matcher's fill on the occlusion side: it heads within 60
    degrees of -x and ends more than ``solid_threshold_m`` further behind the face than it
    started (it falls away; one coming back to the face's plane is the face beyond a dent).

    The second imager sits along +x: past a near object's side facing -x lies the band of
    background the left image shows and the right one cannot (as wide as the disparity step),
    and with the steepest part of a rounded side that faces away from the second imager, it
    has no match. A semi-global matcher carries the face's disparity into that band, a little
    further each row, and it falls away from a face turned away like a bevel. Where no walk at
    the line's other end shows the object falling away there too (its own rounded or bevelled
    sides, on both of them), ``_beyond_edges`` drops it, where the frame shows a matcher's
    fattening (a walk's trim): lpc's noise model fills nothing, and dropping its walks moved
    the rotation suite's 40 mm prism (40.6 -> 40.4 mm at 30 degrees of roll). The four
    functional boxes lay 6.0 mm out (median before the trim) on their -x sides through an
    occluding seed, 2.7 mm on +x, and a walk past the -x side set it 9 mm out (median, 13
    smooth settings). Cuboid width MAE over the 39 study settings 3.01 -> 2.82 mm, none worse
    by 0.05 mm or more (the box lying at SGBM 7 1.5 -> 1.2); 2.77 without the fattening's
    gate; dropping such walks heading +x instead 2.91; heading -x whatever the other end 2.82
    and the soap bar (rounded on both sides) 7.8 -> 9.4 mm, 8.7 so.

    The other end's walk counts before the fattening's trim where it falls no more than
    ``bevel_free_depth_m``: the soap bar's rounded side facing +x falls away there over 1-4
    samples, 0.5-2.7 mm (SGBM 7 and P1 x 3, P2 x 6), no longer than the trim, and its walks
    past the side facing -x, all on the bar, were dropped as fill on 9 of 10 frames at SGBM
    7. Soap bar width MAE over the 44 study settings 8.56 -> 8.13 mm (better on 31, SGBM 7
    9.5 -> 8.6), cuboids 2.880 -> 2.885 (a box's smear at the other end, 1-2 samples and 1
    mm, kept its fill on two frames: hh5's upright box 4.6 -> 5.0, hh7-p2x4's tilted right
    4.9 -> 5.3). Whatever the other end's fall: the frying pan's handle 2.15 -> 2.22 mm (hh5
    6.2 -> 8.2, pattern2 1.0 -> 2.0: the other end fell 7-12 mm over 3-4 samples, the step
    behind the handle); so 2.150 -> 2.155."""
    return heading_x < -_RIGHTWARD_COS and h_edge - h_end > params.solid_threshold_m


# --------------------------------------------------------------------------- 3-D candidates


def _canonical_axis(axis: np.ndarray) -> np.ndarray:
    # np.linalg.norm of a 1-D vector is this root of its dot product, without its checks.
    axis = axis / math.sqrt(float(axis @ axis))
    i = int(np.argmax(np.abs(axis)))
    return -axis if axis[i] < 0 else axis


def _axis_angle(axis: np.ndarray) -> float:
    return wrap_half_turn(math.atan2(axis[1], axis[0]))


def _fraction(residuals: np.ndarray, threshold: float) -> float:
    return (
        float(np.count_nonzero(residuals <= threshold) / len(residuals)) if len(residuals) else 0.0
    )


_PAIRS: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _pairs(count: int) -> tuple[np.ndarray, np.ndarray]:
    # np.triu_indices(count, 1), cached: the same few lines every frame.
    if count not in _PAIRS:
        _PAIRS[count] = np.triu_indices(count, 1)
    return _PAIRS[count]


@dataclass
class _Candidate:
    shape: str
    fraction: float = 0.0
    solid: Any = None
    reason: str = ""
    # The solid's residuals on the lines' runs, for _camera_facing's first pass.
    residuals: np.ndarray | None = None
    # Which of the runs' samples are a smeared tail, no part of the solid (see
    # _without_straight_tail); None where none are.
    smeared: np.ndarray | None = None

    @property
    def score(self) -> float:
        return 0.0 if self.reason else self.fraction


def _plane_candidate(lines: list[LineModels], clean: np.ndarray, params: LaserParams) -> _Candidate:
    """The face plane: the best of the plane through all runs and the planes spanned by each
    pair of line runs (a run that crossed onto a side face spoils only the first)."""
    thr = params.solid_threshold_m
    first = PlaneSolid.estimate(clean)
    if not first:
        return _Candidate("cuboid", reason=first.reason)
    residuals = first.residuals(clean)
    fraction = _fraction(residuals, thr)
    if fraction >= 1.0 - params.cuboid_margin:
        return _Candidate("cuboid", fraction, first)
    # The planes through two runs' end points, in Python floats (six pairs of 3-vectors).
    ends = [ln.points.take((ln.run[0], ln.run[-1]), axis=0).tolist() for ln in lines]
    normals, points = [first.normal.tolist()], [first.point.tolist()]
    for (p0, p1), (q0, q1) in itertools.combinations(ends, 2):
        a = (p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2])
        b = (q1[0] - q0[0], q1[1] - q0[1], q1[2] - q0[2])
        c = (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
        norm = math.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
        if norm > 1e-6:
            normals.append([c[0] / norm, c[1] / norm, c[2] / norm])
            points.append([(p0[k] + p1[k] + (q0[k] + q1[k])) / 4 for k in range(3)])
    offsets = [n[0] * q[0] + n[1] * q[1] + n[2] * q[2]
               for n, q in zip(normals, points, strict=True)]  # fmt: skip
    # The ufunc's reduce and the method: ndarray.sum's and np.argmax's Python wrappers cost
    # more than these few columns.
    counts = np.add.reduce(np.abs(clean @ np.array(normals).T - offsets) <= thr, axis=0)
    best = int(counts.argmax())
    solid = first
    if best != 0:
        solid = PlaneSolid(point=np.array(points[best]), normal=np.array(normals[best]))
        residuals = solid.residuals(clean)
    inliers = clean.compress(residuals <= thr, axis=0)
    if len(inliers) >= 3:
        solid = PlaneSolid.estimate(inliers) or solid
    return _Candidate("cuboid", _fraction(solid.residuals(clean), thr), solid)


def _sphere_candidate(
    lines: list[LineModels], clean: np.ndarray, params: LaserParams
) -> _Candidate:
    circles = [ln for ln in lines if ln.fits.get("circle")]
    init = None
    if len(circles) >= 2:
        init = sphere_from_circles(
            [ln.angle for ln in circles],
            [ln.fits["circle"].params[:2] for ln in circles],
            [p for ln in circles for p in ln.seeds().tolist()],
        )
    solid = SphereSolid.estimate(clean, init=init, iterations=2)
    if not solid:
        return _Candidate("sphere", reason=solid.reason)
    thr = params.solid_threshold_m
    residuals = solid.residuals(clean)
    inliers = clean.compress(residuals <= thr, axis=0)
    if 4 <= len(inliers) < len(clean):
        refined = SphereSolid.estimate(inliers, init=(solid.center, solid.radius), iterations=1)
        if refined:
            solid, residuals = refined, refined.residuals(clean)
    lo, hi = params.radius_limits_m
    if not lo <= solid.radius <= hi:
        return _Candidate("sphere", solid=solid, reason=f"radius {solid.radius * 1e3:.0f} mm")
    # The paper's rule: a sphere's centre lies beyond the surface seen (not a hollow).
    if solid.center[2] - float(clean[:, 2].min()) < params.sphere_depth_ratio * solid.radius:
        return _Candidate("sphere", solid=solid, reason="centre not beyond the surface")
    return _Candidate("sphere", _fraction(residuals, thr), solid, residuals=residuals)


# Two axis guesses within 5 degrees are one.
_SAME_GUESS_COS = math.cos(math.radians(5.0))


def _axis_guesses(lines: list[LineModels], params: LaserParams) -> Iterator[np.ndarray]:
    """Cylinder axis directions from the 2-D results, most trusted first, without repeats;
    lazily, since the first good one ends the search."""
    seen: list[np.ndarray] = []
    for guess in _raw_axis_guesses(lines, params):
        guess = guess / math.sqrt(guess @ guess)
        if all(abs(guess @ u) < _SAME_GUESS_COS for u in seen):
            seen.append(guess)
            yield guess
            if len(seen) >= params.max_axis_guesses:
                return


def _raw_axis_guesses(lines: list[LineModels], params: LaserParams) -> Iterator[np.ndarray]:
    # A plane through the axis cuts a cylinder along a generator: a line model is the axis.
    for line in lines:
        if line.model == "line":
            along = line.points[line.run[-1]] - line.points[line.run[0]]
            if along @ along > 0.01**2:
                yield along
    seeds_axis = _seeds_axis(lines, params)
    if seeds_axis is not None:
        yield seeds_axis


def _seeds_axis(
    lines: list[LineModels], params: LaserParams, *, longest: bool = False
) -> np.ndarray | None:
    """Algorithm 1 on the seeds (the runs' ends: the outline), in the longitudinal plane
    through them; with ``longest``, the outline's longest extent instead (the uncut seeds'
    principal axis: a round's length, wherever its outline is curved and Algorithm 1 finds
    no straight side). None when fewer than three are uncut or they give no direction."""
    seeds = _collect_seeds(lines, params, extend=False)
    keep = ~seeds.cropped
    if keep.sum() < 3:
        return None
    uncut = seeds.points.compress(keep, axis=0)
    plane = PlaneSolid.estimate(uncut)
    if not plane:
        return None
    origin, e1, e2 = _face_frame(plane)
    d = uncut - origin
    uv = np.column_stack([d @ e1, d @ e2])
    if longest:
        u, v = (uv - column_sums(uv) / len(uv)).T
        direction = _principal_axis(float(u @ u), float(u @ v), float(v @ v), (1.0, 0.0))
        return direction[0] * e1 + direction[1] * e2
    found = principal_direction(
        uv[sort_around(uv, np.zeros(2))], params.alpha_max_rad, pick="straightest"
    )
    if found is None:
        return None
    return found[0] * e1 + found[1] * e2


def _cylinder_candidate(
    lines: list[LineModels], clean: np.ndarray, params: LaserParams
) -> _Candidate:
    thr = params.solid_threshold_m
    step = max(1, len(clean) // params.cylinder_points)
    sample = clean[::step]
    lo, hi = params.radius_limits_m
    best: CylinderSolid | None = None
    best_rank = (False, -1.0)
    best_residuals = _EMPTY_RUN
    best_guess: np.ndarray | None = None

    def attempt(axis: np.ndarray) -> None:
        nonlocal best, best_rank, best_residuals, best_guess
        solid = CylinderSolid.estimate(sample, axis, iterations=params.cylinder_iterations)
        if solid:
            residuals = solid.residuals(sample)
            fraction = _fraction(residuals, thr)
            # A cylinder outside the radius limits is rejected below, so one within them
            # outranks it whatever its share: a matcher's fattened shallow arc fits a wider
            # circle better (BM 11, the tilted 75 mm can: 56 mm on 0.975 of the points).
            rank = (bool(lo <= solid.radius <= hi), fraction)
            if rank > best_rank:
                best, best_rank, best_residuals, best_guess = solid, rank, residuals, axis

    good = (True, params.axis_good_fraction)
    for axis in _axis_guesses(lines, params):
        attempt(axis)
        if best_rank >= good:
            break
    if best_rank < good:
        sub = clean[:: max(1, len(clean) // params.axis_grid_points)]
        axis, _ = best_cylinder_axis(sub, _grid(params.axis_grid), thr)
        attempt(axis)
        if best is None or not lo <= best.radius <= hi:
            # The coarse grid's directions lie ~12 degrees apart: on a noisy shallow arc the
            # one nearest the axis may hold few points, and a wrong one's wide cylinder is
            # rejected (SGBM 9, the 60 mm can: 139 mm). Four times finer, among the directions
            # whose circle is within the limits.
            fine = _grid(4 * params.axis_grid)
            axis, _ = best_cylinder_axis(sub, fine, thr, params.radius_limits_m)
            attempt(axis)
        if best_rank < good:
            # An object only roughly a cylinder (a potato: bumpy, and curved along its
            # length too) lets no guess hold its arcs well, and on a block matcher's noisy
            # samples the grid's best direction may run across it (the sweet potato under
            # BM 7 with a high texture threshold, trial 0 frame 1: a 98 mm round 65 degrees
            # off, holding 0.77 of the runs). A long round's axis runs along its outline's
            # longest extent (as _tapered_tilt reads it): there, 0.89. It counts only where
            # it holds more than the rest; a cylinder's own guesses end the search before.
            outline = _seeds_axis(lines, params, longest=True)
            if outline is not None:
                attempt(outline)
    if best is None:
        return _Candidate("cylinder", reason="no cylinder converged")
    solid = best
    residuals = best_residuals if step == 1 else solid.residuals(clean)
    smeared = None
    if best_rank < good or best_rank[1] < _TAIL_REST_FRACTION:
        # No guess made a good cylinder, or one nearly: one line's run may be no part of it.
        # Where a guess made a good one, only the run it came from (hh9-uneven's upright
        # can, 0.97 from line 2's guess: leaving line 3 out would turn it 30 degrees).
        without = _without_straight_tail(
            lines, best_rank[1], params, None if best_rank < good else best_guess
        )
        if without is not None:
            solid, residuals = without[0], without[0].residuals(clean)
            # The tail's samples: its line's run off the cylinder the others make.
            starts = np.cumsum([0] + [len(ln.run) for ln in lines])
            smeared = np.zeros(len(clean), dtype=bool)
            tail = slice(starts[without[1]], starts[without[1] + 1])
            smeared[tail] = residuals[tail] > thr
    keep = residuals <= thr
    inliers = clean.compress(keep, axis=0)
    if len(inliers) >= 5 and (step > 1 or not keep.all()):
        # Refit on every inlier: the first fit saw a sample, or outliers.
        refined = CylinderSolid.estimate(inliers, solid.axis, iterations=1)
        if refined:
            solid, residuals = refined, refined.residuals(clean)
    if not lo <= solid.radius <= hi:
        return _Candidate("cylinder", solid=solid, reason=f"radius {solid.radius * 1e3:.0f} mm")
    # The camera sees the outside of a cylinder: its axis lies beyond the surface.
    if (solid.point - column_sums(clean) / len(clean))[2] <= 0:
        return _Candidate("cylinder", solid=solid, reason="axis in front of the surface")
    return _Candidate(
        "cylinder", _fraction(residuals, thr), solid, residuals=residuals, smeared=smeared
    )


# A line's straight run left out explains the others nearly all (the bottle tilted right on
# base55 and P1 x 3 / P2 x 6: 0.985-1.0, the whole fit 0.86-0.91), and no more than this
# share of the run itself lies on what they make (0.40-0.60 there; a true generator's 1.0).
_TAIL_REST_FRACTION = 0.97
_TAIL_ON_SHARE = 0.7
# How far past the silhouette the tail's end must reach, px: farther than a window fattens a
# rim (half a block, 2-5 px on the sweep's matchers) by as much again (the bottle's tails
# 14-16 px; a banana's bend leaves the fit 5 px past it).
_TAIL_PAST_PX = 8.0


def _without_straight_tail(
    lines: list[LineModels],
    fraction: float,
    params: LaserParams,
    guessed: np.ndarray | None = None,
) -> tuple[CylinderSolid, int] | None:
    """The cylinder the other lines make where one line's straight run is no generator of
    theirs, and that line's index; None where every straight run is (or there are fewer than
    two).

    Past an oblique occluding rim a smoothing matcher carries the rim's depth straight on
    across the background it cannot see: the line crossing the round there becomes a line
    model (its run the shallow half of the arc and the smeared tail), and its direction, an
    axis guess, fits a wide cylinder that holds the tail and most of the rest (the 50 mm
    bottle tilted right at 80-95 mm). A real generator lies on the cylinder the other lines
    make; a smeared tail leaves it at the rim."""
    straight = [i for i, ln in enumerate(lines) if ln.model == "line" and len(ln.run)]
    if len(straight) < 2:
        return None
    thr = params.solid_threshold_m
    lo, hi = params.radius_limits_m
    past = -_TAIL_PAST_PX * _pixel_rad(lines, params)
    for i in straight:
        run = lines[i].points.take(lines[i].run, axis=0)
        if guessed is not None:
            along = run[-1] - run[0]
            if abs(float(along @ guessed)) < _SAME_GUESS_COS * math.sqrt(float(along @ along)):
                continue
        rest = np.concatenate(
            [ln.points.take(ln.run, axis=0) for k, ln in enumerate(lines) if k != i]
        )
        for j in straight:
            if j == i:
                continue
            ln = lines[j]
            along = ln.points[ln.run[-1]] - ln.points[ln.run[0]]
            if along @ along <= 0.01**2:
                continue
            solid = CylinderSolid.estimate(
                rest, along / math.sqrt(along @ along), iterations=params.cylinder_iterations
            )
            if not solid or not lo <= solid.radius <= hi:
                continue
            held = _fraction(solid.residuals(rest), thr)
            if held < _TAIL_REST_FRACTION or held <= fraction:
                continue
            off = solid.residuals(run) > thr
            # One end of the run on the others' cylinder, the other leaving it and reaching
            # on past its silhouette: a tail, not an object curving away from the fit at
            # both ends (a banana's bend).
            if (
                np.count_nonzero(off) >= (1 - _TAIL_ON_SHARE) * len(run)
                and bool(off[0]) != bool(off[-1])
                and float(solid.silhouette_distance(run[[-1 if off[-1] else 0]])[0]) < past
            ):
                return solid, i
    return None


_GRID_CACHE: dict[int, np.ndarray] = {}


def _grid(count: int) -> np.ndarray:
    # A pure function of ``count``, rebuilt identically every frame: cache it.
    if count not in _GRID_CACHE:
        _GRID_CACHE[count] = hemisphere_directions(count)
    return _GRID_CACHE[count]


# --------------------------------------------------------------------------- decision


def _none(
    reason: str,
    summaries: tuple[LineSummary, ...],
    total: int,
    extra: dict[str, float] | None = None,
) -> Reconstruction:
    return Reconstruction(
        shape="none", reason=reason, lines=summaries, points=total, extra=extra or {}
    )


def reconstruct_laser(
    scan_lines: ScanLinesLike,
    params: LaserParams = LaserParams(),
    seed: int = 0,
    *,
    joined: np.ndarray | None = None,
) -> Reconstruction:
    """Shape, grasp width and wrist angle of the object the optical axis pierces.

    Parameters
    ----------
    scan_lines : ScanLines
        ``angles_rad`` (4,) and ``points``, one (N_i, 3) array per line, metres, camera frame.
    params : LaserParams
    seed : int
        Seeds every RANSAC draw (use the frame's ``seq``).
    joined : ndarray, optional
        ``analyse_lines``'s: the lines' points already concatenated and checked.

    Returns a ``Reconstruction`` (``method="laser"``) whose ``lines`` hold each line's chosen
    model and ``confidence`` the fraction of the lines' points the chosen solid explains;
    ``extra`` holds the count of each 2-D model (``n_line``, ...) and each solid's inlier
    fraction (``f_cuboid``, ``f_sphere``, ``f_cylinder``; a solid that could not win is not
    fitted). ``shape="none"`` comes with a ``reason``.
    """
    return decide(analyse_lines(scan_lines, params, seed, joined=joined), params, scan_lines)


def analyse_lines(
    scan_lines: ScanLinesLike,
    params: LaserParams = LaserParams(),
    seed: int = 0,
    *,
    joined: np.ndarray | None = None,
) -> list[LineModels]:
    """First stage of ``reconstruct_laser``: the 2-D models and pierced run of each line.

    When a line already has a ``reason`` (too few points, or the optical axis misses the
    object on it) no line is fitted: the frame has no shape whatever the others hold.
    ``joined``: where the caller holds the lines' points as consecutive slices of one
    float64 (sum N, 3) array already checked finite (the reconstructor's, from the scans
    message), that array, read-only: the lines' points are not concatenated and checked again.
    """
    angles = np.asarray(scan_lines.angles_rad, dtype=np.float64).reshape(-1)
    if joined is not None:
        raw = list(scan_lines.points)  # slices of joined: float64 (N, 3) already
    else:
        raw = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in scan_lines.points]
    if len(raw) != len(angles):
        raise ValueError(f"scan_lines has {len(angles)} angles but {len(raw)} point arrays")
    if joined is None and raw:
        joined = np.concatenate(raw)
        # The ufunc's reduce, not ndarray.all's Python wrapper.
        if not np.logical_and.reduce(np.isfinite(joined), axis=None):
            raise ValueError("scan_lines.points must be finite")
    lines = _prepare_lines(angles.tolist(), raw, params, joined)
    if any(ln.reason for ln in lines):
        # A line the optical axis does not pierce (or too short) already decides the frame:
        # no shape. While the hand is still aiming this is most frames; fit nothing.
        return lines
    _fit_lines_models(lines, params, _lines_rng(seed))
    need = params.min_points_per_line
    # A line counted across its holes (``_across_holes_count``) is short too: its segment
    # joined across them is tried first, as where it has no count.
    thinned = frozenset(ln.index for ln in lines if len(ln.run) < need)
    if not thinned:
        return lines
    # A block matcher's texture check leaves holes wherever a window holds too few dots, so
    # a line's samples across a round or a face come in clumps a few millimetres apart, and
    # a hole with a slope behind it is a jump longer than ``segment_gap_m``: the pierced
    # segment stops there, and once it holds ``need`` points no hole is crossed (only a
    # shorter one is joined across them), so one outlier leaves its run short (BM 5 with a
    # texture threshold of 15, the line at 45 degrees: 10-12 points on the lying 40 mm
    # marker and the upright box, each ended by a 7-8 mm hole beside the axis with the
    # surface 5-6 mm deeper past it, and 8-9 inliers). The surface goes on past such a hole
    # (``_hole``): the lines are fitted again, with the short ones' segments joined across
    # every hole beside them, and kept where no line is short then.
    again = _prepare_lines(angles.tolist(), raw, params, joined, across=thinned)
    if any(ln.reason for ln in again) or all(
        len(again[k].points) == len(lines[k].points) for k in thinned
    ):
        return lines
    _fit_lines_models(again, params, _lines_rng(seed))
    return lines if any(ln.reason for ln in again) else again


def _lines_rng(seed: int) -> np.random.Generator:
    """The generator that serves every line's fits in a frame: default_rng's own PCG64, which
    mixes the seed's bits, built directly (a third cheaper than through default_rng's
    checks)."""
    return np.random.Generator(np.random.PCG64(seed & 0x7FFFFFFFFFFFFFFF))


def decide(
    lines: list[LineModels],
    params: LaserParams = LaserParams(),
    scan_lines: ScanLinesLike | None = None,
) -> Reconstruction:
    """Second stage of ``reconstruct_laser``: the shape and its grasp from the lines' models.
    ``scan_lines`` (the whole lines, table and all) size the fattening a face run does not
    show (``LaserParams.window_fattening_px``); without them such a face keeps its seeds."""
    total = sum(ln.total for ln in lines)
    summaries = tuple(ln.summary() for ln in lines)
    models = [ln.model for ln in lines]
    counts = {m: models.count(m) for m in MODELS}
    extra: dict[str, float] = {f"n_{m}": float(k) for m, k in counts.items()}
    failed = next((ln for ln in lines if ln.reason), None)
    if failed is not None:
        return _none(failed.reason, summaries, total, extra)
    if params.variant == "paper":
        return _decide_paper(lines, counts, params, summaries, total, extra)
    return _decide(lines, params, summaries, total, extra, scan_lines)


def _decide(
    lines: list[LineModels],
    params: LaserParams,
    summaries: tuple[LineSummary, ...],
    total: int,
    extra: dict[str, float],
    scan_lines: ScanLinesLike | None = None,
) -> Reconstruction:
    """Fit the solids, fewest parameters first (plane 3, sphere 4, cylinder 5); a richer solid
    must explain more of the lines' points by its margin, so one that cannot is not fitted."""
    clean = np.concatenate([ln.points.take(ln.run, axis=0) for ln in lines])
    candidates = {"cuboid": _plane_candidate(lines, clean, params)}
    shape, bar = "cuboid", candidates["cuboid"].score + params.cuboid_margin
    polyhedral = _polyhedral(lines)
    if polyhedral:
        # Every line is straight pieces (no circle was fitted on any): a polyhedron, whose
        # runs may lie on two faces, but never a sphere's or a cylinder's (see
        # _straight_pieces); a disc lying on a found table may still be (see below).
        bar = math.inf
    short_of_ball = False
    if bar < 1.0:
        candidates["sphere"] = _sphere_candidate(lines, clean, params)
        if candidates["sphere"].score > bar:
            short_of_ball = _short_of_ball(lines, candidates["sphere"].solid, params)
            if not short_of_ball:
                shape, bar = "sphere", candidates["sphere"].score + params.cylinder_margin
    if bar < 1.0:
        candidates["cylinder"] = _cylinder_candidate(lines, clean, params)
        if candidates["cylinder"].score > bar:
            shape = "cylinder"
    if short_of_ball:
        extra["short_of_ball"] = 1.0
        if shape != "cylinder":
            # No cylinder explains more of the lines than the face does: the ball stands, as
            # without the test (a cylinder below the face's bar is below the ball's too).
            shape = "sphere"
        elif candidates["cylinder"].score <= candidates["sphere"].score + params.cylinder_margin:
            # Only the band a ball would have won (the cylinder not ahead of it by the
            # margin): a cylinder that is ahead keeps its own axis (a tilted can, the horse
            # toy's torso, the banana).
            banded = _rim_axis(lines, candidates["sphere"].solid, candidates["cylinder"], clean,
                               params)  # fmt: skip
            if banded is not None:
                extra["rim_axis"] = 1.0
                candidates["cylinder"] = replace(
                    candidates["cylinder"], solid=banded, residuals=banded.residuals(clean)
                )
    support: PlaneSolid | None = None
    supported = False
    # A cylinder, or a frame no solid explains where a cylinder was fitted (the jar cap's
    # free cylinder put its axis in front of the band: SGBM 5 trial 0 frames 1 and 4), or a
    # face where one was: a 60 mm round's band seen from the front is flat within the
    # threshold across 20 mm (the jar cap under SGBM 3-7: faces 18-30 mm wide holding
    # 0.74-0.82 of the runs, 16-83 degrees off its axis; the disc 0.70-0.77, within a degree).
    lost = shape != "cylinder" and candidates[shape].score < params.min_solid_fraction
    rival = "cylinder" in candidates and (lost or shape == "cuboid")
    if shape == "cylinder" or rival:
        beside = _beside(lines)
        support, supported = _support_plane(lines, params, beside=beside), True
        sizes = [len(ln.run) for ln in lines]
        disc = _lying_disc(clean, support, params, sizes) if support is not None else None
        table = None
        # A band's rims (_rim_axis) lie 15-20 mm apart and a few samples place them: the
        # table the support search found pins a lying disc's axis better (the jar cap from the
        # front under sparse dots on a 35 mm baseline, trial 1 frames 1-2: the rims 39
        # degrees off the truth's wrist angle, the disc on the table within 1.5). A table the
        # searches below only guess does not (BM 7 with uniqueness 5, trial 0 frame 2: a plane
        # beside, its normal 65 degrees off the cap's axis, held a disc 8 mm tall, 71 degrees
        # off; the rims within 3): those are for the other rounds.
        guess = "rim_axis" not in extra
        if disc is None and guess:
            # A matcher smears the band's lower rim down behind the table, which then hides
            # the table from the support search (see _DISC_SUPPORT).
            table = _support_plane(
                lines, params, _DISC_SUPPORT, _DISC_SUPPORT_LINE_POINTS, beside=beside
            )
            if _same_plane(table, support):
                # The search that lets the table hide more behind it found the support again
                # (a quarter of the rounds): its disc is the one not found above.
                table = None
            disc = _lying_disc(clean, table, params, sizes) if table is not None else None
        if disc is None and guess:
            # Both searches may take a plane across the cap's top face for the table, or
            # find none, and a free cylinder then wins along the band (soft SGBM 9, the jar
            # cap from the front, trial 0 frame 0: 53 degrees off; the table beside, 0.78).
            searched = [plane for plane in (support, table) if plane is not None]
            disc = _disc_on_plane_beside(lines, clean, params, sizes, beside, searched)
        for plane in (support, table) if disc is None and guess else ():
            # Last, as a wrong table's scored circles may just reach the share a disc needs
            # (SGBM 7 with the OpenCV sample's smoothness, the jar cap from the front, trial 0
            # frame 4: 0.61 on a plane 25 degrees off the table, 0.79 on the table).
            if plane is not None and disc is None:
                disc = _lying_disc(clean, plane, params, sizes, scored=True)
                if (
                    disc is not None
                    and shape == "cylinder"
                    and candidates["cylinder"].score > disc[1] + params.cylinder_margin
                    and _lies_on(candidates["cylinder"].solid, plane, params)
                ):
                    # A round lying on its side stands its diameter high: the free fit that lies
                    # on the same table, the richer solid, explains more of the runs by its
                    # margin and stands (the banana under BM 7 on sparser dots and SGBM 9 in
                    # 3-way mode, trial 0: 0.94 and 1.0 of the runs, 0.5 and 7.9 degrees off the
                    # table, 1.1 and -2.2 mm from it; a circle through three samples on its side
                    # 78-80 mm across, 0.62 and 0.61, 83 degrees off). The jar cap's free fits
                    # along its band lie 50-60 degrees off the table and sink 20-60 mm into it.
                    disc = None
        if (
            disc is not None
            and shape == "cuboid"
            and disc[1] < candidates["cuboid"].score - params.disc_face_margin
        ):
            # A disc lying on the table shows the camera its band, which is flat across its
            # middle only: where a plane across the jar cap's band won, it held 0.03-0.16 more
            # of the runs than the disc (12 frames of 50 settings). A face that holds far more
            # of them than the disc is a flat face, whose samples a circle through part of
            # them leaves out (BM 9 with a prefilter cap of 25, the lying box, trial 0 frame
            # 3: the face 0.97, a disc 99 mm across 0.62, 90 degrees off).
            disc = None
        if disc is not None:
            extra["disc_axis"] = 1.0
            solid, fraction = disc
            # The disc's own share, its flat top with it, where no other solid holds the
            # runs; a cylinder keeps the share it won with.
            candidates["cylinder"] = replace(
                candidates["cylinder"],
                solid=solid,
                residuals=solid.residuals(clean),
                **({"fraction": fraction, "reason": ""} if rival else {}),
            )
            shape = "cylinder"
        elif shape == "cuboid":
            # A face rests on no support (_resting_width's rounds do).
            support = None
        elif (
            shape == "cylinder"
            and "rim_axis" not in extra
            and candidates["cylinder"].smeared is None
        ):
            # The free fit's own axis: a taper may have turned it (see _tapered_tilt). Not
            # past a smeared tail, whose end the outline's longest extent would run to.
            tapered = _tapered_tilt(lines, candidates["cylinder"], clean, params)
            if tapered is not None:
                extra["tapered_tilt"] = 1.0
                candidates["cylinder"] = replace(
                    candidates["cylinder"], solid=tapered, residuals=tapered.residuals(clean)
                )
    elif polyhedral and candidates["cuboid"].score < 1.0 - params.cylinder_margin:
        # A disc's band seen from the front is straight across it along the axis, and along
        # it over a run too short for its bend to leave the threshold: straight pieces all
        # (the jar cap from the front under sparse dots on a 35 mm baseline, depth in 1 mm
        # steps, trial 1 frame 4: runs of 12-18 samples; a box 12 mm wide, 72 degrees off).
        # Only a table the support search found, and a disc on it explaining the runs by a
        # richer solid's margin over the face: a box's face holds nearly all of its runs.
        table = _support_plane(lines, params)
        sizes = [len(ln.run) for ln in lines]
        disc = _lying_disc(clean, table, params, sizes) if table is not None else None
        if disc is not None and disc[1] >= candidates["cuboid"].score + params.cylinder_margin:
            extra["disc_axis"] = 1.0
            solid, fraction = disc
            candidates["cylinder"] = _Candidate(
                "cylinder", float(fraction), solid, residuals=solid.residuals(clean)
            )
            shape, support, supported = "cylinder", table, True
        else:
            # No disc where no table shows on two lines (the jar cap's lines hold its band, a
            # few samples of its top and three or none of the table: BM 7 with a low texture
            # threshold, trial 1): the band's bend along it, by the same margin.
            band = _band_candidate(clean, candidates["cuboid"].solid, params)
            if (
                band is not None
                and band.score >= candidates["cuboid"].score + params.cylinder_margin
            ):
                extra["band_axis"] = 1.0
                candidates["cylinder"] = band
                shape = "cylinder"
    for name, c in candidates.items():
        extra[f"f_{name}"] = c.score
    confidence = candidates[shape].score
    if confidence < params.min_solid_fraction:
        details = ", ".join(
            f"{n}: {c.reason}" if c.reason else f"{n} {c.fraction:.2f}"
            for n, c in candidates.items()
        )
        return _none(f"no solid explains the scan lines ({details})", summaries, total, extra)
    solid = candidates[shape].solid
    smeared = candidates[shape].smeared
    if smeared is not None and "disc_axis" not in extra:
        # A smeared tail is no part of the round: its width and rims are the other samples'.
        clean = clean.compress(~smeared, axis=0)
        candidates[shape] = replace(
            candidates[shape], residuals=candidates[shape].residuals.compress(~smeared)
        )
    if shape in ("sphere", "cylinder"):
        full = solid
        free = None
        fattened = params.end_plateaus and _fattened(lines)
        if shape == "sphere" and fattened:
            free = _plateau_free(lines, full, params)
        if free is not None:
            # A matcher's fattening all round the ball: the fit on every inlier but the
            # plateaus, without _camera_facing's trim (see _fattened).
            solid = free
        else:
            faced = _camera_facing(
                solid, clean, params, _pixel_rad(lines, params), candidates[shape].residuals,
                fattened=fattened,
            )  # fmt: skip
            # Not a ball's under an SGBM-like matcher: its facing cap alone trades the radius
            # against the centre's depth (see _fattened) whether or not the lines show the
            # fattening. Where the cap changed a ball's width on the sweep's SGBM frames it
            # was 3-11 mm narrow on four of eleven and 1.1 mm nearer the truth on none; lpc's
            # noise model keeps the cap (a ball the window pulled toward the camera at its
            # rims is fitted on its cap there). Asked only where the cap changed the ball:
            # the correlation costs about 0.4 ms, and on the live scene the cap leaves 1063 of
            # 1071 rounds as they were.
            if faced is not solid and (shape == "cylinder" or _matched(scan_lines, params) is None):
                solid = faced
            if params.end_plateaus and not (shape == "sphere" and fattened):
                # A fattened ball's plateau-free refit was tried above and came out None: the
                # same call again would too.
                solid = _without_end_plateaus(lines, full, solid, params, clean)
    if not supported and shape in ("sphere", "cylinder"):
        support = _support_plane(lines, params)
    resting = _resting_width(lines, clean, solid, params, support)
    if shape == "cylinder" and resting is None and solid is not full:
        # The trims may have lifted the round off the support its whole arc's fit lies on, or
        # left it touching the support where that fit sinks into it: the contact refit takes
        # every sample of the runs whichever fit says the round rests, so the whole arc's fit
        # may say so too (the 40 mm marker lying before the camera under SGBM 5-9: fits of
        # 41-47 mm sinking 2-6 mm into the table, camera-facing ones of 30-35 mm touching it
        # or standing off it, 5.3-10.4 mm narrow; on the contact within 2.3 mm).
        lifted = _lifted_off(full, solid, support, params)
        if lifted is not None:
            solid = replace(solid, radius=lifted)
        else:
            resting = _resting_width(lines, clean, full, params, support)
    if shape == "sphere":
        return Reconstruction(
            shape="sphere",
            grasp_width_m=_ball_width(clean, solid, support, resting, params),
            center_m=_tuple3(solid.center),
            lines=summaries,
            confidence=confidence,
            points=total,
            extra=extra,
        )
    if shape == "cylinder":
        if resting is None:
            # The support pins a resting round's radius already (and _resting_width starts
            # from the solid as fitted).
            pixel_rad = _pixel_rad(lines, params)
            seen = _seen_round(lines, full)
            inner = _rim_free(lines, full, clean, params, pixel_rad, scan_lines, support, seen)
            if inner is not None and inner.radius < solid.radius:
                # The pull toward the camera only widens a fit: one narrower already (the
                # camera-facing or plateau-free fit) stands. As in _camera_facing, the rims
                # shift the radius, hardly the axis.
                solid = replace(solid, radius=inner.radius)
            bound = _silhouette_bound(lines, full, params, pixel_rad, scan_lines, seen)
            if bound is not None and bound < 2 * solid.radius:
                extra["silhouette_width_mm"] = 1000 * bound
                solid = replace(solid, radius=bound / 2)
            background = _background_bound(lines, solid, full, params, pixel_rad, scan_lines, seen)
            if background is not None:
                extra["background_width_mm"] = 1000 * background
                solid = replace(solid, radius=background / 2)
        axis = _canonical_axis(_axis_on_support(solid.axis, full, support, params))
        return Reconstruction(
            shape="cylinder",
            grasp_width_m=_round_width(solid, full, clean, params, resting, lines, support),
            wrist_angle_rad=_axis_angle(axis),
            center_m=_tuple3(_closest_to_optical_axis(solid.point, axis)),
            axis=_tuple3(axis),
            lines=summaries,
            confidence=confidence,
            points=total,
            extra=extra,
        )
    # Seeds come from each line's run on the face plane itself, whatever 2-D model won the line
    # (an ellipse may have followed a rounded edge down the side).
    on_face = [ln for ln in (_face_run(ln, solid, params) for ln in lines) if ln is not None]
    if len(on_face) < 2:
        return _none("fewer than two scan lines lie on the pierced face", summaries, total, extra)
    measured = 0.0
    window = False
    shares = params
    past = getattr(scan_lines, "past_ends_m", None)
    edge_past = getattr(scan_lines, "edge_past_m", None)
    hole_past_edge = False
    if params.edge_fattening_px == 0 and params.measure_fattening:
        measured = _fattening(on_face)
        if measured == 0 and params.window_fattening_px > 0:
            correlation = _matched(scan_lines, params, _weak_gate(params))
            if correlation is not None and correlation >= params.window_correlation_gate:
                measured = params.window_fattening_px
                extra["residual_correlation"] = correlation
                window = True
            elif params.hole_fattening_px > 0 and (
                correlation is not None
                or (
                    past is not None
                    and _hole_past_edge(on_face, np.asarray(past, dtype=np.float64).tolist())
                )
            ):
                measured = params.hole_fattening_px
                if correlation is not None:
                    extra["weak_correlation"] = correlation
                else:
                    hole_past_edge = True
                    extra["hole_past_edge"] = 1.0
                window = True
                shares = replace(params, far_window_shares=min(params.far_window_shares, 1.0))
        extra["fattening_px"] = measured
    seeds = _collect_seeds(
        on_face, params, extend=True, face=solid,
        past=np.asarray(past, dtype=np.float64).tolist() if past is not None else None,
        pixel_rad=_pixel_rad(lines, params),
        # Not where the fattening is a block matcher's assumed one (a hole past an occluding
        # edge, no run showing it): an edge point stands in for an uncut seed's fattened end,
        # and how far those ends lie past the edges is then unknown (BM 5, the box tilted
        # right, trial 1 frame 1: 0.9 -> 2.6 degrees, 2.9 -> 4.8 mm narrow with them).
        edges=(
            None if edge_past is None or hole_past_edge
            else np.asarray(edge_past, dtype=np.float64).tolist()
        ),
    )  # fmt: skip
    seeds = replace(seeds, points=solid.project(seeds.points))
    if seeds.occluding is not None:
        # A run ended on the fattening's ramp: the ramp's samples, left out of the run, took
        # that much of the fattening with them. Without the scans' depth past the lines' ends
        # (recorded before it was), a ramp with no samples beyond its segment counts as far.
        behind = np.asarray(past).tolist() if past is not None else []
        ramp = np.array(_ramp_ends(on_face, solid, behind, params), dtype=float)
        rest = np.maximum(0.0, 1.0 - ramp / measured) if measured > 0 else np.ones_like(ramp)
        ramped = np.where((ramp > 0) & ~seeds.cropped, rest, 0.0)
        seeds = replace(seeds, occluding=np.where(seeds.occluding > 0, 1.0, ramped))
    stepped = None
    # The depths past the lines' ends as Python floats, for the per-end rules below.
    past_rows = None if past is None else np.asarray(past).tolist()
    if window and past_rows is not None and seeds.occluding is not None:
        share = np.array(_window_shares(on_face, past, _pixel_rad(lines, params), shares))
        extra["near_ends"] = float(np.count_nonzero((seeds.occluding > 0) & (share < 1.0)))
        # Each seed's share of the window's trim (0: not occluding): see _trimmed_sides.
        seeds = replace(seeds, occluding=seeds.occluding * share)
        # A run ending on a ramp down to a near background: its share of the step behind it,
        # for its side's median only (see _consistent_sides).
        stepped = np.array(_stepped_ends(on_face, solid, past_rows, params))
        stepped = np.where(seeds.cropped | (seeds.occluding > 0), 0.0, stepped)
    if seeds.occluding is not None and past_rows is not None:
        # A run that stops short of its segment's end with a far background behind it ended
        # at the face's edge as well, its last samples on a fattening ramp too long for
        # _ramp_ends: its place took a whole window's fattening, as an occluding seed's.
        # Not without the scans' depth past the lines' ends (recorded before it was): with
        # no samples beyond its segment, a crease's run would count as far.
        far = np.array(_far_behind(on_face, past_rows, params))
        fattened = np.where(far & ~seeds.cropped, 1.0, 0.0)
        seeds = replace(seeds, fattened=np.where(seeds.occluding > 0, seeds.occluding, fattened))
        if stepped is not None:
            stepped = _stopped_shares(seeds, far, stepped)
    elif seeds.occluding is not None:
        seeds = replace(seeds, fattened=seeds.occluding)
    if stepped is not None:
        seeds = replace(seeds, stepped=stepped)
    walk = replace(params, edge_fattening_px=measured) if measured else params
    beyond, smeared = _beyond_edges(on_face, solid, walk) if params.bevels else (None, False)
    face = _face_geometry(
        solid, seeds, params, paper=False, beyond=beyond, smeared=smeared,
        trim_px=measured, pixel_rad=_pixel_rad(lines, params),
    )  # fmt: skip
    if isinstance(face, str):
        return _none(face, summaries, total, extra)
    crease = _crease_direction(on_face, solid, seeds)
    if crease is not None:
        face = replace(face, axis=_along_crease(face.axis, crease, solid.normal))
    if face.disc is not None:
        extra["disc_rms_mm"] = 1000 * face.disc[2]
        extra["rectangle_residual_mm"] = 1000 * face.rectangle_residual
    if (
        face.disc is not None
        and face.disc[2] <= params.disc_max_rms_m
        and face.disc[2] < 0.5 * face.rectangle_residual
        and params.radius_limits_m[0] <= face.disc[1] <= params.radius_limits_m[1]
        and _disc_holds_cut_seeds(face.disc, seeds, params)
    ):
        # A flat round face (a lid seen from above): a short cylinder along the face normal.
        normal = _canonical_axis(solid.normal)
        along_view = math.hypot(normal[0], normal[1]) < params.axis_along_view
        return Reconstruction(
            shape="cylinder",
            grasp_width_m=2 * face.disc[1],
            wrist_angle_rad=None if along_view else _axis_angle(normal),
            center_m=_tuple3(face.disc[0]),
            axis=_tuple3(normal),
            lines=summaries,
            confidence=confidence,
            points=total,
            extra=extra,
        )
    axis = _canonical_axis(face.axis)
    return Reconstruction(
        shape="cuboid",
        grasp_width_m=face.width,
        wrist_angle_rad=_axis_angle(axis),
        center_m=_tuple3(face.centre),
        axis=_tuple3(axis),
        lines=summaries,
        confidence=confidence,
        points=total,
        extra=extra,
    )


def _band_candidate(clean: np.ndarray, face: PlaneSolid, params: LaserParams) -> _Candidate | None:
    """A cylinder along the direction the runs ``clean`` spread least across in ``face``'s
    plane, convex toward the camera, within the radius limits; or ``None``.

    A short round seen from its side (the jar cap's 15 mm band from the front) shows the
    lines a band straight across it, along its axis, and every run too short for its bend
    along the band to leave the threshold: straight pieces all, and a face wins (0.70-0.89
    of the runs, 14-15 mm wide across the band, 88 degrees off, under BM 7 with a low
    texture threshold, trial 1 frames 0-2). The band's ends recede from that face; a
    cylinder along its short side holds them (0.99-1.00 of the runs, 64-71 mm across)."""
    e1, e2 = orthonormal_basis(face.normal)
    uv = (clean - clean.mean(axis=0)) @ np.column_stack([e1, e2])
    _, vectors = np.linalg.eigh(uv.T @ uv)
    axis = vectors[0, 0] * e1 + vectors[1, 0] * e2
    solid = CylinderSolid.estimate(clean, axis, iterations=params.cylinder_iterations)
    if not solid:
        return None
    lo, hi = params.radius_limits_m
    if not lo <= solid.radius <= hi:
        return None
    centre = _closest_to_optical_axis(solid.point, solid.axis)
    if float(np.median(clean[:, 2])) >= centre[2]:
        return None  # the runs lie behind the axis: a concave face, no round's side
    residuals = solid.residuals(clean)
    fraction = _fraction(residuals, params.solid_threshold_m)
    return _Candidate("cylinder", fraction, solid, residuals=residuals)


# The resting rule's support search starts every frame from PCG64(0)'s first state: set on a
# generator kept per thread, 1 us; a new PCG64(0) builds its seed sequence again, 13 us.
_SUPPORT_SEED_STATE = np.random.PCG64(0).state
_support_rngs = threading.local()


def _support_rng() -> np.random.Generator:
    rng = getattr(_support_rngs, "rng", None)
    if rng is None:
        rng = _support_rngs.rng = np.random.Generator(np.random.PCG64(0))
    rng.bit_generator.state = _SUPPORT_SEED_STATE
    return rng


# The table beside a round holds most of the samples its lines have off the object. Fewer
# than SCAN_LINE_SUPPORT's 30, or all on one line, were as often a cylinder's own flank below
# its runs, or a plane through one line's trace, as the table.
_SUPPORT_MIN_LINE_POINTS = 10
# A line's samples past a jump from the round's segment are no part of the round, and lying
# on the plane another line's table trace spans, they tilt it as the table does: three show
# the support (a plane's own minimum). A wide window leaves the table beside a 70 mm ball
# 0-8 samples on its second line inside the capture volume (SGBM 5 and 7, OpenCV's sample's
# smoothness, half the signal: 3-8, all past the jump); a few samples joined to the run
# were the round's own rim or flank (SGBM 9, the ball, trial 0 frame 0: its rim 33 mm above
# the table on line 3 tilted line 1's trace 36 degrees, the ball 17.7 mm narrow).
_SUPPORT_MIN_FAR_POINTS = 3
# The table a disc lies on (_lying_disc) where the support search found none, or none the
# disc stands on: the plane most of the samples beside the runs lie on, whatever lies behind
# it, on five samples of two lines. The matcher smears the band's lower rim down behind the
# table, and the table's few samples beside a 60 mm cap split between the lines (the jar cap
# from the front, SGBM 7 trial 0 frame 1: 2 of 39 samples 4-9 mm behind the table, its 34
# samples 7, 8 and 19 on three lines: no support; this one 0.4 degrees off the cap's axis).
# The disc's own tests (its band reaching down to the plane and standing under its radius,
# its circle explaining the runs) keep a plane that is no table from reading a disc.
_DISC_SUPPORT = replace(SCAN_LINE_SUPPORT, support_max_behind_fraction=1.0)
_DISC_SUPPORT_LINE_POINTS = 5


def _matched(
    scan_lines: ScanLinesLike | None, params: LaserParams, gate: float | None = None
) -> float | None:
    """The scan lines' residual correlation (``scans.residual_correlation``) where it is at
    least ``gate`` (``window_correlation_gate``, correlated like an SGBM matcher's, unless
    given); else ``None``."""
    if scan_lines is None or params.window_correlation_gate <= 0:
        return None
    correlation = residual_correlation(scan_lines.angles_rad, scan_lines.points)
    return (
        correlation
        if correlation >= (params.window_correlation_gate if gate is None else gate)
        else None
    )


def _weak_gate(params: LaserParams) -> float | None:
    """The residual correlation from which a frame with no fattening in view came from a
    matching window (``weak_correlation_gate``), for ``_matched``; ``None`` where it is off.

    Each pixel of a window matcher's depth comes from a window it shares with its neighbours,
    so their errors move together; lpc's noise model draws each pixel's error on its own. Its
    frames that show no fattening read at most 0.10 (all four suites, 5 trials x 10 frames:
    1156 such frames), the sweep's stereo frames that show none 0.04-0.25 (median 0.18): block
    matchers with depth past their edges facing +x (``_hole_past_edge`` finds none), and SGBM,
    HH and 3-way frames short of ``window_correlation_gate`` whose faces keep their depth along
    the lines (seen square-on, the fattened pixels lie on the face's plane). The window still
    fattened their edges, by about half of it whatever lay behind: those frames take
    ``hole_fattening_px``, as a block matcher's with no depth past an edge facing +x. Untrimmed,
    the functional boxes on the frames that showed no fattening and passed neither gate came
    out 4.0 mm too wide on average over the sweep's 74 studied settings (248 frames; the
    upright box 9.9 mm on 27, its face square to the view). Cuboid width MAE
    over those settings 2.970 -> 2.825 mm, 49 better by 0.05 mm or more, 1 worse (BM 9 at a
    prefilter cap of 25, 3.81 -> 3.91: its boxes were narrow already)."""
    if params.weak_correlation_gate <= 0:
        return None
    return min(params.weak_correlation_gate, params.window_correlation_gate)


class _Beside(NamedTuple):
    """The lines' samples off the round's runs (``points``), in pieces of ``counts`` samples,
    each piece's line (``owners``) and whether a jump parts it from the round's segment
    (``far``); and the support search's planes through them (``cloud.support_hypotheses``, or
    ``None`` when too few samples lie beside for a support). Both support searches and
    ``_disc_on_plane_beside`` draw the same 64 triples of the same samples from the same seed:
    drawn and scored once a frame."""

    points: np.ndarray
    counts: list[int]
    owners: list[int]
    far: list[bool]
    hypotheses: SupportHypotheses | None


def _beside(lines: list[LineModels]) -> _Beside | None:
    """The frame's samples beside the runs (``_Beside``), or ``None`` where there are none."""
    pieces = [
        (ln.index, k < len(ln.beyond), p)
        for ln in lines
        for k, p in enumerate((*ln.beyond, ln.points[: ln.run[0]], ln.points[ln.run[-1] + 1 :]))
        if len(p)
    ]
    if not pieces:
        return None
    points = np.concatenate([p for *_, p in pieces])
    # A fixed seed: the same lines give the same support (decide has no frame seed).
    # _DISC_SUPPORT draws and scores as SCAN_LINE_SUPPORT does (it lets more lie behind).
    hypotheses = support_hypotheses(points, SCAN_LINE_SUPPORT, _support_rng())
    return _Beside(
        points,
        [len(p) for *_, p in pieces],
        [i for i, _, _ in pieces],
        [b for _, b, _ in pieces],
        hypotheses,
    )


def _support_plane(
    lines: list[LineModels],
    params: LaserParams,
    search: CloudParams = SCAN_LINE_SUPPORT,
    min_line_points: int = _SUPPORT_MIN_LINE_POINTS,
    beside: _Beside | bool | None = True,
) -> PlaneSolid | None:
    """The support the lines show beside the round, or ``None`` (or when resting is off,
    ``rest_gap_ratio`` 0).

    The support is the cloud method's (``cloud.find_support``: the largest plane with
    almost no sample behind it) among the lines' samples off the round's runs, on at least two
    lines so that it is a plane and not one line's trace. ``search`` and ``min_line_points``
    (the samples it needs on each of those two lines) are the disc's where the plain search
    found no table under it (``_DISC_SUPPORT``); a line whose samples past a jump from the
    round's segment lie on the plane shows it with ``_SUPPORT_MIN_FAR_POINTS`` of them.
    ``beside``: ``_beside(lines)`` where the caller has it already.
    """
    if params.rest_gap_ratio == 0:
        return None
    if beside is True:
        beside = _beside(lines)
    if not isinstance(beside, _Beside) or beside.hypotheses is None:
        return None
    points = beside.points
    found = find_support(points, search, _support_rng(), beside.hypotheses)
    if found is None:
        return None
    mask = found.mask
    # The arrays' method: np.repeat of a list goes through its wrapper's fallback (5 -> 2 us).
    owner = np.array(beside.owners).repeat(beside.counts).compress(mask)
    far = np.array(beside.far).repeat(beside.counts).compress(mask)
    per_line = np.bincount(owner, minlength=len(lines))
    per_line_far = np.bincount(owner.compress(far), minlength=len(lines))
    shown = (per_line >= min_line_points) | (per_line_far >= _SUPPORT_MIN_FAR_POINTS)
    if np.count_nonzero(shown) < 2:
        return None
    # The search's own fit where it was on these very points (half the resting rounds).
    support = found.plane or PlaneSolid.estimate(points.compress(mask, axis=0))
    return support if support else None


def _same_plane(a: PlaneSolid | None, b: PlaneSolid | None) -> bool:
    """Whether two supports are one plane to the last bit (the same samples' fit)."""
    return (
        a is not None
        and b is not None
        and a.point.tolist() == b.point.tolist()
        and a.normal.tolist() == b.normal.tolist()
    )


def _resting_width(
    lines: list[LineModels],
    clean: np.ndarray,
    solid: SphereSolid | CylinderSolid,
    params: LaserParams,
    support: PlaneSolid | bool | None = True,
) -> float | None:
    """The width of a round that rests on the support the lines show (``_support_plane``,
    or ``support`` where the caller found it already), fitted again touching it
    (``solids.resting_width``) to ``clean``, every sample of the lines' runs; ``None`` when
    the lines show no support or the round does not rest on it."""
    if support is True:
        support = _support_plane(lines, params)
    if not isinstance(support, PlaneSolid):
        return None
    # Every sample of the runs: the contact holds the fit where a free one would follow a
    # fattened tail, and a fit that was far off leaves few samples near it to choose.
    cylinder = isinstance(solid, CylinderSolid)
    return resting_width(
        clean,
        support,
        solid.point if cylinder else solid.center,
        solid.radius,
        solid.axis if cylinder else None,
        gap_ratio=params.rest_gap_ratio,
        float_ratio=params.rest_float_ratio,
        max_tilt_rad=params.rest_max_tilt_rad,
        tolerance_m=params.solid_threshold_m,
        radius_limits_m=params.radius_limits_m,
    )


def _lifted_off(
    full: CylinderSolid, solid: CylinderSolid, support: PlaneSolid | None, params: LaserParams
) -> float | None:
    """The radius of ``full`` (the fit on every inlier) when the round lies on ``support``,
    ``full`` touches it (within ``solid_threshold_m``) and ``solid``, the camera-facing or
    plateau-free refit, stands off it by more: ``None`` otherwise.

    The trims take off what a matcher's fattened rims added to the whole arc's fit, which
    then sinks into the support it lies on; one already touching it had nothing to take off,
    and a narrower refit that floats off the support is the shorter arc trading its radius
    against its centre's depth (the rotation suite's 40 mm cylinder seen from above under
    SGBM 7-9: the whole arc's fit within 1 mm of the truth and touching the table, the
    camera-facing refit 7-9 mm narrower standing 4-5.5 mm off it: past the quarter radius
    within which the resting rule moves a round onto its support, and the runs, stopping
    short of the rims, spread too little to move it from further off).
    """
    if support is None or solid.radius >= full.radius:
        return None
    n = support.normal
    if abs(float(n @ full.axis)) > math.sin(params.rest_max_tilt_rad):
        return None  # not lying along the support
    tol = params.solid_threshold_m
    gap_full = float((full.point - support.point) @ n) - full.radius
    gap_solid = float((solid.point - support.point) @ n) - solid.radius
    if abs(gap_full) <= tol < gap_solid:
        return full.radius
    return None


def _lies_on(solid: CylinderSolid | None, plane: PlaneSolid, params: LaserParams) -> bool:
    """Whether the cylinder lies on ``plane`` as a resting round does (``_resting_width``'s
    bounds): along it, sinking into it by at most ``rest_gap_ratio`` of its radius and
    standing off it by at most ``rest_float_ratio``."""
    if solid is None or not _lying_along(solid, plane, params):
        return False
    gap = float((solid.point - plane.point) @ plane.normal) - solid.radius
    return -params.rest_gap_ratio * solid.radius <= gap <= params.rest_float_ratio * solid.radius


def _lying_along(full: CylinderSolid, support: PlaneSolid | None, params: LaserParams) -> bool:
    """Whether the cylinder's axis lies along ``support`` (within ``rest_max_tilt_rad``)."""
    if support is None:
        return False
    return abs(float(support.normal @ full.axis)) <= math.sin(params.rest_max_tilt_rad)


def _axis_on_support(
    axis: np.ndarray, full: CylinderSolid, support: PlaneSolid | None, params: LaserParams
) -> np.ndarray:
    """``axis`` held in the plane of ``support`` where the whole arc's fit ``full`` lies along
    it and touches it (sinks into it by at most ``rest_gap_ratio`` of its radius or stands off
    it by at most ``rest_float_ratio``, as ``_resting_width`` asks); ``axis`` itself otherwise.

    A round lying on a table has its axis in the table's plane. On the short arcs the lines
    cross it by, a fit's tilt out of that plane trades against its turn about the view: a line
    running along the round a few millimetres off its crest sees a depth gradient along it
    (the matcher's error, 0.5-1 mm over the run) either as a tilt or as a turn, by the ratio
    of the radius to that offset. The support, fitted on the table's samples beside the
    round, fixes the tilt, and the turn with it: the 40 mm marker lying on the table, the
    found table within a degree of its axis, wrist angle 1.7-2.3 deg mean error over the
    sweep's settings per frame -> 0.3-0.4. ``full`` asks, not the trimmed fit: it is the one
    that touches the support (see ``_lifted_off``)."""
    if support is None or not _lying_along(full, support, params):
        return axis
    n = support.normal
    gap = float((full.point - support.point) @ n) - full.radius
    if not -params.rest_gap_ratio * full.radius <= gap <= params.rest_float_ratio * full.radius:
        return axis
    along = axis - float(axis @ n) * n
    return along / math.sqrt(float(along @ along))


def _pixel_rad(lines: list[LineModels], params: LaserParams) -> float:
    """The angle of one pixel: ``params.pixel_rad``, else the finest sample spacing along a
    line (s/z steps by 1/fx between the pixels of a line along a row or a column)."""
    if params.pixel_rad is not None:
        return params.pixel_rad
    steps = [ln.step for ln in lines if ln.step > 0]
    return min(steps) if steps else 0.0


# How far _camera_facing's refit moves its radius when refitted on the points it was fitted on:
# a sphere's Gauss-Newton stops on steps under 0.1 um (0.03 um at most seen); a cylinder's two
# Levenberg-Marquardt steps start again from the circle across the refit's axis (0.15 mm at
# most seen, over 1955 calls: the live recording's scans, --quick and five of the stereo
# sweep's settings). Indexed by whether the solid is a cylinder.
_SETTLED_M = (1e-6, 2e-4)


def _camera_facing(
    solid: SphereSolid | CylinderSolid,
    clean: np.ndarray,
    params: LaserParams,
    pixel_rad: float,
    residuals: np.ndarray | None = None,
    fattened: bool = False,
) -> SphereSolid | CylinderSolid:
    """The solid refitted on its inliers at least ``silhouette_margin_px`` inside its
    silhouette: the arc that faces the camera, which edge fattening and the steep rim do not
    reach. Fattened points lie beyond the true silhouette, so the first fit is too large and
    its silhouette too wide: a second pass trims against the refitted one. The solid as it
    was when too few points remain, the refit fails, its diameter is within
    ``silhouette_tolerance_m`` (or 4 sd) of the refit's, or it exceeds it by more than the
    margin on both sides, or, where ``fattened`` (the lines show a matcher's fattening), a
    cylinder's refit is narrower than its runs span (``_narrower_than_runs``). ``residuals``:
    the solid's on ``clean``, where the caller has them."""
    margin = params.silhouette_margin_px * pixel_rad
    if margin <= 0:
        return solid
    full = solid
    thr = params.solid_threshold_m
    lo, hi = params.radius_limits_m
    need = max(params.min_points_per_line, len(clean) // 4)
    keep = np.zeros(len(clean), dtype=bool)
    for _ in range(3):
        if residuals is None:
            residuals = solid.residuals(clean)
        trusted = (residuals <= thr) & (solid.silhouette_distance(clean) >= margin)
        residuals = None  # those of the refit, next pass
        if np.count_nonzero(trusted) < need:
            break
        # Two boolean masks of clean's length: np.array_equal's own test, without its checks.
        if solid is not full and bool((trusted == keep).all()):
            # The trim has settled: it keeps the points the refit was fitted on, and the passes
            # left would refit them again, which moves the radius by at most _SETTLED_M (see
            # there). A refit that far inside the tolerance still would be: the solid stands.
            settled = _SETTLED_M[isinstance(solid, CylinderSolid)]
            if 2 * (full.radius - solid.radius + settled) <= params.silhouette_tolerance_m:
                return full
        keep = trusted
        if isinstance(solid, SphereSolid):
            refit = SphereSolid.estimate(
                clean.compress(keep, axis=0), init=(solid.center, solid.radius)
            )
        else:
            refit = CylinderSolid.estimate(clean.compress(keep, axis=0), solid.axis, iterations=2)
        if not refit or not lo <= refit.radius <= hi:
            break
        solid = refit
    if solid is full:
        return full
    wider = full.radius - solid.radius
    if 2 * wider <= params.silhouette_tolerance_m or wider <= 4 * _radius_sd(solid, clean[keep]):
        return full
    # Nor can the window widen it by more than the margin on each side: a larger change says
    # the object is not that solid (a gourd taken for a cylinder), not that its rim fattened.
    if wider > margin * float(np.median(clean[:, 2])):
        return full
    if isinstance(full, CylinderSolid):
        if fattened and _narrower_than_runs(solid, clean, pixel_rad):
            # Under a matcher's correlated depth errors the facing arc alone trades its radius
            # against its centre's depth (as a ball's cap does, see _fattened): a 50 mm
            # cylinder lying across the lines, whose runs span it to within 2 mm, came out
            # 6-12 mm narrower than the truth on SGBM 5-9 where the whole arc's fit was
            # within 3 mm. Not under lpc's noise model, where an object only roughly a
            # cylinder (the horse toy) spans more than its facing arc says.
            return full
        # The axis keeps the fit on every inlier: the rims shift the radius, hardly the axis,
        # and on an object only roughly a cylinder the facing arc alone turns it.
        return replace(full, radius=solid.radius)
    return solid


def _span_across(solid: CylinderSolid, points: np.ndarray) -> float:
    """How far ``points`` spread across the cylinder's axis as seen: along the direction
    perpendicular to both the axis and the line of sight to it."""
    centre = _closest_to_optical_axis(solid.point, solid.axis)
    across = _cross(solid.axis, centre)
    norm = float(np.linalg.norm(across))
    if norm < 1e-9:
        return 0.0  # the axis lies along the line of sight: nothing spreads across it as seen
    spread = points @ (across / norm)
    return float(spread.max() - spread.min())


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two 3-vectors, to the bit (its products and differences, in the same
    order), in plain floats: its axis handling costs more than the product on a 3-vector
    (the round frames' view angles, 15 us a call)."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _round_width(
    solid: CylinderSolid,
    full: CylinderSolid,
    clean: np.ndarray,
    params: LaserParams,
    resting: float | None = None,
    lines: list[LineModels] | None = None,
    support: PlaneSolid | None = None,
) -> float:
    """The diameter of ``solid`` (or ``resting``, its width from the support, when given), or
    the spread of the lines' runs across its axis where that is wider than any inlier of
    ``full`` (the fit on every inlier) could spread: then the object is no round cylinder, and
    how high it stands says nothing of how wide it is. Given ``lines`` (and the ``support``
    they show), the spread of their segments past the runs (``_runs_to_rims``) where wider,
    and ``full``'s diameter where the fit took one bump of the round (``_bump_fit``) and the
    segments go on past the runs by more than an inlier band.

    No two points within ``solid_threshold_m`` of a cylinder lie farther apart across its axis
    than its diameter plus twice that. Runs that do are on an object only roughly a cylinder
    whose pierced arc curves more tightly than the whole (a potato's bumps: the 62 mm sweet
    potato fitted 30-48 mm on every sensor), and the object is at least as wide as the runs
    span. Against ``full``, not the camera-facing fit: a matcher's fattening widens the span
    and ``full`` alike (a 40 mm cylinder under a 7 x 7 window: span 43-44 mm, ``full`` 44-46
    mm, camera-facing 40 mm); and a stereo matcher's runs mostly end inside the silhouette,
    where grazing and shadowed rims leave holes."""
    span = _span_across(solid, clean)
    if span > 2 * (full.radius + params.solid_threshold_m):
        if lines is not None:
            # Such a round's runs end where its bumps leave the run's model, short of its
            # rims, and its segments go on over it without a jump up to the plateau a
            # matcher smears past the rim (the 62 mm sweet potato under BM 9 with a strict
            # speckle filter, trial 1: runs spanning 39.7-43.7 mm, their segments 43.3-53.0
            # without the plateaus; the runs alone left its median width at 39.6 mm).
            span = max(span, _span_across(solid, _runs_to_rims(lines, support, params)))
        return span
    if resting is None and lines is not None and _bump_fit(solid, full, span, params):
        # Where the segments go on past the runs, the matcher ended the runs inside the
        # limbs, and the whole arc's fit, as wide as the runs, is the nearer the round;
        # where they do not, the runs end where the seen surface does, on a fattened arc
        # past the rims (the 40 mm cylinder lying, SGBM 7 on a 55 mm baseline, trial 0
        # frame 2: fit 35 mm, runs and the whole arc's fit 46 mm). The segments' own
        # span is no width: past a lying round's runs they go on over a table no support
        # search found (the 40 mm cylinder, SGBM 7 in 8-path mode, trial 0 frame 4: 54 mm).
        reach = _span_across(solid, _runs_to_rims(lines, support, params))
        if reach > span + 2 * params.solid_threshold_m:
            return 2 * full.radius
    return 2 * solid.radius if resting is None else resting


def _bump_fit(solid: CylinderSolid, full: CylinderSolid, span: float, params: LaserParams) -> bool:
    """Whether the trimmed fit ``solid`` took one bump of a rough round: the runs spread wider
    across its axis than its diameter by more than two inlier bands a side, the whole arc's
    fit ``full`` is wider by as much, and the runs reach as wide as ``full`` (within a band a
    side). A trimmed fit 6-10 mm narrower than both curves along one bump (the 62 mm sweet
    potato under BM 9 with a 25 % uniqueness ratio: fits of 28-37 mm whose runs span 38-48 mm,
    and ``full`` 37-47 mm). A matcher's fattening widens the runs and ``full`` over the
    camera-facing fit too, but pulls ``full`` out past the runs: the 40 mm cylinder lying
    under SGBM 9, trial 0: fits of 34-36 mm, runs spanning 43 mm, ``full`` 49 mm."""
    margin = 2 * params.solid_threshold_m
    return (
        span > 2 * (solid.radius + margin)
        and full.radius > solid.radius + margin
        and span > 2 * (full.radius - params.solid_threshold_m)
    )


def _runs_to_rims(
    lines: list[LineModels], support: PlaneSolid | None, params: LaserParams
) -> np.ndarray:
    """Each line's segment from its run's ends on to the segment's ends, less a plateau that
    shows a matcher's fattening there (``_fattened_end``), and up to the first sample on the
    ``support`` (within three inlier bands of it), laid end to end: the segment holds no
    jump, so past the run it is the object's surface still but for that plateau, until it
    reaches what the object rests on (a round lying on the table meets it without a jump:
    the 40 mm marker's segments on a 40 mm baseline, trial 1 frame 4, went on 40 mm over
    the table)."""
    on = 3 * params.solid_threshold_m
    pieces = []
    for ln in lines:
        first, last = int(ln.run[0]), int(ln.run[-1])
        start = min(_fattened_end(ln, 0), first)
        stop = max(_fattened_end(ln, 1), last)
        if support is not None:
            height = (ln.points - support.point) @ support.normal
            below = np.flatnonzero(height[start:first] <= on)
            if len(below):
                start += int(below[-1]) + 1
            below = np.flatnonzero(height[last + 1 : stop + 1] <= on)
            if len(below):
                stop = last + int(below[0])
        pieces.append(ln.points[start : stop + 1])
    return np.concatenate(pieces)


# Samples past a round's outermost one across its axis that say its segment goes on there.
_ROUND_GOES_ON = 3
_NO_ANGLES = np.empty(0)

# Samples within this many pixels of the silhouette they show: the rim a matcher bows out.
_RIM_PX = 4.0
# How far inside the rims a refit's silhouette may lie where both rims are occluding edges
# before a far background (see _reaching_rims).
_OCCLUDED_RIM_PX = 2.0
# ... and where those rims also lie this far or more inside the whole arc's fit's silhouette on
# the two sides' mean: the window carried none of them out with the flattened fit (see
# _rim_free's end).
_RIMS_INSIDE_FIT_PX = 2.0
_INSIDE_FIT_RIM_PX = 1.0
# The least fraction of a round's seen span across its axis that its inner samples must span.
_ROUND_INNER_SPAN = 0.5


def _across_view(solid: CylinderSolid, points: np.ndarray) -> np.ndarray | None:
    """Each point's view angle across the cylinder's axis: its direction from the camera in
    the cross-section (the plane across the axis), from the foot of the axis's perpendicular
    through the camera; ``None`` when the axis passes through the camera."""
    foot = solid.point - (solid.point @ solid.axis) * solid.axis
    norm = math.sqrt(float(foot @ foot))
    if norm < 1e-9:
        return None
    towards = foot / norm
    side = _cross(solid.axis, towards)
    return np.arctan2(points @ side, points @ towards)


class _SeenRound(NamedTuple):
    """The lines' samples laid end to end (``points``, read-only), the whole arc's fit's
    ``residuals`` on them and their view angles across its axis (``_across_view``): what
    ``_rim_free``, ``_silhouette_bound`` and ``_background_bound`` each read of that fit,
    worked out once a frame (``_seen_round``)."""

    points: np.ndarray
    residuals: np.ndarray
    angle: np.ndarray | None


def _seen_round(lines: list[LineModels], full: CylinderSolid) -> _SeenRound:
    samples = _read_only(np.concatenate([ln.points for ln in lines]))
    angle = _across_view(full, samples)
    return _SeenRound(
        samples,
        _read_only(full.residuals(samples)),
        None if angle is None else _read_only(angle),
    )


def _rim_free(
    lines: list[LineModels],
    full: CylinderSolid,
    clean: np.ndarray,
    params: LaserParams,
    pixel_rad: float,
    scan_lines: ScanLinesLike | None = None,
    support: PlaneSolid | None = None,
    seen: _SeenRound | None = None,
) -> CylinderSolid | None:
    """The cylinder refitted on its lines' samples at least ``rim_bias_px`` inside both the
    silhouette the samples show (the extremes of their view angles across the axis: every
    segment ends at the rim or before it) and ``full``'s; ``None`` when the samples at that
    silhouette do not bow out of ``full`` by ``rim_bow_m`` (the median of those within
    ``_RIM_PX``), too few samples or too short an arc remain, or the refit fails or leaves
    the radius limits.

    A stereo matcher's window pulls a steep surface toward the camera (see
    ``LaserParams.rim_bias_px``), so a fit on the whole arc comes out too flat and too wide,
    and its silhouette lies too far out to trim against as ``_camera_facing`` does: the
    samples' own extent does not depend on the fit. The rim then bows out of the whole arc's
    fit (median 0.7-2.0 mm on the functional cylinders under SGBM 5-9 and BM 9, p10 0.2-0.5
    mm); under lpc's noise model it lies on it (p90 0.18 mm), and the whole arc pins the
    radius far better than the inner part alone (an upright can seen from 45 degrees above:
    2-4 mm narrower on inner samples within 0.6 mm of the truth).

    A fit so flat that the rims lie on it (no bow) is refitted all the same where its
    silhouette lies ``_FLAT_FIT_PX`` or more beyond the samples on both sides (``_flat_fit``),
    each of which ends its segment at an occluding edge before a background at least
    ``full``'s diameter further (``_occluding_rims``, with ``scan_lines``): there the samples
    reach the silhouette, and the fit's lies beyond it because the window flattened the arc,
    not because the rims were lost (the 60 mm can under SGBM 7: 13.9 mm wide, 1.9 mm
    refitted). A round lying on the table has the table within a diameter behind its rims,
    where a matcher's samples stop 2-7 px short of them (see ``_occluding_rims``): it keeps
    its fit. So too, under uncorrelated residuals with no rim fattened (BM's holes), a fit
    that flat is refitted bounded by the samples: the refit is dropped where an unfattened
    sample lies more than a pixel beyond its silhouette, since such samples lie inside the
    round's.

    Under residuals correlated like SGBM's (``_matched``) the silhouette the samples show
    leaves out the plateaus a window fattened past it (``_fattened_samples``), unless the
    round lies along ``support`` or rests on a surface right behind its rims
    (``_rests_behind_rims``).

    The refit's silhouette lies within ``_RIM_PX`` of the rims the lines show on at least one
    side, else it is widened until it lies that far inside them on the two sides' mean
    (``_reaching_rims``; rims without what a window carried past them, ``_past_rims``);
    within ``_OCCLUDED_RIM_PX`` where both rims are occluding edges before a far background
    (``_occluding_rims``, read on ``full``), and within ``_INSIDE_FIT_RIM_PX`` where such rims
    also lie ``_RIMS_INSIDE_FIT_PX`` or more inside ``full``'s silhouette (``_past_silhouette``):
    the window carried none of them out with the fit it flattened. ``seen``:
    ``_seen_round(lines, full)`` where the caller has it.
    """
    margin = params.rim_bias_px * pixel_rad
    if margin <= 0:
        return None
    seen = seen or _seen_round(lines, full)
    samples = seen.points
    thr = params.solid_threshold_m
    lo, hi = params.radius_limits_m
    angle = seen.angle
    if angle is None:
        return None
    residuals = seen.residuals
    # The scan lines' correlation (0.2 ms) when first asked: up to twice below.
    matched = functools.cache(lambda: _matched(scan_lines, params))
    # Under an SGBM-like window the samples run past the silhouette in the plateau the window
    # carries the rim's depth into (the 50 mm bottle tilted right at SGBM 9: 2-9 px past it),
    # so their extent lies too far out to trim the pulled arc inside it. The extent leaves
    # those plateaus out (_fattened_end: a plateau, then a rim), but not a round's that lies
    # along or rests on a surface seen right behind its rims, where what ends a segment is not
    # fattening alone (the lying 50 mm bottle without them: +1.9 -> +9.0 mm on a BM 7 frame
    # that passed the correlation gate, +1.9 -> -4.1 at P1 x 3, P2 x 6).
    fattened = _fattened_samples(lines)
    if not (
        fattened.any()
        and not _lying_along(full, support, params)
        and matched() is not None
        and not _rests_behind_rims(lines, full, angle, residuals, params, pixel_rad, scan_lines)
    ):
        fattened[:] = False
    unfattened = ~fattened
    # Samples that run on past the round only in a window's smear toward a background far
    # behind (see _smeared_past) show no support the round's segment goes on onto.
    counted = ~_smeared_past(lines, full, params, pixel_rad, scan_lines, samples, residuals)
    # The samples at the rims the lines show: on the round, not smeared past it, nor in a
    # plateau or ramp a window carried past a rim (_past_rims). Not all of a plateau that
    # ends a segment (_fattened_samples, which the trim below leaves out): a window flattens
    # a rim's last pixels in place too, and such a plateau may lie inside the silhouette
    # (the 60 mm can under 3-way SGBM 9: line 0's last six samples within 1 mm of depth,
    # from 4 px inside the true silhouette to 1 px past it, the refit 8.4 mm narrow with
    # them left out; the 50 mm bottle tilted right on a 48 mm baseline: a plateau from 5 px
    # inside to 2 px past it, 5.5 mm narrow). _past_rims keeps a plateau's samples only up to
    # the last step that still rises as fast as a rim (over the sweep's studied settings, the
    # four cylinders: 27 better, 10 worse).
    on_full = residuals <= 4 * thr
    rims = on_full & counted & ~_past_rims(lines, on_full)
    # Read on the whole arc's fit, as the bow's test reads it below.
    occluding = scan_lines is not None and _occluding_rims(
        lines, angle, residuals, params, pixel_rad, scan_lines, 2 * full.radius
    )
    solid = full
    kept = None
    bounded = False
    for attempt in range(3):
        if attempt:
            angle = _across_view(solid, samples)
            if angle is None:
                return None
            residuals = solid.residuals(samples)
        on = residuals <= 4 * thr
        on_round = angle.compress(on)
        if len(on_round) == 0:
            return None
        first, last = _seen_extent(angle.compress(counted), on_round)
        inset = np.minimum(angle - first, last - angle)
        if attempt == 0:
            rim = (inset < _RIM_PX * pixel_rad) & on
            if np.count_nonzero(rim) < _ROUND_GOES_ON:
                return None
            bow = full.offsets(samples.compress(rim, axis=0))
            flat = _flat_fit(full, first, last, pixel_rad)
            if median(bow.tolist()) < params.rim_bow_m and not (flat and occluding):
                # Residuals correlated like an SGBM window's on a round not lying along a
                # support: the window flattened the whole arc's fit, and rims fattened along
                # with it lie on that fit (no bow) while the fit is too wide all the same (the
                # 50 mm bottle tilted right, SGBM 5-9 and sparse dots: rims 1-4 px past the
                # true silhouette on both sides, the fit 2-9 mm wide where no bow was seen).
                # So too where both outermost samples end their segments in the plateau a
                # window leaves past a rim it reached (_fattened_rims), correlated or not (BM 7
                # and 9: the 50 mm bottle 6.5-13.6 mm wide, refitted -0.4 to +7.3; the 60 mm
                # can 1.8-13.1 mm wide, refitted 2.3-2.7 mm narrow).
                # Not a round lying along a support the lines show, right behind its rims,
                # where the samples stop short of them (the rotation suite's 40 mm cylinder
                # refitted without the bow: width MAE 1.0-1.5 -> 1.3-2.3 mm on SGBM 5-9), nor
                # one whose rims stand on a surface behind them (_rests_behind_rims: the 75 mm
                # one, whose support the lines do not fit as a plane, refitted went 1.9-3.1 ->
                # 2.2-3.3 mm).
                if _lying_along(full, support, params):
                    return None
                # Nor, uncorrelated and unfattened, lpc's noise model's samples, which reach
                # the whole arc's silhouette, nor BM's where they stop short of the rims in
                # holes while the fit passes no further out than they do. Where the fit lies
                # _FLAT_FIT_PX or more beyond them on both sides (_flat_fit), the window
                # flattened it (the 60 mm can under BM 7-11: 6-11 mm wide): refitted, bounded
                # by the samples, which lie within the round's silhouette where nothing
                # fattened them (the can under BM 5, its fit within 1 mm, came out 5-13 mm
                # narrow refitted unbounded).
                holes = matched() is None and not _fattened_rims(lines, angle, residuals, params)
                bounded = holes and flat
                if (holes and not bounded) or _rests_behind_rims(
                    lines, full, angle, residuals, params, pixel_rad, scan_lines
                ):
                    return None
                on_seen = on & counted
        if fattened.any():
            # The bow and the arc's least span are read on every sample, as without plateaus:
            # only where the trim starts moves in.
            bare_on = angle.compress(on & unfattened)
            if len(bare_on) == 0:
                break
            bare_first, bare_last = _seen_extent(angle.compress(unfattened & counted), bare_on)
            inset = np.minimum(angle - bare_first, bare_last - angle)
        # Twice the inlier band: the whole arc's fit, too flat, may miss the inner arc by more.
        near = residuals <= 2 * thr
        keep = near & (np.minimum(inset, solid.silhouette_distance(samples)) >= margin)
        if np.count_nonzero(keep) < max(params.min_points_per_line, np.count_nonzero(near) // 4):
            break
        # Too short an arc trades its radius against its centre's depth: a round that spans
        # few more pixels than twice the margin (the 40 mm cylinder lying 230 mm away, 40 px)
        # keeps its fit.
        inner = angle.compress(keep)
        if attempt == 0:
            # The span the samples show about the whole arc's fit. Not the refit's: a narrower
            # refit holds fewer samples within its bands, so its own span shrinks with it, and
            # the arc could narrow pass after pass (the jar cap's 60 mm band under SGBM 5, its
            # third arc 25 px of the 43 px its second refit's bands held, 56 px seen: 23 mm).
            seen = float(on_round.max() - on_round.min())
        if inner.max() - inner.min() < _ROUND_INNER_SPAN * seen:
            break
        refit = CylinderSolid.estimate(samples.compress(keep, axis=0), solid.axis, iterations=2)
        if not refit or not lo <= refit.radius <= hi:
            break
        solid, kept = refit, samples.compress(keep, axis=0)
    if kept is None:
        return None
    # A sample seen on the round, where nothing fattened it, lies within its silhouette.
    beyond = -solid.silhouette_distance(samples[on_seen]) if bounded else _NO_ANGLES
    if len(beyond) and float(beyond.max()) > pixel_rad:
        return None
    # An object only roughly a cylinder (the 62 mm sweet potato, whose ends curve more
    # tightly, 42 -> 31 mm on BM 9) keeps the fit on its whole arc (and _round_width its span).
    if _narrower_than_runs(solid, clean, pixel_rad):
        return None
    # The window pulls the flanks toward the camera, so the refit may only narrow the whole
    # arc's: but where the crest alone is more curved than the can (the 60 mm can refitted
    # 8-12 mm narrow at SGBM 7 with a weak pattern or a projector beside the left imager,
    # whole-arc fits within 3 mm), its silhouette lies inside the rims the lines show.
    slack = _OCCLUDED_RIM_PX if occluding else _RIM_PX
    # The window's pull flattens the whole arc's fit, so its silhouette lies past the round's
    # by as much as the flanks were pulled; occluding rims that the window carried out with
    # it reach that silhouette (the 50 mm bottle tilted right: 2-3 px past the true one where
    # they lie within a pixel of it), while rims 2 px or more inside it are where the surface
    # ended (the 60 mm can: 1-3 px inside the true silhouette there, the refit 5-11 mm narrow
    # under SGBM 7 with the projector 15 mm from the left imager or 1.7 times the shot noise).
    # Inside such rims the refit keeps a pixel's slack: over the sweep's 84 studied settings,
    # the four cylinders 19 settings better, 8 worse (the can 18 / 4).
    rim_points = samples.compress(rims, axis=0)
    if occluding:
        inside = _past_silhouette(full, rim_points)
        if inside is not None and inside <= -_RIMS_INSIDE_FIT_PX * pixel_rad:
            slack = _INSIDE_FIT_RIM_PX
    solid = _reaching_rims(solid, rim_points, pixel_rad, slack)
    if matched() is None:
        solid = _unoccluded_hole(lines, solid, full, samples, params, pixel_rad, scan_lines)
    return solid


# The hole between a round's last sample and the background beside it, on the side that faces
# the second imager, that says a block matcher lost the rim there (pixels across the axis):
# at least this wide, at most _HOLE_RIM_MAX_PX (a wider one is no lost rim but another gap).
_HOLE_RIM_PX = 3.0
_HOLE_RIM_MAX_PX = 10.0


def _unoccluded_hole(
    lines: list[LineModels],
    solid: CylinderSolid,
    full: CylinderSolid,
    samples: np.ndarray,
    params: LaserParams,
    pixel_rad: float,
    scan_lines: ScanLinesLike | None,
) -> CylinderSolid:
    """``solid`` with its silhouette moved about its axis's distance to the middle of the hole
    between the round's outermost sample (by view angle across ``solid``'s axis, among those
    within four inlier bands of ``full``) and the first far background past it (the scans'
    ``far_past_m``), where that sample ends its line on the side toward the second imager
    (+x), lies a pixel or more inside ``solid``'s silhouette, and the hole spans
    ``_HOLE_RIM_PX`` to ``_HOLE_RIM_MAX_PX`` pixels; else ``solid``.

    On that side the background right beside a round is seen by both imagers: occlusion
    leaves no hole there (it leaves its band on the -x side), so a hole between the round and
    its background is the matcher's own loss, a block matcher's window straddling the rim
    failing its texture or uniqueness test. Its samples then stop 1-7 px short of the true
    silhouette (the 60 mm upright can, BM 5-11: median 3.5 px), the background resumes 0-5 px
    past it, and the silhouette lies within the hole, about its middle (within 1.5 px on most
    such frames). Only under residuals uncorrelated like a block matcher's (``_matched`` is
    None): an SGBM-like window fattens that rim past the silhouette before the hole (1-10 px
    on SGBM 5 with uniqueness 15 and hand-held settings), and the hole's middle lies beyond
    it. The refit the hole widens is the samples' own (see ``_rim_free``): a sample a pixel or
    more inside its silhouette shows the round goes on past its last sample."""
    far = getattr(scan_lines, "far_past_m", None)
    if far is None:
        return solid
    view = _axis_in_view(solid)
    angle = _across_view(solid, samples)
    if view is None or angle is None:
        return solid
    on = np.flatnonzero(full.residuals(samples) <= 4 * params.solid_threshold_m)
    if len(on) == 0:
        return solid
    distance, half = view
    for sign, (ln, k) in zip((-1.0, 1.0), _outermost_samples(lines, angle, on), strict=True):
        if k not in (0, len(ln.points) - 1) or ln.index >= len(far):
            continue
        end = ln.points[k]
        seen = far[ln.index][0 if k == 0 else 1]
        if seen[2] <= 0 or seen[0] / seen[2] <= end[0] / end[2]:
            continue  # no background within reach, or the side away from the second imager
        past, at = sign * _across_view(solid, np.stack([seen, end]))
        hole = (past - at) / pixel_rad
        if at > half - pixel_rad or not _HOLE_RIM_PX <= hole <= _HOLE_RIM_MAX_PX:
            continue
        middle = min(0.5 * float(past + at), 0.5 * math.pi)
        return replace(solid, radius=distance * math.sin(middle))
    return solid


# How many on-round samples at each end of a line's run show where its rim is, and how fast
# (of the steepest rise among them) the depth must still rise outward at a rim.
_RIM_RISE_SAMPLES = 12
_RIM_RISE = 0.5


def _past_rims(lines: list[LineModels], on: np.ndarray) -> np.ndarray:
    """Whether each of the lines' samples (laid end to end) lies past the rim at an end of its
    line's run of ``on`` samples: past the outermost step, among the run's last
    ``_RIM_RISE_SAMPLES`` (a third of the run at most), whose depth rises outward by at least
    ``_RIM_RISE`` of the steepest such step there.

    A round's depth rises fastest at its silhouette, and a window that averages the rim's
    depth with the background's still rises fastest there: samples past that step, rising
    slower or not at all, are what the window carried past the rim, whether as a plateau
    (``_fattened_end``) or a slow ramp toward the background that stays on the whole arc's
    fit (the 50 mm bottle tilted right at SGBM 7: 195 mm over five samples past a rim at
    about 202 mm, then 197 mm, 2-8 px past the true silhouette; unmarked by
    ``_fattened_end``, whose plateau must end the segment and a rim follow it)."""
    marks = []
    start = 0
    for ln in lines:
        z = ln.sz[:, 1]
        mark = np.zeros(len(z), dtype=bool)
        run = on[start : start + len(z)].nonzero()[0]
        start += len(z)
        count = min(_RIM_RISE_SAMPLES, len(run) // 3)
        if count >= 2:
            for end in (run[:count][::-1], run[-count:]):  # each from inside outward
                depths = z[end]
                rise = depths[1:] - depths[:-1]  # np.diff's own subtraction, without its wrapper
                steepest = float(rise.max())
                if steepest > 0:
                    rim = int((rise >= _RIM_RISE * steepest).nonzero()[0][-1])
                    mark[end[rim + 2 :]] = True
        marks.append(mark)
    return np.concatenate(marks) if marks else np.zeros(0, dtype=bool)


def _reaching_rims(
    solid: CylinderSolid, rims: np.ndarray, pixel_rad: float, slack_px: float = _RIM_PX
) -> CylinderSolid:
    """``solid`` widened about its axis's distance, where its silhouette lies more than
    ``slack_px`` inside the outermost of ``rims`` on the two sides' mean, until it lies
    ``slack_px`` inside them there (the widening moves both sides alike): the band a window
    bows a rim over (see ``_rim_free``) bounds how far inside its own rims a round's samples
    can place its silhouette; a refit narrower than that took a crest more curved than the
    round for the round.

    ``_RIM_PX`` where a surface may lie close behind a rim: the window carries the rim's depth
    onto it in a ramp that stays on the round's fit, and the rims the lines show lie up to a
    window's half past the silhouette (the 40 mm cylinder lying on the table: 2.8 px past it
    on the median frame, 4.3 at the 90th percentile). ``_OCCLUDED_RIM_PX`` where both rims
    are occluding edges before a far background (``_occluding_rims``): nothing behind lies
    near enough in depth to take the rim's, and the rims lie nearer the silhouette (1.3 px
    past it on the median such frame of the lying cylinder and of the bottle tilted right,
    0.1 px inside on the 75 mm jar's, 1.8 px inside on the 60 mm can's; 10th to 90th
    percentile -4.6 to +3.7 px over the four). A refit more than 2 px inside such rims took
    the crest for the round: the 60 mm can on five SGBM 5-7 settings (proj15, p1w-shot,
    sg5-s150, base40, hh7-d; 12 frames), refitted 2-13 mm narrow with the rims 2.1-5.4 px
    past it on the mean, came out 0.2-3.9 mm nearer the truth widened; over the sweep's
    studied settings 29 better, 9 worse on the four cylinders.

    On the mean, not on each side: a refit whose axis lies off sideways has one side's rims
    farther out and the other's nearer in by as much, and the mean alone does not move with
    it (the 60 mm can under SGBM 7 in HH mode: rims 8.4 and 2.0 px past the refit, 6.2 mm
    narrow; on the mean 3.8 mm; over the sweep's studied settings 36 frames nearer the truth,
    14 farther, none by more than 2.7 mm)."""
    past = _past_silhouette(solid, rims)
    view = _axis_in_view(solid)
    if past is None or view is None:
        return solid
    distance, half = view
    slack = slack_px * pixel_rad
    if past <= slack:
        return solid
    reach = min(half + past - slack, 0.5 * math.pi)
    return replace(solid, radius=distance * math.sin(reach))


def _past_silhouette(solid: CylinderSolid, points: np.ndarray) -> float | None:
    """How far the outermost of ``points`` lie past ``solid``'s silhouette on the two sides'
    mean, as a view angle across its axis (``_across_view``; negative inside it); ``None``
    where there are none or the camera lies within the round or on its axis."""
    view = _axis_in_view(solid)
    if view is None or len(points) == 0:
        return None
    angle = _across_view(solid, points)
    if angle is None:
        return None
    half = view[1]
    return 0.5 * ((-half - float(angle.min())) + (float(angle.max()) - half))


def _smeared_past(
    lines: list[LineModels],
    full: CylinderSolid,
    params: LaserParams,
    pixel_rad: float,
    scan_lines: ScanLinesLike | None,
    samples: np.ndarray,
    residuals: np.ndarray,
) -> np.ndarray:
    """Whether each of the lines' ``samples`` (laid end to end, ``full``'s ``residuals`` on
    them) lies off ``full`` (beyond four inlier bands) past the line's last inlier toward a
    segment end that is an occluding edge before a background more than ``full``'s diameter
    behind it, or before nothing (the line's own samples beyond the segment within
    ``background_reach_px``, else the scans' ``past_ends_m``, as ``_occluding_rims`` reads
    them), or none of them farther than the last inlier by more than the depth quantum
    (``_END_PLATEAU_M``), whatever lies past the end, where that inlier is a rim beside the
    round: not within ``_RIM_PX`` (of its pixel footprint) of the round's ends along its axis,
    where its base may stand on a support whose near side comes nearer past the contact (the jar
    cap from the front, SGBM 5: the table 29 mm nearer over 17 samples; marked, its band came
    out 45 mm for 60, unmarked 71).

    Such samples are a matcher's smear from the rim toward the far background, whose depth
    its smoothness carries over a few pixels (they part from the fit by about 1 mm a pixel),
    not a support the round's segment goes on onto: a support a round rests on lies within a
    diameter behind its rims (see ``_rests_behind_rims``)."""
    marks = []
    past = getattr(scan_lines, "past_ends_m", None)
    reach = params.background_reach_px * pixel_rad
    along = (samples @ full.axis).compress(residuals <= 4 * params.solid_threshold_m)
    lowest, highest = (float(along.min()), float(along.max())) if len(along) else (0.0, 0.0)
    for ln in lines:
        mark = np.zeros(len(ln.points), dtype=bool)
        marks.append(mark)
        inliers = (full.residuals(ln.points) <= 4 * params.solid_threshold_m).nonzero()[0]
        if past is None or len(inliers) == 0:
            continue
        c, s_ = math.cos(ln.angle), math.sin(ln.angle)
        for side, outside in ((0, slice(0, inliers[0])), (1, slice(inliers[-1] + 1, None))):
            # Between the last inlier and the segment's end every sample is off the fit.
            if not len(mark[outside]):
                continue
            rim = ln.points[inliers[0] if side == 0 else inliers[-1]]
            footprint = _RIM_PX * pixel_rad * float(rim[2])
            if (
                lowest + footprint < float(rim @ full.axis) < highest - footprint
                and float(ln.points[outside, 2].max()) - float(rim[2]) <= _END_PLATEAU_M
            ):
                # Nothing past the rim lies farther than it: no surface seen past an occluding
                # rim beside the round lies nearer (a support it lies on is touched behind
                # it), so this is the window's plateau at the rim's depth smoothed on past the
                # segment's end.
                mark[outside] = True
                continue
            end = ln.points[0 if side == 0 else -1]
            beyond = ln.beyond[side] if ln.beyond else _NO_POINTS
            behind = 0.0
            if len(beyond):
                b = (beyond[:, 0] * c + beyond[:, 1] * s_) / beyond[:, 2]
                near = np.abs(b - (end[0] * c + end[1] * s_) / end[2]) <= reach
                if not near.any():
                    continue  # a hole beside the end: what lies behind it is not seen
                behind = float(np.median(beyond[near, 2]))
            elif ln.index < len(past):
                behind = float(past[ln.index][side])
            if behind == 0.0 or behind - float(end[2]) > 2 * full.radius:
                mark[outside] = True
    return np.concatenate(marks) if marks else np.zeros(0, dtype=bool)


def _seen_extent(angle: np.ndarray, on_round: np.ndarray) -> tuple[float, float]:
    """The extremes of the view angles ``on_round`` (those of the samples on the round, among
    ``angle``, every sample's): the silhouette the samples show, infinite on a side past which
    ``_ROUND_GOES_ON`` or more samples go on (onto the support a lying round touches), which
    shows no silhouette: only the fit's counts there."""
    first, last = float(on_round.min()), float(on_round.max())
    if np.count_nonzero(angle < first) >= _ROUND_GOES_ON:
        first = -math.inf
    if np.count_nonzero(angle > last) >= _ROUND_GOES_ON:
        last = math.inf
    return first, last


def _outermost_samples(
    lines: list[LineModels], angle: np.ndarray, on: np.ndarray
) -> list[tuple[LineModels, int]]:
    """The line and the index on it of the samples among ``on`` (indices into the lines'
    points laid end to end, as ``angle`` is) at the smallest and at the largest ``angle``
    about a round's axis: where its two rims would be."""
    sizes = [len(ln.points) for ln in lines]
    owner = np.repeat(np.arange(len(lines)), sizes)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    found = []
    for i in (int(on[np.argmin(angle[on])]), int(on[np.argmax(angle[on])])):
        found.append((lines[int(owner[i])], i - int(offsets[owner[i]])))
    return found


def _fattened_rims(
    lines: list[LineModels], angle: np.ndarray, residuals: np.ndarray, params: LaserParams
) -> bool:
    """Whether the round's two outermost samples (by ``angle``, among those within four inlier
    bands) each end their segment in a plateau of three or more samples within the depth
    quantum (``_end_plateaus``, as ``_fattened`` reads a segment's end): a round's depth changes
    fastest at its silhouette, so the samples reached both rims and a matcher's window carried
    the rim's depth past them, as it pulled the arc inside them toward the camera."""
    on = (residuals <= 4 * params.solid_threshold_m).nonzero()[0]
    if len(on) == 0:
        return False
    for ln, k in _outermost_samples(lines, angle, on):
        if k not in (0, len(ln.points) - 1):
            return False  # the segment goes on past the round: no rim there
        if abs(_end_plateaus(ln)[0 if k == 0 else 1] - k) < 2:
            return False
    return True


# How far from the axis, in radii, the plane behind a round's two rims may lie for the round
# to rest on it: the table behind the rotation suite's lying cylinders lay 0.74-1.10 radii
# from their whole-arc fits' axes on SGBM 5-9 (the fit's own radius error moves it).
_REST_BEHIND_RADII = (0.7, 1.35)
# How far behind each rim, in diameters, a support the round rests on may show: a rim stands
# at most a diameter above it, and a slanting view adds (0.5-1.10 on the rotation suite's
# cylinders). Where the plane through both rims' depths happened to pass a radius from the
# axis of a round not lying down, the room lay further behind one rim: 6.3 diameters behind
# the 60 mm can's at SGBM 9, 84 behind the tilted 50 mm bottle's at SGBM 5.
_REST_BEHIND_DIAMETERS = 1.25


def _rests_behind_rims(
    lines: list[LineModels],
    full: CylinderSolid,
    angle: np.ndarray,
    residuals: np.ndarray,
    params: LaserParams,
    pixel_rad: float,
    scan_lines: ScanLinesLike | None,
) -> bool:
    """Whether the round rests on a surface seen right behind both its outermost samples (by
    ``angle``, among those within four inlier bands): the plane through the depth behind each
    (the line's own samples past the segment within ``background_reach_px``, else the scans'
    ``past_ends_m``, taken along the outermost sample's ray), each within
    ``_REST_BEHIND_DIAMETERS`` of ``full``'s diameter, and along ``full``'s axis lies
    ``_REST_BEHIND_RADII`` of its radius from the axis.

    A round lying on the table seen from above has the table a radius below its axis behind
    both rims, whether or not enough of it shows beside the round for ``_support_plane`` to
    fit it (the rotation suite's 75 mm cylinder fills most of the lines). A matcher's samples
    stop short of such rims (see ``_occluding_rims``) rather than fattening past them with
    the whole arc's fit, and a refit inside them trades the radius against the centre's depth
    on what is left (the 75 mm cylinder at SGBM 7: 66 mm on two frames). A round not lying
    down has the room or the table further behind at least one rim on most frames; the 60 mm
    can at SGBM 9 had both about a diameter behind on two, where the silhouette's bound
    (``_silhouette_bound``) gives its width either way."""
    past = getattr(scan_lines, "past_ends_m", None)
    if past is None:
        return False
    reach = params.background_reach_px * pixel_rad
    on = np.flatnonzero(residuals <= 4 * params.solid_threshold_m)
    if len(on) == 0:
        return False
    behind = []
    for ln, k in _outermost_samples(lines, angle, on):
        last = len(ln.points) - 1
        if k not in (0, last):
            return False  # the segment goes on past the round: no rim there
        rim = ln.points[k]
        side = 0 if k == 0 else 1
        c, s_ = math.cos(ln.angle), math.sin(ln.angle)
        beyond = ln.beyond[side] if ln.beyond else _NO_POINTS
        depth = 0.0
        if len(beyond):
            b = (beyond[:, 0] * c + beyond[:, 1] * s_) / beyond[:, 2]
            near = np.abs(b - (rim[0] * c + rim[1] * s_) / rim[2]) <= reach
            if near.any():
                depth = float(np.median(beyond[near, 2]))
        elif ln.index < len(past):
            depth = float(past[ln.index][side])
        if not 0.0 < depth - rim[2] <= _REST_BEHIND_DIAMETERS * 2 * full.radius:
            return False  # nothing seen behind this rim, or the room far behind it
        behind.append(rim * (depth / rim[2]))
    normal = np.cross(full.axis, behind[0] - behind[1])
    norm = float(np.linalg.norm(normal))
    if norm < 1e-9:
        return False
    distance = abs(float((full.point - behind[0]) @ normal)) / norm
    lo, hi = _REST_BEHIND_RADII
    return lo * full.radius <= distance <= hi * full.radius


# How far (pixels) the fit on every inlier's silhouette must lie beyond the samples on both
# sides for the samples' own silhouette to bound its width.
_FLAT_FIT_PX = 2.0


def _flat_fit(full: CylinderSolid, first: float, last: float, pixel_rad: float) -> bool:
    """Whether ``full``'s silhouette lies ``_FLAT_FIT_PX`` or more beyond the samples on both
    sides, ``first`` and ``last`` their extreme view angles across its axis (``_across_view``;
    infinite on a side whose segments go on, which shows no silhouette)."""
    view = _axis_in_view(full)
    if view is None or not (math.isfinite(first) and math.isfinite(last)):
        return False
    half = view[1]
    return min(first + half, half - last) >= _FLAT_FIT_PX * pixel_rad


def _axis_in_view(solid: CylinderSolid) -> tuple[float, float] | None:
    """The distance from the camera to ``solid``'s axis and the half-angle its silhouette
    subtends across the axis; ``None`` where the camera lies within the round."""
    foot = solid.point - float(solid.point @ solid.axis) * solid.axis
    distance = math.sqrt(float(foot @ foot))
    if distance <= solid.radius:
        return None
    return distance, math.asin(solid.radius / distance)


# The samples at a segment's end that must step one pixel at a time for it to end at a rim.
_RIM_SAMPLES = 6


def _silhouette_bound(
    lines: list[LineModels],
    full: CylinderSolid,
    params: LaserParams,
    pixel_rad: float,
    scan_lines: ScanLinesLike | None,
    seen: _SeenRound | None = None,
) -> float | None:
    """The width of the cylinder along ``full``'s axis whose silhouette is the samples' own
    (the extremes of their view angles across the axis) and whose front meets the samples
    between them, at least ``rim_bias_px`` inside; ``None`` unless ``full``'s silhouette lies
    ``_FLAT_FIT_PX`` or more beyond the samples on both sides and the scan lines' residuals
    are correlated like SGBM's (``scans.residual_correlation`` at least
    ``window_correlation_gate``).

    An SGBM window pulls a round's flanks toward the camera as far as a window or more inside
    its silhouette (1.5-2.5 mm within 6 px at block 9), so the whole arc's fit comes out too
    flat: 8-28 mm too wide on the 60 mm can at SGBM 9 and BM 9, whose rims then lie on it
    (``_rim_free`` finds no bow) while its silhouette lies 2-12 px beyond the samples on each
    side. Where the rims are occluding edges before a far background (``_occluding_rims``),
    SGBM's samples reach the true silhouette or pass it (0-3 px), so their extent bounds the
    width: the bound was within 3.6 mm of the truth on every such upright can at SGBM 5-9.
    Not BM's samples, whose rims end in holes 5-14 px inside (their extent 5-18 mm narrow),
    nor lpc's noise model's (samples within 1.4 px of the fit's silhouette, residuals
    uncorrelated)."""
    margin = params.rim_bias_px * pixel_rad
    if margin <= 0 or scan_lines is None or params.window_correlation_gate <= 0:
        return None
    # The cross-section's frame in plain floats: np.cross and np.linalg.norm on 3-vectors
    # cost more than this whole check on a frame it does not apply to.
    ax, ay, az = full.axis.tolist()
    px, py, pz = full.point.tolist()
    along = px * ax + py * ay + pz * az
    fx, fy, fz = px - along * ax, py - along * ay, pz - along * az
    distance = math.sqrt(fx * fx + fy * fy + fz * fz)
    if distance <= full.radius:
        return None
    towards = np.array([fx, fy, fz]) / distance
    tx, ty, tz = towards.tolist()
    side = np.array([ay * tz - az * ty, az * tx - ax * tz, ax * ty - ay * tx])
    seen = seen or _seen_round(lines, full)
    samples = seen.points
    x, y = samples @ towards, samples @ side
    angle = np.arctan2(y, x)
    residuals = seen.residuals
    on_round = angle.compress(residuals <= 4 * params.solid_threshold_m)
    if len(on_round) == 0:
        return None
    first, last = float(on_round.min()), float(on_round.max())
    if (
        np.count_nonzero(angle < first) >= _ROUND_GOES_ON
        or np.count_nonzero(angle > last) >= _ROUND_GOES_ON
    ):
        return None  # a side whose segments go on (onto the support) shows no silhouette
    half = math.asin(full.radius / distance)
    if min(first + half, half - last) < _FLAT_FIT_PX * pixel_rad:
        return None
    if _matched(scan_lines, params) is None:
        return None
    inset = np.minimum(angle - first, last - angle)
    front = (residuals <= 2 * params.solid_threshold_m) & (inset >= margin)
    if np.count_nonzero(front) < params.min_points_per_line:
        return None
    # The axis's distance D in the cross-section, with the radius D sin(half extent): one
    # Gauss-Newton fit of the front samples' distances from the centre to that radius.
    centre = 0.5 * (first + last)
    u = np.array([math.cos(centre), math.sin(centre)])
    sine = math.sin(0.5 * (last - first))
    q = np.stack([x.compress(front), y.compress(front)], axis=1)
    for _ in range(5):
        d = q - distance * u
        norm = np.sqrt(np.einsum("ij,ij->i", d, d))
        f = norm - distance * sine
        jac = -(d @ u) / norm - sine
        distance -= float(jac @ f) / float(jac @ jac)
    width = 2 * distance * sine
    lo, hi = params.radius_limits_m
    if not (math.isfinite(width) and 2 * lo <= width <= 2 * hi):
        return None
    if not _occluding_rims(lines, angle, residuals, params, pixel_rad, scan_lines, width):
        return None
    return width


def _background_bound(
    lines: list[LineModels],
    solid: CylinderSolid,
    full: CylinderSolid,
    params: LaserParams,
    pixel_rad: float,
    scan_lines: ScanLinesLike | None,
    seen: _SeenRound | None = None,
) -> float | None:
    """The width of ``solid`` (along its axis, about its centre) whose silhouette lies at
    most a pixel past the first background seen past either of the round's outermost
    samples (by their view angles across its axis, among those within four inlier bands of
    ``full``, the fit on every inlier); ``None`` where ``solid``'s silhouette lies within
    that on both sides, or no background shows past them.

    The background past a segment's end is the first of the line's own samples beyond it,
    else the scans' ``far_past_m`` (the first pixel past the line whose depth lies beyond the
    capture volume), that lies more than ``full``'s diameter behind the end: no surface of
    the round can (as ``_smeared_past`` reads a far background). A matcher fattens an edge
    outward over the background or leaves a hole beside it; it does not give the far
    background's depth to a pixel whose window the round fills, so the round's silhouette
    lies before that pixel, whatever its window, its smoothness or which side it occludes.
    The pixel: its depth stands for its whole footprint. A fit the window flattened can lie
    far beyond it where the rims do not bow out of it and the samples stop short of the
    silhouette in holes, which neither ``_rim_free`` nor ``_silhouette_bound`` trims (the
    60 mm can under BM 7-9 and SGBM 11: 11-20 mm wide, its silhouette 4-10 px past the
    background on one side). Under lpc's noise model the background shows within half a
    pixel of the silhouette, and the fit's silhouette within it.

    Other segments' ends near a rim (``_near_rim_ends``) bound it too, with the slack that gives
    (``_NEAR_RIM_SLACK_PX`` past a plateau): a cylinder's silhouette lies at one view angle
    across its axis all along it, so every line crossing a rim meets it there, and where the
    outermost sample lies in a window's fattening another line may show the background nearer
    (the 50 mm bottle tilted right: samples 3.3 px past the true silhouette on each side,
    median). Not a pixel past: on the side that faces the second imager (+x), where the
    background beside the round is seen by both and matched, a window may give the rim's last
    pixels its depth, and that background lay up to 3 px inside the true silhouette (p1 of such
    ends, stereo sweep; lpc's noise model 1.1 px); on the occluded side it lay 10 or more pixels
    past.
    """
    far = getattr(scan_lines, "far_past_m", None)
    seen = seen or _seen_round(lines, full)
    samples = seen.points
    # The view angles depend on the axis alone: full's where solid keeps it (trims change radii).
    aligned = solid.point is full.point and solid.axis is full.axis
    angle = seen.angle if aligned else _across_view(solid, samples)
    if angle is None:
        return None
    on = (seen.residuals <= 4 * params.solid_threshold_m).nonzero()[0]
    if len(on) == 0:
        return None
    view = _axis_in_view(solid)
    if view is None:
        return None
    distance, half = view
    limit = half
    outermost = _outermost_samples(lines, angle, on)
    ends = [(sign, ln, k, pixel_rad) for sign, (ln, k) in zip((-1.0, 1.0), outermost, strict=True)]
    ends += _near_rim_ends(lines, samples, angle, on, full, outermost, pixel_rad)
    for sign, ln, k, allowance in ends:
        last = len(ln.points) - 1
        if k not in (0, last):
            continue  # the segment goes on past the round: no rim there
        side = 0 if k == 0 else 1
        end = ln.points[k]
        deeper = float(end[2]) + 2 * full.radius
        beyond = ln.beyond[side] if ln.beyond else _NO_POINTS
        behind = (beyond[:, 2] > deeper).nonzero()[0]
        if len(behind):
            # The line's samples run outward from the segment: back from its first end.
            seen = beyond[behind[-1] if side == 0 else behind[0]]
        elif far is not None and ln.index < len(far) and far[ln.index][side][2] > deeper:
            seen = far[ln.index][side]
        else:
            continue
        past, at = sign * _across_view(solid, np.stack([seen, end]))
        if past > at:
            limit = min(limit, float(past) + allowance)
    if limit >= half:
        return None
    return 2 * distance * math.sin(limit)


# How far inside a round's outermost sample on a side (pixels across its axis) another
# segment's end still meets that rim: twice the band a matcher bows a rim out by.
_NEAR_RIM_PX = 2 * _RIM_PX
# How far past the background seen beyond such an end the silhouette may lie (pixels).
_NEAR_RIM_SLACK_PX = 2.0


def _near_rim_ends(
    lines: list[LineModels],
    samples: np.ndarray,
    angle: np.ndarray,
    on: np.ndarray,
    full: CylinderSolid,
    outermost: list[tuple[LineModels, int]],
    pixel_rad: float,
) -> list[tuple[float, LineModels, int, float]]:
    """The side (-1 or +1 by ``angle``, the view angles across the axis of ``samples``, the
    lines' points laid end to end), line and index of every segment end among ``on`` (the
    samples on the round) but the ``outermost`` two within ``_NEAR_RIM_PX`` of its side's
    outermost sample, on a side whose outermost sample ends its segment in a matcher's
    fattening (``_fattened_end``: a plateau, then the rim) or a window's smoothing
    (``_smoothed_rim``: no rim's rise), and not at either of the round's ends along its
    axis: within ``_RIM_PX`` (of the end's pixel footprint) of the farthest sample on the
    round along ``full``'s axis; with the slack (radians) past the background seen beyond
    it that the silhouette may lie: ``_NEAR_RIM_SLACK_PX`` on a fattened side, ``_RIM_PX``
    on a smoothed one, where on other lines the background may reach the rim band's last
    pixels (the 75 mm jar tilted left, proj35 and base55: 3-7 px inside the fit's
    silhouette, the width 3.4-5.3 mm narrow at 2 px).

    Where the outermost sample ends at the rim itself, the background past it bounds the
    silhouette already, and other lines' ends a few pixels in belong to an object only
    roughly a cylinder as often (lpc's noise model, which fattens nothing: the horse toy
    49-55 mm cut to 40-50, the banana 38.1 -> 36.9 mm).

    A line that leaves the round over its end (an upright can's top rim) ends inside the
    silhouette, a few pixels in where it leaves near a side, and the background past it says
    nothing of the width (lpc's noise model: such ends 7-15 px inside, which cut the 60 mm
    can to 44-56 mm); every sample on the top rim lies at the round's end along its axis."""
    if len(on) == 0:
        return []
    sizes = [len(ln.points) for ln in lines]
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    on_round = np.zeros(len(angle), dtype=bool)
    on_round[on] = True
    edge = {-1.0: float(angle[on].min()), 1.0: float(angle[on].max())}
    slack = {}
    for sign, (ln, k) in zip((-1.0, 1.0), outermost, strict=True):
        last = len(ln.points) - 1
        if k in (0, last) and _fattened_end(ln, 0 if k == 0 else 1) != k:
            slack[sign] = _NEAR_RIM_SLACK_PX * pixel_rad
        elif k in (0, last) and _smoothed_rim(ln, k, full, pixel_rad):
            # A window that smoothed the rim mixed it with the background both ways: on
            # other lines the background's depth may reach the rim band's last pixels.
            slack[sign] = _RIM_PX * pixel_rad
        else:
            del edge[sign]  # that side's outermost sample ends at the rim, or the round goes on
    if not edge:
        return []
    along = samples @ full.axis
    lowest, highest = float(along[on].min()), float(along[on].max())
    found = []
    for ln, start in zip(lines, starts.tolist(), strict=True):
        for k in (0, len(ln.points) - 1):
            i = start + k
            if not on_round[i] or any(o is ln and j == k for o, j in outermost):
                continue
            sign = 1.0 if angle[i] > 0 else -1.0
            if sign not in edge or sign * (edge[sign] - angle[i]) > _NEAR_RIM_PX * pixel_rad:
                continue
            footprint = _RIM_PX * pixel_rad * float(ln.points[k][2])
            if not lowest + footprint < along[i] < highest - footprint:
                continue  # over the round's end
            found.append((sign, ln, k, slack[sign]))
    return found


# The least fraction of a round rim's rise over its first _RIM_PX inward that a segment's end
# reached by no window shows: a rim is reached within a pixel or two of its silhouette.
_SMOOTHED_RIM = 1 / 3


def _smoothed_rim(ln: LineModels, k: int, full: CylinderSolid, pixel_rad: float) -> bool:
    """Whether the segment of ``ln`` that ends at sample ``k`` comes nearer the camera over
    its samples within ``_RIM_PX`` across ``full``'s axis inward of the end by less than
    ``_SMOOTHED_RIM`` of what a round of ``full``'s radius whose silhouette lay at the end
    would: a round's depth changes fastest at its silhouette (the square root of the inset),
    and only a matcher's window flattens that into a slow ramp or carries the rim's depth out
    past it in a smear longer than the rim behind it shows (``_fattened_end`` reads a plateau
    that a rim then follows): the 60 mm can at SGBM 11, its depth within a millimetre over
    eight samples where the rim rises 15 mm over four pixels.

    Under lpc's noise model, with no window, every outermost sample on the functional
    cylinders came 0.48 or more of that nearer (p5; a rim reached a pixel or two inside its
    silhouette rises less than one reached at it); under SGBM 7-9, P1 and P2 x 2 and cvsample
    0.12-0.18 at the median."""
    view = _axis_in_view(full)
    last = len(ln.points) - 1
    if view is None or last < 1:
        return False
    distance, half = view
    inward = 1 if k == 0 else -1
    run = ln.points[k::inward] if inward == 1 else ln.points[k::-1]
    angle = _across_view(full, run)
    if angle is None:
        return False
    inset = np.abs(angle - angle[0])
    within = (inset <= _RIM_PX * pixel_rad).nonzero()[0]
    j = int(within[-1])
    if inset[j] < 0.5 * _RIM_PX * pixel_rad:
        return False  # the line runs along the axis there: no rim profile across it
    across = run.take((0, j), axis=0)
    # Two samples: their parts across the axis and lengths in Python floats, as numpy forms
    # them (the products, the differences, einsum's (x^2 + z^2) + y^2 and the root).
    ax, ay, az = full.axis.tolist()
    reach = []
    for (x, y, z), t in zip(across.tolist(), (across @ full.axis).tolist(), strict=True):
        qx, qy, qz = x - t * ax, y - t * ay, z - t * az
        reach.append(math.sqrt(qx * qx + qz * qz + qy * qy))
    seen = reach[0] - reach[1]
    ray = half - float(inset[j])
    chord = full.radius**2 - (distance * math.sin(ray)) ** 2
    if chord <= 0:
        return False
    rise = distance * math.cos(half) - (distance * math.cos(ray) - math.sqrt(chord))
    return seen < _SMOOTHED_RIM * rise


def _occluding_rims(
    lines: list[LineModels],
    angle: np.ndarray,
    residuals: np.ndarray,
    params: LaserParams,
    pixel_rad: float,
    scan_lines: ScanLinesLike,
    width: float,
) -> bool:
    """Whether the round's two outermost samples (by ``angle``, among those within four inlier
    bands) each end their segment at an occluding edge before a far background: the
    segment's last ``_RIM_SAMPLES`` samples there step one pixel at a time (no hole: BM
    loses a round's rims to holes and its samples stop 5-14 px inside the silhouette), and
    what lies behind the end (the line's own samples past the segment within
    ``background_reach_px``, else the scans' ``past_ends_m``) lies further behind it than
    ``width`` (the round's diameter), or nothing does.

    A support the round lies on is within about its radius behind its rims seen from above,
    and there its samples stopped 2-7 px short of the rims (the rotation suite's 40 and 75 mm
    cylinders: the surface behind the outermost samples 0.67-0.94 of the bound's diameter
    further, the bound 3-13 mm narrow), as they do beside a hole; the room or the table
    behind an upright can lay 1.3-1.5 diameters further (or out of range), its rims
    fattened outward, and the bound was within 3.6 mm of the truth."""
    past = getattr(scan_lines, "past_ends_m", None)
    if past is None:
        return False
    past = np.asarray(past, dtype=np.float64)
    reach = params.background_reach_px * pixel_rad
    hw = params.capture_half_width_m
    zlo, zhi = params.capture_z_m
    on = np.flatnonzero(residuals <= 4 * params.solid_threshold_m)
    if len(on) == 0:
        return False  # no sample on the round: no rims to read
    for ln, k in _outermost_samples(lines, angle, on):
        last = len(ln.points) - 1
        if k not in (0, last) or ln.step <= 0 or last < _RIM_SAMPLES:
            return False
        x, y, z = ln.points[k].tolist()
        if (
            max(abs(x), abs(y)) >= hw - params.crop_margin_m
            or z <= zlo + params.crop_margin_m
            or z >= zhi - params.crop_margin_m
        ):
            return False  # the capture volume's edge, not the round's
        side = 0 if k == 0 else 1
        c, s_ = math.cos(ln.angle), math.sin(ln.angle)
        along = ln.points.take(
            np.arange(_RIM_SAMPLES + 1) if side == 0 else np.arange(last - _RIM_SAMPLES, last + 1),
            axis=0,
        )
        q = (along[:, 0] * c + along[:, 1] * s_) / along[:, 2]
        if float(np.abs(np.diff(q)).max()) > 1.5 * ln.step:
            return False
        beyond = ln.beyond[side] if ln.beyond else _NO_POINTS
        behind = 0.0
        if len(beyond):
            b = (beyond[:, 0] * c + beyond[:, 1] * s_) / beyond[:, 2]
            near = np.abs(b - (x * c + y * s_) / z) <= reach
            if not near.any():
                return False  # a hole beside the rim: the samples may stop short of it
            behind = float(np.median(beyond[near, 2]))
        elif ln.index < len(past):
            behind = float(past[ln.index][side])
        if behind != 0.0 and behind - z < width:
            return False
    return True


def _narrower_than_runs(solid: CylinderSolid, clean: np.ndarray, pixel_rad: float) -> bool:
    """Whether ``solid`` is narrower than the runs ``clean`` span across its axis, less the
    rims a matcher may fatten past the silhouette (``_RIM_PX`` on each side): no cylinder
    that the runs lie on can be."""
    allowance = 2 * _RIM_PX * pixel_rad * float(np.median(clean[:, 2]))
    return 2 * solid.radius < _span_across(solid, clean) - allowance


def _without_end_plateaus(
    lines: list[LineModels],
    full: SphereSolid | CylinderSolid,
    solid: SphereSolid | CylinderSolid,
    params: LaserParams,
    clean: np.ndarray,
) -> SphereSolid | CylinderSolid:
    """``solid``, or the round refitted without the plateaus that end the lines' segments
    (``_plateau_free``) when that one is narrower by more than ``silhouette_tolerance_m``, or
    a ball whose lines reach its silhouette narrower by more than its width's standard
    deviation (twice ``_radius_sd``, on its inliers among ``clean``).

    A ball's fit on its whole cap is pinned far closer than a cylinder's on its arcs: its
    width's SD was 0.4-0.7 mm on the sweep's 70 mm ball (150-230 samples), and refits 0.5-1.0
    mm narrower without the plateaus were their widening, not the noise; such a ball kept the
    fit with them, 2-5 mm wide, on most SGBM 7-9 and BM 9 frames. A matcher fattens a ball
    only past its silhouette, where its surface turns away from the camera (the median of
    the lines' run ends faces it below ``_RIM_FACING``: 0.42-0.59 on that ball); where the
    ends still face the camera the rim was lost, and a plateau there is the depth quantum on
    the cap, whose refit trades its radius against its centre's depth (a 40 mm ball's cap
    within 0.6 of its radius: 0.75-0.77, a refit 1.4 mm narrower, 1.4 SD). On lpc's noise
    model, which has no matcher to fatten the silhouette, the refits were within 0.1 mm.
    """
    refit = _plateau_free(lines, full, params)
    if refit is None:
        return solid
    narrower = 2 * (solid.radius - refit.radius)
    tolerance = params.silhouette_tolerance_m
    # The ball's SD can only lower the tolerance to zero or more: it decides only a refit
    # narrower by at most silhouette_tolerance_m, and it is worked out only for those.
    if (
        0 < narrower <= tolerance
        and isinstance(full, SphereSolid)
        and _ends_facing(lines, full) < _RIM_FACING
    ):
        inliers = clean.compress(full.residuals(clean) <= params.solid_threshold_m, axis=0)
        if len(inliers) > 4:
            tolerance = min(tolerance, 2 * _radius_sd(full, inliers))
    if narrower <= tolerance:
        return solid
    if isinstance(solid, CylinderSolid):
        # As in _camera_facing: the rims shift the radius, hardly the axis.
        return replace(solid, radius=refit.radius)
    return refit


def _ends_facing(lines: list[LineModels], ball: SphereSolid) -> float:
    """The median, over the lines' run ends, of the cosine between ``ball``'s surface normal
    there and the line of sight: near 0 at its silhouette, 1 where it faces the camera."""
    ends = np.concatenate([ln.points.take((ln.run[0], ln.run[-1]), axis=0) for ln in lines])
    normal = (ends - ball.center) / ball.radius
    facing = np.abs(np.einsum("ij,ij->i", normal, ends)) / np.linalg.norm(ends, axis=1)
    return float(np.median(facing))


def _fattened(lines: list[LineModels]) -> bool:
    """Whether at least ``_FATTENED_ENDS`` of the lines' segment ends show a matcher's
    fattening: a plateau of three or more samples within the depth quantum
    (``_plateau_end``), then a rim: the surface comes nearer by two quanta or more over as
    many samples again inward. A matcher fattens all round an object (1.5-3 px at the median
    end for block 5-9, SGBM and BM); lpc's noise model has no matching window, and a ball
    whose rim is lost ends in a shallow cap (1-2 mm over as many samples: no rim).

    A ball's width then comes from the fit on every inlier but the plateaus
    (``_plateau_free``), not from the camera-facing cap: under a matcher's correlated depth
    errors (SGBM's pixel-locked staircase terraces a 40 mm ball's visible 20 mm of depth into
    four or five disparity levels) a sphere fitted to the cap alone trades its radius against
    its centre's depth, and its width scattered by 10 mm about the truth (31-54 mm for 40 mm,
    SGBM 7), while the points' median radial error is under 0.5 mm."""
    count = 0
    for ln in lines:
        last = len(ln.sz) - 1
        count += (_fattened_end(ln, 0) != 0) + (_fattened_end(ln, 1) != last)
    return count >= _FATTENED_ENDS


def _end_plateaus(ln: LineModels) -> tuple[int, int]:
    """``_plateau_end`` within ``_END_PLATEAU_M`` from the first and from the last sample of
    ``ln``'s segment, read once a segment: the round rules ask for them up to four times."""
    cached = ln._end_plateaus
    if cached is not None and cached[0] is ln.sz:
        return cached[1]
    z = ln.sz[:, 1]
    ends = (_plateau_end(z, 0, 1, _END_PLATEAU_M), _plateau_end(z, len(z) - 1, -1, _END_PLATEAU_M))
    ln._end_plateaus = (ln.sz, ends)
    return ends


def _fattened_end(ln: LineModels, side: int) -> int:
    """The last sample of the plateau that ends ``ln``'s segment at its first (``side`` 0)
    or last (1) sample where that end shows a matcher's fattening, else that end: three or
    more samples within the depth quantum (``_end_plateaus``), then a rim, the surface nearer
    by two quanta or more over as many samples again inward."""
    z = ln.sz[:, 1]
    end, inward = (len(z) - 1, -1) if side else (0, 1)
    j = _end_plateaus(ln)[side]
    span = abs(j - end)
    k = j + inward * span
    # Python floats (``item``): the same difference as numpy's scalars, at half the cost.
    if span >= 2 and 0 <= k < len(z) and z.item(j) - z.item(k) >= 2 * _END_PLATEAU_M:
        return j
    return end


def _fattened_samples(lines: list[LineModels]) -> np.ndarray:
    """Whether each of the lines' samples (laid end to end) lies in a plateau that ends its
    segment and shows a matcher's fattening (``_fattened_end``)."""
    marks = []
    for ln in lines:
        mark = np.zeros(len(ln.sz), dtype=bool)
        for side, end in enumerate((0, len(ln.sz) - 1)):
            j = _fattened_end(ln, side)
            if j != end:
                mark[min(j, end) : max(j, end) + 1] = True
        marks.append(mark)
    return np.concatenate(marks)


def _plateau_free(
    lines: list[LineModels], full: SphereSolid | CylinderSolid, params: LaserParams
) -> SphereSolid | CylinderSolid | None:
    """The round refitted without the plateaus that end the lines' segments, or None when no
    segment ends in one (or the refit fails or leaves the radius limits).

    A round's depth changes fastest at its silhouette, so two or more samples within a depth
    quantum of a segment's end are no rim but a matcher's fattening: background given the
    edge's depth, beyond the silhouette, where they widen every fit (and the silhouette that
    ``_camera_facing`` trims against). The refit takes the points within three inlier bands
    of the fit on every inlier (``full``), once (a second pass changed the widths by 0.2 mm at
    most, on BM 7 cylinders, for another 0.25 ms).
    """
    kept = []
    trimmed = False
    for ln in lines:
        keep = np.zeros(len(ln.sz), dtype=bool)
        keep[ln.run] = True
        for end, j in zip((0, len(ln.sz) - 1), _end_plateaus(ln), strict=True):
            if j != end:
                keep[min(j, end) : max(j, end) + 1] = False
                trimmed = True
        kept.append(ln.points.compress(keep, axis=0))
    if not trimmed:
        return None
    points = np.concatenate(kept)
    near = points.compress(full.residuals(points) <= 3 * params.solid_threshold_m, axis=0)
    if len(near) < params.min_points_per_line:
        return None
    if isinstance(full, SphereSolid):
        refit = SphereSolid.estimate(near, init=(full.center, full.radius))
    else:
        refit = CylinderSolid.estimate(near, full.axis, iterations=2)
    lo, hi = params.radius_limits_m
    if not refit or not lo <= refit.radius <= hi:
        return None
    return refit


# A ball seen through a scan line spans its whole chord on the line (bar the rims a matcher
# or the table takes): a surface that covers less than this share of the fitted ball's chord
# on two lines or more is some other round (the jar cap seen from the front: a 15 mm band of a
# 60 mm cylinder, 0.25-0.51 on stereo; real balls 0.64-1.0 over the sweep's eight settings and
# lpc's noise model, the pear's lower bulb included).
_BALL_SPAN = 0.57
# Samples along each line's chord of the ball (the chord's angle in the scan plane).
_CHORD_SAMPLES = 48
_CHORD_STEPS = _read_only(np.linspace(-1.0, 1.0, _CHORD_SAMPLES))


def _short_of_ball(lines: list[LineModels], ball: SphereSolid, params: LaserParams) -> bool:
    """Whether the surface the lines see covers less than ``_BALL_SPAN`` of ``ball``'s visible
    chord on two lines or more: no ball then, whose outline the lines would cross whole.

    On each line the chord runs between the rays that graze the ball in the scan plane, and
    only the part whose front surface lies in the capture volume counts (the lines hold no
    other samples). The line covers it from its first to its last sample within three inlier
    bands of the ball (matchers' holes within a ball do not shorten it).
    """
    center, radius = ball.center, ball.radius
    cx, cy, cz = center.tolist()
    # Each line whose plane cuts the ball: (line, cos, sin, along, r, rho, the chord's middle
    # and half angle).
    chords = []
    for ln in lines:
        c, s = math.cos(ln.angle), math.sin(ln.angle)
        off = -s * cx + c * cy  # the centre's distance from the scan plane
        if abs(off) >= radius:
            continue
        r = math.sqrt(radius * radius - off * off)
        along = c * cx + s * cy
        rho = math.hypot(along, cz)
        if rho <= r:
            continue
        chords.append((ln, c, s, along, r, rho, math.atan2(along, cz), math.asin(r / rho)))
    if len(chords) < 2:
        return False
    # Every line's chord at once (numpy's per-call cost, not the arithmetic, is what a line
    # alone pays: this runs on every round a ball would win).
    table = np.array([chord[1:] for chord in chords])
    c, s, along, r, rho, mid, half = table.T[:, :, None]  # (L, 1) columns
    theta = mid + half * _CHORD_STEPS
    # The front surface on each ray of the chord: the nearer root of |k d - c'| = r.
    ray_s, ray_z = np.sin(theta), np.cos(theta)
    b = ray_s * along + ray_z * cz
    k = b - np.sqrt(np.maximum(b * b - (rho * rho - r * r), 0.0))
    hw = params.capture_half_width_m
    zlo, zhi = params.capture_z_m
    z = k * ray_z
    inside = (z >= zlo) & (z <= zhi) & (np.abs(k * ray_s * c) <= hw) & (np.abs(k * ray_s * s) <= hw)
    # Counted by add.reduce: count_nonzero along an axis goes through dtype checks in Python.
    wide = np.add.reduce(inside, axis=1)
    # Each line's samples within three inlier bands of the ball, as angles in its scan plane,
    # for all lines in one pass: the angles' extremes on each line (+inf/-inf where none lies
    # on the ball, so that no ray falls between them).
    points = [ln.points for ln, *_ in chords]
    p = np.concatenate(points)
    counts = [len(q) for q in points]
    on = ball.residuals(p) <= 3 * params.solid_threshold_m
    along_line = p[:, 0] * c[:, 0].repeat(counts) + p[:, 1] * s[:, 0].repeat(counts)
    angles = np.arctan2(along_line, p[:, 2])
    starts = list(itertools.accumulate(counts[:-1], initial=0))
    lo = np.minimum.reduceat(np.where(on, angles, np.inf), starts)
    hi = np.maximum.reduceat(np.where(on, angles, -np.inf), starts)
    seen = np.add.reduce((theta >= lo[:, None]) & (theta <= hi[:, None]) & inside, axis=1)
    short = 0
    for w, n_seen in zip(wide.tolist(), seen.tolist(), strict=True):
        if w < 2:
            continue
        short += n_seen < _BALL_SPAN * w
        if short >= 2:
            return True
    return False


def _ball_width(
    clean: np.ndarray,
    ball: SphereSolid,
    support: PlaneSolid | None,
    resting: float | None,
    params: LaserParams,
) -> float:
    """The ball's width: ``resting``, its contact refit on ``support`` (``_resting_width``),
    unless a sample of the lines' runs (``clean``) lies behind that plane by more than three
    inlier bands, else ``ball``'s own.

    A ball resting on a surface shows none of itself behind it; a plane that cuts through
    the ball is no support. Under a 3-way SGBM 7 with twice the shot noise (3way7-shot,
    the 70 mm ball, trial 0 frame 1) the search took a plane beside the ball's -x side for
    the table (its normal 73 degrees off the line of sight, the true ball 15.6 mm into it):
    5 of the 152 run samples lay 1.0-6.7 mm behind it, two of them 5.3 and 6.7, and the
    contact refit made the ball 19.7 mm narrow, its own fit 7.9 mm wide. Of the 441 other
    balls the sweep's 49 settings sized by a contact, none had a run sample behind its
    support (the nearest 0.8 mm in front of it). The pear's lower bulb met the same plane
    (SGBM 7 with P2 x 2, trial 1 frame 3: normal (-0.89, 0.44, -0.14), samples down to 11.6
    mm behind it, the contact refit 23.8 mm narrow, its own fit 2.4 mm wide); the pear's
    width MAE on the four settings where it did went 2.6-3.6 -> 1.1-2.1 mm."""
    if resting is None or support is None:
        return 2 * ball.radius
    heights = (clean - support.point) @ support.normal
    if float(heights.min()) < -3 * params.solid_threshold_m:
        return 2 * ball.radius
    return resting


# A line crosses a band from rim to rim where the ball's surface faces the camera at both
# ends of its samples on the ball (the cosine between the surface normal and the view ray):
# at a round's silhouette it turns away (the jar cap's horizontal line: 0.1-0.5).
_RIM_FACING = 0.6
# A line that crosses a band spans at least this share of the band's height (see _across_band).
_BAND_SPAN = 0.5


def _rim_axis(
    lines: list[LineModels],
    ball: SphereSolid,
    cylinder: _Candidate,
    clean: np.ndarray,
    params: LaserParams,
) -> CylinderSolid | None:
    """The cylinder of a band too short for a ball (``_short_of_ball``: a jar cap seen from
    the front), fitted across the axis its rims give; None when fewer than two lines cross
    the band from rim to rim, or the fit fails, leaves the radius limits or explains less
    than ``min_solid_fraction`` of the runs.

    A band 15-20 mm high pins no axis: its own cylinder fit turned the cap's 5-70 degrees
    about the view on stereo frames (and on lpc's noise model). Its rims do: circles across
    the axis, each line that crosses the band ends on both (``_RIM_FACING``). The ends are
    split between the rims so that each rim's ends lie on a line (the split whose ends
    scatter least across their rims' common direction), that direction runs along the rims,
    and the axis lies across it and across the band's surface normal (the ball's, at the
    band's middle)."""
    tol = 3 * params.solid_threshold_m
    center, radius = ball.center, ball.radius
    ends = []
    for ln in lines:
        p = ln.points
        on = np.flatnonzero(ball.residuals(p) <= tol)
        if len(on) < 2:
            continue
        pair = p.take((on[0], on[-1]), axis=0)
        normal = (pair - center) / radius
        facing = np.abs(np.einsum("ij,ij->i", normal, pair)) / np.linalg.norm(pair, axis=1)
        if facing.min() >= _RIM_FACING:
            ends.append(pair)
    if len(ends) < 2:
        return None
    inliers = clean.compress(cylinder.residuals <= params.solid_threshold_m, axis=0)
    if len(inliers) < params.min_points_per_line:
        return None
    middle = column_sums(inliers) / len(inliers) - center
    if len(ends) >= 3:
        ends = _across_band(ends, middle)
    axis = _across_rims(ends, middle)
    if axis is None:
        return None
    solid = CylinderSolid.estimate(inliers, axis, iterations=0)
    lo, hi = params.radius_limits_m
    if not solid or not lo <= solid.radius <= hi:
        return None
    if _fraction(solid.residuals(clean), params.solid_threshold_m) < params.min_solid_fraction:
        # The rims choose among the axes the band allows: one across which the runs are no
        # solid is no band's (the rotation suite's 40 mm cylinder at SGBM 7, a ball short on
        # its lines: 0.57 of the runs, against 0.98 on its own axis; the jar cap's 0.64-1.0).
        return None
    return solid


def _turned_about_view(axis: np.ndarray, outline: np.ndarray, view: np.ndarray) -> float:
    """The angle (radians, signed about ``view``, a unit ray) from ``outline`` to ``axis`` as
    the camera sees them (both projected across the ray), either way along each."""
    a = axis - (axis @ view) * view
    o = outline - (outline @ view) * view
    if a @ o < 0:
        a = -a
    return math.atan2(float(_cross(o, a) @ view), float(o @ a))


def _tapered_tilt(
    lines: list[LineModels], cylinder: _Candidate, clean: np.ndarray, params: LaserParams
) -> CylinderSolid | None:
    """The cylinder of a round that tapers along its axis, fitted across the axis between the
    two turns about the view its free fit may take; None where the fit takes one turn only.

    A line along a tapering round (the horse toy's ellipsoid torso, 130 mm long) bends away
    toward both ends. A cylinder bends it only by turning its axis about the view, so that
    the line cuts it obliquely, and turning either way bends it alike: the free fit took
    whichever turn its start and the noise favoured, 11-31 degrees either side of the truth
    (BM 5 and 9, trial 0, where the line along x runs along the torso; 8-16 on lpc's noise
    model). The outline's longest extent (the runs' ends, ``_seeds_axis``) is the round's own
    and turns with neither; a straight side Algorithm 1 finds on a bumpy round may not be
    (hh9-uneven, the sweet potato, trial 1 frame 0: 44 degrees off its fit, which was within
    4 of the truth, and the axis between them 43 off). A fit started from the mirror image
    of the free fit's turn about it that turns the other way, and explains the runs within
    ``cylinder_margin`` of the free fit, is the same taper's: the axis lies between the two.
    A true cylinder's fit turns back to its own axis from there (the functional cylinders
    under SGBM 7 and 9, BM 7 and HH 9 with uneven dots: none turned away)."""
    solid = cylinder.solid
    if solid is None:
        return None
    outline = _seeds_axis(lines, params, longest=True)
    if outline is None:
        return None
    view = solid.point / math.sqrt(float(solid.point @ solid.point))
    axis = solid.axis if solid.axis @ outline > 0 else -solid.axis
    turn = _turned_about_view(axis, outline, view)
    # Rodrigues' rotation of the axis by -2 turn about the view: its mirror image.
    c, s = math.cos(-2 * turn), math.sin(-2 * turn)
    mirror = axis * c + _cross(view, axis) * s + view * float(view @ axis) * (1 - c)
    other = CylinderSolid.estimate(clean, mirror, iterations=params.cylinder_iterations)
    if not other:
        return None
    back = other.axis if other.axis @ outline > 0 else -other.axis
    if turn * _turned_about_view(back, outline, view) >= 0:
        return None
    thr = params.solid_threshold_m
    if _fraction(other.residuals(clean), thr) < cylinder.score - params.cylinder_margin:
        return None
    between = axis + back
    between /= math.sqrt(float(between @ between))
    # A turn that moves the axis's ends over the runs by less than a pixel is none the lines
    # resolve (the live recording's 40 mm marker lying along x: both fits within 0.05 degrees
    # of the outline; the axis between them changed only the radius's circle fit, 0.16 mm).
    reach = float(np.ptp(clean @ axis)) / 2
    depth = float(column_sums(clean)[2]) / len(clean)
    if (
        reach * math.sqrt(max(0.0, 1.0 - float(axis @ between) ** 2))
        < _pixel_rad(lines, params) * depth
    ):
        return None
    inliers = clean.compress(cylinder.residuals <= thr, axis=0)
    if len(inliers) < params.min_points_per_line:
        return None
    tapered = CylinderSolid.estimate(inliers, between, iterations=0)
    lo, hi = params.radius_limits_m
    if not tapered or not lo <= tapered.radius <= hi:
        return None
    if _fraction(tapered.residuals(clean), thr) < params.min_solid_fraction:
        # The outline's longest extent runs across a round seen short (a tilted can, the jar
        # cap's band, the banana's bend: the axis between 83-89 degrees off, explaining 0.09-0.26
        # of the runs); the horse toy's explains 0.47-0.91 (the two below 0.6 keep their turn).
        return None
    return tapered


def _lying_disc(
    clean: np.ndarray,
    support: PlaneSolid,
    params: LaserParams,
    sizes: list[int] | None = None,
    scored: bool = False,
) -> tuple[CylinderSolid, float] | None:
    """The cylinder along ``support``'s normal whose runs ``clean`` stand lower above the
    support than its radius: a disc lying flat on it (a jar cap seen from the front), and the
    share of the runs it explains; or ``None``.

    Such a band shows 15-20 mm of a round 60 mm across: a cylinder fitted to it with a free
    axis finds one as well across it (the jar cap under SGBM 5-7: 26-31 mm wide cylinders
    lying along the band, 53-86 degrees off its axis, 0.70-0.89 of the runs). A disc stands
    on its flat face, so its axis is the support's normal; the circle across it is
    ``fit.fit_circle``'s RANSAC one (the runs hold samples of the top face and the table in
    front, which pull a least-squares circle to 13 mm on the cap's 30 mm arc), and must
    explain ``min_solid_fraction`` of the runs, within the radius limits, with the camera
    outside it. A round lying on its side stands its diameter high, a ball too: neither is
    a disc. ``sizes``, the runs' lengths in ``clean``, let the band's lower rim that a
    matcher smeared behind the table lie below it (``_smeared_below``). ``scored``: the
    circles through three samples are scored as discs instead, for a support whose RANSAC
    circle made none (the caller's unscored call returned ``None``)."""
    normal = support.normal
    d = clean - support.point
    height = d @ normal
    n = len(height)
    lo, hi = params.radius_limits_m
    thr = params.solid_threshold_m
    if n < 3:
        return None
    tallest = float(height.max())
    lowest = float(height.min())
    if lowest < -3 * thr and sizes is not None and _smeared_below(height, sizes, 3 * thr):
        lowest = -3 * thr  # the band's lower rim smeared down behind the table
    if abs(lowest) > 3 * thr or not 3 * thr < tallest < hi:
        # Not on the support, in it, or taller than any disc's radius: a disc's band reaches
        # down to the support it lies on (the cap's lowest samples 0.4 mm below the table to
        # 0.9 mm above it, 3.2 under a matcher's smear), and nothing lies below it; and it
        # stands off it (runs within 2.2 mm of a plane are that plane's: a box's face that
        # _DISC_SUPPORT's search took for the table, cuboid_tilt_left under SGBM 7). Most
        # rounds end here, before the circle is fitted.
        return None
    e1, e2 = orthonormal_basis(normal)
    uv = d @ np.column_stack([e1, e2])
    # The camera (the origin) sees the outside of the disc.
    camera = -support.point @ np.column_stack([e1, e2])
    shares = None
    if not scored:
        circle = fit.fit_circle(uv, thr, radius_limits=(lo, hi), seed=_support_rng())
        if circle:
            centres, radii = np.array([circle.center]), np.array([circle.radius])
            # Most of these circles are no disc by their radius or the camera's side alone
            # (254 of 262 on the recordings): their samples are not weighed.
            if _disc_possible(centres, radii, tallest, camera, params)[0]:
                shares = _disc_shares(uv, height, centres, radii, camera, params)
    else:
        # The RANSAC circle makes no disc where it explains too few of the runs as well as
        # none (HH SGBM 5, the jar cap from the front, trial 0 frame 0: a run on the table in
        # front, 16 of the 69 samples, left its 42 mm circle 0.48; a circle through three,
        # 0.61); the caller's unscored call on this support found that already.
        # The circle with most samples on it need not be the disc's: the top face's samples
        # near its front rim lie on a chord, on small circles with a band (the jar cap from
        # the front under blurrier optics and HH mode, trial 0 frame 0: 10.6 and 7.8 mm
        # circles through 35 and 41 samples, 16-20 mm under the top; the disc's own rim holds
        # 27 and 31, its top the chord's 29 and 31). The circles through three samples each
        # are scored as the disc is judged, its band and its top together.
        picks = _support_rng().integers(0, n, size=(_DISC_CIRCLE_TRIALS, 3))
        centres, radii = _circumcircles(uv.take(picks, axis=0))
        # Only the circles that can be a disc by their radius and the camera's side (953 of
        # 20,480 on the recordings): _disc_shares weighs each circle on its own and gives the
        # others no sample, so the best of these is the best of all (the first of the best,
        # as argmax takes), or none explains any sample and none is a disc.
        possible = _disc_possible(centres, radii, tallest, camera, params).nonzero()[0]
        if len(possible):
            centres, radii = centres.take(possible, axis=0), radii.take(possible)
            shares = _disc_shares(uv, height, centres, radii, camera, params, scored=True)
    if shares is None:
        return None
    best = int(np.argmax(shares.sum(axis=1)))
    fraction = np.count_nonzero(shares[best]) / n
    if fraction < params.min_solid_fraction:
        return None
    centre = centres[best]
    point = support.point + centre[0] * e1 + centre[1] * e2 + float(height.mean()) * normal
    return CylinderSolid(point=point, axis=normal.copy(), radius=float(radii[best])), fraction


# The circles _lying_disc scores as discs where the RANSAC circle makes none.
_DISC_CIRCLE_TRIALS = 256


def _circumcircles(triples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres ``(T, 2)`` and radii ``(T,)`` of the circles through each of ``triples``
    ``(T, 3, 2)``; collinear or repeated points give an infinite or NaN radius."""
    d = triples[:, 1:] - triples[:, :1]
    sq = np.einsum("tij,tij->ti", d, d)
    cross = 2.0 * (d[:, 0, 0] * d[:, 1, 1] - d[:, 0, 1] * d[:, 1, 0])
    with np.errstate(all="ignore"):
        ux = (d[:, 1, 1] * sq[:, 0] - d[:, 0, 1] * sq[:, 1]) / cross
        uy = (d[:, 0, 0] * sq[:, 1] - d[:, 1, 0] * sq[:, 0]) / cross
    return triples[:, 0] + np.column_stack([ux, uy]), np.hypot(ux, uy)


def _disc_possible(
    centres: np.ndarray, radii: np.ndarray, tallest: float, camera: np.ndarray,
    params: LaserParams,
) -> np.ndarray:  # fmt: skip
    """Which circles (``centres`` ``(T, 2)``, ``radii`` ``(T,)``) can be a disc's whose runs
    stand at most ``tallest`` above the support, before any sample is weighed: within the
    radius limits, taller than the runs (a round lying on its side stands its diameter
    high), and the camera outside them."""
    lo, hi = params.radius_limits_m
    with np.errstate(invalid="ignore"):
        ok = (lo <= radii) & (radii <= hi) & (tallest < radii)
        ok &= np.hypot(*(camera - centres).T) > radii
    return ok


def _disc_shares(
    uv: np.ndarray,
    height: np.ndarray,
    centres: np.ndarray,
    radii: np.ndarray,
    camera: np.ndarray,
    params: LaserParams,
    scored: bool = False,
) -> np.ndarray:
    """The samples (``uv`` in the support plane, ``height`` above it) that each disc with
    the circle of ``centres`` ``(T, 2)`` and ``radii`` ``(T,)`` explains, ``(T, N)``: on its
    band, or inside it at its top's height; none for a disc that cannot be the one seen.
    ``scored``: the circles are guesses through three samples, whose band must also end at
    the top's rim."""
    thr = params.solid_threshold_m
    rho = np.hypot(uv[:, 0] - centres[:, :1], uv[:, 1] - centres[:, 1:])
    ok = _disc_possible(centres, radii, float(height.max()), camera, params)
    with np.errstate(invalid="ignore"):
        explained = np.abs(rho - radii[:, None]) <= thr
        inside = rho < radii[:, None] - thr
    count = np.count_nonzero(inside, axis=1)
    rows = np.flatnonzero(ok & (count >= 3))
    top = np.full(len(radii), np.nan)
    top[rows] = _row_medians(height, inside[rows])
    with np.errstate(invalid="ignore"):
        on_top = inside & (np.abs(height - top[:, None]) <= thr)
    held = np.count_nonzero(on_top, axis=1)
    # The samples inside the circle are the disc's flat top, most of them at one height (else
    # they would lie inside the solid), and a disc seen from the front shows more of its band
    # than of its top (a round face seen from above is the face's own disc test's). A wall
    # beside the cap under SGBM 9 (trial 0 frame 0), taken for the table: its samples inside
    # the circle spread 13 mm in height. The lines run onto the top past the band's upper
    # rim (the cap from 20-25 degrees above: 0.2-0.4 of the runs).
    ok &= (count < 3) | ((2 * held >= count) & (held <= np.count_nonzero(explained, axis=1)))
    # Nothing of a disc lying on the table stands higher than its band and its top: samples
    # outside its circle that do are a taller solid's, whose side the circle follows (the
    # banana lying under HH SGBM 5, trial 1 frame 1: a circle 80 mm across on its side, its
    # band up to 35.5 mm above the table, and 7 samples beyond it 1.7-3.0 mm higher still,
    # the banana's crest; a disc 90 degrees off its axis). A few, as a segment goes on.
    rim = np.max(np.where(explained | inside, height, -np.inf), axis=1)
    with np.errstate(invalid="ignore"):
        above = (rho > radii[:, None] + thr) & (height > rim[:, None] + thr)
    ok &= np.count_nonzero(above, axis=1) < _ROUND_GOES_ON
    if not scored:
        return (explained | on_top) & ok[:, None]
    # The band ends at the top's rim: none of it stands higher. A round lying on its side or
    # a box's face holds a wide circle on samples far above the samples inside it (the 40 mm
    # cylinder lying under the OpenCV sample's smoothness, trial 1 frame 2: 43 mm against
    # 27; the box lying under 2x supersampling, trial 0 frame 1: 39 against 16; the jar cap,
    # 15.2-15.6 against 15.4-15.8).
    rim_top = np.max(np.where(explained, height, -np.inf), axis=1)
    with np.errstate(invalid="ignore"):
        ok &= (count < 3) | (top >= rim_top - 2 * thr)
    return (explained | on_top) & ok[:, None]


def _row_medians(values: np.ndarray, present: np.ndarray) -> np.ndarray:
    """The median of ``values`` (N,) where each row of ``present`` (R, N) is true, each row
    holding one or more: ``np.nanmedian`` of the rows with NaN elsewhere, the middle value
    or the middle two summed and halved as its masked sort's are, without its masked arrays
    (a tenth of its cost on a disc's one row). To the bit but for a zero's sign where -0.0
    and 0.0 tie in the middle (the sort may order them either way): no comparison sees it."""
    counts = np.count_nonzero(present, axis=1)
    ordered = np.sort(np.where(present, values, np.inf), axis=1)
    high = counts // 2
    low = np.where(counts % 2 == 1, high, high - 1)
    rows = np.arange(len(counts))
    return (ordered[rows, low] + ordered[rows, high]) / 2


# The planes _disc_on_plane_beside tries: the scan lines' support search's triples, the disc
# fitted on the three largest that lie 5 degrees or more apart.
_DISC_TABLE_TRIES = 3
_DISC_TABLE_APART_COS = math.cos(math.radians(5.0))


def _smeared_below(height: np.ndarray, sizes: list[int], depth: float) -> bool:
    """Whether the runs' samples more than ``depth`` below the table (``height``, the runs
    one after another, ``sizes`` long) are each a run's last or first samples, no more than
    ``_RIM_PX`` of them: the band's lower rim that a matcher smeared down behind the table
    (the jar cap from the front under SGBM 9 and the OpenCV sample's smoothness: one to
    five samples 5-9 mm below the table found within 2 degrees, at the ends of the lines
    crossing the band). A plane that cuts the solid leaves more, or some mid-run."""
    below = height < -depth
    start = 0
    for size in sizes:
        b = below[start : start + size]
        start += size
        k = int(np.count_nonzero(b))
        if k == 0:
            continue
        if k > _RIM_PX or not (b[:k].all() or b[size - k :].all()):
            return False
    return True


def _disc_on_plane_beside(
    lines: list[LineModels],
    clean: np.ndarray,
    params: LaserParams,
    sizes: list[int],
    beside: _Beside | bool | None = True,
    searched: Sequence[PlaneSolid] = (),
) -> tuple[CylinderSolid, float] | None:
    """The lying disc (``_lying_disc``) on a plane through samples beside the runs, where
    the support searches found none: of the planes through three such samples holding five
    samples or more on two lines, with the runs standing on them, the three holding most
    (5 degrees apart or more), and the disc among them that explains most of the runs.

    A face that won over a fitted cylinder: the jar cap from the front under SGBM 7 with
    uniqueness 5 and with half the signal (trial 0 frame 4: boxes 29 and 15 mm wide, 46
    and 76 degrees off), where both searches took a plane through the cap's top face and
    the table behind it (27 and 65 degrees off the table); the disc on the table's own
    plane holds 0.80-0.82 of the runs, within a degree of the truth. The guessed plane
    makes a richer solid: its disc must explain ``cylinder_margin`` more than
    ``min_solid_fraction`` (a hexagonal prism's side under BM 9, 0.60 against the face's
    0.94). ``beside``: ``_beside(lines)`` where the caller has it already: its planes are
    the support searches' (the same triples of the same samples from the same seed).
    ``searched``: planes whose disc ``_lying_disc`` found none already (the supports the
    searches found, which one of these planes may be to the bit: a fifth of the fits)."""
    if beside is True:
        beside = _beside(lines)
    if not isinstance(beside, _Beside) or beside.hypotheses is None:
        return None
    hypotheses = beside.hypotheses
    normals, offsets, valid = hypotheses.normals, hypotheses.offsets, hypotheses.valid
    height = -(clean @ normals + offsets)
    thr = params.solid_threshold_m
    lowest, tallest = height.min(axis=0), height.max(axis=0)
    stands = (lowest >= -3 * thr) & (tallest > 3 * thr) & (tallest < params.radius_limits_m[1])
    ok = valid & stands
    # The runs standing on a plane first: on a standing round none does (its runs stand
    # taller than any disc), and then the samples on the planes are not counted at all.
    if not ok.any():
        return None
    owner = np.repeat(beside.owners, beside.counts)
    # The searches' scores are every sample's distances unless they scored a sample.
    signed = hypotheses.signed if not hypotheses.sampled else beside.points @ normals + offsets
    on = np.abs(signed) <= _DISC_SUPPORT.support_threshold_m
    per_line = np.stack([on[owner == ln.index].sum(axis=0) for ln in lines])
    ok &= (per_line >= _DISC_SUPPORT_LINE_POINTS).sum(axis=0) >= 2
    if not ok.any():
        return None
    count = on.sum(axis=0)
    # A table guessed, not found: its disc must explain the runs by a richer solid's margin.
    need = params.min_solid_fraction + params.cylinder_margin
    best = None
    tried: list[np.ndarray] = []
    for k in np.argsort(np.where(ok, -count, 1)):
        if not ok[k] or len(tried) >= _DISC_TABLE_TRIES:
            break
        if any(abs(float(normals[:, k] @ t)) > _DISC_TABLE_APART_COS for t in tried):
            continue
        tried.append(normals[:, k])
        plane = PlaneSolid.estimate(beside.points.compress(on[:, k], axis=0))
        if not plane or any(_same_plane(plane, known) for known in searched):
            continue
        disc = _lying_disc(clean, plane, params, sizes)
        if disc is not None and disc[1] >= need and (best is None or disc[1] > best[1]):
            best = disc
    return best


def _across_rims(ends: list[np.ndarray], middle: np.ndarray) -> np.ndarray | None:
    """The axis (unit) across the rims that ``ends`` (each line's first and last sample on the
    band) lie on and across ``middle``, the band's surface normal; None when they are parallel.
    The ends are split between the rims so that each rim's ends lie on a line: the split whose
    ends scatter least across their rims' common direction, which runs along the rims."""
    best = None
    for flips in itertools.product((False, True), repeat=len(ends) - 1):
        sides = [ends[0], *(e[::-1] if f else e for e, f in zip(ends[1:], flips, strict=True))]
        first = np.array([e[0] for e in sides])
        second = np.array([e[1] for e in sides])
        spread = np.vstack([first - first.mean(axis=0), second - second.mean(axis=0)])
        values, vectors = np.linalg.eigh(spread.T @ spread)
        if best is None or values[:2].sum() < best[0]:
            best = (float(values[:2].sum()), vectors[:, 2])
    assert best is not None
    axis = np.cross(best[1], middle)
    norm = float(np.linalg.norm(axis))
    return axis / norm if norm > 0 else None


def _across_band(ends: list[np.ndarray], middle: np.ndarray) -> list[np.ndarray]:
    """``ends`` without the lines that run along the band rather than across it: a line that
    ends on both rims spans the band's height along the axis, one along the band ends on its
    sides, at one height, and is the longest on it (a band is wider than high). Each line's
    span is taken along the axis the other lines' rims give (the line itself would turn it);
    a line spanning less than ``_BAND_SPAN`` of the others' median there runs along the band
    if it is no shorter than any line kept. All lines are kept when fewer than two would be,
    or when a line that would go is shorter than one kept: no band's then.

    The facing test (``_RIM_FACING``) lets a line along the band through where the ball is
    wider than the band, whose sides turn away from the camera less than the band's do (the
    jar cap from the front under BM 7: 0.63-0.65 on two of ten frames, each 10-11 degrees off
    the truth's wrist angle with it, within 0.5 without it; it spans 2 mm of the 14-17 mm the
    lines across the band do, and is 47-49 mm long on the ball against their 14-20 mm). The
    rotation suite's 40 mm cylinder lying before the camera (SGBM 7, a 90 degree roll,
    trial 0 frame 4: a ball beats it, and its lines fall short of that ball) shows no band:
    the lines across it and along it, 34 and 39 mm long on the ball, would go and leave the
    two diagonal ones, 41 and 53 mm, whose ends are no rims (an axis 11 degrees off, against
    its own fit's 4).
    """
    crossing = []
    for k in range(len(ends)):
        axis = _across_rims(ends[:k] + ends[k + 1 :], middle)
        if axis is None:
            return ends
        spans = [abs(float((e[1] - e[0]) @ axis)) for e in ends]
        crossing.append(spans[k] >= _BAND_SPAN * float(np.median(spans[:k] + spans[k + 1 :])))
    kept = [e for e, keep in zip(ends, crossing, strict=True) if keep]
    if len(kept) < 2:
        return ends
    longest = max(float(np.linalg.norm(e[1] - e[0])) for e in kept)
    for e, keep in zip(ends, crossing, strict=True):
        if not keep and float(np.linalg.norm(e[1] - e[0])) < longest:
            return ends
    return kept


def _radius_sd(solid: SphereSolid | CylinderSolid, points: np.ndarray) -> float:
    """Standard deviation of a least-squares radius from its points' residuals: the
    Gauss-Newton covariance s^2 (J'J)^-1, J's rows (surface normal, 1) (the normal lies
    across a cylinder's axis, so its J'J is singular along the axis: pseudo-inverse)."""
    if isinstance(solid, SphereSolid):
        normal = points - solid.center
    else:
        w = points - solid.point
        normal = w - (w @ solid.axis)[:, None] * solid.axis
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    jac = np.column_stack([normal, np.ones(len(points))])
    s2 = float(np.mean(solid.residuals(points) ** 2)) * len(points) / max(len(points) - 4, 1)
    return math.sqrt(s2 * float(np.linalg.pinv(jac.T @ jac)[3, 3]))


def _disc_holds_cut_seeds(
    disc: tuple[np.ndarray, float, float], seeds: _Seeds, params: LaserParams
) -> bool:
    """Whether every seed the capture volume cut lies within the disc its uncut seeds fit: a
    cut run goes on across the face past its seed, so a round face holds it. A hexagonal
    prism's side face (base 40 mm and 3-way SGBM 5, trial 1 frame 3) put four of its six uncut
    seeds where the lines left it at the crease, smoothed into an arc, and the circle through
    them held the six within 0.5-1.2 mm RMS: 21.5 mm across, while its two cut seeds lay 41-54
    mm from its centre on the face (a cylinder 43 mm wide, 38-40 degrees off the prism)."""
    if seeds.cropped.any():
        centre, radius, _ = disc
        off = seeds.points.compress(seeds.cropped, axis=0) - centre
        reach = float(np.sqrt(np.einsum("ij,ij->i", off, off)).max())
        return reach <= radius + params.edge_tolerance_m
    return True


def _polyhedral(lines: list[LineModels]) -> bool:
    """Whether ``_straight_pieces`` held on the frame: no line has a circle fitted because
    each is straight pieces or covered by its line."""
    return all(getattr(ln.fits.get("circle"), "reason", None) in (_COVERED, _STRAIGHT)
               for ln in lines)  # fmt: skip


def _face_run(line: LineModels, plane: PlaneSolid, params: LaserParams) -> LineModels | None:
    """The line with its run replaced by its points on ``plane`` through the optical axis (or
    its longest such run); bumps in front of the face (buttons) do not end the run."""
    heights = (line.points - plane.point) @ plane.normal
    runs = _runs(np.abs(heights) <= params.solid_threshold_m, line.points, params, heights > 0)
    if not runs:
        return None
    run = _pierced_run(runs, line.sz[:, 0], params)
    if len(run) < params.min_points_per_line:
        run = max(runs, key=len)
        if len(run) < params.min_points_per_line:
            return None
    run = _without_end_stubs(run, line.points, line.sz, params)
    _ = line.step  # the step belongs to the model's run, not the face run
    moved = copy.copy(line)  # dataclasses.replace, without re-running __init__
    moved.run = run
    if line.beyond:
        _across_face_holes(moved, plane, params)
    moved.run = _across_excursions(moved.run, (moved.points - plane.point) @ plane.normal, params)
    return moved


# A face run's end piece past a bump (see _without_end_stubs) goes when at least this many
# pixels along the line between them have no depth.
_STUB_HOLE_PX = 2.0


def _without_end_stubs(
    run: np.ndarray, points: np.ndarray, sz: np.ndarray, params: LaserParams
) -> np.ndarray:
    """The face ``run`` (indices into its line's ``points``, plane coordinates ``sz``)
    without a piece of fewer than _EXCURSION_RESUME samples at either end that only
    ``_runs``' bump rule joined to it (the samples between, all in front of the face,
    spanning more than max_outlier_run samples or segment_gap_m) across pixels without
    depth (_STUB_HOLE_PX or more: the run's median step along the line counts them).

    A bump (a remote's buttons, measured pixel by pixel) has the face go on past it; a few
    samples on the plane's extension past a hole at the face's edge need not be the face:
    the box tilted right, trial 0 frame 2, its line at 45 degrees, two samples 1.8-3.2 mm
    in front of the face, a 7-pixel hole, then two samples on the plane's extension 6 mm
    nearer the camera, 11 mm past the edge (SGBM 7 with 2.5 times the shot noise: the box
    turned 20.2 degrees, 3.5 without them; SGBM 9 with P1 and P2 halved 19.4 -> 2.2). The
    same frame's seed lay 12-27 mm outside under six more settings, past bumps without a
    hole: left as they are (the rule without the hole turned the remote 0.6 -> 1.6 degrees
    on lpc's noise model)."""
    gaps = (np.diff(run) > 1).nonzero()[0].tolist()
    if not gaps:
        return run
    q = sz[:, 0] / sz[:, 1]
    step = float(np.median(np.abs(np.diff(q.take(run)))))
    longest, gap2 = params.max_outlier_run + 1, params.segment_gap_m**2

    def bumped(at: int) -> bool:
        i, j = int(run[at]), int(run[at + 1])
        d = points[j] - points[i]
        holes = abs(float(q[j] - q[i])) - (j - i) * step
        return (j - i > longest or float(d @ d) > gap2) and holes >= _STUB_HOLE_PX * step

    lo, hi = 0, len(run)
    if gaps[0] + 1 < _EXCURSION_RESUME and bumped(gaps[0]):
        lo = gaps[0] + 1
    if len(run) - gaps[-1] - 1 < _EXCURSION_RESUME and bumped(gaps[-1]):
        hi = gaps[-1] + 1
    return run if hi - lo < params.min_points_per_line else run[lo:hi]


# A face run goes on across at most _EXCURSION_SAMPLES samples off the face's plane (about a
# matching window across), two or more on one side of it (the last of them may lie off the
# other side: the shift snapping back) and within _EXCURSION_OFF of solid_threshold_m of it,
# where the next _EXCURSION_RESUME samples past them lie on the plane again. A matcher's
# disparity shifts across a patch with little texture reach 3.3 mm off the plane at 21 cm
# (sparse dots 35 mm apart, the box tilted right, trial 1 frame 3) and snap back 1.6-1.7 mm
# past it (BM 7 texture threshold 20, trial 0 frame 4; SGBM 3-way 7 with shot noise, trial
# 1 frame 0): those runs ended there, and their seeds, 17-35 mm inside the face, turned the
# box 29-33 degrees.
_EXCURSION_SAMPLES = 8
_EXCURSION_OFF = 2.5
_EXCURSION_RESUME = 4


def _across_excursions(run: np.ndarray, heights: np.ndarray, params: LaserParams) -> np.ndarray:
    """The face ``run`` (indices into its line's samples, whose ``heights`` above the face's
    plane are given) gone on across short excursions off the plane (see _EXCURSION_SAMPLES).

    A block matcher's disparity wanders by half a pixel over a patch with little texture (2 mm
    at 20 cm: BM 7 with a texture threshold of 20, the box tilted right, trial 0 frame 0,
    five samples 1.6-2.5 mm behind its face, then eight on it again to the segment's end),
    which ended the run there: its seed lay 27 mm inside the face, on no side, and turned
    the box's axis 17 degrees. An edge leaves the plane for good: the next face parts from
    it further with every sample, a background or the table lies beyond the window. Samples
    either side of the plane are its noise, not such a shift: joined as well, the box tilted
    right at BM 5 (trial 0 frame 2: 1.8 mm in front, then 1.7 behind) turned 0.7 -> 3.5
    degrees, though at BM 7 t20 (trial 0 frame 4) 28.8 -> 2.0."""
    on = (np.abs(heights) <= params.solid_threshold_m).tolist()
    near = (np.abs(heights) <= _EXCURSION_OFF * params.solid_threshold_m).tolist()
    lo, hi, n = int(run[0]), int(run[-1]), len(on)

    def resumes(end: int, step: int) -> int:
        """The last sample of the plane's resumed run past an excursion from ``end`` along
        ``step``, or ``end`` when there is none."""
        j = end + step
        side = heights[j] > 0 if 0 <= j < n else False
        crossed = False
        while 0 <= j < n and not on[j] and near[j] and abs(j - end) <= _EXCURSION_SAMPLES:
            # A shift holds for two samples or more, then may snap back across the plane, but
            # never returns to its first side: a lone sample each side is noise.
            if (heights[j] > 0) != side:
                if abs(j - end) < 3:
                    break
                crossed = True
            elif crossed:
                break
            j += step
        if not (0 <= j < n and on[j]) or abs(j - end) == 1 or abs(j - end) > _EXCURSION_SAMPLES + 1:
            return end
        k = j
        while 0 <= k + step < n and on[k + step]:
            k += step
        return k if abs(k - j) + 1 >= _EXCURSION_RESUME else end

    while (grown := resumes(hi, 1)) != hi:
        hi = grown
    while (grown := resumes(lo, -1)) != lo:
        lo = grown
    if (lo, hi) == (int(run[0]), int(run[-1])):
        return run
    return np.arange(lo, hi + 1)


def _across_face_holes(line: LineModels, plane: PlaneSolid, params: LaserParams) -> None:
    """Where the face run reaches within ``max_outlier_run`` samples of its segment's end (a hole's
    border leaves the face: BM 5's tilted box turned 17 degrees, trial 0 frame 2, and 0.7 so
    joined) and the line's next samples past the gap lie on ``plane`` again
    (``min_points_per_line`` of them in a run, the first of them among the first
    ``max_outlier_run`` + 1), the run goes on through them: the gap was a hole in the face (a
    matcher's failed windows: BM 5 broke the tilted box's lines 18-56 mm inside it), not its
    edge, and the seed there lay inside the face, on no side. An edge leaves the next samples
    off the plane: the background, the table (whose contact line meets the face's plane for a
    sample or two), an object in front. The whole segment past the hole joins, as a segment
    (split at the next jump): a run ending short of its end is no occluding edge (see
    ``_collect_seeds``)."""
    before, after = line.beyond
    c, s_ = math.cos(line.angle), math.sin(line.angle)
    for k, side in ((1, after), (0, before)):
        end = len(line.points) - 1 if k else 0
        if (
            len(side) < params.min_points_per_line
            or abs(int(line.run[-k]) - end) > params.max_outlier_run
        ):
            continue
        ordered = side if k else side[::-1]  # outward from the gap
        heights = (ordered - plane.point) @ plane.normal
        runs = _runs(np.abs(heights) <= params.solid_threshold_m, ordered, params, heights > 0)
        if (
            not runs
            or runs[0][0] > params.max_outlier_run
            or len(runs[0]) < params.min_points_per_line
        ):
            continue
        jumps = squared_norms(ordered[1:] - ordered[:-1]) > params.segment_gap_m**2
        reach = int(jumps.argmax()) + 1 if jumps.any() else len(ordered)
        if int(runs[0][-1]) >= reach:
            continue
        joined = ordered[:reach] if k else ordered[:reach][::-1]
        sz = np.column_stack([joined[:, 0] * c + joined[:, 1] * s_, joined[:, 2]])
        if k:
            first = len(line.points)
            line.points = np.concatenate([line.points, joined])
            line.sz = np.concatenate([line.sz, sz])
            line.run = np.concatenate([line.run, first + runs[0]])
            line.beyond = (line.beyond[0], side[reach:])
        else:
            # runs[0] counts outward from the gap: as indices of the joined points, reversed.
            line.points = np.concatenate([joined, line.points])
            line.sz = np.concatenate([sz, line.sz])
            line.run = np.concatenate([(reach - 1 - runs[0])[::-1], reach + line.run])
            line.beyond = (side[: len(side) - reach], line.beyond[1])


def _plateau_end(z: np.ndarray, end: int, inward: int, tolerance_m: float) -> int:
    """The last sample, walking from the segment's ``end`` in direction ``inward`` (+1 or -1),
    whose neighbours all lie within ``tolerance_m`` of the end sample's depth ``z[end]``."""
    # Python floats (``item``): the walk is a few samples on most ends but the whole segment
    # on a flat one, and numpy's scalars cost twice as much per step (same values, same test).
    depth, j, last = z.item(end), end, len(z) - 1
    while 0 <= j + inward <= last and abs(z.item(j + inward) - depth) <= tolerance_m:
        j += inward
    return j


def _fattening(lines: list[LineModels]) -> float:
    """The edge fattening (pixels) the face runs' ends show: the median over the ends where
    it can be seen, 0 where it cannot be seen anywhere.

    A matcher gives the background pixels within about half its window of an occluding edge
    the disparity at the edge: depth stays constant past the edge (a plateau). Along a line
    where the face's depth changes, its inner half predicts the depth (1/z is affine in s/z
    on a plane), and the plateau's samples part from that prediction where the face ends:
    the edge is where the prediction reaches the plateau's depth. Where the face keeps its
    depth along the line, the plateau is the face and shows nothing.
    """
    found = []
    for ln in lines:
        run, last = ln.run, len(ln.points) - 1
        n = len(run)
        if n < 8 or ln.step <= 0:
            continue
        q = ln.sz[:, 0] / ln.sz[:, 1]
        inv = 1.0 / ln.sz[:, 1]
        inner = run[n // 4 : n - n // 4]
        a, b = _fit_affine(q[inner], inv[inner])
        if a == 0:
            continue
        for end, inward, first in ((0, 1, run[0]), (last, -1, run[-1])):
            # The plateau: the segment's last samples at its end sample's depth. It must
            # reach the face's run: past it the segment is no plateau but more object.
            z_end = ln.sz[end, 1]
            j = _plateau_end(ln.sz[:, 1], end, inward, _PLATEAU_M)
            if (first - j) * inward > 1:
                continue
            q_cross = (1.0 / z_end - b) / a
            # The prediction reaches the plateau's depth inside the plateau, and the plateau
            # parts from it by more than the depth's quantum at its end.
            inside = min(q[j], q[end]) <= q_cross <= max(q[j], q[end])
            gap = abs(1.0 / (a * q[end] + b) - z_end)
            # The plateau's depth is known to half a quantum: where the face's depth changes
            # so slowly along the line that this moves the crossing by more than
            # _CROSSING_SAMPLES, the plateau cannot size the fattening (on stereo frames such
            # ends gave 12-15 px where the seeds lay about 5 px past the true edge).
            spread = 0.5 * _QUANTUM_M / (z_end * z_end * abs(a) * ln.step)
            if inside and gap > _PARTED_M and spread <= _CROSSING_SAMPLES:
                # In samples: a diagonal line's samples are a pixel apart along x and y, as
                # far as a fattening along rows or columns reaches.
                # The plateau's first sample is the face's last: the edge lies half a sample on.
                found.append(abs(q[end] - q_cross) / ln.step - 0.5)
    return float(median(found)) if found else 0.0


def _fit_affine(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """``np.polyfit(x, y, 1)``: slope and intercept, to the bit.

    The same scaled Vandermonde system solved by the same LAPACK least squares (``gelsd``,
    through the gufunc ``numpy.linalg.lstsq`` calls), without the wrappers' checks and
    error-state set-up, which cost more than the solve (173 k instructions a call, this
    about 70 k). A rank-deficient or failed fit goes through ``np.polyfit`` itself, which
    warns or raises as it always did.
    """
    n = len(x)
    lhs = np.empty((n, 2))
    lhs[:, 0], lhs[:, 1] = x, 1.0
    scale = np.sqrt(column_sums(lhs * lhs))
    lhs /= scale
    solution, _, rank, _ = _umath_linalg.lstsq(lhs, y[:, None], n * _EPS, signature="ddd->ddid")
    a, b = (solution[:, 0] / scale).tolist()
    if rank != 2 or not (math.isfinite(a) and math.isfinite(b)):
        a, b = np.polyfit(x, y, 1).tolist()
    return a, b


_EPS = float(np.finfo(np.float64).eps)


def measured_fattening_px(
    scan_lines: ScanLinesLike, plane: PlaneSolid, params: LaserParams = LaserParams()
) -> float:
    """The edge fattening (pixels) that the scan lines show at the edges of the face
    ``plane``: ``_fattening`` on each line's run on that face (0 when none shows it). For
    the full-cloud method, which finds the face on the whole frame."""
    angles = np.asarray(scan_lines.angles_rad, dtype=np.float64).reshape(-1).tolist()
    raw = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in scan_lines.points]
    lines = [ln for ln in _prepare_lines(angles, raw, params) if not ln.reason]
    on_face = []
    for ln in lines:
        ln.run = np.arange(len(ln.points))
        moved = _face_run(ln, plane, params)
        if moved is not None:
            on_face.append(moved)
    return _fattening(on_face)


_PLATEAU_M = 0.0006
_QUANTUM_M = 0.001
# A face whose best rectangle leaves a seed this far inside its sides (a fraction of its
# smaller extent) is taken as rounded: see _unless_rounded.
_INSIDE_SIDES = 0.25
# A side's seed lying this many fattening trims beyond every other seed of the side is taken
# as an outlier of the matcher's fattening, not as the side: see _consistent_sides.
_OUTLYING_TRIMS = 2.0
# A side of this many uncut seeds or more, its background far behind, goes through the median
# of its seeds' edges; a seed at no occluding edge lying more than _HOLE_APART times the
# outlier distance inside the side's farthest seed is left out: see _consistent_sides. Without
# that, BM 5's box tilted right (trial 0 frame 2) kept a hole's seed 41 mm inside a side of
# two edges, and came out 12 mm narrow.
_SIDE_MEDIAN_SEEDS = 2
_HOLE_APART = 2.0
# The share of a side's occluding seeds that must take a whole window or more for the side to
# go through its seeds' median (see _consistent_sides). SGBM 9, the box tilted left, trial 0
# frames 1-3: a side's farthest seed 8.8-9.5 mm past the true side at an end with the table
# 0.07-0.13 of its depth behind (0.21-0.24 of a window), its others 3.3-6.2 mm past; with
# every edge required far, the side went through the farthest (7.9-8.5 mm out, widths 6.6-12.7
# mm too wide). Where a side has no edge far behind (the 40 mm bar on the table), the farthest
# seed still rules.
_FAR_EDGES = 0.5
# Where no fattening was measured, a side's seed lying this many samples (pixels at the
# face's depth) beyond every other seed of the side, of this many seeds at least, is taken as
# the matcher's fattening, not as the side: see _straight_sides.
_STRAIGHT_SIDE_SAMPLES = 2.0
_STRAIGHT_SIDE_SEEDS = 3
_CROSSING_SAMPLES = 1.5
_PARTED_M = 0.0014
# A round's end plateau: neighbouring samples within one depth quantum (1 mm, the camera's
# depth units) and noise; a stereo plateau steps by the quantum.
_END_PLATEAU_M = 0.0011
_FATTENED_ENDS = 3


def _tuple3(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _closest_to_optical_axis(point: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The point of the cylinder axis nearest the optical (z) axis."""
    b = axis[2]
    denom = 1.0 - b * b
    if denom < 1e-9:
        return point
    t = (b * point[2] - point @ axis) / denom
    return point + t * axis


def _decide_paper(
    lines: list[LineModels],
    counts: dict[str, int],
    params: LaserParams,
    summaries: tuple[LineSummary, ...],
    total: int,
    extra: dict[str, float],
) -> Reconstruction:
    """The paper's decision: count the 2-D models; sphere from circle centres; cylinder and
    cuboid from Algorithm 1 on the seeds in the plane through them."""
    n = len(lines)
    fraction = {
        m: float(np.mean([ln.fits[m].inlier_fraction if ln.fits[m] else 0.0 for ln in lines]))
        for m in MODELS
    }
    extra.update({f"f_{m}": v for m, v in fraction.items()})
    if counts["circle"] == n:
        shape = "sphere"
    elif counts["line"] == n:
        shape = "cuboid"
    elif counts["ellipse"] == n or (
        counts["ellipse"] >= 2 and counts["ellipse"] + counts["circle"] + counts["line"] == n
    ):
        shape = "cylinder"
    else:
        return _none(
            f"the 2-D models match no shape ({counts['circle']} circles, {counts['line']} "
            f"lines, {counts['ellipse']} ellipses)",
            summaries,
            total,
            extra,
        )
    if shape == "sphere":
        got = sphere_from_circles(
            np.array([ln.angle for ln in lines]),
            np.array([ln.fits["circle"].params[:2] for ln in lines]),
            np.concatenate([ln.seeds() for ln in lines]),
        )
        if got is None:
            return _none("circle centres do not fix a sphere", summaries, total, extra)
        centre, radius = got
        if centre[2] <= min(float(ln.points[ln.run, 2].min()) for ln in lines):
            return _none("sphere centre not beyond the surface", summaries, total, extra)
        return Reconstruction(
            shape="sphere",
            grasp_width_m=2 * radius,
            center_m=_tuple3(centre),
            lines=summaries,
            confidence=fraction["circle"],
            points=total,
            extra=extra,
        )
    seeds = _collect_seeds(lines, params, extend=False)
    plane = PlaneSolid.estimate(seeds.points)
    if not plane:
        return _none(f"seed points give no plane: {plane.reason}", summaries, total, extra)
    face = _face_geometry(plane, seeds, params, paper=True)
    if isinstance(face, str):
        return _none(face, summaries, total, extra)
    axis = _canonical_axis(face.axis)
    return Reconstruction(
        shape=shape,
        grasp_width_m=face.width,
        wrist_angle_rad=_axis_angle(axis),
        center_m=_tuple3(face.centre),
        axis=_tuple3(axis),
        lines=summaries,
        confidence=max(fraction.values()),
        points=total,
        extra=extra,
    )


__all__ = [
    "LaserParams",
    "LineModels",
    "analyse_lines",
    "decide",
    "principal_direction",
    "reconstruct_laser",
    "sort_around",
    "sphere_from_circles",
]
