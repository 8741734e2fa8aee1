"""Aim guidance: which way to move the hand so that the optical axis pierces an object.

Method (the paper's "Vibrotactile Feedback for Aiming Guidance"): the scan-line points inside
the capture volume are projected on the image plane xOy (z set to zero) and their convex hull
is taken. The axis is on target when the origin lies inside the hull; otherwise the shortest
vector ``v`` from the origin to the hull gives the cue,

    rho = min(|v| / width, 1),        theta = atan2(v_y, v_x)   (x right, y down),

with ``width`` the capture volume's width (100 mm). Four tactors sit 90 degrees apart around
the forearm; tactor ``k`` at image direction ``phi_k`` vibrates with

    a_k = (1 - rho) * max(0, 1 - |theta - phi_k| / 90 deg),

so the amplitude rises as the hull comes closer and is shared linearly between the two tactors
around ``theta`` (the shares sum to one). On target, all four vibrate; on target with a
reconstructed grasp target, all four pulse together (the bridge renders the pulse).

While the controller has stopped the hand (a stale grasp target, EMG or hand status: its state
``stopped`` on ``lpc/controller/state``), the cues are off: every frame still gives a cue and
a tactor command, with state ``nothing`` and all amplitudes 0, so the tactor bridge keeps
sending all-off; they come back with the first frame after the controller leaves ``stopped``.

Where lpc departs from the paper:

- Two objects in view are not merged into one hull (the paper's known weakness, whose cue can
  lead into the gap between them). Points are first split into objects by single linkage in
  3-D: two points closer than ``cluster_gap_m`` belong to the same object. The cue leads to the
  object that contains the axis or lies nearest to it.
- The supporting plane is no object: the table under the objects (the largest plane of the
  points with almost none behind it, spanning half the capture width or more) is set aside
  when an object stands in front of it. Without this, a small ball touching the table made
  one object of both, whose hull held the axis while it pointed at the table.
- Hysteresis: once on target, the cue stays on target until the axis leaves the hull by more
  than ``hysteresis_m``; the chosen object is kept while it stays within ``switch_margin_m`` of
  the nearest one, so the cue does not flicker between two objects at equal distance.
- Scan lines are planes through the optical axis, so their projected points lie on four lines
  through the origin and the hull is often a segment or a point. Those degenerate hulls are
  handled as such (distance to the segment or point), never as an error.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from lpc_core.control.state import evolve
from lpc_core.perception.cloud import SCAN_LINE_SUPPORT, find_support_plane
from schemas import (
    AimCue,
    ControllerState,
    GraspTarget,
    ProsthesisState,
    ScanLines,
    TactorCommand,
    from_wire,
    joined_points,
)

N_TACTORS = 4
CueState = Literal["nothing", "guiding", "on_target", "ready"]


def tactor_placement(
    arm: Literal["left", "right"] = "right", rotation_deg: float = 0.0
) -> tuple[float, ...]:
    """Image-plane direction (radians) that each tactor asks the user to move toward.

    Right arm: tactor ``k`` at ``rotation + k * 90 deg``, so by default tactor 0 means right
    (+x), 1 down (+y), 2 left, 3 up. Left arm: the order is mirrored, ``rotation - k * 90 deg``.
    ``rotation_deg`` is how far the sleeve (or the wrist carrying the camera) is turned.
    """
    if arm not in ("left", "right"):
        raise ValueError(f"arm must be 'left' or 'right', got {arm!r}")
    sign = 1.0 if arm == "right" else -1.0
    return tuple(
        math.radians(rotation_deg + sign * 90.0 * k) % (2 * math.pi) for k in range(N_TACTORS)
    )


@dataclass(frozen=True)
class AimParams:
    """Parameters of the aim step, SI units. The capture volume is ``|x|, |y| <= half_width``
    and ``z_min <= z <= z_max``; ``width_m`` normalises the distance to the hull."""

    half_width_m: float = 0.050
    z_min_m: float = 0.150
    z_max_m: float = 0.250
    width_m: float = 0.100
    min_points: int = 10
    cluster_gap_m: float = 0.010
    min_cluster_points: int = 5
    hysteresis_m: float = 0.002
    switch_margin_m: float = 0.005
    track_radius_m: float = 0.020
    tactor_angles_rad: tuple[float, ...] = field(default_factory=tactor_placement)
    on_target_amplitude: float = 1.0
    target_max_age_ns: int = 1_000_000_000
    frequency_hz: float = 250.0
    # The supporting plane (the table under the objects) is no object to aim at: the largest
    # plane of the capture points with (almost) none behind it is set aside when an object
    # remains in front of it (a box face that fills the view stays).
    remove_support: bool = True
    # The camera turns with the wrist (on the hand, as in the paper) while the tactors stay on
    # the forearm: the tactor directions above are at wrist angle 0 and turn by minus the
    # hand's reported wrist angle (an axis seen at image angle a lies at wrist + a, as the
    # controller's set-point has it).
    follow_wrist: bool = False

    def __post_init__(self) -> None:
        positive = ("half_width_m", "width_m", "cluster_gap_m", "track_radius_m")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("hysteresis_m", "switch_margin_m", "target_max_age_ns"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must not be negative, got {getattr(self, name)}")
        if not 0 <= self.z_min_m < self.z_max_m:
            raise ValueError(
                f"z_min_m, z_max_m must satisfy 0 <= min < max, got {self.z_min_m}, {self.z_max_m}"
            )
        if self.min_points < 1 or self.min_cluster_points < 1:
            raise ValueError("min_points and min_cluster_points must be at least 1")
        if not 0 < self.on_target_amplitude <= 1:
            raise ValueError(
                f"on_target_amplitude must lie in (0, 1], got {self.on_target_amplitude}"
            )
        angles = np.sort(np.mod(self.tactor_angles_rad, 2 * np.pi))
        gaps = np.diff(np.append(angles, angles[0] + 2 * np.pi))
        if len(angles) != N_TACTORS or not np.allclose(gaps, np.pi / 2, atol=1e-6):
            raise ValueError("tactor_angles_rad must be four directions 90 degrees apart")


# --------------------------------------------------------------------------- geometry


def capture_points(lines: list[np.ndarray], params: AimParams) -> np.ndarray:
    """The points of all scan lines inside the capture volume, as one (N, 3) float64 array."""
    for i, line in enumerate(lines):
        if line.ndim != 2 or line.shape[1] != 3:
            raise ValueError(f"points of scan line {i} must have shape (N, 3), got {line.shape}")
    if not lines:
        return np.empty((0, 3))
    if len(lines) == 1:
        points = np.asarray(lines[0], dtype=float)
    else:
        points = np.concatenate([np.asarray(x, dtype=float) for x in lines])
    inside = (
        (np.abs(points[:, 0]) <= params.half_width_m)
        & (np.abs(points[:, 1]) <= params.half_width_m)
        & (points[:, 2] >= params.z_min_m)
        & (points[:, 2] <= params.z_max_m)
    )
    return points[inside]


# Cube keys (x, y, z) -> (x * R + y) * R + z with R = 2**17: exact in float64 (below 2**53)
# and in (x, y, z) order for cell indices within +-R / 2 (163 m at a 10 mm gap).
_CELL_RADIX = np.array([2.0**34, 2.0**17, 1.0])
_CELL_LIMIT = 2.0**16
_LEAF_CUBES = 256  # cKDTree brute-forces a leaf: a frame's cubes fit in one


def cluster_points(points: np.ndarray, gap_m: float) -> np.ndarray:
    """Single-linkage labels (N,): points closer than ``gap_m`` (3-D) share an object.

    Linkage runs on one representative point per cube of side ``gap_m / 4``, so the gap is
    honoured to within that resolution; this keeps a 90 Hz frame's clustering well under a
    millisecond (linking every raw point pair costs ~10 ms at 1300 points).
    """
    n = len(points)
    if n == 0:
        return np.empty(0, dtype=np.intp)
    cells = np.floor(np.divide(points, gap_m / 4.0))
    # Each cube's key in (x, y, z) cell order is one product with a fixed radix, in floats
    # that hold it exactly (no cell's span to find first: 16 -> 10 us a frame); the order,
    # and so every label, is the one any radix gives while the cells stay inside it.
    if not np.maximum.reduce(np.abs(cells), axis=None) < _CELL_LIMIT:
        raise ValueError(
            f"points must lie within +-{_CELL_LIMIT * gap_m / 4.0:g} m to be clustered"
        )
    keys = cells @ _CELL_RADIX
    # np.unique(keys, return_index=True, return_inverse=True) spelled out, without the
    # argument handling that cost as much as the sort: each cube's first point, cubes in key
    # order, and each point's cube.
    order = keys.argsort(kind="stable")
    ordered = keys[order]
    starts = np.empty(n, dtype=bool)
    starts[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=starts[1:])
    first = order[starts]
    cube = np.empty(n, dtype=np.intp)
    cube[order] = starts.cumsum() - 1
    # A frame's 30-220 cubes in one leaf: query_pairs then tests every pair's distance in C,
    # which costs less than walking a tree's node pairs (51 -> 42 us a frame on the
    # recordings, less at every size up to their 218 cubes); a larger cloud still splits, at
    # midpoints (balanced_tree=False: fewer instructions than medians). The search is exact
    # either way, so the pairs, and the components, are the same.
    pairs = cKDTree(points[first], leafsize=_LEAF_CUBES, balanced_tree=False).query_pairs(
        gap_m, output_type="ndarray"
    )
    return _components(len(first), pairs)[cube]


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected-component labels of ``n`` nodes joined by ``pairs`` (E, 2), each row
    ``i < j`` as query_pairs gives them, each component labelled by its smallest node.
    Shiloach-Vishkin in array operations: each pass hooks the larger root of every pair under
    the smaller, then jumps every pointer to its root, until every pair shares its root
    (scipy's csgraph costs more in set-up than this whole loop). Min-label propagation, which
    it replaced, took six passes of the edges on a recorded frame; this takes two or three."""
    parent = np.arange(n)
    if len(pairs) == 0:
        return parent
    i, j = pairs[:, 0], pairs[:, 1]
    # Every node is its own root to begin with, and query_pairs gives each pair as i < j: the
    # first pass hooks j under i without sorting the roots of each pair.
    high, low = j, i
    while True:
        np.minimum.at(parent, high, low)
        # Two jumps for each test: a pointer already at its root stays there, so jumping past
        # the fixed point costs one gather, against the test's comparison and reduction.
        # np.logical_and.reduce is what .all() runs, without its Python wrapper.
        while True:
            jumped = parent[parent]
            if np.logical_and.reduce(jumped == parent):
                break
            parent = jumped[jumped]
        roots_i, roots_j = parent[i], parent[j]
        if np.logical_and.reduce(roots_i == roots_j):
            return parent
        high, low = np.maximum(roots_i, roots_j), np.minimum(roots_i, roots_j)


