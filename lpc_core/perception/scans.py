"""Crop a depth frame to the capture volume and cut the four laser-like scan lines.

The scan planes all contain the optical z-axis; the plane at angle phi contains the direction
(cos phi, sin phi, 0), so its normal is n = (-sin phi, cos phi, 0). A point belongs to a scan
line when |n . p| <= band. In-plane coordinates of a point: s = x cos phi + y sin phi, and z.

Only pixels that can ever meet a scan line inside the capture volume are deprojected: with
p = z (u', v', 1), |n . p| = z |g(u', v')|, so a pixel qualifies only if
|g| <= band / z_near. Those pixels form a thin strip (about 1.4 px wide at the defaults)
along each image line through the principal point; their indices are computed once per
(intrinsics, params).
"""

from __future__ import annotations

import bisect
import itertools
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

try:  # numpy's private gufuncs behind np.linalg.qr: qr_r_raw from numpy 2.0 (1.x split it in two)
    from numpy.linalg import _umath_linalg

    _QR_R_RAW = getattr(_umath_linalg, "qr_r_raw", None)
except ImportError:
    _QR_R_RAW = None

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.solids import einsum_norms


@dataclass(frozen=True, kw_only=True)
class ScanParams:
    """Scan line geometry and the capture volume (camera frame, metres).

    Defaults are the paper's: four planes 45 degrees apart, ±0.5 mm band, a 100 mm cube
    150 mm in front of the sensor, at least 10 points per line for a usable fit.
    """

    angles_deg: tuple[float, ...] = (0.0, 45.0, 90.0, 135.0)
    band_m: float = 0.0005
    x_limits_m: tuple[float, float] = (-0.05, 0.05)
    y_limits_m: tuple[float, float] = (-0.05, 0.05)
    z_limits_m: tuple[float, float] = (0.15, 0.25)
    min_points: int = 10

    def __post_init__(self) -> None:
        # math.isfinite, not np.isfinite: a ScanParams is built per frame, and numpy's
        # scalar calls cost most of its construction.
        if not self.angles_deg or not all(math.isfinite(a) for a in self.angles_deg):
            raise ValueError(f"angles_deg must be finite and non-empty, got {self.angles_deg}")
        if not math.isfinite(self.band_m) or self.band_m <= 0:
            raise ValueError(f"band_m must be positive, got {self.band_m}")
        for name in ("x_limits_m", "y_limits_m", "z_limits_m"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"{name} must be finite with lo < hi, got {(lo, hi)}")
        if self.z_limits_m[0] <= 0:
            raise ValueError(f"z_limits_m must be in front of the camera, got {self.z_limits_m}")
        if self.min_points < 0:
            raise ValueError(f"min_points must be >= 0, got {self.min_points}")

    @property
    def angles_rad(self) -> np.ndarray:
        return np.radians(np.asarray(self.angles_deg, dtype=np.float64))


@dataclass(frozen=True, eq=False)
class ScanLines:
    """The points of each scan line, camera frame, metres, each sorted by s.

    ``points[i]`` is (N_i, 3) for the plane at ``angles_rad[i]``; ``pixels[i]`` holds the flat
    pixel index (row * width + column) of each point, for overlays. A line with fewer than
    ``min_points`` points keeps them (aim guidance uses every point) but is not ``line_ok``.
    ``capture_count`` is the number of valid points in the whole capture volume (what the
    full-cloud method would see), or -1 when not counted. ``past_ends_m`` (L, 2): per line,
    the depth the image holds just past its first and last point (``past_line_ends``), 0
    where it holds none (as in a depth image); None when not measured. ``far_past_m`` (L, 2,
    3): per line, the point of the first pixel past its first and last point whose depth
    lies beyond the capture volume (``far_past_ends``), zeros where none does within
    ``_FAR_STEPS_PX``; None when not measured. ``edge_past_m`` (L, 2, 3): per line, the point
    past its first and last point where the line leaves the surface its end lies on
    (``_edge_points``), zeros where it does not within ``_FAR_STEPS_PX``; None when not
    measured.
    """

    angles_rad: np.ndarray
    points: tuple[np.ndarray, ...]
    pixels: tuple[np.ndarray, ...]
    min_points: int = 10
    capture_count: int = -1
    past_ends_m: np.ndarray | None = None
    far_past_m: np.ndarray | None = None
    edge_past_m: np.ndarray | None = None

    def plane_coords(self, i: int) -> np.ndarray:
        """(N_i, 2) in-plane coordinates (s, z) of line ``i``."""
        phi = float(self.angles_rad[i])
        p = self.points[i]
        return np.column_stack([p[:, 0] * np.cos(phi) + p[:, 1] * np.sin(phi), p[:, 2]])

    @property
    def counts(self) -> np.ndarray:
        return np.array([len(p) for p in self.points], dtype=np.int64)

    @property
    def total_points(self) -> int:
        return int(sum(len(p) for p in self.points))

    @property
    def line_ok(self) -> np.ndarray:
        """Per line: has at least ``min_points`` points."""
        return self.counts >= self.min_points

    @property
    def ok(self) -> bool:
        """Every line has at least ``min_points`` points."""
        return bool(np.all(self.line_ok))

    def all_points(self) -> np.ndarray:
        """(N, 3) every line's points, line after line (a point near the centre may repeat)."""
        return np.concatenate(self.points) if self.points else np.empty((0, 3))


