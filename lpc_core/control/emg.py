"""EMG intent: normalisation, smoothing and the two-site decision rules.

Two channels, (flexor, extensor), of rectified EMG envelopes at about 100 Hz. Each sample is
normalised by the user's rest baseline and maximal contraction, ``n = (x - rest) / (max - rest)``
(0 at rest, 1 at maximal contraction), then smoothed by a moving average over ``window`` samples
(10 = 100 ms). From the smoothed levels the detector reads:

- a **quick flexion** ("auto pre-shape") and a **quick extension** ("take over"): one channel
  rises from the on-threshold to the upper threshold within ``quick_ms`` (the commercial
  two-site rule, about 80 ms) while the other stays below the upper threshold;
- a **co-contraction** ("switch the degree of freedom"): both channels above ``co_contraction``
  at the same time;
- a **proportional velocity** for direct control, flexor positive, zero during a co-contraction.

Gestures fire on release, when both channels have stayed below ``off`` for ``release_ms``, so
one contraction (an *episode*, from the first crossing of ``on`` until release) gives at most one
gesture. Contractions held longer than ``max_trigger_ms`` are proportional commands and never
trigger. After a gesture, an episode that starts within ``lockout_ms`` is ignored as a whole.

Everything here is pure: ``intent_step(state, channels, t_ns) -> (state, Intent)``.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lpc_core.control.state import evolve

N_CHANNELS = 2
FLEXOR, EXTENSOR = 0, 1


class Gesture(enum.Enum):
    """What one contraction meant."""

    QUICK_FLEXION = "quick_flexion"
    QUICK_EXTENSION = "quick_extension"
    CO_CONTRACTION = "co_contraction"


@dataclass(frozen=True)
class EmgProfile:
    """A user's calibration and decision thresholds.

    ``rest`` and ``maximal`` are per channel in the source's raw envelope units; all thresholds
    are in normalised units (0 rest, 1 maximal contraction). Defaults follow DESIGN.md.
    """

    rest: tuple[float, ...] = (0.0, 0.0)
    maximal: tuple[float, ...] = (1.0, 1.0)
    window: int = 10
    off: float = 0.10
    on: float = 0.15
    upper: float = 0.50
    co_contraction: float = 0.55
    quick_ms: float = 80.0
    release_ms: float = 30.0
    max_trigger_ms: float = 450.0
    lockout_ms: float = 300.0
    gain: float = 1.5
    user: str = ""
    unit: str = ""

    def __post_init__(self) -> None:
        if len(self.rest) != N_CHANNELS or len(self.maximal) != N_CHANNELS:
            raise ValueError(f"rest and maximal need {N_CHANNELS} channels (flexor, extensor)")
        for i, (lo, hi) in enumerate(zip(self.rest, self.maximal, strict=True)):
            if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
                raise ValueError(f"maximal[{i}] must exceed rest[{i}], got {hi} <= {lo}")
        if not 1 <= self.window <= 100:
            raise ValueError(f"window must be 1..100 samples, got {self.window}")
        if not 0 < self.off <= self.on < self.upper <= 1.0:
            raise ValueError(
                f"thresholds must satisfy 0 < off <= on < upper <= 1, got off={self.off}, "
                f"on={self.on}, upper={self.upper}"
            )
        if not self.upper <= self.co_contraction <= 1.0:
            raise ValueError(f"co_contraction must be in [upper, 1], got {self.co_contraction}")
        for name in ("quick_ms", "release_ms", "max_trigger_ms", "lockout_ms", "gain"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["rest"], out["maximal"] = list(self.rest), list(self.maximal)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> EmgProfile:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown profile field(s): {', '.join(unknown)}")
        values = dict(data)
        for name in ("rest", "maximal"):
            if name in values:
                values[name] = tuple(float(x) for x in values[name])
        return cls(**values)


def normalise(raw: np.ndarray | Sequence[float], profile: EmgProfile) -> np.ndarray:
    """Raw envelopes, shape (..., 2), to normalised levels clipped to [0, 2]."""
    raw = np.asarray(raw, dtype=float)
    if raw.shape[-1:] != (N_CHANNELS,):
        raise ValueError(f"raw must have shape (..., {N_CHANNELS}), got {raw.shape}")
    rest = np.asarray(profile.rest)
    span = np.asarray(profile.maximal) - rest
    return np.clip((raw - rest) / span, 0.0, 2.0)


def smooth(levels: np.ndarray, window: int) -> np.ndarray:
    """Causal moving average over ``window`` samples along axis 0 (shorter at the start)."""
    levels = np.asarray(levels, dtype=float)
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    csum = np.cumsum(levels, axis=0)
    out = csum.copy()
    out[window:] = csum[window:] - csum[:-window]
    counts = np.minimum(np.arange(1, len(levels) + 1), window).reshape(-1, *[1] * (levels.ndim - 1))
    return out / counts


def proportional_velocity(level: Sequence[float], profile: EmgProfile) -> float:
    """Direct-control velocity in [-1, 1]: flexor closes (+), extensor opens (-).

    Each channel counts only above the on-threshold; a co-contraction commands nothing, so that
    switching the degree of freedom does not also move it.
    """
    flex, ext = float(level[FLEXOR]), float(level[EXTENSOR])
    if flex >= profile.co_contraction and ext >= profile.co_contraction:
        return 0.0
    span = 1.0 - profile.on
    drive = (max(flex - profile.on, 0.0) - max(ext - profile.on, 0.0)) / span
    return min(max(drive * profile.gain, -1.0), 1.0)  # np.clip on one float cost ~5 us


def calibrate(
    rest: np.ndarray,
    contractions: Sequence[np.ndarray],
    base: EmgProfile | None = None,
) -> EmgProfile:
    """A profile from a rest recording (N, 2) and one maximal-contraction recording per channel.

    ``rest`` is the rest mean; ``maximal[c]`` the median of channel c's smoothed envelope over
    the plateau of its own contraction (above half its peak), robust to spikes and ramps. The
    off-threshold is raised to the rest mean + 3 SD (Hodges and Bui) when the rest noise
    demands it.
    """
    base = base or EmgProfile()
    rest = np.asarray(rest, dtype=float)
    if rest.ndim != 2 or rest.shape[1] != N_CHANNELS or len(rest) < base.window:
        raise ValueError(f"rest must be (N >= {base.window}, {N_CHANNELS}), got {rest.shape}")
    if len(contractions) != N_CHANNELS:
        raise ValueError(f"contractions needs one recording per channel, got {len(contractions)}")
    rest_mean = rest.mean(axis=0)
    maximal = np.empty(N_CHANNELS)
    for c, rec in enumerate(contractions):
        rec = np.asarray(rec, dtype=float)
        if rec.ndim != 2 or rec.shape[1] != N_CHANNELS or len(rec) < base.window:
            raise ValueError(f"contractions[{c}] must be (N >= {base.window}, 2), got {rec.shape}")
        envelope = smooth(rec[:, c], base.window)
        peak = np.percentile(envelope, 99)
        # The plateau's median: a held maximal contraction, not its noise peaks or its ramps.
        maximal[c] = np.median(envelope[envelope >= rest_mean[c] + 0.5 * (peak - rest_mean[c])])
    if np.any(maximal <= rest_mean * 1.5) or np.any(maximal <= rest_mean + 1e-12):
        bad = int(np.argmax(maximal <= rest_mean * 1.5))
        raise ValueError(
            f"contraction of channel {bad} ({maximal[bad]:.4g}) is not clearly above rest "
            f"({rest_mean[bad]:.4g}): was the muscle contracted?"
        )
    noise = float(np.max(3.0 * rest.std(axis=0) / (maximal - rest_mean)))
    off = max(base.off, round(noise, 3))
    on = round(max(base.on, off + 0.05), 3)
    if on >= base.upper:
        raise ValueError(f"rest noise too high: 3 SD is {noise:.2f} of the maximal contraction")
    return dataclasses.replace(
        base,
        rest=tuple(float(x) for x in rest_mean),
        maximal=tuple(float(x) for x in maximal),
        off=off,
        on=on,
    )


# --------------------------------------------------------------------------- detector


@dataclass(frozen=True)
class Episode:
    """One contraction, from the first crossing of ``on`` until release."""

    start_ns: int
    on_ns: tuple[int | None, int | None]
    upper_ns: tuple[int | None, int | None]
    co: bool = False
    locked: bool = False


@dataclass(frozen=True)
class IntentState:
    """The detector's memory: the smoothing window, the current episode, the lock-out."""

    profile: EmgProfile = field(default_factory=EmgProfile)
    window: tuple[tuple[float, float], ...] = ()
    episode: Episode | None = None
    below_since_ns: int | None = None
    lockout_until_ns: int = 0
    last_t_ns: int = -1


