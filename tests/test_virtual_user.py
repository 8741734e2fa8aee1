"""The virtual user: practice, Fitts timing, reading the tactors, reaching, and triggering
through EMG that the real intent detector recognises."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from lpc_core.control.aim import AimParams, tactor_shares
from lpc_core.control.emg import EmgProfile, Gesture, detect
from lpc_core.sim.emg_sim import MuscleParams
from lpc_core.sim.virtual_user import (
    Learned,
    Percept,
    UserParams,
    axial_error_deg,
    feel,
    fitts_time,
    individual,
    min_jerk,
    new_trial,
    user_step,
)
from schemas import ProsthesisState, TactorCommand

ANGLES = AimParams().tactor_angles_rad
MUSCLES = MuscleParams(artifact_rate_hz=0.0)
START_NS = 2_000_000_000
TICK_NS = 10_000_000
# A user without perceptual or motor noise, so that geometry can be checked exactly.
EXACT = UserParams(
    visual_aim_sd_m=Learned(0.0, 0.0),
    aim_bias_m=Learned(0.0, 0.0),
    depth_aim_sd_m=0.0,
    motor_noise_ratio=0.0,
    motor_noise_floor_m=0.0,
    sway_sd_m=0.0,
    tremor_m=0.0,
    cue_direction_sd_deg=Learned(0.0, 0.0),
    cue_intensity_weber=0.0,
    quick_level_sd=0.0,
    notice_probability=1.0,
)


def start(params: UserParams = EXACT, feedback: bool = True, trial: int = 1, seed: int = 0):
    return new_trial(
        params,
        MUSCLES,
        trial=trial,
        feedback=feedback,
        tactor_angles_rad=ANGLES,
        seed=(seed, 1),
        start_ns=START_NS,
        lead_in_s=0.5,
        max_s=20.0,
    )


def run(state, seconds: float, percept=lambda t_s: Percept(width_mm=50.0)):
    """Step the user from the lead-in for ``seconds``; (state, times, offsets, emg, events)."""
    times, offsets, emg, events = [], [], [], []
    t_ns = START_NS - 500_000_000
    for _ in range(round(seconds * 100)):
        t_s = (t_ns - START_NS) / 1e9
        state, action = user_step(state, percept(t_s), t_ns)
        times.append(t_s)
        offsets.append(action.offset)
        emg.append(action.emg)
        events += [(t_s, e) for e in action.events]
        t_ns += TICK_NS
    return state, np.array(times), np.array(offsets), np.array(emg), events


def test_learned_goes_from_first_to_final_with_practice() -> None:
    skill = Learned(0.45, 0.30)
    values = [skill.at(n, 12.0) for n in (1, 5, 15, 45, 500)]
    assert values[0] == pytest.approx(0.45)
    assert all(a > b for a, b in itertools.pairwise(values))
    assert values[-1] == pytest.approx(0.30, abs=1e-9)
    # exponential law: one time constant closes 1 - 1/e of the gap
    assert skill.at(13, 12.0) == pytest.approx(0.30 + 0.15 / math.e)
    with pytest.raises(ValueError, match="trial"):
        skill.at(0, 12.0)


def test_fitts_time_grows_with_difficulty_and_respects_the_speed_bound() -> None:
    p = UserParams()
    near, far = fitts_time(0.05, 0.05, p), fitts_time(0.4, 0.05, p)
    assert near == pytest.approx(p.fitts_a_s + p.fitts_b_s_per_bit * 1.0)  # log2(1 + 1)
    assert far > near
    slow = dataclasses.replace(p, peak_speed_m_s=0.2)
    assert fitts_time(0.4, 0.05, slow) == pytest.approx(1.875 * 0.4 / 0.2)


def test_min_jerk_starts_and_ends_at_rest_and_is_symmetric() -> None:
    assert min_jerk(0.0) == 0.0 and min_jerk(1.0) == 1.0
    assert min_jerk(0.5) == pytest.approx(0.5)
    assert min_jerk(0.2) == pytest.approx(1.0 - min_jerk(0.8))
    assert min_jerk(-1.0) == 0.0 and min_jerk(2.0) == 1.0


def test_individual_draws_reproducible_different_people() -> None:
    base = UserParams()
    a = individual(base, np.random.default_rng(1))
    b = individual(base, np.random.default_rng(1))
    c = individual(base, np.random.default_rng(2))
    assert a == b
    assert a.fitts_a_s != c.fitts_a_s
    factors = [individual(base, np.random.default_rng(s)).simple_rt_s / base.simple_rt_s
               for s in range(200)]  # fmt: skip
    assert np.mean(factors) == pytest.approx(1.0, abs=0.05)
    assert np.std(factors) == pytest.approx(base.individual_cv, abs=0.05)


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 45.0, 100.0, -135.0])
def test_feel_reads_the_cue_direction_and_distance(theta_deg: float) -> None:
    rho = 0.3
    shares = (1.0 - rho) * tactor_shares(math.radians(theta_deg), ANGLES)
    felt = feel(TactorCommand(seq=0, t_ns=0, amplitudes=list(shares)), ANGLES, 0.05)
    assert felt.kind == "guiding"
    # Linear sharing between two tactors reads back within 4.1 degrees (worst at 22.5 deg).
    error = (math.degrees(felt.direction_rad) - theta_deg + 180.0) % 360.0 - 180.0
    assert abs(error) <= 4.1
    assert felt.distance_m == pytest.approx(rho * 0.1)


def test_feel_pulse_all_on_and_silence() -> None:
    on = TactorCommand(seq=0, t_ns=0, amplitudes=[1.0] * 4)
    assert feel(on, ANGLES, 0.05).kind == "on_target"
    assert (
        feel(TactorCommand(seq=0, t_ns=0, amplitudes=[1.0] * 4, pulse=True), ANGLES, 0.05).kind
        == "ready"
    )
    assert (
        feel(TactorCommand(seq=0, t_ns=0, amplitudes=[0.01, 0, 0, 0]), ANGLES, 0.05).kind
        == "nothing"
    )
    assert feel(None, ANGLES, 0.05).kind == "nothing"


def test_axial_error_is_the_angle_to_the_nearest_grasp_axis() -> None:
    assert axial_error_deg(0.0) == 0.0
    assert axial_error_deg(170.0) == pytest.approx(10.0)
    assert axial_error_deg(-95.0) == pytest.approx(85.0)


def test_user_reach_ends_on_the_object_in_fitts_time() -> None:
    """Without feedback and without noise the reach lands on the object's centre."""
    _, times, offsets, _, _ = run(start(feedback=False), 3.0)
    p = EXACT
    distance = math.dist(p.start_offset_m, (0.0, 0.0, 0.0))
    duration = fitts_time(distance, 0.05, p)
    np.testing.assert_allclose(offsets[times < 0], np.tile(p.start_offset_m, (50, 1)))
    np.testing.assert_allclose(offsets[-1], 0.0, atol=1e-12)
    moving = times[1:][np.linalg.norm(np.diff(offsets, axis=0), axis=1) > 1e-9]
    assert moving[-1] == pytest.approx(duration, abs=0.02)
    speed = np.linalg.norm(np.diff(offsets, axis=0), axis=1) / 0.01
    assert speed.max() == pytest.approx(1.875 * distance / duration, rel=0.02)


