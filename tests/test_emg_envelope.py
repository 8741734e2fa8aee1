"""The raw-EMG envelope filter against signals whose envelope is known."""

from __future__ import annotations

import numpy as np
import pytest

from lpc_core.devices.emg_envelope import (
    EnvelopeParams,
    design,
    envelope_state,
    envelope_step,
)
from lpc_core.sim.raw_emg import envelope_error, raw_emg, run_chunked

T0_NS = 1_700_000_000_000_000_000


def _run(params: EnvelopeParams, raw: np.ndarray, seed: int = 1, max_chunk_s: float = 0.05):
    return run_chunked(params, raw, T0_NS, seed=seed, max_chunk_s=max_chunk_s)


@pytest.mark.parametrize("fs", [200.0, 250.0, 512.0, 1000.0, 2000.0])
@pytest.mark.parametrize("mains", [50.0, 60.0])
def test_envelope_follows_modulated_carrier(fs: float, mains: float) -> None:
    emg = raw_emg(fs, 12.0, "sine", mains)
    t_ns, values = _run(EnvelopeParams(rate_hz=fs, mains_hz=mains), emg.raw)
    e = envelope_error(emg, t_ns, values, T0_NS)
    err0, delay_ms, err = e.error_at_zero, e.delay_ms, e.error
    # The second-order 8 Hz low-pass delays a slow envelope by about 30 ms; the sampling
    # picks the first input sample at or after each output instant (at most 5 ms at 200 Hz).
    assert 25.0 <= delay_ms <= 40.0, delay_ms
    assert err < 0.03, (err, delay_ms)  # mains hum 5x the EMG, offset and artefact: gone
    assert err0 < 0.08, err0
    # The second channel is the first at half the amplitude: the filter is linear per channel.
    np.testing.assert_allclose(values[50:, 1], 0.5 * values[50:, 0], rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("fs", [512.0, 1000.0, 2000.0])
def test_envelope_of_gaussian_emg_is_its_mean_absolute_value(fs: float) -> None:
    emg = raw_emg(fs, 30.0, "noise", 50.0, seed=3)
    t_ns, values = _run(EnvelopeParams(rate_hz=fs), emg.raw)
    e = envelope_error(emg, t_ns, values, T0_NS)
    delay_ms, err = e.delay_ms, e.error
    ts = (t_ns - T0_NS) / 1e9
    keep = ts > 2.0
    truth = emg.mav * np.interp(ts[keep] - delay_ms / 1e3, emg.t, emg.drive)
    bias = values[keep, 0].mean() / truth.mean()
    # A random signal's MAV estimate fluctuates (fewer independent samples in a narrower band):
    # the bound is on the estimator's spread, the bias must be small.
    assert err < 0.2, err
    assert abs(bias - 1.0) < 0.03, bias
    assert 20.0 <= delay_ms <= 45.0, delay_ms


@pytest.mark.parametrize("fs", [200.0, 250.0, 500.0, 512.0, 1000.0, 1024.0, 2000.0])
def test_envelope_is_100_hz_whatever_the_rate_and_chunks(fs: float) -> None:
    n = round(10.0 * fs)
    raw = np.random.default_rng(0).standard_normal((n, 2)) * 1e-4
    params = EnvelopeParams(rate_hz=fs)
    t_a, v_a = _run(params, raw, seed=1, max_chunk_s=0.003)
    t_b, v_b = _run(params, raw, seed=2, max_chunk_s=0.2)
    # One output per rate/100 input samples, the first at sample 0.
    assert len(t_a) == len(t_b) == int(np.floor((n - 1) * 100.0 / fs + 1e-9)) + 1
    np.testing.assert_allclose(v_a, v_b, rtol=1e-12, atol=1e-18)  # chunking changes nothing
    assert np.max(np.abs(t_a - t_b)) <= 2  # ns: rounding of each chunk's own stamp
    gaps_ms = np.diff(t_a) / 1e6
    assert np.all(gaps_ms > 0)
    assert abs(np.mean(gaps_ms) - 10.0) <= 1e3 / fs / len(gaps_ms) + 1e-9
    assert np.max(np.abs(gaps_ms - 10.0)) <= 1e3 / fs + 1e-6  # jitter at most one input sample


def test_envelope_rejects_mains_hum() -> None:
    fs = 1000.0
    t = np.arange(round(5 * fs)) / fs
    hum = 1e-3 * np.sin(2 * np.pi * 50.0 * t)
    raw = np.stack([hum, hum], axis=1)
    _, with_notch = _run(EnvelopeParams(rate_hz=fs, mains_hz=50.0), raw)
    _, wrong_notch = _run(EnvelopeParams(rate_hz=fs, mains_hz=60.0), raw)
    late = slice(200, None)  # after 2 s
    hum_mav = 1e-3 * 2 / np.pi
    assert with_notch[late, 0].max() < 0.01 * hum_mav
    assert wrong_notch[late, 0].mean() > 0.5 * hum_mav  # the 60 Hz notch leaves 50 Hz through


def test_envelope_output_times_never_go_back() -> None:
    params = EnvelopeParams(rate_hz=1000.0)
    state = envelope_state(params)
    chunk = np.zeros((50, 2))
    state, first = envelope_step(state, chunk, T0_NS)
    # The next chunk is stamped earlier than the previous one ended (a late, jittery arrival).
    state, second = envelope_step(state, chunk, T0_NS - 20_000_000)
    both = np.concatenate([first.t_ns, second.t_ns])
    assert len(both) == 10
    assert np.all(np.diff(both) > 0)


def test_design_clamps_and_skips_with_reasons() -> None:
    d = design(EnvelopeParams(rate_hz=200.0))
    assert d.band_hz == (20.0, 90.0)
    assert any("clamped to 90 Hz" in note for note in d.notes)
    assert d.notch_hz == 50.0
    d = design(EnvelopeParams(rate_hz=100.0, mains_hz=50.0))
    assert d.notch_hz is None
    assert any("no notch" in note for note in d.notes)
    d = design(EnvelopeParams(rate_hz=100.0, band_hz=(40.0, 450.0), mains_hz=60.0))
    assert d.band_hz == (40.0, None)
    assert any("high-pass only" in note for note in d.notes)
    d = design(EnvelopeParams(rate_hz=2000.0))
    assert d.band_hz == (20.0, 450.0) and d.notes == ()


@pytest.mark.parametrize(
    ("changes", "word"),
    [
        ({"rate_hz": 50.0}, "rate_hz"),
        ({"rate_hz": float("nan")}, "rate_hz"),
        ({"mains_hz": 55.0}, "mains_hz"),
        ({"band_hz": (300.0, 100.0)}, "band_hz"),
        ({"lowpass_hz": 60.0}, "lowpass_hz"),
        ({"channels": 0}, "channels"),
    ],
)
def test_params_reject_bad_values(changes: dict, word: str) -> None:
    with pytest.raises(ValueError, match=word):
        EnvelopeParams(**{"rate_hz": 1000.0, **changes})


def test_envelope_step_rejects_bad_chunks_and_keeps_state() -> None:
    state = envelope_state(EnvelopeParams(rate_hz=1000.0))
    with pytest.raises(ValueError, match="shape"):
        envelope_step(state, np.zeros((10, 3)), T0_NS)
    bad = np.zeros((10, 2))
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        envelope_step(state, bad, T0_NS)
    same, out = envelope_step(state, np.zeros((0, 2)), T0_NS)
    assert same is state and len(out.t_ns) == 0