@dataclass(frozen=True)
class Intent:
    """What one sample says: smoothed levels, direct-control velocity, and a gesture if one
    contraction has just been released."""

    level: tuple[float, float]
    velocity: float
    gesture: Gesture | None = None
    co_active: bool = False
    active: bool = False
    reason: str = ""


def intent_step(
    state: IntentState, channels: Sequence[float], t_ns: int
) -> tuple[IntentState, Intent]:
    """Feed one raw sample (flexor, extensor) taken at ``t_ns``."""
    p = state.profile
    if len(channels) < N_CHANNELS:
        raise ValueError(f"channels needs {N_CHANNELS} values, got {len(channels)}")
    if t_ns <= state.last_t_ns:
        # Out-of-order or repeated sample: timing rules would be wrong, so skip it.
        return state, Intent(level=_mean(state.window), velocity=0.0, reason="out of order")
    # Plain floats: this runs per sample at 100 Hz, numpy's per-call overhead dominates here.
    raw = [float(x) for x in channels[:N_CHANNELS]]
    if not all(math.isfinite(x) for x in raw):
        return state, Intent(level=_mean(state.window), velocity=0.0, reason="non-finite sample")
    n = tuple(
        min(max((x - r) / (m - r), 0.0), 2.0)
        for x, r, m in zip(raw, p.rest, p.maximal, strict=True)
    )
    window = (*state.window[len(state.window) - p.window + 1 :], n)
    level = _mean(window)
    velocity = proportional_velocity(level, p)
    co_now = level[0] >= p.co_contraction and level[1] >= p.co_contraction
    active = max(level) >= p.on

    episode, below_since, lockout = state.episode, state.below_since_ns, state.lockout_until_ns
    gesture: Gesture | None = None
    reason = ""
    if episode is None and active:
        # An episode begun during lock-out is tracked to its release, so that its tail cannot
        # start a fresh (and falsely quick) episode when the lock-out ends.
        episode = Episode(
            start_ns=t_ns, on_ns=(None, None), upper_ns=(None, None), locked=t_ns < lockout
        )
    if episode is not None:
        on_ns = tuple(
            prev if prev is not None else (t_ns if lv >= p.on else None)
            for prev, lv in zip(episode.on_ns, level, strict=True)
        )
        upper_ns = tuple(
            prev if prev is not None else (t_ns if lv >= p.upper else None)
            for prev, lv in zip(episode.upper_ns, level, strict=True)
        )
        episode = evolve(episode, on_ns=on_ns, upper_ns=upper_ns, co=episode.co or co_now)  # type: ignore[arg-type]
        if max(level) < p.off:
            below_since = t_ns if below_since is None else below_since
            if t_ns - below_since >= p.release_ms * 1e6:
                gesture, reason = classify(episode, below_since, p)
                episode, below_since = None, None
                if gesture is not None:
                    lockout = t_ns + int(p.lockout_ms * 1e6)
        else:
            below_since = None
    new_state = evolve(
        state,
        window=window,
        episode=episode,
        below_since_ns=below_since,
        lockout_until_ns=lockout,
        last_t_ns=t_ns,
    )
    return new_state, Intent(
        level=level,
        velocity=velocity,
        gesture=gesture,
        co_active=co_now,
        active=active,
        reason=reason,
    )


