"""Shedding perception before control: the camera's frame rate, driven by the control path's
lateness.

When the set has less CPU than it needs (a small board, a CPU quota, a busy machine), the
camera would still deliver every frame, the perception behind it would take what CPU there is,
and the control path (EMG, controller, hand commands at 100 Hz) would wake late. Here the
camera sheds frames at the source instead. The feedback is what the control path reports in
its health (``lpc/health/<service>``, once a second): ``ticks``, the periodic ticks of its
100 Hz timer, and ``late_ticks``, those that woke more than one period late. The rate follows
AIMD, as TCP's congestion window does:

- two windows in a row of one service whose share of late ticks exceeds ``late_above``
  multiply the rate by ``decrease``: one window alone is taken for a passing burst (a busy
  neighbour, services starting up), which under load here made the camera shed at full CPU.
  At most once per report window: a report whose window began before the last decrease
  describes the old rate and is not acted on again;
- a report under ``clean_below`` adds, for each second since the last change,
  ``increase_hz_per_s`` or ``increase_share_per_s`` of the rate, whichever is more, up to
  ``max_rate_hz`` (1 Hz a second near the 10 Hz a half-core quota leaves here, but 45 Hz back
  to 90 in 7 s after a neighbour's burst of load); in between the rate holds;
- with no report for ``stale_ns`` (the reporting service stopped), the rate climbs back the
  same way, so that a control path that went away does not leave the camera throttled.

The thresholds come from measurement (``lpc bench footprint --together --record --cpus 0.5``,
the device held at a fixed rate, nothing shed): the controller's ticks more than 10 ms late
were 14 % at 5 Hz of camera, 26 % at 10 Hz, 38 % at 15 Hz, 51 % at 20 Hz, and hand commands
kept their 100 Hz up to 10 Hz (108, 100, 90, 81 Hz); without a quota 0.2 % at 73 Hz. Under a
CFS quota every burst of perception work freezes the whole set for the rest of a period, so
some late ticks come with any frame rate; the band of 20-30 % holds the rate where the hand
commands keep up there, and stays far above what a machine with CPU to spare shows.

At ``max_rate_hz`` every frame passes; below it a credit of ``rate * elapsed`` (carried over
from one frame to the next at most one frame's worth) lets a frame through when it reaches one,
so that the frames kept are spread evenly and come at the allowed rate on average.

``shed_step(state, message, now_ns)`` is pure: the state is an immutable value, time comes in
as ``now_ns``, nothing reads a clock or touches the bus.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from lpc_core.perception.state import evolve
from schemas import Health

# A frame passes when the credit reaches this: frames a little early (jitter) are not shed.
_CREDIT_TO_PASS = 0.95


@dataclass(frozen=True, kw_only=True)
class ShedParams:
    """Rates in Hz, shares of ticks in [0, 1], times in ns."""

    max_rate_hz: float = 90.0
    min_rate_hz: float = 5.0
    late_above: float = 0.30
    clean_below: float = 0.20
    decrease: float = 0.5
    increase_hz_per_s: float = 1.0
    increase_share_per_s: float = 0.1
    stale_ns: int = 3_000_000_000

    def __post_init__(self) -> None:
        if not 0 < self.min_rate_hz <= self.max_rate_hz:
            raise ValueError(
                f"min_rate_hz must be in (0, max_rate_hz], got {self.min_rate_hz} "
                f"(max_rate_hz {self.max_rate_hz})"
            )
        if not 0 <= self.clean_below <= self.late_above < 1:
            raise ValueError(
                f"need 0 <= clean_below <= late_above < 1, got clean_below {self.clean_below}, "
                f"late_above {self.late_above}"
            )
        if not 0 < self.decrease < 1:
            raise ValueError(f"decrease must be in (0, 1), got {self.decrease}")
        if self.increase_hz_per_s <= 0:
            raise ValueError(f"increase_hz_per_s must be positive, got {self.increase_hz_per_s}")
        if self.increase_share_per_s < 0:
            raise ValueError(f"increase_share_per_s must be >= 0, got {self.increase_share_per_s}")
        if self.stale_ns <= 0:
            raise ValueError(f"stale_ns must be positive, got {self.stale_ns}")


@dataclass(frozen=True)
class TickCount:
    """A reporting service's counters as last seen, and when (``now_ns`` of the report)."""

    ticks: int
    late_ticks: int
    seen_ns: int
    behind: bool = False  # the window that ended with this report had too many late ticks


