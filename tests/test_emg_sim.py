"""The simulated EMG user: envelope statistics, cross-talk, fatigue, and the scripted user
closing the loop with the controller and the simulated hand."""

from __future__ import annotations

import numpy as np
import pytest

from lpc_core.control.controller import ControllerCore, ControllerParams, State, controller_step
from lpc_core.control.controller import Tick as ControllerTick
from lpc_core.control.emg import EmgProfile
from lpc_core.devices.hand import HandCommand
from lpc_core.sim.emg_sim import (
    MuscleParams,
    MuscleState,
    Segment,
    Tick,
    UserState,
    script_drive,
    simulate_emg,
    user_step,
)
from lpc_core.sim.hand import HandState, hand_step
from schemas import AimCue, ControllerState, GraspTarget, ProsthesisCommand, ProsthesisState

PARAMS = MuscleParams()


def test_simulate_emg_is_reproducible_from_the_seed() -> None:
    drive = script_drive([Segment(0.5, 1.0, flexor=0.7)], 300)
    _, a = simulate_emg(MuscleState(), drive, PARAMS, seed=4, seq=0)
    _, b = simulate_emg(MuscleState(), drive, PARAMS, seed=4, seq=0)
    _, c = simulate_emg(MuscleState(), drive, PARAMS, seed=5, seq=0)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_simulate_emg_rest_level_and_noise() -> None:
    params = MuscleParams(artifact_rate_hz=0.0)
    _, rest = simulate_emg(MuscleState(), np.zeros((20_000, 2)), params, seed=1, seq=0)
    np.testing.assert_allclose(rest.mean(axis=0), params.rest, rtol=0.02)
    # relative SD of the envelope = noise (AR(1) with unit variance), within 5 %
    np.testing.assert_allclose(rest.std(axis=0) / rest.mean(axis=0), params.noise, rtol=0.05)
    assert (rest >= 0).all()


def test_simulate_emg_plateau_and_crosstalk() -> None:
    params = MuscleParams(fatigue_rate=0.0, artifact_rate_hz=0.0)
    drive = np.zeros((2_000, 2))
    drive[:, 0] = 0.5
    _, emg = simulate_emg(MuscleState(), drive, params, seed=2, seq=0)
    plateau = emg[100:].mean(axis=0)
    span = np.asarray(params.maximal) - np.asarray(params.rest)
    # flexor: half its range (quadrature with the rest level is negligible at this amplitude)
    assert plateau[0] == pytest.approx(0.5 * span[0], rel=0.03)
    # extensor: the cross-talk share of the flexor's activation, in quadrature with rest
    expected = np.hypot(params.rest[1], params.crosstalk * 0.5 * span[1])
    assert plateau[1] == pytest.approx(expected, rel=0.05)


def test_simulate_emg_fatigue_lowers_the_amplitude_then_recovers() -> None:
    params = MuscleParams(fatigue_rate=0.05, artifact_rate_hz=0.0, noise=0.0)
    drive = np.zeros((6_000, 2))
    drive[:3_000, 0] = 0.8
    state, emg = simulate_emg(MuscleState(), drive, params, seed=3, seq=0)
    assert emg[2_990, 0] < 0.85 * emg[100, 0]
    assert state.fatigue[0] < 0.5 * 0.05 * 0.8 * 30  # recovered from its peak during rest


def test_simulate_emg_stepwise_equals_one_call() -> None:
    drive = script_drive([Segment(0.1, 0.5, flexor=0.9), Segment(1.5, 0.3, extensor=0.6)], 250)
    state, whole = simulate_emg(MuscleState(), drive, PARAMS, seed=0, seq=40)
    stepped, parts = MuscleState(), []
    for i in range(len(drive)):
        stepped, out = simulate_emg(stepped, drive[i : i + 1], PARAMS, seed=0, seq=40 + i)
        parts.append(out)
    np.testing.assert_allclose(np.concatenate(parts), whole, rtol=1e-12)
    assert stepped == state