def classify(episode: Episode, released_ns: int, p: EmgProfile) -> tuple[Gesture | None, str]:
    """The gesture of a finished episode, or None with the reason it was not one."""
    if episode.locked:
        return None, "started during lock-out"
    if episode.co:
        return Gesture.CO_CONTRACTION, "co-contraction"
    duration_ms = (released_ns - episode.start_ns) / 1e6
    if duration_ms > p.max_trigger_ms:
        return None, f"held {duration_ms:.0f} ms: proportional, not a trigger"
    reached = [u is not None for u in episode.upper_ns]
    if all(reached):
        return None, "both channels reached the upper threshold without co-contraction"
    for channel, gesture in ((FLEXOR, Gesture.QUICK_FLEXION), (EXTENSOR, Gesture.QUICK_EXTENSION)):
        on, up = episode.on_ns[channel], episode.upper_ns[channel]
        if up is None or on is None:
            continue
        rise_ms = (up - on) / 1e6
        if rise_ms <= p.quick_ms:
            return gesture, f"rise {rise_ms:.0f} ms"
        return None, f"slow rise {rise_ms:.0f} ms"
    return None, "below the upper threshold"


def _mean(window: Sequence[tuple[float, float]]) -> tuple[float, float]:
    if not window:
        return (0.0, 0.0)
    k = len(window)
    return (sum(w[0] for w in window) / k, sum(w[1] for w in window) / k)


def detect(
    raw: np.ndarray, t_ns: np.ndarray | None = None, profile: EmgProfile | None = None
) -> list[tuple[int, Gesture]]:
    """Run the detector over a recording (N, 2); the (sample index, gesture) pairs it fires.

    ``t_ns`` defaults to 100 Hz sampling.
    """
    raw = np.asarray(raw, dtype=float)
    if raw.ndim != 2 or raw.shape[1] != N_CHANNELS:
        raise ValueError(f"raw must have shape (N, {N_CHANNELS}), got {raw.shape}")
    if t_ns is None:
        t_ns = np.arange(len(raw), dtype=np.int64) * 10_000_000
    state = IntentState(profile=profile or EmgProfile())
    fired: list[tuple[int, Gesture]] = []
    for i, (sample, t) in enumerate(zip(raw.tolist(), np.asarray(t_ns).tolist(), strict=True)):
        state, intent = intent_step(state, sample, int(t))
        if intent.gesture is not None:
            fired.append((i, intent.gesture))
    return fired