@dataclass(frozen=True)
class ShedState:
    params: ShedParams = field(default_factory=ShedParams)
    rate_hz: float = -1.0  # -1: not set yet, taken as max_rate_hz
    credit: float = 1.0
    last_frame_ns: int | None = None
    last_decrease_ns: int = -1
    last_increase_ns: int = -1
    last_report_ns: int = -1
    reports: Mapping[str, TickCount] = field(default_factory=lambda: MappingProxyType({}))
    shed_frames: int = 0

    @property
    def rate(self) -> float:
        """The frame rate now allowed, Hz."""
        return self.params.max_rate_hz if self.rate_hz < 0 else self.rate_hz

    @property
    def shedding(self) -> bool:
        return self.rate < self.params.max_rate_hz


@dataclass(frozen=True)
class FrameReady:
    """A frame the source has (or a frame slot that is due): publish it or shed it?"""


class Gate(enum.Enum):
    PUBLISH = "publish"
    SHED = "shed"


@dataclass(frozen=True)
class RateChange:
    """The allowed rate moved, on a report of ``service`` with ``late_fraction`` late ticks."""

    previous_hz: float
    rate_hz: float
    late_fraction: float
    service: str


def shed_step(
    state: ShedState, message: Health | FrameReady, now_ns: int
) -> tuple[ShedState, Gate | RateChange | None]:
    """One event: a frame gets ``Gate.PUBLISH`` or ``Gate.SHED``; a health report that moves
    the rate gets a ``RateChange`` (otherwise ``None``, as do reports without tick counters)."""
    match message:
        case FrameReady():
            return _frame(state, now_ns)
        case Health():
            return _report(state, message, now_ns)
    raise TypeError(f"shed_step takes Health or FrameReady, not {type(message).__name__}")


def _frame(state: ShedState, now_ns: int) -> tuple[ShedState, Gate | RateChange | None]:
    p = state.params
    stale = state.last_report_ns >= 0 and now_ns - state.last_report_ns > p.stale_ns
    if stale and state.shedding:
        since = max(state.last_increase_ns, state.last_report_ns + p.stale_ns)
        state = _increase(state, since, now_ns)
    if not state.shedding:
        return evolve(state, credit=1.0, last_frame_ns=now_ns), Gate.PUBLISH
    elapsed_ns = 0 if state.last_frame_ns is None else max(0, now_ns - state.last_frame_ns)
    # Capped at one frame and one camera period's share (no burst after a pause): capping at
    # one frame lost the remainder of every passed frame, which kept 90/k Hz of a 90 Hz camera
    # (30 Hz for any rate in 28.5-42.7 Hz, 18 Hz in 17.1-21.3 Hz).
    credit = min(state.credit + state.rate * elapsed_ns / 1e9, 1.0 + state.rate / p.max_rate_hz)
    if credit >= _CREDIT_TO_PASS:
        return evolve(state, credit=credit - 1.0, last_frame_ns=now_ns), Gate.PUBLISH
    state = evolve(state, credit=credit, last_frame_ns=now_ns, shed_frames=state.shed_frames + 1)
    return state, Gate.SHED


def _report(
    state: ShedState, health: Health, now_ns: int
) -> tuple[ShedState, Gate | RateChange | None]:
    ticks = health.counters.get("ticks")
    late = health.counters.get("late_ticks")
    if ticks is None or late is None:
        return state, None  # a service without a control timer
    p = state.params
    previous = state.reports.get(health.service)
    fresh = previous is None or ticks <= previous.ticks or late < previous.late_ticks
    fraction = 0.0 if fresh else (late - previous.late_ticks) / (ticks - previous.ticks)
    reports = dict(state.reports)
    reports[health.service] = TickCount(ticks, late, now_ns, fraction > p.late_above)
    state = evolve(state, reports=MappingProxyType(reports), last_report_ns=now_ns)
    if previous is None or fresh:
        return state, None  # the first report, or the service restarted: a new baseline
    before = state.rate
    if fraction > p.late_above:
        if not previous.behind or previous.seen_ns < state.last_decrease_ns:
            # One late window alone, or one that saw the rate before the last decrease.
            return state, None
        rate = max(p.min_rate_hz, before * p.decrease)
        state = evolve(state, rate_hz=rate, last_decrease_ns=now_ns, last_increase_ns=now_ns)
    elif fraction < p.clean_below:
        state = _increase(state, max(state.last_increase_ns, previous.seen_ns), now_ns)
    else:
        state = evolve(state, last_increase_ns=now_ns)  # hold
    if state.rate == before:
        return state, None
    return state, RateChange(before, state.rate, fraction, health.service)


def _increase(state: ShedState, since_ns: int, now_ns: int) -> ShedState:
    p = state.params
    seconds = min(max(0, now_ns - since_ns) / 1e9, 2.0)  # no leap after a long silence
    step_hz = max(p.increase_hz_per_s, p.increase_share_per_s * state.rate)
    rate = min(p.max_rate_hz, state.rate + step_hz * seconds)
    return evolve(state, rate_hz=rate, last_increase_ns=now_ns)
