"""Raw EMG with a known envelope, and how far an envelope estimate is from it.

For testing and measuring ``lpc_core.devices.emg_envelope``: a slow, always positive muscle
drive ``a(t)`` (volts) multiplies a carrier — Gaussian noise inside the EMG band (unit standard
deviation, mean absolute value sqrt(2/pi)) or a sine (mean absolute value 2/pi) — and mains
hum five times the EMG's size, an electrode offset and a slow motion artefact are added. The
true envelope, in the filter's units (mean absolute value), is ``mav * a(t)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from lpc_core.devices.emg_envelope import EnvelopeParams, envelope_state, envelope_step


def slow_drive(t: np.ndarray) -> np.ndarray:
    """The muscle drive (V) at times ``t`` (s): 0.5 Hz and 1.3 Hz components, always > 0."""
    return 1e-4 * (2.0 + np.sin(2 * np.pi * 0.5 * t) + 0.5 * np.sin(2 * np.pi * 1.3 * t + 1.0))


@dataclass(frozen=True)
class RawEmg:
    """``raw`` (N, 2): the flexor, and the extensor at half its size; ``drive`` (N,) is a(t)."""

    rate_hz: float
    t: np.ndarray
    raw: np.ndarray
    drive: np.ndarray
    mav: float  # the carrier's mean absolute value: the true envelope is mav * drive


def raw_emg(
    rate_hz: float, seconds: float, carrier: str = "noise", mains_hz: float = 50.0, seed: int = 0
) -> RawEmg:
    """``carrier``: ``noise`` (Gaussian, 40 Hz to min(400 Hz, 0.4 rate)) or ``sine`` (at
    min(150 Hz, 0.35 rate))."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(seconds * rate_hz)) / rate_hz
    a = slow_drive(t)
    if carrier == "noise":
        band = (40.0, min(400.0, 0.4 * rate_hz))
        sos = signal.butter(6, band, "bandpass", fs=rate_hz, output="sos")
        w = signal.sosfiltfilt(sos, rng.standard_normal(len(t)))
        c, mav = w / w.std(), float(np.sqrt(2 / np.pi))
    elif carrier == "sine":
        c, mav = np.sin(2 * np.pi * min(150.0, 0.35 * rate_hz) * t), 2 / np.pi
    else:
        raise ValueError(f"carrier must be noise or sine, got {carrier!r}")
    hum = 5e-4 * np.sin(2 * np.pi * mains_hz * t)
    x = a * c + hum + 2e-3 + 3e-4 * np.sin(2 * np.pi * 0.3 * t)
    return RawEmg(rate_hz=rate_hz, t=t, raw=np.stack([x, 0.5 * x], axis=1), drive=a, mav=mav)


def run_chunked(
    params: EnvelopeParams, raw: np.ndarray, t0_ns: int, seed: int = 1, max_chunk_s: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """Feed ``raw`` through the filter in chunks of random size (1 sample to ``max_chunk_s``),
    as a stream arrives; all outputs' ``(t_ns, values)``. Sample i was taken at t0 + i/rate."""
    rng = np.random.default_rng(seed)
    state = envelope_state(params)
    times, values, i = [], [], 0
    while i < len(raw):
        k = int(rng.integers(1, int(params.rate_hz * max_chunk_s) + 2))
        chunk = raw[i : i + k]
        i += len(chunk)
        state, out = envelope_step(state, chunk, t0_ns + round((i - 1) / params.rate_hz * 1e9))
        times.append(out.t_ns)
        values.append(out.values)
    return np.concatenate(times), np.concatenate(values)


@dataclass(frozen=True)
class EnvelopeError:
    """Relative RMS error of the flexor's envelope at zero lag, the delay (ms) that minimises
    it, and the error at that delay; past the filters' start-up."""

    error_at_zero: float
    delay_ms: float
    error: float


def envelope_error(
    emg: RawEmg, t_ns: np.ndarray, values: np.ndarray, t0_ns: int, skip_s: float = 2.0
) -> EnvelopeError:
    ts = (t_ns - t0_ns) / 1e9
    keep = ts > skip_s
    truth = emg.mav * np.interp(ts[keep], emg.t, emg.drive)
    scale = np.sqrt(np.mean(truth**2))
    lags = np.arange(0.0, 0.1, 0.001)
    shifted = emg.mav * np.interp(ts[keep][None, :] - lags[:, None], emg.t, emg.drive)
    errors = np.sqrt(np.mean((values[keep, 0][None, :] - shifted) ** 2, axis=1)) / scale
    best = int(np.argmin(errors))
    return EnvelopeError(
        error_at_zero=float(errors[0]), delay_ms=float(lags[best] * 1e3), error=float(errors[best])
    )
