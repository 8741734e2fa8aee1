"""Vectorised RANSAC over the scan lines of a frame, apart from any model.

The machinery the fits in :mod:`lpc_core.perception.fit` share: checking their arguments,
drawing ``(lines, trials, k)`` minimal samples at once (Floyd's algorithm, one column at a time),
the standard adaptive trial bound, the :class:`Segments` layout that puts several scan lines side
by side so one numpy call serves them all, and the loop that hands chunks of samples to a
model's scorer and keeps each line's best hypothesis. A model enters only through its scorer
(:data:`Scorer`), which turns sample indices into each line's best ``(count, cost, params)``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import numpy as np

__all__ = [
    "CONFIDENCE",
    "Best",
    "Scorer",
    "Segments",
    "as_points",
    "as_segments",
    "check_goals",
    "check_limits",
    "check_threshold",
    "check_trials",
    "checked",
    "draw_batch",
    "draw_samples",
    "on_rows",
    "pick_rows",
    "ransac",
    "trials_needed",
]

CONFIDENCE = 0.99


def as_points(points: np.ndarray, name: str = "points") -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite")
    return arr


def check_threshold(threshold: float) -> float:
    t = float(threshold)
    if not (math.isfinite(t) and t > 0.0):
        raise ValueError(f"threshold must be a finite positive distance in metres, got {threshold}")
    return t


def check_limits(limits: tuple[float, float] | None, name: str) -> tuple[float, float]:
    """``(low, high)`` as floats; None is no limit, ``(0, inf)``, as in PCL's models."""
    if limits is None:
        return 0.0, math.inf
    try:
        lo, hi = (float(v) for v in limits)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (low, high) in metres, got {limits!r}") from None
    if not (math.isfinite(lo) and 0.0 <= lo < hi) or math.isnan(hi):
        raise ValueError(f"{name} must satisfy 0 <= low < high, got {limits!r}")
    return lo, hi


def check_trials(trials: tuple[int, int], confidence: float, name: str = "trials") -> None:
    lo, hi = trials
    if int(hi) != hi or hi < 1:
        raise ValueError(f"max_trials ({name}) must be a positive integer, got {hi}")
    if int(lo) != lo or lo < 1:
        raise ValueError(f"min_trials ({name}) must be a positive integer, got {lo}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be within (0, 1), got {confidence}")


def draw_batch(rng: np.random.Generator, n: np.ndarray, size: int, k: int) -> np.ndarray:
    """``(L, size, k)`` indices, row ``l`` into ``range(n[l])``, distinct within each sample.

    Floyd's algorithm, one column at a time for all samples: for j = n-k .. n-1 draw v
    uniform in [0, j] and take v, or j if v is already in the sample. Every k-subset is equally
    likely (the order within a sample is not uniform, which no model here cares about); no
    sorting. The columns are worked on as contiguous ``(k, L, size)`` blocks (strided columns
    cost a third more) and returned as a view in ``(L, size, k)`` order. With one row it
    draws exactly what ``draw_samples`` draws.
    """
    # The uniforms are drawn in (L, size, k) order, as ever, and scaled into column blocks,
    # truncated to indices on their way out of the product (astype's cast, without the float
    # block in between).
    u = rng.random((n.shape[0], size, k)).transpose(2, 0, 1)
    v = np.empty(u.shape, dtype=np.intp)
    np.multiply(u, n[:, None] + _FLOYD_OFFSETS[k], out=v, casting="unsafe")
    fill = n[:, None] + _FLOYD_TOPS[k]  # (k, L, 1): column j takes n - k + j when v is taken
    for col in range(1, k):
        current = v[col]
        # Compare with each earlier column: cheaper than an any() reduction at this size.
        taken = current == v[0]
        for c in range(1, col):
            taken |= current == v[c]
        np.copyto(current, fill[col], where=taken)
    return v.transpose(1, 2, 0)


# Column j of a sample of k draws from [0, n - k + j]: n + (1 - k + j) values, the top one
# n - k + j.
_FLOYD_OFFSETS = {k: np.arange(1.0 - k, 1.0)[:, None, None] for k in range(1, 8)}
_FLOYD_TOPS = {k: np.arange(-k, 0)[:, None, None] for k in range(1, 8)}


def draw_samples(rng: np.random.Generator, n: int, size: int, k: int) -> np.ndarray:
    """``(size, k)`` indices into ``range(n)``, distinct within each row (see ``draw_batch``)."""
    return draw_batch(rng, np.array([n]), size, k)[0]


@functools.lru_cache(maxsize=4096)
def trials_needed(n_inliers: float, n: int, k: int, confidence: float) -> float:
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


