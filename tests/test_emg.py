"""EMG intent detection on synthetic signals: normalisation, smoothing, gestures, velocity."""

from __future__ import annotations

import numpy as np
import pytest

from lpc_core.control.emg import (
    EmgProfile,
    Gesture,
    IntentState,
    calibrate,
    detect,
    intent_step,
    normalise,
    proportional_velocity,
    smooth,
)
from lpc_core.sim.emg_sim import (
    MuscleParams,
    MuscleState,
    co_contraction,
    quick_extension,
    quick_flexion,
    script_drive,
    simulate_emg,
    slow_hold,
)

REST = (4e-6, 5e-6)
MAXIMAL = (180e-6, 150e-6)
PROFILE = EmgProfile(rest=REST, maximal=MAXIMAL)


def trapezoid(n: int, start: int, rise: int, hold: int, level: float, fall: int = 3) -> np.ndarray:
    """A noiseless normalised contraction: linear rise over ``rise`` samples, hold, linear fall."""
    x = np.zeros(n)
    up = np.linspace(0, level, rise + 1)[1:]
    down = np.linspace(level, 0, fall + 1)[1:]
    seg = np.concatenate([up, np.full(hold, level), down])
    x[start : start + len(seg)] = seg
    return x


def raw_from_levels(flexor: np.ndarray, extensor: np.ndarray) -> np.ndarray:
    levels = np.stack([flexor, extensor], axis=1)
    return np.asarray(REST) + levels * (np.asarray(MAXIMAL) - np.asarray(REST))


# --------------------------------------------------------------------------- basics


def test_normalise_maps_rest_to_zero_and_maximal_to_one() -> None:
    out = normalise([REST, MAXIMAL, (0.0, 0.0), (1.0, 1.0)], PROFILE)
    np.testing.assert_allclose(out, [[0, 0], [1, 1], [0, 0], [2, 2]])


def test_normalise_rejects_wrong_shape() -> None:
    with pytest.raises(ValueError, match="raw"):
        normalise(np.zeros((4, 3)), PROFILE)


@pytest.mark.parametrize(
    ("changes", "name"),
    [
        ({"maximal": (1.0, 0.0)}, "maximal"),
        ({"window": 0}, "window"),
        ({"off": 0.3, "on": 0.2}, "off"),
        ({"co_contraction": 0.3}, "co_contraction"),
        ({"quick_ms": 0.0}, "quick_ms"),
        ({"rest": (0.0,)}, "rest"),
    ],
)
def test_profile_rejects_bad_parameters(changes: dict, name: str) -> None:
    fields = {"rest": REST, "maximal": MAXIMAL, **changes}
    with pytest.raises(ValueError, match=name):
        EmgProfile(**fields)


def test_profile_round_trips_through_dict() -> None:
    profile = EmgProfile(rest=REST, maximal=MAXIMAL, upper=0.45, user="anna", unit="V")
    assert EmgProfile.from_dict(profile.to_dict()) == profile
    with pytest.raises(ValueError, match="bogus"):
        EmgProfile.from_dict({**profile.to_dict(), "bogus": 1})


def test_smooth_is_a_causal_moving_average() -> None:
    x = np.arange(20, dtype=float)
    out = smooth(x, 10)
    assert out[0] == 0.0
    assert out[4] == pytest.approx(np.mean(x[:5]))
    assert out[15] == pytest.approx(np.mean(x[6:16]))


def test_proportional_velocity_sign_deadband_and_co_contraction() -> None:
    assert proportional_velocity((0.1, 0.0), PROFILE) == 0.0  # below the on-threshold
    assert proportional_velocity((0.5, 0.0), PROFILE) > 0  # flexor closes
    assert proportional_velocity((0.0, 0.5), PROFILE) < 0  # extensor opens
    assert proportional_velocity((1.5, 0.0), PROFILE) == 1.0  # clipped
    assert proportional_velocity((0.8, 0.8), PROFILE) == 0.0  # switching, not moving
    v1 = proportional_velocity((0.3, 0.0), PROFILE)
    v2 = proportional_velocity((0.45, 0.0), PROFILE)
    assert 0 < v1 < v2  # proportional


