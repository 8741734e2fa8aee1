"""A simulated EMG user: intended muscle drive in, rectified EMG envelopes out.

The model, per channel (flexor, extensor), sampled at 100 Hz:

- **activation** follows the intended drive ``u`` with first-order dynamics, faster on the way
  up (``rise_ms``) than on the way down (``fall_ms``);
- **cross-talk**: each electrode also picks up a fraction of the other muscle's activation;
- **fatigue** lowers the amplitude a given drive produces; it builds with activation and
  recovers at rest (``df/dt = fatigue_rate * a - recovery_rate * f``);
- **envelope**: the amplifier noise and the muscle's signal add in quadrature, as independent
  processes do, ``e = sqrt(rest**2 + (a * (maximal - rest))**2)``, then a multiplicative
  AR(1) fluctuation of relative SD ``noise`` (a finite-window envelope of a random signal);
- **motion artifacts**: rare decaying spikes, so rest is not unrealistically clean.

Randomness comes from ``numpy.random.default_rng((seed, seq))`` for the block starting at sample
``seq``, so a run is reproducible from its seed.

``ScriptedUser`` is the user for ``lpc up --source sim``: it watches the controller's state and
the hand (the person feels the ready pulse and sees the hand move), and answers with a quick
flexion (pre-shape), a quick extension (take over), a co-contraction and a little rotation, a
proportional close on the object, a hold, and an opening that releases it.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from lpc_core.control.controller import ControllerParams
from lpc_core.control.emg import EmgProfile
from lpc_core.control.state import evolve
from schemas import AimCue, ControllerState, EmgSample, ProsthesisState

RATE_HZ = 100.0
PERIOD_NS = 10_000_000


@dataclass(frozen=True)
class MuscleParams:
    """Envelope amplitudes in volts (rectified, smoothed surface EMG)."""

    rest: tuple[float, float] = (4.0e-6, 5.0e-6)
    maximal: tuple[float, float] = (180.0e-6, 150.0e-6)
    noise: float = 0.15
    noise_corr: float = 0.6
    crosstalk: float = 0.12
    rise_ms: float = 20.0
    fall_ms: float = 40.0
    fatigue_rate: float = 0.01
    recovery_rate: float = 0.02
    max_fatigue: float = 0.5
    artifact_rate_hz: float = 0.02
    artifact_level: float = 0.3

    def __post_init__(self) -> None:
        for i in range(2):
            if not 0 < self.rest[i] < self.maximal[i]:
                raise ValueError(f"need 0 < rest[{i}] < maximal[{i}]")
        if not 0 <= self.noise < 1:
            raise ValueError(f"noise must be in [0, 1), got {self.noise}")
        if not 0 <= self.noise_corr < 1:
            raise ValueError(f"noise_corr must be in [0, 1), got {self.noise_corr}")
        if not 0 <= self.crosstalk < 1:
            raise ValueError(f"crosstalk must be in [0, 1), got {self.crosstalk}")
        if not (self.rise_ms > 0 and self.fall_ms > 0):
            raise ValueError("rise_ms and fall_ms must be positive")


@dataclass(frozen=True)
class MuscleState:
    activation: tuple[float, float] = (0.0, 0.0)
    fatigue: tuple[float, float] = (0.0, 0.0)
    fluctuation: tuple[float, float] = (0.0, 0.0)
    artifact: tuple[float, float] = (0.0, 0.0)


NOISE_BLOCK = 100  # samples drawn per seeded block


@functools.lru_cache(maxsize=8)
def _noise_block(seed: int, block: int) -> np.ndarray:
    """(NOISE_BLOCK, 6): AR shocks (2), artifact draws (2), artifact sizes (2), seeded by the
    block so that any sample's noise depends only on ``(seed, seq)``, however it is stepped."""
    rng = np.random.default_rng((seed, block))
    noise = np.concatenate(
        [
            rng.standard_normal((NOISE_BLOCK, 2)),
            rng.random((NOISE_BLOCK, 2)),
            rng.uniform(0.3, 1.0, (NOISE_BLOCK, 2)),
        ],
        axis=1,
    )
    noise.flags.writeable = False
    return noise


