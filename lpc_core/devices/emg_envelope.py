"""Raw EMG in, the controller's 100 Hz envelope out: a pure, stateful filter.

Amplifiers that stream over LSL or through BrainFlow send the raw signal at 200 Hz to 2 kHz;
the controller (``lpc_core.control.emg``) expects rectified, smoothed envelopes at 100 Hz. Per
channel, in order:

1. **band-pass** ``band_hz`` (default 20-450 Hz, Butterworth, ``order`` per edge): removes the
   electrode offset and motion artefacts below and noise above the EMG band. The upper edge
   is clamped to ``0.45 * rate`` (below Nyquist); when that leaves no band above the lower
   edge, only the high-pass runs (``notes`` says so);
2. **notch** at the mains frequency (``mains_hz``, 50 or 60; Q = 30), skipped when mains lies
   at or above Nyquist;
3. **full-wave rectification**;
4. **low-pass** ``lowpass_hz`` (Butterworth, second order): the envelope is the mean absolute
   value (MAV) of the band-passed signal; for a Gaussian signal of standard deviation s it is
   s * sqrt(2 / pi);
5. **resampling** to ``out_hz``: one output each ``rate / out_hz`` input samples, whatever the
   chunk sizes (a fractional step, e.g. 5.12 samples at 512 Hz, carries its phase from chunk
   to chunk); the low-pass has removed everything above ``out_hz / 2`` first.

The envelope stays in the source's units (e.g. volts); the user profile's rest and maximal,
recorded from these same envelopes by ``lpc emg calibrate --source bus``, normalise it in the
controller as for any other source.

State is explicit: ``envelope_step(state, chunk, t_last_ns) -> (state, EnvelopeOut)``. No I/O,
no clock: the caller says when the chunk's last sample was taken, and each output carries the
time of its input sample (kept strictly increasing, so a late chunk never reorders samples).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import signal

MIN_RATE_HZ = 100.0
NOTCH_Q = 30.0
LOWPASS_ORDER = 2


@dataclass(frozen=True)
class EnvelopeParams:
    """The filter's settings; frequencies in Hz."""

    rate_hz: float
    channels: int = 2
    mains_hz: float = 50.0
    band_hz: tuple[float, float] = (20.0, 450.0)
    order: int = 4
    lowpass_hz: float = 8.0
    out_hz: float = 100.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_hz) and self.rate_hz >= max(MIN_RATE_HZ, self.out_hz)):
            raise ValueError(
                f"rate_hz must be at least {max(MIN_RATE_HZ, self.out_hz):g} Hz to give "
                f"{self.out_hz:g} Hz envelopes, got {self.rate_hz}"
            )
        if self.channels < 1:
            raise ValueError(f"channels must be >= 1, got {self.channels}")
        if self.mains_hz not in (50.0, 60.0):
            raise ValueError(f"mains_hz must be 50 or 60, got {self.mains_hz}")
        low, high = self.band_hz
        if not 0 < low < high:
            raise ValueError(f"band_hz must be (low, high) with 0 < low < high, got {self.band_hz}")
        if not 1 <= self.order <= 8:
            raise ValueError(f"order must be 1..8, got {self.order}")
        if not 0 < self.lowpass_hz < self.out_hz / 2:
            raise ValueError(
                f"lowpass_hz must be in (0, {self.out_hz / 2:g}) Hz (below the output's Nyquist), "
                f"got {self.lowpass_hz}"
            )
        if not 0 < self.out_hz <= 1000:
            raise ValueError(f"out_hz must be in (0, 1000], got {self.out_hz}")


@dataclass(frozen=True)
class EnvelopeDesign:
    """The filters' coefficients for one rate, and what had to be left out and why."""

    params: EnvelopeParams
    pre: np.ndarray  # SOS before rectification: band-pass (or high-pass), notch
    post: np.ndarray  # SOS after rectification: the envelope's low-pass
    band_hz: tuple[float, float | None]  # as applied: high None when only the high-pass runs
    notch_hz: float | None
    notes: tuple[str, ...] = ()