def test_user_with_feedback_reaches_beside_the_object_and_follows_the_cue() -> None:
    """The instructed approach from the side, then a move the length and way the tactors say."""
    width_m = 0.05
    beside = 0.5 * width_m + EXACT.side_approach_m
    reach_end = fitts_time(math.dist(EXACT.start_offset_m, (-beside, 0.0, 0.0)), width_m, EXACT)
    # The hull's nearest point 40 mm to the right: the right tactor at 0.6; then on target.
    guiding = TactorCommand(seq=0, t_ns=0, amplitudes=[0.6, 0.0, 0.0, 0.0])
    on = TactorCommand(seq=0, t_ns=0, amplitudes=[1.0] * 4)

    def percept(t_s: float) -> Percept:
        tactors = guiding if t_s < reach_end + 0.3 else on
        return Percept(tactors=tactors if t_s > 0.1 else None, width_mm=50.0)

    state, times, offsets, _, _ = run(start(), 4.0, percept)
    reached = offsets[np.searchsorted(times, reach_end + 0.01)]
    assert reached[0] == pytest.approx(-beside, abs=1e-9)
    moved = offsets[-1] - reached
    assert moved[0] == pytest.approx(0.04 + EXACT.cue_overshoot * 0.5 * width_m, abs=1e-9)
    assert abs(moved[1]) < 1e-9
    steps = np.linalg.norm(np.diff(offsets, axis=0), axis=1) > 1e-9
    correction_start = times[1:][steps & (times[1:] > reach_end + 0.01)][0]
    # the look waits for the next 10 ms tick, and so does the first visible step
    assert correction_start - reach_end == pytest.approx(EXACT.tactile_rt_s.first, abs=0.03)
    # A tactor-led move is slower than Fitts' law by the (novice) slowdown.
    correction_end = times[1:][steps][-1]
    duration = fitts_time(0.0525, width_m, EXACT) * EXACT.tactile_move_slowdown.first
    assert correction_end - correction_start == pytest.approx(duration, abs=0.03)
    assert state.corrections == 1
    assert state.phase == "aim"  # on target: holding, waiting for the pulse