@functools.lru_cache(maxsize=8)
def _noise_rows(seed: int, block: int) -> list[list[float]]:
    """``_noise_block`` as Python floats (the same values), converted once per block of 100
    samples: the live user reads one row a tick, where a numpy slice and its ``tolist`` were
    most of the row's cost. Read only."""
    return _noise_block(seed, block).tolist()


def _noise(seed: int, seq: int, n: int) -> list[list[float]]:
    """Rows ``seq`` to ``seq + n`` of the seeded noise, as Python floats."""
    first, last = seq // NOISE_BLOCK, (seq + n - 1) // NOISE_BLOCK
    start = seq - first * NOISE_BLOCK
    if first == last:  # the live user's one sample a tick: no concatenation
        return _noise_rows(seed, first)[start : start + n]
    rows = [row for b in range(first, last + 1) for row in _noise_rows(seed, b)]
    return rows[start : start + n]


def simulate_emg(
    state: MuscleState,
    drive: np.ndarray,
    params: MuscleParams,
    seed: int,
    seq: int,
) -> tuple[MuscleState, np.ndarray]:
    """Envelopes (N, 2) in volts for the intended drive (N, 2) in [0, 1], from sample ``seq``.

    Stepping one sample at a time gives the same envelopes as one call over the whole drive.
    """
    drive = np.clip(np.asarray(drive, dtype=float), 0.0, 1.0)
    if drive.ndim != 2 or drive.shape[1] != 2:
        raise ValueError(f"drive must have shape (N, 2), got {drive.shape}")
    if len(drive) == 0:
        return state, np.empty((0, 2))
    state, rows = _simulate_rows(state, drive.tolist(), params, seed, seq)
    return state, np.array(rows, dtype=float).reshape(len(rows), 2)


_Rates = tuple[float, float, float, float, float, list[float]]
# The live user's params and their rates: one object for the whole run, so an identity test
# finds them, where the lru_cache hashed the twelve fields (two of them tuples) every tick.
_last_rates: tuple[MuscleParams, _Rates] | None = None


def _rates(params: MuscleParams) -> _Rates:
    """The per-sample constants of ``params``: (k_rise, k_fall, k_artifact, innovation, hit_p,
    span), worked out once for the params stepped last, not on each sample of the live user."""
    global _last_rates
    last = _last_rates
    if last is not None and last[0] is params:
        return last[1]
    dt = 1.0 / RATE_HZ
    k_rise = 1.0 - math.exp(-dt * 1e3 / params.rise_ms)
    k_fall = 1.0 - math.exp(-dt * 1e3 / params.fall_ms)
    k_artifact = math.exp(-dt / 0.03)
    rho = params.noise_corr
    innovation = math.sqrt(1.0 - rho * rho)
    hit_p = params.artifact_rate_hz / RATE_HZ
    span = [m - r for r, m in zip(params.rest, params.maximal, strict=True)]
    rates = k_rise, k_fall, k_artifact, innovation, hit_p, span
    # Replaced whole: another thread's step reads either pair, never half of one.
    _last_rates = (params, rates)
    return rates