class Segments:
    """Scan lines side by side, so that one numpy call serves every line of a frame.

    Row ``l`` holds line ``l``'s ``(N_l, 2)`` points, centred on their mean (``x``, ``y``) and
    as given (``ox``, ``oy``), padded with NaN to a common width plus one NaN column: padded
    entries fail every inlier test by themselves, and a sample index pointing at the last
    column reads NaN. With ~100 points per line the fits are bound by numpy's per-call
    overhead, not by arithmetic, so four lines cost little more than one.

    Parameters
    ----------
    points : sequence of (N_l, 2) arrays
        Each scan line's points in its plane, metres (validated as by ``fit_line``).
    """

    __slots__ = (
        "_bases",
        "count",
        "mean",
        "n",
        "ox",
        "oy",
        "points",
        "valid",
        "width",
        "x",
        "y",
    )

    def __init__(self, points: Sequence[np.ndarray], *, validated: bool = False) -> None:
        pts = list(points) if validated else [as_points(p) for p in points]
        self.points = pts
        self.n = n = [p.shape[0] for p in pts]
        self.count = count = len(pts)
        self.width = width = (max(n) if n else 0) + 1
        raw = np.zeros((2, count, width))
        for i, p in enumerate(pts):
            raw[:, i, : n[i]] = p.T
        counts = np.array(n, dtype=np.float64)
        self.valid = valid = np.arange(width) < counts[:, None]
        # The points are finite and every divisor at least 1: no floating-point error to
        # silence (an error state costs more than the arithmetic here).
        mean = np.add.reduce(raw, axis=2) / np.maximum(counts, 1.0)
        given = np.where(valid, raw, np.nan)
        # Padding stays NaN through the subtraction (a quiet NaN raises no error).
        centred = given - mean[:, :, None]
        # Indexed, not unpacked: iterating an array ends on a formatted IndexError.
        self.x, self.y = centred[0], centred[1]
        self.ox, self.oy = given[0], given[1]
        self.mean = mean.T.tolist()
        self._bases: dict[str, np.ndarray] = {}

    def take(self, rows: Sequence[int]) -> Segments:
        """The lines ``rows`` only, sharing this batch's centring."""
        out = object.__new__(Segments)
        idx = np.asarray(rows, dtype=np.intp)
        out.points = [self.points[r] for r in rows]
        out.n = [self.n[r] for r in rows]
        out.count, out.width = len(out.n), self.width
        out.valid, out.x, out.y = (a.take(idx, axis=0) for a in (self.valid, self.x, self.y))
        out.ox, out.oy = self.ox.take(idx, axis=0), self.oy.take(idx, axis=0)
        out.mean = [self.mean[r] for r in rows]
        out._bases = {k: v.take(idx, axis=0) for k, v in self._bases.items()}
        return out

    def offsets(self, count: int) -> np.ndarray:
        """Flat offsets of ``count`` rows, to gather ``(L, T, k)`` sample indices at once."""
        return _row_offsets(self.width, count)

    def gather_offsets(self, name: str, count: int) -> np.ndarray:
        """``(2, 1, count, 1)`` flat offsets of ``count`` lines' ``x`` and ``y`` rows in
        ``basis(name)``: added to ``(k, L, T)`` sample indices, one ``take`` gathers the
        samples' coordinates as ``(2, k, L, T)``."""
        return _gather_offsets(self.basis(name).shape[1], self.width, count)

    def basis(self, name: str) -> np.ndarray:
        """``(L, m, W)`` monomials of the centred points, built once per batch."""
        found = self._bases.get(name)
        if found is None:
            # Filled row by row (np.stack's Python wrapper costs more than the copies).
            x, y = self.x, self.y
            line = name == "line"
            found = np.empty((self.count, 3 if line else 4, self.width))
            found[:, 0], found[:, 1], found[:, -1] = x, y, 1.0
            if not line:
                np.add(x * x, y * y, out=found[:, 2])
            self._bases[name] = found
        return found


# The offsets depend on the layout's sizes alone, which repeat from frame to frame (a width is
# a frame's longest line plus one): built once each, read-only, rather than once a fit.
@functools.lru_cache(maxsize=1024)
def _row_offsets(width: int, count: int) -> np.ndarray:
    return _read_only((np.arange(count) * width)[:, None, None])


@functools.lru_cache(maxsize=1024)
def _gather_offsets(monomials: int, width: int, count: int) -> np.ndarray:
    lines = (np.arange(count) * (monomials * width))[:, None]
    return _read_only(lines + np.array([0, width])[:, None, None, None])


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def as_segments(points: Segments | Sequence[np.ndarray]) -> Segments:
    return points if isinstance(points, Segments) else Segments(points)


def check_goals(min_inliers: Sequence[float] | None, seg: Segments) -> list[float] | None:
    if min_inliers is None:
        return None
    goals = [float(g) for g in min_inliers]
    if len(goals) != seg.count or not all(math.isfinite(g) for g in goals):
        raise ValueError(f"min_inliers must hold one finite count per line, got {min_inliers!r}")
    return goals