def test_simulate_emg_rejects_a_bad_drive() -> None:
    with pytest.raises(ValueError, match="drive"):
        simulate_emg(MuscleState(), np.zeros((10, 3)), PARAMS, seed=0, seq=0)
    with pytest.raises(ValueError, match="noise"):
        MuscleParams(noise=1.5)


# --------------------------------------------------------------------------- the whole loop


def run_session(seconds: float, seed: int = 0) -> tuple[list[ControllerState], list, HandState]:
    """Controller, scripted user, simulated hand and a stand-in for vision, 10 ms steps."""
    profile = EmgProfile(rest=PARAMS.rest, maximal=PARAMS.maximal)
    core = ControllerCore(params=ControllerParams(profile=profile))
    user = UserState(seed=seed)
    hand = HandState(aperture_mm=100.0, wrist_deg=-20.0, object_mm=55.0)
    command = HandCommand()
    published: list[ControllerState] = []
    hands: list[ProsthesisState] = []
    t = 1_000_000_000
    for k in range(round(seconds * 100)):
        t += 10_000_000
        inputs: list = []
        user, emg = user_step(user, Tick(t), t)
        inputs += emg
        hand, status = hand_step(hand, command, t)
        state_msg = ProsthesisState(
            seq=k,
            t_ns=t,
            wrist_angle_deg=status.wrist_angle_deg,
            aperture_mm=status.aperture_mm,
            grip_force_pct=status.grip_force_pct,
        )
        hands.append(state_msg)
        inputs.append(state_msg)
        if k % 3 == 0:  # vision at about 33 Hz: object in view from 1 s on
            in_view = k >= 100
            inputs.append(
                AimCue(seq=k, t_ns=t, frame_seq=k, state="on_target" if in_view else "nothing")
            )
            inputs.append(
                GraspTarget(
                    seq=k,
                    t_ns=t,
                    frame_seq=k,
                    shape="cylinder" if k >= 150 else "none",
                    grasp_width_mm=55.0 if k >= 150 else None,
                    wrist_angle_deg=30.0 if k >= 150 else None,
                    reconstructed=k >= 150,
                )
            )
        inputs.append(ControllerTick(t))
        for message in inputs:
            core, out = controller_step(core, message, t)
            for o in out:
                if isinstance(o, ProsthesisCommand):
                    command = HandCommand(grasp=o.grasp, wrist=o.wrist)
                elif isinstance(o, ControllerState):
                    published.append(o)
                    user, _ = user_step(user, o, t)
            if isinstance(message, ProsthesisState):
                user, _ = user_step(user, message, t)
    return published, hands, hand


def test_scripted_user_goes_through_the_whole_cycle() -> None:
    published, _, _ = run_session(20.0)
    path = [(s.previous, s.event, s.state) for s in published if s.previous != s.state]
    states = [p[2] for p in path]
    for expected in ("aiming", "ready", "preshaping", "direct", "idle"):
        assert expected in states, path
    # The order of the paper's cycle, once each at least.
    first = {s: states.index(s) for s in ("aiming", "ready", "preshaping", "direct")}
    assert first["aiming"] < first["ready"] < first["preshaping"] < first["direct"]
    events = [s.event for s in published if s.event]
    assert "at_target" in events
    assert events.count("switch_dof") >= 2  # to rotation and back
    assert "grasped" in events and "released" in events
    released = [p for p in path if p[1] == "released"]
    assert released and released[0] == ("direct", "released", "idle")
    assert all(s.state != State.STOPPED.value for s in published[3:])


def test_scripted_user_preshape_reaches_the_target_within_tolerance() -> None:
    published, hands, _ = run_session(8.0)
    at = next(s for s in published if s.event == "at_target")
    hand = next(h for h in hands if h.t_ns >= at.t_ns)
    # width 55 + slack 15 = 70 mm; wrist -20 (at the trigger) + 30 = 10 degrees
    assert abs(hand.aperture_mm - 70.0) <= 3.0
    assert abs(hand.wrist_angle_deg - 10.0) <= 5.0