def _simulate_rows(
    state: MuscleState, drive: list[list[float]], params: MuscleParams, seed: int, seq: int
) -> tuple[MuscleState, list[list[float]]]:
    """``simulate_emg`` of a drive already in [0, 1], as rows of floats; the envelopes as rows
    of floats too (the live user publishes them as they are, with no array between)."""
    n = len(drive)
    rows = _noise(seed, seq, n)
    dt = 1.0 / RATE_HZ
    k_rise, k_fall, k_artifact, innovation, hit_p, span = _rates(params)
    rho = params.noise_corr

    # A loop over time in plain floats: the activation dynamics are asymmetric and the fatigue
    # state-dependent, and at one sample per call numpy's per-call overhead would dominate.
    a, f = list(state.activation), list(state.fatigue)
    z, art = list(state.fluctuation), list(state.artifact)
    out = [[0.0, 0.0] for _ in range(n)]
    for i, u in enumerate(drive):
        row = rows[i]
        for c in range(2):
            a[c] += (u[c] - a[c]) * (k_rise if u[c] > a[c] else k_fall)
            f[c] += (params.fatigue_rate * a[c] - params.recovery_rate * f[c]) * dt
            f[c] = min(max(f[c], 0.0), params.max_fatigue)
            z[c] = rho * z[c] + innovation * row[c]
            art[c] = art[c] * k_artifact + (
                row[4 + c] * params.artifact_level if row[2 + c] < hit_p else 0.0
            )
        for c in range(2):
            seen = a[c] + params.crosstalk * a[1 - c]
            amplitude = seen * (1.0 - f[c]) * span[c]
            envelope = math.sqrt(params.rest[c] ** 2 + amplitude**2) * (1.0 + params.noise * z[c])
            out[i][c] = max(envelope + art[c] * span[c], 0.0)
    new_state = MuscleState(
        activation=(a[0], a[1]),
        fatigue=(f[0], f[1]),
        fluctuation=(z[0], z[1]),
        artifact=(art[0], art[1]),
    )
    return new_state, out


# --------------------------------------------------------------------------- intents


@dataclass(frozen=True)
class Segment:
    """One intended contraction: a trapezoid of drive on one or both channels (times in s)."""

    start_s: float
    hold_s: float
    flexor: float = 0.0
    extensor: float = 0.0
    ramp_s: float = 0.02

    @property
    def end_s(self) -> float:
        return self.start_s + 2 * self.ramp_s + self.hold_s

    def drive(self, t_s: np.ndarray) -> np.ndarray:
        rel = np.asarray(t_s, dtype=float) - self.start_s
        up = np.clip(rel / self.ramp_s, 0.0, 1.0)
        down = np.clip((self.end_s - self.start_s - rel) / self.ramp_s, 0.0, 1.0)
        shape = np.minimum(up, down)
        return np.stack([shape * self.flexor, shape * self.extensor], axis=-1)


def quick_flexion(start_s: float, level: float = 0.9) -> Segment:
    return Segment(start_s, hold_s=0.15, flexor=level, ramp_s=0.02)


def quick_extension(start_s: float, level: float = 0.9) -> Segment:
    return Segment(start_s, hold_s=0.15, extensor=level, ramp_s=0.02)


def co_contraction(start_s: float, level: float = 0.8) -> Segment:
    return Segment(start_s, hold_s=0.25, flexor=level, extensor=level, ramp_s=0.04)


def slow_hold(start_s: float, hold_s: float, flexor: float = 0.0, extensor: float = 0.0) -> Segment:
    """A proportional command: a slow rise (well beyond the quick window) and a long hold."""
    return Segment(start_s, hold_s=hold_s, flexor=flexor, extensor=extensor, ramp_s=0.4)


def _drive_at(segments: Sequence[Segment], t_s: float, floor: tuple[float, float]) -> list[float]:
    """``np.maximum(script_drive(segments, 1, t_s), [floor])`` clipped to [0, 1], in plain
    floats (the same arithmetic, so the same values): the live user's one sample a tick, where
    numpy's per-call overhead was most of the EMG service's step."""
    flexor, extensor = 0.0, 0.0
    for segment in segments:
        rel = t_s - segment.start_s
        up = min(max(rel / segment.ramp_s, 0.0), 1.0)
        down = min(max((segment.end_s - segment.start_s - rel) / segment.ramp_s, 0.0), 1.0)
        shape = min(up, down)
        flexor = max(flexor, shape * segment.flexor)
        extensor = max(extensor, shape * segment.extensor)
    return [
        min(max(flexor, floor[0], 0.0), 1.0),
        min(max(extensor, floor[1], 0.0), 1.0),
    ]


def script_drive(segments: list[Segment], n: int, t0_s: float = 0.0) -> np.ndarray:
    """The drive (n, 2) at 100 Hz from ``t0_s``; overlapping segments take the larger drive."""
    t = t0_s + np.arange(n) / RATE_HZ
    drive = np.zeros((n, 2))
    for segment in segments:
        drive = np.maximum(drive, segment.drive(t))
    return drive