# --------------------------------------------------------------------------- gestures


def test_detect_quick_flexion_fires_once_on_release() -> None:
    flex = trapezoid(300, start=100, rise=2, hold=15, level=0.9)
    fired = detect(raw_from_levels(flex, np.zeros(300)), profile=PROFILE)
    assert [g for _, g in fired] == [Gesture.QUICK_FLEXION]
    # On release: after the contraction ended (sample 120) and the average fell below off.
    assert 120 < fired[0][0] < 140


def test_detect_quick_extension_fires_once() -> None:
    ext = trapezoid(300, start=50, rise=3, hold=12, level=0.8)
    fired = detect(raw_from_levels(np.zeros(300), ext), profile=PROFILE)
    assert [g for _, g in fired] == [Gesture.QUICK_EXTENSION]


def test_detect_co_contraction_gives_one_event_only() -> None:
    flex = trapezoid(300, start=50, rise=2, hold=20, level=0.8)
    ext = trapezoid(300, start=52, rise=2, hold=20, level=0.75)
    fired = detect(raw_from_levels(flex, ext), profile=PROFILE)
    assert [g for _, g in fired] == [Gesture.CO_CONTRACTION]


def test_detect_slow_rise_is_not_a_trigger() -> None:
    # 0.15 -> 0.5 takes about 35 samples here: far beyond the 80 ms quick window.
    flex = trapezoid(400, start=50, rise=60, hold=5, level=0.6)
    assert detect(raw_from_levels(flex, np.zeros(400)), profile=PROFILE) == []


def test_detect_long_hold_is_proportional_not_a_trigger() -> None:
    flex = trapezoid(400, start=50, rise=2, hold=100, level=0.9)  # 1 s hold
    assert detect(raw_from_levels(flex, np.zeros(400)), profile=PROFILE) == []


def test_detect_weak_contraction_below_upper_is_not_a_trigger() -> None:
    flex = trapezoid(300, start=50, rise=2, hold=15, level=0.4)
    assert detect(raw_from_levels(flex, np.zeros(300)), profile=PROFILE) == []


def test_detect_lockout_ignores_a_contraction_right_after_a_gesture() -> None:
    flex = trapezoid(400, start=50, rise=2, hold=12, level=0.9)
    # The first fires near sample 77; the second starts 100 ms later, inside the 300 ms lock-out.
    flex += trapezoid(400, start=87, rise=2, hold=12, level=0.9)
    fired = detect(raw_from_levels(flex, np.zeros(400)), profile=PROFILE)
    assert [g for _, g in fired] == [Gesture.QUICK_FLEXION]


def test_detect_two_contractions_after_lockout_give_two_events() -> None:
    flex = trapezoid(500, start=50, rise=2, hold=12, level=0.9)
    ext = trapezoid(500, start=200, rise=2, hold=12, level=0.9)
    fired = detect(raw_from_levels(flex, ext), profile=PROFILE)
    assert [g for _, g in fired] == [Gesture.QUICK_FLEXION, Gesture.QUICK_EXTENSION]


def test_detect_short_dip_below_off_keeps_one_episode() -> None:
    # A one-sample dropout in the middle of a held contraction must not split it in two.
    flex = trapezoid(300, start=50, rise=2, hold=20, level=0.9)
    levels = smooth(flex, PROFILE.window)
    assert levels.max() > PROFILE.upper
    raw = raw_from_levels(flex, np.zeros(300))
    raw[62] = REST  # the smoothed level stays above off: still one episode
    fired = detect(raw, profile=PROFILE)
    assert [g for _, g in fired] == [Gesture.QUICK_FLEXION]


def test_intent_step_skips_out_of_order_and_non_finite_samples() -> None:
    state = IntentState(profile=PROFILE)
    state, _ = intent_step(state, list(MAXIMAL), 20_000_000)
    same, intent = intent_step(state, list(MAXIMAL), 10_000_000)
    assert same is state and intent.reason == "out of order"
    same, intent = intent_step(state, [float("nan"), 0.0], 30_000_000)
    assert same is state and intent.reason == "non-finite sample"
    with pytest.raises(ValueError, match="channels"):
        intent_step(state, [1.0], 40_000_000)


