"""The tactor bridge's logic, pure: tactor commands and the passing of time in, the outputs to
write to the controller out. The service (``services.tactor_bridge``) owns the port and the
clock; everything it decides lives here, so a test drives it with a scripted clock.

Rules, in order:

- No command yet, or the last one older than ``stale_ns``: all off. Age counts from the
  command's capture time ``t_ns`` (``stale_from="capture"``: a cue about a frame more than
  100 ms old no longer says where the object is) or from its arrival (``"receipt"``, for a
  replay whose capture times belong to another clock).
- ``pulse``: the amplitudes are on for ``pulse_on_ns`` of every ``pulse_period_ns``, counted
  from the first pulsing command, so the pattern starts with a buzz.
- The user's gain limits map an amplitude ``a > 0`` to ``gain_min + a (gain_max - gain_min)``
  per tactor, so the weakest cue is still felt and the strongest never hurts.
- Writes are rate-limited by a token bucket: one token per ``min_interval_ns``, at most
  ``burst`` saved. A bucket rather than a fixed gap, so that two frames bunched together by
  scheduling jitter both go out at once, while a flood still cannot exceed the rate. A change
  that finds the bucket empty is held and written when the next token comes (the newest
  wins). An unchanged output is written again every ``refresh_ns``, which refreshes a
  controller that lost a frame and feeds a board's watchdog.

``BridgeState.wake_ns`` says when the step next needs a ``Tick`` even if no command arrives.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from lpc_core.devices.tactor_protocol import N_TACTORS, OFF, TactorOutput
from lpc_core.perception.state import evolve
from schemas import TactorCommand


@dataclass(frozen=True)
class TactorProfile:
    """One user's tactor limits (the paper set intensity per participant): drive levels 0..1."""

    gain_min: tuple[float, ...] = (0.0,) * N_TACTORS
    gain_max: tuple[float, ...] = (1.0,) * N_TACTORS

    def __post_init__(self) -> None:
        for name in ("gain_min", "gain_max"):
            values = getattr(self, name)
            if len(values) != N_TACTORS or not all(0.0 <= v <= 1.0 for v in values):
                raise ValueError(f"{name} must hold {N_TACTORS} values in [0, 1], got {values}")
        if any(lo > hi for lo, hi in zip(self.gain_min, self.gain_max, strict=True)):
            raise ValueError("gain_min must not exceed gain_max for any tactor")

    def levels(self, amplitudes: list[float] | tuple[float, ...]) -> tuple[float, ...]:
        return tuple(
            0.0 if a <= 0.0 else min(1.0, lo + min(a, 1.0) * (hi - lo))
            for a, lo, hi in zip(amplitudes, self.gain_min, self.gain_max, strict=True)
        )