def _slope_limits(lo: float, hi: float, z_near: float, z_far: float) -> tuple[float, float]:
    """Range of x/z for which x = z * (x/z) can fall in [lo, hi] with z in [z_near, z_far]."""
    return min(lo / z_near, lo / z_far), max(hi / z_near, hi / z_far)


def _depth_bounds(
    slope_x: np.ndarray,
    slope_y: np.ndarray,
    z_max_extra: np.ndarray | None,
    params: ScanParams,
    depth_scale: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the depth-unit interval [lo, hi] whose points lie in the capture volume.

    x = z * slope_x in [x0, x1] is an interval of z for each pixel (and likewise for y, and
    for the band: z * off <= band); intersecting them with [z0, z1] turns the whole crop into
    two integer comparisons per pixel. Boundaries get 1e-9 m of slack against rounding.
    """
    lo = np.full(np.broadcast(slope_x, slope_y).shape, params.z_limits_m[0])
    hi = np.full(lo.shape, params.z_limits_m[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        for slope, (a, b) in ((slope_x, params.x_limits_m), (slope_y, params.y_limits_m)):
            za, zb = a / slope, b / slope
            z_from = np.where(
                slope > 0, za, np.where(slope < 0, zb, np.where(a <= 0 <= b, 0, np.inf))
            )
            z_to = np.where(
                slope > 0, zb, np.where(slope < 0, za, np.where(a <= 0 <= b, np.inf, 0))
            )
            lo = np.maximum(lo, z_from)
            hi = np.minimum(hi, z_to)
    if z_max_extra is not None:
        hi = np.minimum(hi, z_max_extra)
    lo_units = np.ceil((lo - 1e-9) / depth_scale)
    hi_units = np.floor((hi + 1e-9) / depth_scale)
    # An empty interval becomes (1, 0); depth 0 (no data) is never inside.
    lo_units = np.clip(lo_units, 1, 65536).astype(np.int32)
    hi_units = np.clip(hi_units, 0, 65535).astype(np.int32)
    return lo_units, hi_units


@dataclass(frozen=True, eq=False)
class _ScanTable:
    """Candidate pixels of every line, concatenated line after line."""

    flat_index: np.ndarray  # (M,) int64 row * width + column
    line: np.ndarray  # (M,) line number, unsigned, in the fewest bytes that hold it
    slope_x: np.ndarray  # (M,) x/z of the pixel ray
    slope_y: np.ndarray  # (M,) y/z
    along: np.ndarray  # (M,) s / z
    # A depth d (units) is inside when (d - lo) mod 2^16 <= span, one uint16 comparison with
    # no cast (below lo, d wraps past span): every pixel here has a non-empty interval.
    lo_u16: np.ndarray  # (M,) uint16 smallest depth (units) in the volume and the band
    span_u16: np.ndarray  # (M,) uint16 largest less smallest
    # (2M,) each pixel's two bytes in the image's bytes (``2 * flat_index`` and the next):
    # a decoded frame's depth views its payload at an odd address, where numpy gathers uint16
    # through a copy call per element (a tenth of the cut's instructions); bytes it gathers
    # in place, and each pair reads back as the same uint16.
    byte_index: np.ndarray


def _scan_table(intrinsics: Intrinsics, params: ScanParams) -> _ScanTable:
    xs, ys = intrinsics.pixel_rays()
    z_near, z_far = params.z_limits_m
    ux = _slope_limits(*params.x_limits_m, z_near, z_far)
    vy = _slope_limits(*params.y_limits_m, z_near, z_far)
    in_box = (xs >= ux[0]) & (xs <= ux[1]) & (ys >= vy[0]) & (ys <= vy[1])
    parts: list[tuple[np.ndarray, ...]] = []
    # The smallest type that numbers the lines (a byte): gathered and sorted by every frame.
    line_type = np.min_scalar_type(len(params.angles_deg) - 1)
    for i, phi in enumerate(params.angles_rad):
        off = np.abs(-np.sin(phi) * xs + np.cos(phi) * ys)
        # Slack so that pixels exactly at the band edge at z_near are not lost to rounding.
        flat = np.flatnonzero(in_box & (off <= params.band_m / z_near * (1.0 + 1e-9)))
        sx, sy, of = xs.reshape(-1)[flat], ys.reshape(-1)[flat], off.reshape(-1)[flat]
        with np.errstate(divide="ignore"):
            band_z = params.band_m / of
        lo, hi = _depth_bounds(sx, sy, band_z, params, intrinsics.depth_scale)
        # A pixel whose interval is empty never holds a point of the line.
        some = lo <= hi
        flat, sx, sy, lo, hi = flat[some], sx[some], sy[some], lo[some], hi[some]
        line = np.full(flat.size, i, dtype=line_type)
        along = np.cos(phi) * sx + np.sin(phi) * sy
        parts.append((flat, line, sx, sy, along, lo.astype(np.uint16), (hi - lo).astype(np.uint16)))
    columns = [np.ascontiguousarray(np.concatenate(col)) for col in zip(*parts, strict=True)]
    columns.append((2 * columns[0][:, None] + np.arange(2)).reshape(-1))
    for col in columns:
        col.setflags(write=False)
    return _ScanTable(*columns)


@dataclass(frozen=True, eq=False)
class _VolumeWindow:
    rows: slice
    cols: slice
    slope_x: np.ndarray  # (1, w)
    slope_y: np.ndarray  # (h, 1)
    lo_units: np.ndarray  # (h, w) int32
    hi_units: np.ndarray  # (h, w) int32
    # When every pixel's interval is non-empty: lo and hi - lo as uint16, so that a depth d
    # is inside when (d - lo) mod 2^16 <= hi - lo, one comparison with no cast (below lo, d
    # wraps past hi).
    lo_u16: np.ndarray | None
    span_u16: np.ndarray | None


@lru_cache(maxsize=16)
def _volume_window(intrinsics: Intrinsics, params: ScanParams) -> _VolumeWindow:
    xs, ys = intrinsics.pixel_rays()
    z_near, z_far = params.z_limits_m
    ux = _slope_limits(*params.x_limits_m, z_near, z_far)
    vy = _slope_limits(*params.y_limits_m, z_near, z_far)
    cols = np.flatnonzero((xs[0] >= ux[0]) & (xs[0] <= ux[1]))
    rows = np.flatnonzero((ys[:, 0] >= vy[0]) & (ys[:, 0] <= vy[1]))
    if cols.size == 0 or rows.size == 0:
        cols = rows = np.zeros(0, dtype=np.int64)
        rs = cs = slice(0, 0)
    else:
        rs, cs = slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)
    sx, sy = xs[:1, cs].copy(), ys[rs, :1].copy()
    lo, hi = _depth_bounds(sx, sy, None, params, intrinsics.depth_scale)
    lo_u16 = span_u16 = None
    if (lo <= hi).all():
        lo_u16, span_u16 = lo.astype(np.uint16), (hi - lo).astype(np.uint16)
    return _VolumeWindow(rs, cs, sx, sy, lo, hi, lo_u16, span_u16)


@dataclass(frozen=True, eq=False)
class _Geometry:
    """What a frame's cut needs of its intrinsics and parameters, found in one cache lookup:
    hashing and comparing the two frozen dataclasses (a new ``Intrinsics`` each frame) for
    three caches, and the angles in radians three times, cost about a tenth of the cut."""

    table: _ScanTable
    window: _VolumeWindow
    angles_rad: np.ndarray  # read-only, shared by every ScanLines of this geometry
    # Past each line's ends (rows in _past_offsets' order), the _PAST_STEPS_PX offsets and
    # then the _FAR_STEPS_PX ones, as columns of one array: one gather reads both.
    ends_row: np.ndarray
    ends_col: np.ndarray
    ends_flat: np.ndarray  # the same as flat pixel offsets
    # Per line, its direction (cos, sin) in the scan plane; per line end (rows as ends_row's),
    # each _FAR_STEPS_PX pixel's offset in s / z along the line: Python floats (_edge_points).
    cos_sin: list[list[float]]
    ends_q: list[list[float]]
    far_units: int  # the deepest depth (units) inside the capture volume's far limit


@lru_cache(maxsize=16)
def _geometry(intrinsics: Intrinsics, params: ScanParams) -> _Geometry:
    angles = params.angles_rad
    angles.setflags(write=False)
    d_row, d_col = _past_offsets(intrinsics, tuple(angles.tolist()))
    far_row, far_col = _past_offsets(intrinsics, tuple(angles.tolist()), far=True)
    ends_row, ends_col = np.hstack([d_row, far_row]), np.hstack([d_col, far_col])
    ends_flat = ends_row * intrinsics.width + ends_col
    cos_sin = np.column_stack([np.cos(angles), np.sin(angles)])
    ends_q = far_col / intrinsics.fx * cos_sin[:, :1].repeat(2, axis=0) + (
        far_row / intrinsics.fy * cos_sin[:, 1:].repeat(2, axis=0)
    )
    for offsets in (ends_row, ends_col, ends_flat):
        offsets.setflags(write=False)
    # In units, as the depth image holds it: z = units * depth_scale lies beyond the far limit
    # exactly where units exceed this.
    scale, far_m = intrinsics.depth_scale, params.z_limits_m[1]
    far_units = math.floor(far_m / scale)
    far_units += (far_units + 1) * scale <= far_m
    far_units -= far_units * scale > far_m
    return _Geometry(
        _scan_table(intrinsics, params), _volume_window(intrinsics, params), angles, ends_row,
        ends_col, ends_flat, cos_sin.tolist(), ends_q.tolist(), int(far_units),
    )  # fmt: skip


def _check_depth(depth: object, intrinsics: Intrinsics) -> np.ndarray:
    if not isinstance(depth, np.ndarray):
        raise ValueError(f"depth must be a numpy array, got {type(depth).__name__}")
    if depth.dtype != np.uint16:
        raise ValueError(f"depth must have dtype uint16, got {depth.dtype}")
    shape = (intrinsics.height, intrinsics.width)
    if depth.shape != shape:
        raise ValueError(f"depth must have shape {shape}, got {depth.shape}")
    return depth


def cut_scan_lines(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    params: ScanParams = ScanParams(),
    count_capture: bool = True,
) -> ScanLines:
    """The points of each scan line inside the capture volume (invalid depth 0 is skipped).

    ``depth``: (H, W) uint16 in the intrinsics' depth units. ``count_capture`` also counts
    every point of the capture volume into ``capture_count``.
    """
    depth = _check_depth(depth, intrinsics)
    geometry = _geometry(intrinsics, params)
    tab = geometry.table
    units = depth.reshape(-1).view(np.uint8)[tab.byte_index].view(np.uint16)
    # The mask's own nonzero, not np.flatnonzero's ravel and Python wrappers: the mask is 1-D.
    keep = (np.subtract(units, tab.lo_u16) <= tab.span_u16).nonzero()[0]
    z = units[keep] * intrinsics.depth_scale
    line = tab.line[keep]
    order = np.lexsort((z * tab.along[keep], line))
    keep, z = keep[order], z[order]
    # np.column_stack's rows written in place: the same products, without its wrappers and
    # the three temporary columns it copies.
    pts = np.empty((len(z), 3))
    np.multiply(z, tab.slope_x[keep], out=pts[:, 0])
    np.multiply(z, tab.slope_y[keep], out=pts[:, 1])
    pts[:, 2] = z
    pts.setflags(write=False)
    # Each line's rows as slices (np.split costs more than the cut's arithmetic).
    counts = np.bincount(line, minlength=len(params.angles_deg)).tolist()
    bounds = [0, *itertools.accumulate(counts)]
    pixels = tab.flat_index[keep]
    # The pixels past the ends for both measures in one pass: the far walk reaches farther,
    # and a pixel outside the image reads 0 (no depth) whichever reach was checked.
    filled, flat, values = _pixels_past_ends(
        depth, intrinsics, geometry.ends_row, geometry.ends_col, geometry.ends_flat, pixels,
        bounds, int(_FAR_STEPS_PX[-1]) + 1,
    )  # fmt: skip
    near = len(_PAST_STEPS_PX)
    count = len(bounds) - 1
    past = _past_medians(count, filled, values[:, :near], intrinsics.depth_scale)
    far = _far_points(count, filled, flat[:, near:], values[:, near:], intrinsics, geometry)
    edges = _edge_points(count, filled, values[:, near:], pts, bounds, intrinsics, params, geometry)
    capture_count = -1
    if count_capture:
        win = geometry.window
        d = depth[win.rows, win.cols]
        if win.lo_u16 is not None:
            capture_count = int(np.count_nonzero(np.subtract(d, win.lo_u16) <= win.span_u16))
        else:
            capture_count = int(np.count_nonzero((d >= win.lo_units) & (d <= win.hi_units)))
    return ScanLines(
        angles_rad=geometry.angles_rad,
        points=tuple(pts[a:b] for a, b in itertools.pairwise(bounds)),
        pixels=tuple(pixels[a:b] for a, b in itertools.pairwise(bounds)),
        min_points=params.min_points,
        capture_count=capture_count,
        past_ends_m=past,
        far_past_m=far,
        edge_past_m=edges,
    )


# Pixels past a line's end whose depth tells what lies behind it: 8 px is past a 9 x 9
# window's fattened band, 30 px past the hole an occlusion or the projector's shadow leaves
# (as the full-cloud method's cloud._far_behind reads the background past a face's side).
_PAST_STEPS_PX = np.arange(8.0, 31.0, 2.0)
_NO_INDICES = np.zeros((0, 0), dtype=np.int64)
# Pixels past a line's end walked one at a time for the first that shows the background
# beyond the capture volume: past a 9 x 9 window's fattened band and the widest hole an
# occlusion left beside a round on the stereo sweep (4-35 px).
_FAR_STEPS_PX = np.arange(1.0, 41.0)


def past_line_ends(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    angles_rad: np.ndarray,
    pixels: np.ndarray,
    bounds: list[int],
) -> np.ndarray:
    """(L, 2) per scan line, the median depth (metres) of the image 8-30 px past its first and
    last point, outward along the line's image direction; 0 where no pixel there has depth
    (or the line has no point), as a depth image marks no depth (the bus carries no NaN).

    A line keeps only its samples inside the capture volume, so a face's occluding edge and
    the capture volume's far limit look alike on it; this tells the four-line method whether
    the background behind a face's edge lies far behind it or nowhere (where a window matcher
    fattens the edge) or just behind it (a table, which it hardly fattens). ``pixels`` are
    the lines' flat pixel indices concatenated, line ``i``'s in ``bounds[i]:bounds[i + 1]``.
    """
    d_row, d_col = _past_offsets(intrinsics, tuple(np.asarray(angles_rad).tolist()))
    return _past_ends(depth, intrinsics, d_row, d_col, pixels, bounds)


def _pixels_past_ends(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    d_row: np.ndarray,
    d_col: np.ndarray,
    d_flat: np.ndarray | None,
    pixels: np.ndarray,
    bounds: list[int],
    reach: int,
) -> tuple[list[int], np.ndarray, np.ndarray]:
    """The lines with a point, and past each of their two ends (rows in ``_past_offsets``'
    order) the flat indices of the pixels at the offsets ``d_row``, ``d_col`` (``d_flat``:
    the same as flat offsets, where given; ``reach`` the largest) and their depth units, 0
    outside the image."""
    count = len(bounds) - 1
    filled = [i for i in range(count) if bounds[i + 1] > bounds[i]]
    if not filled:
        return filled, _NO_INDICES, _NO_INDICES
    width, height = intrinsics.width, intrinsics.height
    ends = pixels[[j for i in filled for j in (bounds[i], bounds[i + 1] - 1)]]
    lines = [k for i in filled for k in (2 * i, 2 * i + 1)]
    if d_flat is None:
        offsets = d_row[lines] * width + d_col[lines]
    else:
        offsets = d_flat if len(filled) == count else d_flat[lines]
    flat = ends[:, None] + offsets
    # A handful of ends: Python ints for the bounds check, numpy only for the gather.
    if all(
        reach <= r < height - reach and reach <= c < width - reach
        for r, c in (divmod(e, width) for e in ends.tolist())
    ):
        return filled, flat, depth.reshape(-1)[flat]
    row, col = np.divmod(ends, width)
    r, c = row[:, None] + d_row[lines], col[:, None] + d_col[lines]
    inside = (r >= 0) & (r < height) & (c >= 0) & (c < width)
    return filled, flat, np.where(inside, depth.reshape(-1)[np.where(inside, flat, 0)], 0)


def _past_ends(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    d_row: np.ndarray,
    d_col: np.ndarray,
    pixels: np.ndarray,
    bounds: list[int],
) -> np.ndarray:
    """``past_line_ends`` with the lines' pixel offsets (``_past_offsets``) given."""
    filled, _, values = _pixels_past_ends(
        depth, intrinsics, d_row, d_col, None, pixels, bounds, int(_PAST_STEPS_PX[-1]) + 1
    )
    return _past_medians(len(bounds) - 1, filled, values, intrinsics.depth_scale)