def design(params: EnvelopeParams) -> EnvelopeDesign:
    """The cascade for ``params.rate_hz``; the clamps and skips are listed in ``notes``."""
    fs = params.rate_hz
    low, high = params.band_hz
    notes: list[str] = []
    nyquist_cap = 0.45 * fs
    if high > nyquist_cap:
        notes.append(
            f"band-pass upper edge {high:g} Hz clamped to {nyquist_cap:g} Hz (rate {fs:g} Hz)"
        )
        high = nyquist_cap
    if high <= 1.5 * low:
        notes.append(
            f"rate {fs:g} Hz leaves no band above {low:g} Hz below Nyquist: high-pass only"
        )
        sections = [signal.butter(params.order, low, "highpass", fs=fs, output="sos")]
        applied: tuple[float, float | None] = (low, None)
    else:
        sections = [signal.butter(params.order, (low, high), "bandpass", fs=fs, output="sos")]
        applied = (low, high)
    notch: float | None = params.mains_hz
    if params.mains_hz >= 0.5 * fs * 0.98:
        notes.append(
            f"mains {params.mains_hz:g} Hz is at or above Nyquist ({fs / 2:g} Hz): no notch"
        )
        notch = None
    else:
        b, a = signal.iirnotch(params.mains_hz, NOTCH_Q, fs=fs)
        sections.append(signal.tf2sos(b, a))
    post = signal.butter(LOWPASS_ORDER, params.lowpass_hz, "lowpass", fs=fs, output="sos")
    return EnvelopeDesign(
        params=params,
        pre=np.vstack(sections),
        post=post,
        band_hz=applied,
        notch_hz=notch,
        notes=tuple(notes),
    )


@dataclass(frozen=True)
class EnvelopeState:
    """The filter's memory: its design, the SOS states, the resampling phase, the last time."""

    design: EnvelopeDesign
    pre_zi: np.ndarray | None = None  # (sections, 2, channels); None until the first sample
    post_zi: np.ndarray | None = None
    # Index, in the next chunk, of the input sample that gives the next output.
    phase: float = 0.0
    last_t_ns: int = -1
    samples: int = 0


@dataclass(frozen=True)
class EnvelopeOut:
    """The envelopes a chunk completed: ``t_ns`` shape (M,), ``values`` shape (M, channels)."""

    t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    values: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def envelope_state(params: EnvelopeParams) -> EnvelopeState:
    """A fresh filter (also after an outage: the old state belongs to a signal that stopped)."""
    return EnvelopeState(design=design(params))


def envelope_step(
    state: EnvelopeState, chunk: np.ndarray, t_last_ns: int
) -> tuple[EnvelopeState, EnvelopeOut]:
    """Feed a chunk of raw samples, shape (N, channels), whose last sample was taken at
    ``t_last_ns``; get the envelopes it completes. Raises ``ValueError`` for a bad chunk (wrong
    shape or non-finite values), leaving the state for the caller to keep."""
    p = state.design.params
    x = np.asarray(chunk, dtype=float)
    if x.ndim != 2 or x.shape[1] != p.channels:
        raise ValueError(f"chunk must have shape (N, {p.channels}), got {x.shape}")
    n = len(x)
    if n == 0:
        return state, EnvelopeOut(values=np.zeros((0, p.channels)))
    if not np.all(np.isfinite(x)):
        raise ValueError("chunk contains NaN or inf")
    pre_zi, post_zi = state.pre_zi, state.post_zi
    if pre_zi is None or post_zi is None:
        # Start as if the first value had always been there, so the electrode's offset does not
        # ring through the band-pass as a step; the envelope starts from zero.
        # scipy's zi for axis 0 has shape (sections, 2, channels).
        pre_zi = signal.sosfilt_zi(state.design.pre)[:, :, None] * x[0][None, None, :]
        post_zi = np.zeros((len(state.design.post), 2, p.channels))
    y, pre_zi = signal.sosfilt(state.design.pre, x, axis=0, zi=pre_zi)
    env, post_zi = signal.sosfilt(state.design.post, np.abs(y), axis=0, zi=post_zi)

    step = p.rate_hz / p.out_hz
    picks = np.arange(state.phase, n, step)
    index = np.ceil(picks - 1e-9).astype(np.int64)  # the first input sample at or after the pick
    index = index[index < n]
    phase = state.phase + len(index) * step - n
    period_ns = 1e9 / p.rate_hz
    t = t_last_ns - np.round((n - 1 - index) * period_ns).astype(np.int64)
    # Chunks arrive with jitter: never let an output go back in time or repeat a time.
    floor = state.last_t_ns + 1 + np.arange(len(t), dtype=np.int64)
    t = np.maximum(t, floor)
    new = replace(
        state,
        pre_zi=pre_zi,
        post_zi=post_zi,
        phase=float(phase),
        last_t_ns=int(t[-1]) if len(t) else state.last_t_ns,
        samples=state.samples + n,
    )
    return new, EnvelopeOut(t_ns=t, values=env[index])