@dataclass(frozen=True)
class BridgeParams:
    stale_ns: int = 100_000_000
    stale_from: Literal["capture", "receipt"] = "capture"
    min_interval_ns: int = 5_000_000
    burst: int = 3
    refresh_ns: int = 200_000_000
    pulse_on_ns: int = 150_000_000
    pulse_period_ns: int = 300_000_000
    profile: TactorProfile = field(default_factory=TactorProfile)

    def __post_init__(self) -> None:
        for name in ("stale_ns", "refresh_ns", "pulse_on_ns", "pulse_period_ns"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.min_interval_ns < 0:
            raise ValueError(f"min_interval_ns must not be negative, got {self.min_interval_ns}")
        if self.burst < 1:
            raise ValueError(f"burst must be at least 1, got {self.burst}")
        if self.pulse_on_ns > self.pulse_period_ns:
            raise ValueError("pulse_on_ns must not exceed pulse_period_ns")
        if self.stale_from not in ("capture", "receipt"):
            raise ValueError(f"stale_from must be 'capture' or 'receipt', got {self.stale_from!r}")


@dataclass(frozen=True)
class Tick:
    """Time has passed; no new command."""


@dataclass(frozen=True)
class PortOpened:
    """The controller was (re)opened: what it holds is unknown, so write at once."""


TICK = Tick()
PORT_OPENED = PortOpened()


@dataclass(frozen=True)
class BridgeState:
    params: BridgeParams = field(default_factory=BridgeParams)
    command: TactorCommand | None = None
    received_ns: int = 0
    pulse_since_ns: int | None = None
    written: TactorOutput | None = None  # None: unknown, nothing written since the port opened
    written_ns: int | None = None
    tokens: float | None = None  # None: a full bucket
    tokens_ns: int = 0
    wake_ns: int | None = None


def _expires_ns(state: BridgeState) -> int | None:
    if state.command is None:
        return None
    base = state.command.t_ns if state.params.stale_from == "capture" else state.received_ns
    return base + state.params.stale_ns


def desired_output(state: BridgeState, now_ns: int) -> TactorOutput:
    """What the tactors should do at ``now_ns``."""
    command = state.command
    expires = _expires_ns(state)
    if command is None or expires is None or now_ns > expires:
        return OFF
    p = state.params
    pulsing = command.pulse and state.pulse_since_ns is not None
    if pulsing and (now_ns - state.pulse_since_ns) % p.pulse_period_ns >= p.pulse_on_ns:
        return OFF
    return TactorOutput(p.profile.levels(command.amplitudes), command.frequency_hz)


def _tokens(state: BridgeState, now_ns: int) -> float:
    p = state.params
    if state.tokens is None or p.min_interval_ns == 0:
        return float(p.burst)
    return min(float(p.burst), state.tokens + (now_ns - state.tokens_ns) / p.min_interval_ns)


def _next_wake(state: BridgeState, desired: TactorOutput, now_ns: int) -> int | None:
    p = state.params
    times: list[int] = []
    if state.written_ns is not None:
        if desired != state.written:  # held by the rate limit: wake when a token is back
            missing = max(0.0, 1.0 - _tokens(state, now_ns))
            times.append(now_ns + max(1, int(missing * p.min_interval_ns + 0.5)))
        times.append(state.written_ns + p.refresh_ns)
    expires = _expires_ns(state)
    if expires is not None and expires >= now_ns:
        times.append(expires + 1)
        command = state.command
        if command is not None and command.pulse and state.pulse_since_ns is not None:
            phase = (now_ns - state.pulse_since_ns) % p.pulse_period_ns
            edge = p.pulse_on_ns if phase < p.pulse_on_ns else p.pulse_period_ns
            times.append(now_ns + edge - phase)
    later = [t for t in times if t > now_ns]
    return min(later) if later else None


def bridge_step(
    state: BridgeState, event: TactorCommand | Tick | PortOpened, now_ns: int
) -> tuple[BridgeState, list[TactorOutput]]:
    """One step: at most one output to write now, and the state with its next wake time."""
    if isinstance(event, TactorCommand):
        was_pulsing = state.command is not None and state.command.pulse
        since = state.pulse_since_ns if was_pulsing else None
        if event.pulse and since is None:
            since = now_ns
        state = evolve(state, command=event, received_ns=now_ns, pulse_since_ns=since)
    elif isinstance(event, PortOpened):
        state = evolve(state, written=None, written_ns=None)
    elif not isinstance(event, Tick):
        raise ValueError(f"event must be TactorCommand, Tick or PortOpened, got {type(event)}")
    p = state.params
    desired = desired_output(state, now_ns)
    outputs: list[TactorOutput] = []
    last = state.written_ns
    tokens = _tokens(state, now_ns)
    wanted = last is None or desired != state.written or now_ns - last >= p.refresh_ns
    # Copies by ``evolve``, not ``dataclasses.replace``: a state update needs no __init__, and
    # the bridge steps for every cue and wake-up on the control loop.
    if wanted and (tokens >= 1.0 - 1e-9 or last is None):
        outputs.append(desired)
        tokens = max(0.0, tokens - 1.0)
        state = evolve(state, written=desired, written_ns=now_ns, tokens=tokens, tokens_ns=now_ns)
    else:
        state = evolve(state, tokens=tokens, tokens_ns=now_ns)
    return evolve(state, wake_ns=_next_wake(state, desired, now_ns)), outputs