# --------------------------------------------------------------------------- simulated user


def test_detect_no_false_trigger_over_ten_minutes_of_rest() -> None:
    params = MuscleParams()  # noise, cross-talk, artifacts at 0.02 Hz
    _, raw = simulate_emg(MuscleState(), np.zeros((60_000, 2)), params, seed=7, seq=0)
    profile = EmgProfile(rest=params.rest, maximal=params.maximal)
    assert detect(raw, profile=profile) == []


def test_detect_no_false_trigger_at_rest_with_heavy_artifacts() -> None:
    # Twenty times the artifact rate, twice their size: still no gesture from rest.
    params = MuscleParams(artifact_rate_hz=0.4, artifact_level=0.6, noise=0.3)
    _, raw = simulate_emg(MuscleState(), np.zeros((30_000, 2)), params, seed=3, seq=0)
    profile = EmgProfile(rest=params.rest, maximal=params.maximal)
    assert detect(raw, profile=profile) == []


def test_detect_simulated_gestures_each_exactly_once() -> None:
    params = MuscleParams()
    kinds = [quick_flexion, quick_extension, co_contraction] * 8
    segments = [make(1.0 + 2.0 * i) for i, make in enumerate(kinds)]
    # Proportional commands in between must not trigger anything.
    segments += [slow_hold(50.0 + 3.0 * i, 1.0, flexor=0.6) for i in range(3)]
    drive = script_drive(segments, 6000)
    _, raw = simulate_emg(MuscleState(), drive, params, seed=11, seq=0)
    fired = detect(raw, profile=EmgProfile(rest=params.rest, maximal=params.maximal))
    expected = {
        quick_flexion: Gesture.QUICK_FLEXION,
        quick_extension: Gesture.QUICK_EXTENSION,
        co_contraction: Gesture.CO_CONTRACTION,
    }
    assert [g for _, g in fired] == [expected[k] for k in kinds]
    for (index, _), segment in zip(fired, segments, strict=False):
        assert segment.end_s * 100 < index < segment.end_s * 100 + 40  # fired on release


def test_detect_quick_flexion_survives_fatigue() -> None:
    params = MuscleParams(fatigue_rate=0.05)  # fast fatigue: about 25 % after a long hold
    segments = [slow_hold(0.5, 10.0, flexor=0.8), quick_flexion(12.5)]
    drive = script_drive(segments, 1400)
    state, raw = simulate_emg(MuscleState(), drive, params, seed=5, seq=0)
    assert state.fatigue[0] > 0.15
    fired = detect(raw, profile=EmgProfile(rest=params.rest, maximal=params.maximal))
    assert [g for _, g in fired] == [Gesture.QUICK_FLEXION]


def test_calibrate_recovers_rest_and_maximal() -> None:
    params = MuscleParams(fatigue_rate=0.0, artifact_rate_hz=0.0)
    _, rest = simulate_emg(MuscleState(), np.zeros((300, 2)), params, seed=1, seq=0)
    recordings = []
    for c in range(2):
        drive = np.zeros((300, 2))
        drive[50:250, c] = 1.0
        _, rec = simulate_emg(MuscleState(), drive, params, seed=2 + c, seq=0)
        recordings.append(rec)
    profile = calibrate(rest, recordings)
    # Rest: the quadrature sum of noise with no signal, the rest level itself (within 5 %).
    np.testing.assert_allclose(profile.rest, params.rest, rtol=0.05)
    # Maximal: full activation plus cross-talk's contribution is zero on the other channel,
    # and the 98th percentile of a noisy plateau sits a little above its mean (within 15 %).
    np.testing.assert_allclose(profile.maximal, params.maximal, rtol=0.15)
    assert profile.off >= 0.1 and profile.on > profile.off


def test_calibrate_rejects_a_missing_contraction() -> None:
    params = MuscleParams()
    _, rest = simulate_emg(MuscleState(), np.zeros((300, 2)), params, seed=1, seq=0)
    with pytest.raises(ValueError, match="channel 0"):
        calibrate(rest, [rest, rest])