# --------------------------------------------------------------------------- scripted user


@dataclass(frozen=True)
class Tick:
    """Time to produce the next sample (the sim source's 100 Hz clock)."""

    t_ns: int


@dataclass(frozen=True)
class UserParams:
    reaction_s: float = 0.5
    settle_s: float = 0.4
    close_level: float = 0.45
    open_level: float = 0.5
    grip_pct: float = 30.0
    hold_s: float = 1.5
    rotate_s: float = 0.6
    exercise_wrist: bool = True
    retry_s: float = 2.5


@dataclass(frozen=True)
class UserState:
    """What the simulated person is doing and has noticed."""

    params: MuscleParams = field(default_factory=MuscleParams)
    user: UserParams = field(default_factory=UserParams)
    seed: int = 0
    seq: int = 0
    muscle: MuscleState = field(default_factory=MuscleState)
    plan: tuple[Segment, ...] = ()  # times in seconds of the bus clock
    controller: str = "stopped"
    since_ns: int = 0
    task: str = "rest"
    task_since_ns: int = 0
    hand: ProsthesisState | None = None
    still_since_ns: int | None = None
    cue: str = "nothing"
    contact_mm: float | None = None
    sustain: tuple[float, float] = (0.0, 0.0)  # a held proportional command's drive
    sustained: tuple[float, float] = (0.0, 0.0)  # where that drive is now (slew-limited)


def user_step(
    state: UserState,
    message: Tick | ControllerState | ProsthesisState | AimCue,
    now_ns: int,
) -> tuple[UserState, list[EmgSample]]:
    """Feed what the person perceives; on a ``Tick``, the EMG sample they produce."""
    match message:
        case ControllerState():
            if message.state != state.controller:
                state = evolve(state, controller=message.state, since_ns=now_ns)
            return state, []
        case ProsthesisState():
            return _watch_hand(state, message, now_ns), []
        case AimCue():
            return evolve(state, cue=message.state), []
        case Tick():
            state = _decide(state, now_ns)
            t_s = now_ns / 1e9
            # A held command rises slowly (never a quick contraction) and relaxes faster.
            sustained = tuple(
                cur + min(max(goal - cur, -3.0 / RATE_HZ), 1.2 / RATE_HZ)
                for cur, goal in zip(state.sustained, state.sustain, strict=True)
            )
            drive = _drive_at(state.plan, t_s, sustained)  # type: ignore[arg-type]
            muscle, raw = _simulate_rows(state.muscle, [drive], state.params, state.seed, state.seq)
            plan = tuple(s for s in state.plan if s.end_s > t_s)
            sample = EmgSample(seq=state.seq, t_ns=message.t_ns, channels=raw[0])
            # One copy of the state a tick: its fields change together.
            new = evolve(state, sustained=sustained, muscle=muscle, plan=plan, seq=state.seq + 1)
            return new, [sample]  # type: ignore[arg-type]
        case _:
            raise ValueError(f"message: unexpected {type(message).__name__}")


def _watch_hand(state: UserState, hand: ProsthesisState, now_ns: int) -> UserState:
    previous = state.hand
    moving = previous is None or (
        abs(hand.aperture_mm - previous.aperture_mm) > 0.05
        or abs(hand.wrist_angle_deg - previous.wrist_angle_deg) > 0.05
    )
    still = None if moving else (state.still_since_ns or now_ns)
    return evolve(state, hand=hand, still_since_ns=still)


def _begin(state: UserState, task: str, now_ns: int, *segments: Segment) -> UserState:
    return evolve(state, task=task, task_since_ns=now_ns, plan=state.plan + tuple(segments))