def test_user_triggers_on_the_pulse_with_a_quick_flexion_the_detector_recognises() -> None:
    pulse = TactorCommand(seq=0, t_ns=0, amplitudes=[1.0] * 4, pulse=True)
    # A hand too narrow for the object, which never moves: the pre-shape did not happen.
    hand = ProsthesisState(seq=0, t_ns=0, wrist_angle_deg=0.0, aperture_mm=30.0)
    state, times, _, emg, events = run(
        start(), 6.0, lambda t_s: Percept(tactors=pulse, hand=hand, width_mm=50.0)
    )
    triggers = [t for t, e in events if e == "trigger"]
    assert triggers, events
    reach_end = fitts_time(math.dist(EXACT.start_offset_m, (-0.045, 0.0, 0.0)), 0.05, EXACT)
    # After the reach: the simple reaction time plus the step pause (with its jitter).
    assert triggers[0] - reach_end >= EXACT.simple_rt_s
    assert triggers[0] - reach_end <= EXACT.simple_rt_s + 3 * EXACT.step_pause_s.first
    profile = EmgProfile(rest=MUSCLES.rest, maximal=MUSCLES.maximal)
    fired = detect(emg, profile=profile)
    flexions = [times[i] for i, g in fired if g is Gesture.QUICK_FLEXION]
    assert flexions and flexions[0] == pytest.approx(triggers[0] + 0.45, abs=0.25)
    assert all(g is Gesture.QUICK_FLEXION for _, g in fired)
    # The hand never moved and looks wrong: after check_s the user tries again (the pulse is
    # still felt), so there are several triggers.
    assert state.triggers >= 2


def test_user_step_is_reproducible_from_the_seed() -> None:
    params = UserParams()
    a = run(start(params, seed=3), 2.0)
    b = run(start(params, seed=3), 2.0)
    c = run(start(params, seed=4), 2.0)
    np.testing.assert_array_equal(a[2], b[2])
    np.testing.assert_array_equal(a[3], b[3])
    assert not np.array_equal(a[2], c[2])


def test_practice_shrinks_the_aiming_scatter() -> None:
    """Visual aim endpoints of trial 1 scatter more than those of trial 50."""
    params = dataclasses.replace(UserParams(), individual_cv=0.0)

    def endpoints(trial: int) -> np.ndarray:
        ends = []
        for seed in range(40):
            state = start(params, feedback=False, trial=trial, seed=seed)
            ends.append(_reach_end(state))
        return np.array(ends)

    early, late = endpoints(1), endpoints(50)
    assert early[:, 0].std() > 1.3 * late[:, 0].std()
    assert early[:, 0].std() == pytest.approx(params.visual_aim_sd_m.first, rel=0.35)


def _reach_end(state) -> tuple[float, float, float]:
    state, _ = user_step(state, Percept(width_mm=50.0), START_NS)
    return state.move.end


def test_user_params_reject_bad_values() -> None:
    with pytest.raises(ValueError, match="notice_probability"):
        UserParams(notice_probability=1.5)
    with pytest.raises(ValueError, match="peak_speed_m_s"):
        UserParams(peak_speed_m_s=0.0)
    with pytest.raises(ValueError, match="Learned"):
        Learned(-1.0, 0.0)
