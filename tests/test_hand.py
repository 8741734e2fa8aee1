"""The simulated hand: first-order motors, limits, grip force on an object."""

from __future__ import annotations

import math

import pytest

from lpc_core.devices.hand import HandCommand, HandStatus
from lpc_core.sim.hand import HandParams, HandState, hand_step

MS = 1_000_000


def run(
    state: HandState, command: HandCommand, seconds: float, t0: int = 0, dt_ms: int = 10
) -> tuple[HandState, HandStatus, int]:
    t = t0
    status = None
    for _ in range(round(seconds * 1000 / dt_ms)):
        t += dt_ms * MS
        state, status = hand_step(state, command, t)
    assert status is not None
    return state, status, t


def test_hand_step_follows_first_order_dynamics() -> None:
    p = HandParams()
    state, _ = hand_step(HandState(aperture_mm=100.0), None, 0)
    state, _ = hand_step(state, HandCommand(grasp=1.0), round(p.tau_s * 1e9))
    # After one time constant the speed is 1 - 1/e of the commanded speed.
    assert state.grasp_speed == pytest.approx(p.max_grasp_mm_s * (1 - math.exp(-1)), rel=1e-9)


def test_hand_step_closes_and_opens_within_aperture_limits() -> None:
    state, status, t = run(HandState(aperture_mm=50.0), HandCommand(grasp=1.0), 1.0)
    assert status.aperture_mm == 0.0
    state, status, t = run(state, HandCommand(grasp=-1.0), 2.0, t)
    assert status.aperture_mm == 110.0
    assert not status.moving  # at the stop, the motor has stalled


def test_hand_step_stops_rotation_at_the_wrist_limits() -> None:
    state, status, t = run(HandState(), HandCommand(wrist=1.0), 2.0)
    assert status.wrist_angle_deg == 160.0
    _, status, _ = run(state, HandCommand(wrist=-1.0), 3.0, t)
    assert status.wrist_angle_deg == -160.0


def test_hand_step_half_command_moves_at_half_speed() -> None:
    _, status, _ = run(HandState(), HandCommand(wrist=0.5), 1.0)
    # 1 s at 90 °/s, less the time constant's lag (tau * speed).
    assert status.wrist_angle_deg == pytest.approx(90.0 - 0.05 * 90.0, abs=0.5)


def test_hand_step_grips_an_object_and_builds_force() -> None:
    state = HandState(aperture_mm=90.0, object_mm=60.0)
    state, status, t = run(state, HandCommand(grasp=0.5), 1.0)
    assert status.aperture_mm == 60.0
    assert status.grip_force_pct > 20.0
    held = status.grip_force_pct
    # Zero velocity holds the grip (the gearing is not back-drivable).
    state, status, t = run(state, HandCommand(), 0.5, t)
    assert status.grip_force_pct == pytest.approx(held)
    assert status.aperture_mm == 60.0
    # Opening relieves the force first, then the fingers leave the object.
    state, status, t = run(state, HandCommand(grasp=-1.0), 0.1, t)
    assert status.aperture_mm == 60.0 or status.grip_force_pct == 0.0
    state, status, t = run(state, HandCommand(grasp=-1.0), 0.5, t)
    assert status.grip_force_pct == 0.0 and status.aperture_mm > 80.0


def test_hand_step_ignores_an_object_wider_than_the_hand_was() -> None:
    state = HandState(aperture_mm=40.0, object_mm=60.0)
    _, status, _ = run(state, HandCommand(grasp=1.0), 1.0)
    assert status.aperture_mm == 0.0 and status.grip_force_pct == 0.0


def test_hand_step_rejects_time_going_back_and_bad_commands() -> None:
    state, _ = hand_step(HandState(), None, 10 * MS)
    with pytest.raises(ValueError, match="now_ns"):
        hand_step(state, None, 5 * MS)
    with pytest.raises(ValueError, match="grasp"):
        HandCommand(grasp=1.5)
    with pytest.raises(ValueError, match="wrist"):
        HandCommand(wrist=float("nan"))
    with pytest.raises(ValueError, match="aperture_min_mm"):
        HandParams(aperture_min_mm=120.0)


def test_hand_step_counter_rolls_over() -> None:
    state = HandState(counter=255)
    state, status = hand_step(state, None, 0)
    assert status.counter == 0