def _decide(state: UserState, now_ns: int) -> UserState:
    """The person's policy: one task at a time, each started by what they feel or see."""
    u = state.user
    t_s = now_ns / 1e9
    in_state_s = (now_ns - state.since_ns) / 1e9
    in_task_s = (now_ns - state.task_since_ns) / 1e9
    busy = bool(state.plan)
    hand = state.hand
    mode = state.controller

    if mode != "direct" and any(state.sustain):
        # Control left the user's hands: stop pushing (and the held command ends).
        return _sustain(state, 0.0, 0.0, task="rest", task_since_ns=now_ns, contact_mm=None)
    if mode in ("stopped", "idle", "aiming"):
        if state.task != "rest" and not busy:
            return _sustain(state, 0.0, 0.0, task="rest", task_since_ns=now_ns, contact_mm=None)
        return state
    if mode == "ready":
        # The pulse is felt; pre-shape after a reaction time, and again if it was missed.
        if busy or in_state_s < u.reaction_s or any(state.sustained):
            return state
        if state.task != "preshape" or in_task_s > u.retry_s:
            return _begin(state, "preshape", now_ns, quick_flexion(t_s))
        return state
    if mode == "preshaping":
        settled = (
            state.still_since_ns is not None
            and (now_ns - state.still_since_ns) / 1e9 >= u.settle_s
            and in_state_s >= u.settle_s
        )
        if busy or not settled:
            return state
        if state.task != "take_over" or in_task_s > u.retry_s:
            return _begin(state, "take_over", now_ns, quick_extension(t_s + u.reaction_s))
        return state
    if mode == "direct":
        return _direct(state, now_ns, hand)
    return state


def _sustain(state: UserState, flexor: float, extensor: float, **changes: object) -> UserState:
    return evolve(state, sustain=(flexor, extensor), **changes)  # type: ignore[arg-type]


def _direct(state: UserState, now_ns: int, hand: ProsthesisState | None) -> UserState:
    u = state.user
    t_s = now_ns / 1e9
    in_task_s = (now_ns - state.task_since_ns) / 1e9
    busy = bool(state.plan)
    task = state.task
    if task in ("take_over", "preshape", "rest"):
        if busy:
            return state
        if u.exercise_wrist:
            # Switch to rotation, turn a little, switch back: the second degree of freedom.
            # Gestures fire on release, so the person relaxes between them (and waits out the
            # lock-out after the previous gesture).
            return _begin(
                state,
                "rotate",
                now_ns,
                co_contraction(t_s + 0.5),
                slow_hold(t_s + 1.4, u.rotate_s, flexor=0.35),
                co_contraction(t_s + 3.0),
                Segment(t_s + 3.4, hold_s=0.5),  # relax before the next command
            )
        return _sustain(state, u.close_level, 0.0, task="close", task_since_ns=now_ns)
    if task == "rotate":
        if busy:
            return state
        return _sustain(state, u.close_level, 0.0, task="close", task_since_ns=now_ns)
    if task == "close":
        gripping = hand is not None and (
            hand.grip_force_pct >= u.grip_pct or hand.aperture_mm <= 2.0
        )
        if gripping or in_task_s > 6.0:
            contact = hand.aperture_mm if hand is not None else None
            return _sustain(state, 0.0, 0.0, task="hold", task_since_ns=now_ns, contact_mm=contact)
        return state
    if task == "hold":
        if in_task_s >= u.hold_s:
            return _sustain(state, 0.0, u.open_level, task="open", task_since_ns=now_ns)
        return state
    if task == "open":
        opened = hand is not None and (
            hand.aperture_mm >= min((state.contact_mm or 0.0) + 30.0, 105.0)
        )
        if opened or in_task_s > 6.0:
            return _sustain(state, 0.0, 0.0, task="rest", task_since_ns=now_ns)
        return state
    return state


def sim_user_params(camera_on_hand: bool = False) -> ControllerParams:
    """The parameters ``lpc up --source sim`` runs the controller with: the simulated user's
    calibration (``MuscleParams``' rest and maximal) and a camera that does not turn with the
    wrist. A replay of a simulated session needs the same to reproduce it."""
    m = MuscleParams()
    profile = EmgProfile(rest=m.rest, maximal=m.maximal, user="sim", unit="V")
    return ControllerParams(profile=profile, camera_on_hand=camera_on_hand)
