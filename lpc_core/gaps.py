"""Gaps in a recorded bus: a steady topic that fell silent, or a sequence number that jumped.

The recorder runs ``gap_step`` on every message it writes, and logs each gap on
``lpc/log/recorder``; ``lpc info`` runs it over a file, so a recording says where it has holes
whoever made it. A cut cable shows as one silence per steady topic from the far host, from the
last message before the cut to the first after it, with the messages lost on the way (by
``seq``).

Every publisher numbers its messages 1, 2, 3... per key, so a jump is a loss on the way, with
one exception: ``lpc/reconstruction`` and ``lpc/grasp/target`` carry the ``seq`` of the frame
they came from, and the reconstructor skips frames by design when it is busy. A ``seq`` that
goes back is a publisher that restarted, not a loss.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

# Keys whose seq is their source frame's: jumps are skipped frames, not losses.
SOURCE_SEQ_KEYS = frozenset({"lpc/reconstruction", "lpc/grasp/target"})

_set_attribute = object.__setattr__  # a frozen dataclass refuses plain assignment


@dataclass(frozen=True)
class GapParams:
    """A topic is steady once ``steady_count`` messages have come at ``steady_hz`` or faster
    (on average); a steady topic is silent when nothing came for ``silence_periods`` of its
    period, and at least ``min_silence_ms``. Logs (``lpc/log/``) come when something happens,
    so they are never steady."""

    steady_hz: float = 5.0
    steady_count: int = 20
    silence_periods: float = 10.0
    min_silence_ms: float = 500.0

    def __post_init__(self) -> None:
        for name in ("steady_hz", "silence_periods", "min_silence_ms"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


@dataclass(frozen=True)
class Gap:
    """A hole in one topic: nothing between ``start_ns`` and ``end_ns`` (receive times of the
    messages either side), ``missing`` messages lost by ``seq``, ``silent`` if it was long."""

    key: str
    start_ns: int
    end_ns: int
    missing: int
    silent: bool

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9

    def describe(self, origin_ns: int = 0) -> str:
        """One line; times in seconds from ``origin_ns`` (log time itself by default)."""
        what = f"silent {self.duration_s:.3f} s" if self.silent else "seq jump"
        start = (self.start_ns - origin_ns) / 1e9
        return f"gap on {self.key} from {start:.3f} s: {what}, {self.missing} missing by seq"


# A track is (seq, last_ns, period_ns, count): a plain tuple, because the recorder steps every
# message it writes and a tuple is the cheapest immutable record to build and unpack.
_Track = tuple[int, int, float | None, int]


@dataclass(frozen=True)
class GapState:
    params: GapParams = field(default_factory=GapParams)
    tracks: Mapping[str, _Track] = field(default_factory=lambda: MappingProxyType({}))
    gaps: int = 0
    missing: int = 0


def gap_step(state: GapState, key: str, seq: int, received_ns: int) -> tuple[GapState, list[Gap]]:
    """One message of ``key`` (its ``seq``, received at ``received_ns``); the gaps it closes."""
    return gap_steps(state, ((key, seq, received_ns),))


def gap_steps(
    state: GapState, messages: Iterable[tuple[str, int, int]]
) -> tuple[GapState, list[Gap]]:
    """``gap_step`` for each ``(key, seq, received_ns)`` in turn, and the gaps they close in
    order: the same end state, with one copy of the tracks for all. The recorder steps a
    hand-over's batch at once, where a new state a message (a copy of every track) was about
    half of a step's cost."""
    p = state.params
    steady_count, floor, periods = p.steady_count, p.min_silence_ms * 1e6, p.silence_periods
    steady_period = 1e9 / p.steady_hz
    # The proxy's copy() is its dict's: dict(proxy) would go key by key through the proxy.
    tracks = state.tracks
    tracks = tracks.copy() if isinstance(tracks, MappingProxyType) else dict(tracks)
    gaps: list[Gap] = []
    for key, seq, received_ns in messages:
        track = tracks.get(key)
        if track is None:
            tracks[key] = (seq, received_ns, None, 1)
            continue
        last_seq, last_ns, period, count = track
        dt = received_ns - last_ns
        missing = seq - last_seq - 1 if seq > last_seq and key not in SOURCE_SEQ_KEYS else 0
        silent = False
        if (
            period is not None
            and count >= steady_count
            and period <= steady_period
            and not key.startswith("lpc/log/")
        ):
            pace = periods * period
            # max(floor, pace) spelt out as max decides (floor unless pace is larger, so a NaN
            # pace gives floor): the builtin's call was ~1k of a step's ~14k instructions.
            silent = dt > (pace if pace > floor else floor)
        if silent or missing > 0:
            gaps.append(Gap(key, last_ns, received_ns, missing, silent))
        # The period follows the topic's normal pace: a silence does not stretch it.
        if not silent:
            period = float(dt) if period is None else 0.9 * period + 0.1 * dt
        tracks[key] = (seq, received_ns, period, count + 1)
    if not gaps:
        return _state(p, MappingProxyType(tracks), state.gaps, state.missing), gaps
    lost = state.missing + sum(g.missing for g in gaps)
    return _state(p, MappingProxyType(tracks), state.gaps + len(gaps), lost), gaps


def _state(params: GapParams, tracks: Mapping[str, _Track], gaps: int, missing: int) -> GapState:
    """``GapState(...)`` without the frozen dataclass's ``__init__`` (an ``object.__setattr__``
    per field) or ``evolve``'s keyword merge: one step per message the recorder writes."""
    state = object.__new__(GapState)
    fields = {"params": params, "tracks": tracks, "gaps": gaps, "missing": missing}
    _set_attribute(state, "__dict__", fields)
    return state