# Unit directions every 45 degrees, counter-clockwise, for the Akl-Toussaint filter.
_OCTANTS = np.array(
    [[math.cos(k * math.pi / 4) for k in range(8)], [math.sin(k * math.pi / 4) for k in range(8)]]
)
_FLAT_M = 1e-9  # a hull thinner than this is a segment
# Each ring vertex's successor, for rings of up to eight vertices (one per direction).
_NEXT = [np.roll(np.arange(k), -1) for k in range(9)]


def without_support(points: np.ndarray, params: AimParams, seed: int = 0) -> np.ndarray:
    """``points`` without the supporting plane's, when the plane spans half the capture width
    or more and an object (``min_cluster_points``) stands in front of it; else ``points`` as
    they are. The plane is the cloud method's
    (``cloud.find_support_plane``): the largest with (almost) no point behind it."""
    # default_rng's own generator, PCG64 of the seed, built without its argument checks.
    rng = np.random.Generator(np.random.PCG64(seed))
    support = find_support_plane(points, SCAN_LINE_SUPPORT, rng)
    # A table spans the capture volume; a small flat object behind another does not.
    if support is None:
        return points
    # np.ptp(axis=0).max() without its Python wrappers: the same differences.
    plane_xy = points[support, :2]
    spans = np.maximum.reduce(plane_xy) - np.minimum.reduce(plane_xy)
    if max(spans.tolist()) < params.width_m / 2:
        return points
    rest = points[~support]
    return rest if len(rest) >= params.min_cluster_points else points


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Vertices (M, 2) of the convex hull of (N, 2) points, counter-clockwise for M >= 3.

    Degenerate input gives a degenerate hull: one point (M = 1) or the two ends of a segment
    (M = 2) when the points are collinear (within 1 nm), which projected scan lines often are.

    Andrew's monotone chain, after the Akl-Toussaint filter: the extreme points in eight
    directions span a polygon inside the hull, and no point inside it can be a vertex. Scan
    lines project onto lines through the origin, so few points survive, and a frame's hulls
    cost tens of microseconds (Qhull's set-up alone took ~120).
    """
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) == 0:
        raise ValueError(f"points must have shape (N, 2) with N >= 1, got {points.shape}")
    return np.array(_hull(points))


def _hull(points: np.ndarray) -> list[Point]:
    """``convex_hull`` of valid (N, 2) float points, as a list: the vertices are few, and
    plain floats cost less than small arrays in the steps that follow."""
    extremes = (points @ _OCTANTS).argmax(axis=0).tolist()
    # Consecutive directions often share their extreme point: keep each once, in order.
    starts = points[[e for k, e in enumerate(extremes) if k == 0 or e != extremes[k - 1]]]
    ring: list[list[float]] = starts.tolist()
    if len(ring) > 1 and ring[0] == ring[-1]:
        ring.pop()
        starts = starts[:-1]
    if len(ring) >= 3:
        # Each edge's start and direction as (k, 1) columns: the test below then runs on
        # (k, N) rows.
        edges = starts[_NEXT[len(ring)]] - starts
        ex, ey = edges.T[:, :, None]
        sx, sy = starts.T[:, :, None]
        # cross(edge, p - start) < 0: p lies right of (outside) that counter-clockwise edge;
        # a - b < 0 exactly when a < b for finite floats (subnormals kept), one pass fewer.
        outside = np.less(ex * (points[:, 1] - sy), ey * (points[:, 0] - sx))
        candidates = ring + points[np.logical_or.reduce(outside, axis=0)].tolist()
    else:
        candidates = points.tolist()
    hull = _monotone_chain(candidates)
    if len(hull) >= 3 and _thickness(hull) > _FLAT_M:
        return hull
    if len(hull) == 1 or max(math.dist(hull[0], q) for q in hull) <= 1e-12:
        return hull[:1]
    # Collinear: the segment between the two vertices farthest apart.
    ends = max(itertools.combinations(hull, 2), key=lambda pq: math.dist(*pq))
    return sorted(ends)


Point = tuple[float, float]


def _monotone_chain(points: list[list[float]]) -> list[Point]:
    """Hull vertices, counter-clockwise from the lowest-x point; collinear points dropped."""
    pts: list[Point] = sorted((x, y) for x, y in points)

    def half(seq: list[Point]) -> list[Point]:
        chain: list[Point] = []
        for p in seq:
            while len(chain) >= 2:
                (ax, ay), (bx, by) = chain[-2], chain[-1]
                if (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax) > 0.0:
                    break
                chain.pop()
            chain.append(p)
        return chain

    lower, upper = half(pts), half(pts[::-1])
    return lower[:-1] + upper[:-1] or pts[:1]


def _thickness(hull: list[Point]) -> float:
    """Twice the area over the longest edge: ~ the width of a thin polygon."""
    area2 = longest = 0.0
    (x0, y0) = hull[0]
    for (ax, ay), (bx, by) in zip(hull, hull[1:] + hull[:1], strict=True):
        area2 += (ax - x0) * (by - ay) - (ay - y0) * (bx - ax)
        longest = max(longest, math.hypot(bx - ax, by - ay))
    return abs(area2) / max(longest, 1e-300)


def hull_distance(vertices: np.ndarray) -> tuple[float, np.ndarray]:
    """Signed distance from the origin to a hull, and the hull's boundary point nearest to it.

    Negative inside (minus the distance to the nearest edge), positive outside. Points and
    segments have no inside.
    """
    signed, nearest = _hull_distance(
        [(x, y) for x, y in np.asarray(vertices, dtype=float).tolist()]
    )
    return signed, np.array(nearest)


def _hull_distance(hull: list[Point]) -> tuple[float, Point]:
    """``hull_distance`` of a hull given as its list of vertices. A hull has a handful of
    vertices: a loop over floats costs less than array operations on them."""
    if len(hull) == 1:
        x, y = hull[0]
        return float(np.hypot(x, y)), (x, y)
    closed = len(hull) >= 3
    starts = hull if closed else hull[:1]
    near_x, near_y = [], []
    inside = closed
    for (sx, sy), (bx, by) in zip(starts, hull[1:] + hull[:1], strict=False):
        ex, ey = bx - sx, by - sy
        # max(0.0, t) as np.clip has it: a t of -0.0 becomes +0.0.
        t = min(max(0.0, (-sx * ex + -sy * ey) / max(ex * ex + ey * ey, 1e-300)), 1.0)
        near_x.append(sx + t * ex)
        near_y.append(sy + t * ey)
        # The origin is inside a counter-clockwise polygon when it is left of every edge.
        inside = inside and ex * -sy - ey * -sx >= 0.0
    # numpy's hypot, not math's: they differ in the last bit now and then, and the cue's
    # recorded replays hold numpy's.
    dist = np.hypot(near_x, near_y)
    i = int(dist.argmin())
    return (-float(dist[i]) if inside else float(dist[i])), (near_x[i], near_y[i])


def _unit_clip(x: np.ndarray) -> np.ndarray:
    """``np.clip(x, 0.0, 1.0)`` for arrays without NaN, without clip's Python wrappers. The
    bound comes first: ``np.maximum(0.0, x)`` keeps a -0.0 as clip does, where
    ``np.maximum(x, 0.0)`` gives +0.0 and would change the encoded bytes."""
    return np.minimum(1.0, np.maximum(0.0, x))


def tactor_shares(theta: float, angles: tuple[float, ...]) -> np.ndarray:
    """Linear shares (n,) of direction ``theta`` between the two tactors around it; sum 1."""
    phi = np.asarray(angles, dtype=float)
    delta = np.angle(np.exp(1j * (theta - phi)))  # wrapped to (-pi, pi]
    return _unit_clip(1.0 - np.abs(delta) / (2 * np.pi / len(phi)))


# --------------------------------------------------------------------------- step


@dataclass(frozen=True)
class Guidance:
    """The cue of one frame, before it becomes messages."""

    state: CueState
    rho: float = 1.0
    theta_rad: float = 0.0
    amplitudes: tuple[float, ...] = (0.0,) * N_TACTORS
    objects: int = 0
    signed_distance_m: float = math.inf
    chosen_xy: tuple[float, float] | None = None


def guide(
    points: np.ndarray,
    params: AimParams,
    *,
    was_on_target: bool = False,
    chosen_xy: tuple[float, float] | None = None,
    tactor_angles_rad: tuple[float, ...] | None = None,
    seed: int = 0,
) -> Guidance:
    """The cue for capture-volume ``points`` (N, 3), given what the previous frame chose;
    ``tactor_angles_rad`` (default ``params.tactor_angles_rad``) are the tactors' image
    directions now; ``seed`` seeds the search for the supporting plane (the frame's seq)."""
    objects = object_points(points, params, seed)
    return _cue(
        None if objects is None else objects_in_view(objects, params),
        params,
        was_on_target=was_on_target,
        chosen_xy=chosen_xy,
        tactor_angles_rad=tactor_angles_rad,
    )


def object_points(points: np.ndarray, params: AimParams, seed: int = 0) -> np.ndarray | None:
    """The capture-volume ``points`` that may belong to objects: without the supporting plane
    (``remove_support``); ``None`` when there are too few to look at (``min_points``)."""
    if len(points) < params.min_points:
        return None
    return without_support(points, params, seed) if params.remove_support else points


@dataclass(frozen=True)
class InView:
    """The objects in view of one frame, one row each, in the image plane (xOy): the signed
    distance from the optical axis to the object's hull (negative inside), the hull's point
    nearest the axis, and the object's centroid."""

    signed_m: np.ndarray  # (K,)
    nearest_xy: np.ndarray  # (K, 2)
    centroids_xy: np.ndarray  # (K, 2)


def objects_in_view(points: np.ndarray, params: AimParams) -> InView | None:
    """The objects among ``points`` (N, 3): clusters of at least ``min_cluster_points``;
    ``None`` when there is none."""
    labels = cluster_points(points, params.cluster_gap_m)
    counts = np.bincount(labels)
    kept = (counts >= params.min_cluster_points).nonzero()[0]
    if len(kept) == 0:
        return None
    xy = points[:, :2]
    if len(kept) == 1 and counts[kept[0]] == len(points):
        groups = [np.ascontiguousarray(xy)]  # the common frame: one object and nothing else
    else:
        # Each object's points in their order, one mask each: a frame keeps one to four
        # objects (the rest are specks), where a stable sort of every label cost more.
        groups = [xy[labels == k] for k in kept.tolist()]
    found = [_hull_distance(_hull(members)) for members in groups]
    # members.mean(axis=0) without its argument handling: the same sum over the same array,
    # divided by the count.
    centroids = [np.add.reduce(members, axis=0) / len(members) for members in groups]
    return InView(
        np.array([s for s, _ in found]), np.array([xy for _, xy in found]), np.array(centroids)
    )


def frame_objects(scans: ScanLines, params: AimParams) -> InView | None:
    """The objects in view of one ``lpc/scans`` message (the supporting plane's search seeded
    by its frame); ``ValueError`` if a scan line is malformed. It depends on the frame alone,
    so a replay finds them in its worker processes."""
    points = capture_points(_line_points(scans), params)
    objects = object_points(points, params, scans.frame_seq)
    return None if objects is None else objects_in_view(objects, params)


def _line_points(scans: ScanLines) -> list[np.ndarray]:
    """The points of each scan line, as ``from_wire`` gives them (and with its errors); one
    array of them all where ``joined_points`` takes them, as the scans service sends them."""
    wires = [line.points for line in scans.lines]
    joined = joined_points(wires)
    return [joined] if joined is not None else [from_wire(w) for w in wires]


def _cue(
    view: InView | None,
    params: AimParams,
    *,
    was_on_target: bool,
    chosen_xy: tuple[float, float] | None,
    tactor_angles_rad: tuple[float, ...] | None,
) -> Guidance:
    if view is None:
        return Guidance("nothing")
    signed, nearest, centroids = view.signed_m, view.nearest_xy, view.centroids_xy
    pick = int(signed.argmin())
    if chosen_xy is not None:
        offsets = np.hypot(*(centroids - np.asarray(chosen_xy)).T)
        same = int(offsets.argmin())
        if offsets[same] <= params.track_radius_m and (
            signed[same] <= signed[pick] + params.switch_margin_m
        ):
            pick = same
    s = float(signed[pick])
    centroid = (float(centroids[pick, 0]), float(centroids[pick, 1]))
    on_target = s <= (params.hysteresis_m if was_on_target else 0.0)
    if on_target:
        amplitude = (params.on_target_amplitude,) * N_TACTORS
        return Guidance("on_target", 0.0, 0.0, amplitude, len(signed), s, centroid)
    rho = min(s / params.width_m, 1.0)
    theta = float(math.atan2(nearest[pick, 1], nearest[pick, 0]))
    angles = params.tactor_angles_rad if tactor_angles_rad is None else tactor_angles_rad
    shares = (1.0 - rho) * tactor_shares(theta, angles)
    amplitudes = tuple(float(a) for a in _unit_clip(shares))
    return Guidance("guiding", rho, theta, amplitudes, len(signed), s, centroid)


@dataclass(frozen=True)
class AimState:
    """What the aim step carries from frame to frame."""

    params: AimParams = field(default_factory=AimParams)
    on_target: bool = False
    chosen_xy: tuple[float, float] | None = None
    target: GraspTarget | None = None
    seq: int = 0
    # The controller's newest state; None until it is heard from (cues on: aiming works with
    # no controller running).
    controller: str | None = None
    wrist_deg: float = 0.0  # the hand's newest reported wrist angle

    @property
    def tactor_angles_rad(self) -> tuple[float, ...]:
        """The tactors' image directions at the current wrist angle."""
        if not self.params.follow_wrist or self.wrist_deg == 0.0:
            return self.params.tactor_angles_rad
        turn = math.radians(self.wrist_deg)
        return tuple((a - turn) % (2 * math.pi) for a in self.params.tactor_angles_rad)

    @property
    def cues_off(self) -> bool:
        """The controller has stopped the hand: the cues are off."""
        return self.controller == "stopped"


def aim_step(
    state: AimState,
    message: ScanLines | GraspTarget | ControllerState | ProsthesisState,
    now_ns: int,
) -> tuple[AimState, list[AimCue | TactorCommand]]:
    """One step: a grasp target, a controller state or the hand's status updates the state;
    scan lines give a cue and a tactor command (all off while the controller is ``stopped``).

    Both outputs carry the scans' capture ``t_ns``, so the tactor bridge can tell a stale cue
    and a latency measurement can follow a frame to the serial line.
    """
    del now_ns  # ages are measured between capture times, which replay reproduces
    if isinstance(message, GraspTarget):
        return evolve(state, target=message), []
    if isinstance(message, ControllerState):
        return evolve(state, controller=message.state), []
    if isinstance(message, ProsthesisState):
        return evolve(state, wrist_deg=message.wrist_angle_deg), []
    if not isinstance(message, ScanLines):
        raise ValueError(
            "message must be ScanLines, GraspTarget, ControllerState or ProsthesisState, "
            f"got {type(message)}"
        )
    return cue_step(state, message, frame_objects(message, state.params))


def cue_step(
    state: AimState, message: ScanLines, view: InView | None
) -> tuple[AimState, list[AimCue | TactorCommand]]:
    """The scan-lines half of ``aim_step``, on the frame's ``frame_objects`` (found here or by
    a replay's worker process)."""
    params = state.params
    tracked = _cue(
        view,
        params,
        was_on_target=state.on_target,
        chosen_xy=state.chosen_xy,
        tactor_angles_rad=state.tactor_angles_rad,
    )
    # Stopped: the geometry is still tracked, so the cue resumes where it would have been.
    g = Guidance("nothing", objects=tracked.objects) if state.cues_off else tracked
    target = state.target
    ready = (
        g.state == "on_target"
        and target is not None
        and target.reconstructed
        and abs(message.t_ns - target.t_ns) <= params.target_max_age_ns
    )
    cue_state: CueState = "ready" if ready else g.state
    seq = state.seq + 1
    cue = AimCue(
        seq=seq,
        t_ns=message.t_ns,
        frame_seq=message.frame_seq,
        state=cue_state,
        rho=g.rho,
        theta_deg=math.degrees(g.theta_rad),
        amplitudes=list(g.amplitudes),
        objects=g.objects,
    )
    command = TactorCommand(
        seq=seq,
        t_ns=message.t_ns,
        amplitudes=list(g.amplitudes),
        pulse=ready,
        frequency_hz=params.frequency_hz,
    )
    new_state = evolve(
        state, on_target=tracked.state == "on_target", chosen_xy=tracked.chosen_xy, seq=seq
    )
    return new_state, [cue, command]