def _past_medians(
    count: int, filled: list[int], values: np.ndarray, depth_scale: float
) -> np.ndarray:
    """(count, 2) ``past_line_ends`` of the ``filled`` lines' end pixels' depth ``values``
    (rows as ``_pixels_past_ends`` gives them)."""
    if not filled:
        return np.zeros((count, 2))
    medians = []
    for row_values in values.tolist():
        # filter(None, ...) drops the 0s (no depth) in C, where a generator ran Python per
        # value: 8 ends of 12 pixels a frame.
        valid = sorted(filter(None, row_values))
        n = len(valid)
        medians.append(0.5 * (valid[(n - 1) // 2] + valid[n // 2]) * depth_scale if n else 0.0)
    if len(filled) == count:
        # Every line has points (nearly every frame): no zeroed array to scatter them into.
        return np.array(medians).reshape(count, 2)
    out = np.zeros((count, 2))
    out[filled] = np.array(medians).reshape(-1, 2)
    return out


def _far_points(
    count: int,
    filled: list[int],
    flat: np.ndarray,
    values: np.ndarray,
    intrinsics: Intrinsics,
    geometry: _Geometry,
) -> np.ndarray:
    """(L, 2, 3): per line, the point of the first pixel within ``_FAR_STEPS_PX`` past its
    first and last point along it whose depth lies beyond the capture volume's far limit
    (``geometry.far_units``), zeros where none does (or the line has no point). ``flat`` and
    ``values``: the ``filled`` lines' end pixels and their depth, as ``_pixels_past_ends``
    gives them.

    The lines hold every pixel of the capture volume along them, so this is the first
    background seen past a line's end beyond what the line holds: an object's silhouette
    lies between the line's last sample on it and that pixel (a matcher fattens an edge
    outward over the background, or leaves a hole beside it, and does not carry the far
    background's depth onto the object)."""
    out = np.zeros((count, 2, 3))
    if not filled:
        return out
    width = intrinsics.width
    beyond = values > geometry.far_units
    # A handful of ends: their points in Python floats (numpy's per-call cost dominates).
    fx, fy, ppx, ppy = intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy
    rows = out.reshape(-1, 3)
    # The ufunc's reduction and the mask's own nonzero, not .any and np.flatnonzero: their
    # Python wrappers cost more than the test on a handful of ends.
    hits = np.logical_or.reduce(beyond, axis=1).nonzero()[0].tolist()
    if not hits:
        return out
    steps = beyond.argmax(axis=1).tolist()
    for k in hits:
        step = steps[k]
        r, c = divmod(int(flat[k, step]), width)
        z = float(values[k, step]) * intrinsics.depth_scale
        rows[2 * filled[k // 2] + k % 2] = (z * (c - ppx) / fx, z * (r - ppy) / fy, z)
    return out


# A line's end surface is the straight line through its last _EDGE_FIT_SAMPLES samples (in
# the scan plane); a pixel past the end leaves it where its depth lies more than _EDGE_OFF_M
# off that line (as laser._PAST_ON_FACE_M reads the depth past a line's end on the face) or
# has none. Only ends within _EDGE_SIDE_M of the capture volume's sides are walked: elsewhere
# the line's own samples show where it leaves the face (laser.crop_margin_m is 1.5 mm).
_EDGE_FIT_SAMPLES = 20
_EDGE_OFF_M = 0.003
_EDGE_SIDE_M = 0.003


def _edge_points(
    count: int,
    filled: list[int],
    values: np.ndarray,
    pts: np.ndarray,
    bounds: list[int],
    intrinsics: Intrinsics,
    params: ScanParams,
    geometry: _Geometry,
) -> np.ndarray:
    """(L, 2, 3): per line, where it leaves the face past its first and last point when that
    point lies at the capture volume's side (within _EDGE_SIDE_M of it in x or y): the point,
    on the straight line (in the scan plane) through the line's last _EDGE_FIT_SAMPLES
    samples at that end, half a pixel before the first pixel within ``_FAR_STEPS_PX`` past
    the end whose depth lies off that straight line by more than _EDGE_OFF_M or is missing
    with none past it back on the line; zeros where every pixel there stays on it, the end
    lies inside the capture volume, or the line has fewer samples than the fit takes. ``pts``
    are the lines' points concatenated (line ``i``'s in ``bounds[i]:bounds[i + 1]``),
    ``values`` the depth of the ``filled`` lines' pixels past their ends, as
    ``_pixels_past_ends`` gives them.

    A line keeps only the samples inside the capture volume: where it is cut at the volume's
    side the face goes on past it, and the median depth 8-30 px past the end
    (``past_line_ends``) tells only whether the face ends within that window. The pixels past
    the end go on along the face's straight section in the scan plane until the face's edge,
    where a matcher puts the background's depth or none: that pixel locates the face's side
    to a pixel or so where it crosses the line (the 85 mm box tilted right fills the capture
    volume and keeps about one uncut seed a side)."""
    out = np.zeros((count, 2, 3))
    n, side = _EDGE_FIT_SAMPLES, _EDGE_SIDE_M
    (x0, x1), (y0, y1) = params.x_limits_m, params.y_limits_m
    # A handful of ends: Python floats throughout (numpy's per-call cost dominates), and the
    # walk stops at the first pixel off the face (2-4 px past a cut end, median).
    ends = pts[[j for i in filled for j in (bounds[i], bounds[i + 1] - 1)]].tolist()
    todo = [
        r for r, (x, y, _) in enumerate(ends)
        if (x <= x0 + side or x >= x1 - side or y <= y0 + side or y >= y1 - side)
        and bounds[filled[r // 2] + 1] - bounds[filled[r // 2]] >= n
    ]  # fmt: skip
    if not todo:
        return out
    scale, fx, fy = intrinsics.depth_scale, intrinsics.fx, intrinsics.fy
    rows = out.reshape(-1, 3)
    for r, depths in zip(todo, values[todo].tolist(), strict=True):
        i = filled[r // 2]
        lo = bounds[i] if r % 2 == 0 else bounds[i + 1] - n
        cos, sin = geometry.cos_sin[i]
        # Least squares z = a + b s in the scan plane over the end's samples (sums in one
        # pass of Python floats: numpy's calls cost more than 20 samples' arithmetic).
        s1 = s2 = z1 = sz = 0.0
        for x, y, z in pts[lo : lo + n].tolist():
            s = x * cos + y * sin
            s1 += s
            s2 += s * s
            z1 += z
            sz += s * z
        var = n * s2 - s1 * s1
        if var <= 0.0:
            continue
        b = (n * sz - s1 * z1) / var
        a = (z1 - b * s1) / n
        k = r % 2
        x, y, z_end = ends[r]
        q0 = (x * cos + y * sin) / z_end
        offsets = geometry.ends_q[2 * i + k]
        # A hole (no depth) ends the face only where no pixel past it comes back onto the
        # straight line: a block matcher leaves holes inside a face too (BM 5's tilted box),
        # and at the edge the hole runs on out of the walk. One with the background's depth
        # past it is the band where the matcher dropped the windows straddling the edge (its
        # left-right check fails there): the edge lies anywhere in it, and its first pixel
        # up to 3 mm before the edge (BM 5, the box tilted right, trial 0 frame 2; SGBM 9,
        # the box tilted left, trial 1 frame 1): no point there.
        hole = -1
        for step, d in enumerate(depths):
            den = 1.0 - b * (q0 + offsets[step])
            if den <= 0.0:
                break
            if d == 0:
                hole = step if hole < 0 else hole
                continue
            if abs(d * scale - a / den) > _EDGE_OFF_M:
                break
            hole = -1
        else:
            if hole < 0:
                continue
            step = hole
        if hole >= 0 and step != hole:
            continue
        # Half a pixel before the first pixel off (step j is j + 1 px past the end), along
        # the line's image direction: a pixel there moves s / z by 1 / |(fx cos, fy sin)|.
        q = q0 + (step + 0.5) * (1.0 if k else -1.0) / math.hypot(fx * cos, fy * sin)
        den = 1.0 - b * q
        if den > 0.0:
            z = a / den
            rows[2 * i + k] = (q * z * cos, q * z * sin, z)
    return out


@lru_cache(maxsize=16)
def _past_offsets(
    intrinsics: Intrinsics, angles_rad: tuple[float, ...], far: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """(2L, steps) row and column offsets of the pixels past each line's first end (row 2i,
    walking back along the line) and last end (row 2i + 1, walking on): ``_PAST_STEPS_PX``
    past it, or ``_FAR_STEPS_PX`` where ``far``."""
    steps = _FAR_STEPS_PX if far else _PAST_STEPS_PX
    angles = np.asarray(angles_rad, dtype=np.float64)
    du, dv = intrinsics.fx * np.cos(angles), intrinsics.fy * np.sin(angles)
    norm = np.hypot(du, dv)
    sign = np.tile([-1.0, 1.0], len(angles))
    du, dv = np.repeat(du / norm, 2) * sign, np.repeat(dv / norm, 2) * sign
    d_row = np.rint(dv[:, None] * steps).astype(np.int64)
    d_col = np.rint(du[:, None] * steps).astype(np.int64)
    d_row.setflags(write=False)
    d_col.setflags(write=False)
    return d_row, d_col


def capture_points(
    depth: np.ndarray, intrinsics: Intrinsics, params: ScanParams = ScanParams()
) -> np.ndarray:
    """(N, 3) every valid point inside the capture volume, camera frame, metres, row-major."""
    depth = _check_depth(depth, intrinsics)
    win = _volume_window(intrinsics, params)
    d = depth[win.rows, win.cols]
    rows, cols = np.nonzero((d >= win.lo_units) & (d <= win.hi_units))
    z = d[rows, cols] * intrinsics.depth_scale
    return np.column_stack([z * win.slope_x[0, cols], z * win.slope_y[rows, 0], z])


def residual_correlation(
    angles_rad: object,
    points: tuple[np.ndarray, ...] | list[np.ndarray],
    piece: int = 20,
    segment_gap_m: float = 0.008,
    smooth_m: float = 0.0015,
) -> float:
    """How a depth frame's errors run along its scan lines: the mean lag-1 autocorrelation of
    each smooth piece's residuals (``piece`` samples, a quadratic in s fitted by least
    squares), over the pieces no residual of which exceeds ``smooth_m``. 0 when none is.

    The simulated SGBM's depth errors are shared by neighbouring samples (lag 1 about 0.4,
    lag 2 about 0), lpc's noise model's are independent per pixel, and the 1 mm quantum of
    an exact depth is too: on the noise model this reads -0.10 ± 0.08 (at most 0.22 over
    the 2950 frames of ``lpc bench accuracy --quick --trials 5``), on exact depth -0.09, on
    SGBM 0.36-0.38 at every block size, dot density and uniqueness, on BM 0.12-0.13 (at
    most 0.55; the quantum hides most of its correlation). It tells an SGBM-like matcher
    from per-pixel noise; it follows neither the window's size nor the fattening.
    ``points`` are each line's (N_i, 3) points sorted along the line, as ``ScanLines``
    holds them.

    Nor does any longer view of the same residuals (functional set, 50-100 frames a
    setting, median [10th, 90th percentile] per frame). The lag at which the full image's
    rows' residuals (1/z against a quadratic in u, 48 px pieces) halve: SGBM block 3 1.73
    [1.36, 1.96] px, 5 2.08, 7 2.26 [1.77, 2.48], 9 2.34, 11 2.40 [1.86, 2.65], P1 x 3 and
    P2 x 6 2.22, BM 7-11 1.3-1.5, noise model 0.57: SGBM's sub-pixel error (0.04 px, 0.15
    mm at 200 mm) lies under the 1 mm quantum, and what shows is its pixel-locked staircase,
    whose period follows the surface's slope. Yet the fattening a box's free sides need
    taken off follows the smoothness more than the window: untrimmed, on the frames the
    gate passes, the four-line box sides lie 2.6, 3.2, 5.0, 5.7, 5.8 px out at SGBM blocks
    3-11, 5.7 at P2 x 2, 8.0 at P1 x 3 and P2 x 6, while the plateau that
    ``laser._fattening`` measures where a face run shows it reads 2.8-3.7 px (median) at
    every one of them. Taking the quantum's power (quantum^2 / 12 a sample) out of the
    pooled power reads SGBM 0.53-0.68 and the noise model at most 0.16, but passes 44-62 %
    of BM's frames, whose windows then over-trim (BM 5 four-line boxes 3.4 -> 5.4-6.1 mm,
    and the full cloud handles one irregular object fewer on BM 5-9), and reads -0.25 on
    SGBM 7 at 848 x 480, where the quantum swamps the error altogether.
    """
    # Every line long enough at once, each its own slice of one array: a frame's few lines
    # cost numpy's per-call overhead, not arithmetic (the same products, differences and sums
    # per sample as line by line, so the same value to the bit).
    kept = [
        (phi, pts) for phi, pts in zip(np.asarray(angles_rad, dtype=np.float64).tolist(), points,
                                       strict=True) if len(pts) >= piece
    ]  # fmt: skip
    if not kept:
        return 0.0
    joined = np.concatenate([pts for _, pts in kept])
    counts = [len(pts) for _, pts in kept]
    cos = np.array([math.cos(phi) for phi, _ in kept], dtype=joined.dtype).repeat(counts)
    sin = np.array([math.sin(phi) for phi, _ in kept], dtype=joined.dtype).repeat(counts)
    s = joined[:, 0] * cos + joined[:, 1] * sin
    # Steps across the joins between lines are no line's: passed over below.
    gaps = (squared_steps(joined) > segment_gap_m**2).nonzero()[0].tolist()
    starts: list[int] = []
    offset = 0
    for n in counts:
        inside = gaps[bisect.bisect_left(gaps, offset) : bisect.bisect_left(gaps, offset + n - 1)]
        bounds = [offset, *(g + 1 for g in inside), offset + n]
        for a, b in itertools.pairwise(bounds):
            starts.extend(range(a, a + piece * ((b - a) // piece), piece))
        offset += n
    if not starts:
        return 0.0
    at = np.array(starts)[:, None] + np.arange(piece)
    s_all, z_all = s[at], joined[:, 2][at]
    # The methods' reductions, without np.mean's and np.ptp's Python wrappers (the same sums,
    # divided by the same count; the maximum less the minimum).
    x = s_all - np.add.reduce(s_all, axis=1, keepdims=True) / piece
    x /= np.maximum(
        np.maximum.reduce(x, axis=1, keepdims=True) - np.minimum.reduce(x, axis=1, keepdims=True),
        1e-12,
    )
    vander = np.empty((*x.shape, 3), dtype=x.dtype)
    np.multiply(x, x, out=vander[:, :, 0])
    vander[:, :, 1], vander[:, :, 2] = x, 1.0
    q = _orthonormal_columns(vander)
    r = z_all - np.einsum("pij,pj->pi", q, np.einsum("pij,pi->pj", q, z_all))
    power = np.einsum("pi,pi->p", r, r)
    # The ufuncs' reductions, not the methods' and np.mean's Python wrappers (the same
    # maximum; the same sum over the same count, in the points' precision).
    keep = (np.maximum.reduce(np.abs(r), axis=1) <= smooth_m) & (power > 0)
    if not np.logical_or.reduce(keep):
        return 0.0
    lag1 = np.einsum("pi,pi->p", r[keep, :-1], r[keep, 1:])
    shares = lag1 / power[keep]
    return float(np.add.reduce(shares) / len(shares) * piece / (piece - 1))


def _orthonormal_columns(a: np.ndarray) -> np.ndarray:
    """``np.linalg.qr(a)[0]`` for a stack of tall matrices, to the bit: the same Householder
    factorisation and the same Q built from it in double (the gufuncs ``qr`` calls), cast back
    to ``a``'s type, without the R that ``qr`` forms and drops (a ``triu``), its checks and
    its two error states (42 -> 20 us a call on a frame's pieces). Matrices that are not all
    finite go through ``np.linalg.qr``, which raises or warns as it always did, and so does
    every matrix on a numpy without those gufuncs."""
    if _QR_R_RAW is None or not np.isfinite(np.add.reduce(a, axis=None)):
        return np.linalg.qr(a)[0]
    work = a.astype(np.float64)  # a copy: the factorisation overwrites it
    tau = _QR_R_RAW(work, signature="d->d")
    return _umath_linalg.qr_reduced(work, tau, signature="dd->d").astype(a.dtype, copy=False)


def squared_steps(points: np.ndarray) -> np.ndarray:
    """(N - 1,) squared distance between consecutive points (einsum's sum of squares)."""
    return einsum_norms(np.diff(points, axis=0))