def checked(
    segments: Segments | Sequence[np.ndarray],
    threshold: float,
    trials: tuple[int, int],
    confidence: float,
    min_inliers: Sequence[float] | None = None,
) -> tuple[Segments, float, list[float] | None]:
    """The arguments every public fit takes, checked once for all of them: the scan lines,
    the threshold, the ``(min_trials, max_trials)`` budget and confidence, and the optional
    per-line ``min_inliers``. Bad ones raise ``ValueError`` naming them."""
    seg = as_segments(segments)
    t = check_threshold(threshold)
    check_trials(trials, confidence)
    return seg, t, check_goals(min_inliers, seg)


# A batch scorer takes (L', T, k) sample indices for the rows (scan lines) ``rows`` (None: every
# row) and returns each row's best hypothesis as (inlier count, cost, parameters), or None where
# no sample gave a valid hypothesis. Lines and circles rank by count, ties by cost = residual
# sum over the inliers; the ellipse ranks by cost alone, MSAC's truncated quadratic (see
# fit_ellipse). Counts may be on a fixed subsample (the ellipse's): the RANSAC bound then uses
# that subsample's size.
Best = tuple[int, float, tuple[float, ...]]
Scorer = Callable[[np.ndarray, np.ndarray | None], list[Best | None]]


def on_rows(rows: np.ndarray | None, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """A scorer's per-line ``arrays`` (lines on the first axis) cut to the lines ``rows``
    still searched; None keeps every line."""
    return arrays if rows is None else tuple(a.take(rows, axis=0) for a in arrays)


def ransac(
    n: list[int],
    rows: list[int],
    k: int,
    rng: np.random.Generator,
    trials: tuple[int, int],
    confidence: float,
    score: Scorer,
    n_scored: list[int],
    by_cost: bool = False,
    goals: Sequence[float] | None = None,
) -> tuple[list[Best | None], list[int]]:
    """RANSAC on the scan lines ``rows`` at once: each line keeps its own best hypothesis and
    its own adaptive budget; a chunk of samples goes to every line that still needs one.

    ``goals`` (per line, in scored points) is the inlier count a hypothesis must reach to be
    of any use to the caller: the budget is the standard bound for the larger of it and the
    best count so far, so a line is not searched further for a model that, if it existed,
    would already have been drawn at ``confidence``.
    """
    min_trials, max_trials = trials
    best: list[Best | None] = [None] * len(n)
    done = [0] * len(n)
    goal = [0.0] * len(n) if goals is None else [float(g) for g in goals]
    needed = [
        float(max_trials) if g <= 0.0 else trials_needed(g, m, k, confidence)
        for g, m in zip(goal, n_scored, strict=True)
    ]
    size, spent = min(min_trials, max_trials), 0
    while rows and size > 0:
        idx = draw_batch(rng, np.array([n[r] for r in rows]), size, k)
        found = score(idx, None if len(rows) == len(n) else np.array(rows))
        spent += size
        active, remaining = [], 0.0
        for r, f in zip(rows, found, strict=True):
            done[r] = spent
            b = best[r]
            if f is not None and (
                b is None
                or (by_cost and f[1] < b[1])
                or (not by_cost and (f[0], -f[1]) > (b[0], -b[1]))
            ):
                best[r] = f
                needed[r] = trials_needed(max(f[0], goal[r]), n_scored[r], k, confidence)
            left = min(float(max_trials), needed[r]) - spent
            if left > 0:
                active.append(r)
                remaining = max(remaining, left)
        # Rows still active have all drawn every chunk so far: one size serves them all.
        rows = active
        size = min(max(math.ceil(remaining), min_trials), max_trials - spent) if rows else 0
    return best, done


def pick_rows(
    inl: np.ndarray, residual_sums: Callable[[np.ndarray, np.ndarray], np.ndarray]
) -> list[tuple[int, int, float]]:
    """Each line's hypothesis with the most inliers ``inl`` (L, T, W); ties go to the lowest
    residual sum, then the first. ``(t, count, residual sum)`` per line; the sums are computed
    for the tied hypotheses only (``residual_sums(lines, hypotheses)``)."""
    # Counting the bytes in their own type runs without a buffered cast (numpy's bool sum
    # casts every element to int64): uint8 where no count can pass 255 (a line's points and
    # its padding), else through uint16.
    kind = np.uint8 if inl.shape[2] <= 255 else np.uint16
    counts = np.add.reduce(inl.view(np.uint8), axis=2, dtype=kind)
    top = np.maximum.reduce(counts, axis=1)  # counts.max(axis=1) without its Python wrapper
    tl, tt = (counts == top[:, None]).nonzero()  # the method: no Python wrapper
    tops = top.tolist()
    sums = residual_sums(tl, tt).tolist()
    out: list[tuple[int, int, float]] = [(0, 0, math.inf)] * len(tops)
    for line, t, total in zip(tl.tolist(), tt.tolist(), sums, strict=True):
        if total < out[line][2]:
            out[line] = (t, tops[line], total)
    # A line whose tied sums are all NaN keeps its first tied hypothesis.
    return [
        o if o[2] < math.inf else (int(tt[tl == line][0]), tops[line], math.inf)
        for line, o in enumerate(out)
    ]
