"""The controller's state machine: the table, every guard, the servo, the watchdogs."""

from __future__ import annotations

import dataclasses

import pytest

from lpc_core.control.controller import (
    EMG,
    HAND,
    TARGET,
    TRANSITIONS,
    ControllerCore,
    ControllerParams,
    Event,
    State,
    Tick,
    TransitionError,
    apply_event,
    controller_step,
    transition,
)
from lpc_core.control.emg import EmgProfile
from lpc_core.devices.hand import HandCommand
from lpc_core.sim.hand import HandState, hand_step
from schemas import (
    AimCue,
    ControllerState,
    EmgSample,
    GraspTarget,
    ProsthesisCommand,
    ProsthesisState,
)

MS = 1_000_000
PROFILE = EmgProfile(rest=(0.0, 0.0), maximal=(1.0, 1.0))  # channels are normalised levels


# --------------------------------------------------------------------------- the table


ENTRIES = [(s, e, n) for s, row in TRANSITIONS.items() for e, n in row.items()]
MISSING = [(s, e) for s in State for e in Event if e not in TRANSITIONS[s]]


@pytest.mark.parametrize(("state", "event", "expected"), ENTRIES)
def test_transition_table_entry(state: State, event: Event, expected: State) -> None:
    assert transition(state, event) is expected


@pytest.mark.parametrize(("state", "event"), MISSING)
def test_transition_missing_entry_raises_naming_event_and_state(state: State, event: Event) -> None:
    with pytest.raises(TransitionError) as info:
        transition(state, event)
    assert repr(event.value) in str(info.value) and repr(state.value) in str(info.value)


def test_transition_table_covers_every_state_and_the_paper_cycle() -> None:
    assert set(TRANSITIONS) == set(State)
    cycle = [
        (State.IDLE, Event.OBJECT_SEEN, State.AIMING),
        (State.AIMING, Event.NEW_TARGET, State.READY),
        (State.READY, Event.AUTO_PRESHAPE, State.PRESHAPING),
        (State.PRESHAPING, Event.TAKE_OVER, State.DIRECT),
        (State.DIRECT, Event.RELEASED, State.IDLE),
    ]
    for state, event, expected in cycle:
        assert transition(state, event) is expected
    for state in State:  # a stale input stops the hand from anywhere
        assert transition(state, Event.STALE) is State.STOPPED


def test_apply_event_without_entry_leaves_the_state_as_it_was() -> None:
    core = ControllerCore(mode=State.IDLE)
    out: list = []
    with pytest.raises(TransitionError, match="'at_target' has no transition from state 'idle'"):
        apply_event(core, Event.AT_TARGET, 0, "test", out)
    assert core.mode is State.IDLE and out == []


# --------------------------------------------------------------------------- a test rig


class Rig:
    """The controller in a closed loop with the simulated hand, time in 10 ms steps."""

    def __init__(self, params: ControllerParams | None = None, **hand: float) -> None:
        self.core = ControllerCore(params=params or ControllerParams(profile=PROFILE))
        self.hand = HandState(**hand)
        self.command = HandCommand()
        self.t = 1_000 * MS
        self.seq = 0
        self.out: list = []
        self.hand_on = True
        self.emg_on = True
        self.vision: dict | None = None  # the target vision keeps publishing, every 30 ms

    def feed(self, message: object) -> list:
        self.core, out = controller_step(self.core, message, self.t)
        self.out += out
        for o in out:
            if isinstance(o, ProsthesisCommand):
                self.command = HandCommand(grasp=o.grasp, wrist=o.wrist)
        return out

    def step(self, flexor: float = 0.0, extensor: float = 0.0) -> None:
        self.t += 10 * MS
        self.seq += 1
        if self.emg_on:
            self.feed(EmgSample(seq=self.seq, t_ns=self.t, channels=[flexor, extensor]))
        if self.hand_on:
            self.hand, status = hand_step(self.hand, self.command, self.t)
            self.feed(
                ProsthesisState(
                    seq=self.seq,
                    t_ns=self.t,
                    wrist_angle_deg=status.wrist_angle_deg,
                    aperture_mm=status.aperture_mm,
                    grip_force_pct=status.grip_force_pct,
                )
            )
        if self.vision is not None and self.seq % 3 == 0:
            self._publish_target(**self.vision)
        self.feed(Tick(self.t))

    def run(self, seconds: float, flexor: float = 0.0, extensor: float = 0.0) -> None:
        for _ in range(round(seconds * 100)):
            self.step(flexor, extensor)

    def gesture(self, flexor: float, extensor: float) -> None:
        self.run(0.15, flexor, extensor)
        self.run(0.45)  # release: the gesture fires here; then the lock-out passes

    def quick_flexion(self) -> None:
        self.gesture(0.9, 0.0)

    def quick_extension(self) -> None:
        self.gesture(0.0, 0.9)

    def co_contraction(self) -> None:
        self.gesture(0.8, 0.8)

    def target(
        self,
        width: float | None = 60.0,
        angle: float | None = 20.0,
        ok: bool = True,
        grip: str = "power",
    ):
        """Vision now reports this target (once at once, then every 30 ms)."""
        self.vision = {"width": width, "angle": angle, "ok": ok, "grip": grip}
        return self._publish_target(width, angle, ok, grip)

    def _publish_target(
        self, width: float | None, angle: float | None, ok: bool, grip: str = "power"
    ) -> list:
        self.seq += 1
        return self.feed(
            GraspTarget(
                seq=self.seq,
                t_ns=self.t,
                frame_seq=self.seq,
                shape="cylinder" if ok else "none",
                grasp_width_mm=width if ok else None,
                wrist_angle_deg=angle if ok else None,
                reconstructed=ok,
                frames=10,
                grip=grip,  # type: ignore[arg-type]
            )
        )

    def cue(self, state: str = "guiding") -> list:
        self.seq += 1
        return self.feed(AimCue(seq=self.seq, t_ns=self.t, frame_seq=self.seq, state=state))

    @property
    def mode(self) -> State:
        return self.core.mode

    def states(self) -> list[ControllerState]:
        return [o for o in self.out if isinstance(o, ControllerState)]

    def events(self) -> list[ControllerState]:
        """The published states that carry an event (not the heartbeats)."""
        return [s for s in self.states() if s.event]

    def transitions(self) -> list[tuple[str, str, str]]:
        return [(s.previous, s.event, s.state) for s in self.states() if s.previous != s.state]

    def commands(self) -> list[ProsthesisCommand]:
        return [o for o in self.out if isinstance(o, ProsthesisCommand)]


def ready_rig(**hand: float) -> Rig:
    rig = Rig(**hand)
    rig.run(0.05)
    rig.cue()
    rig.target()
    assert rig.mode is State.READY
    return rig


# --------------------------------------------------------------------------- guards


def test_controller_starts_stopped_until_emg_and_hand_are_fresh() -> None:
    rig = Rig()
    assert rig.mode is State.STOPPED
    rig.feed(Tick(rig.t))
    assert rig.mode is State.STOPPED and "never received" in rig.core.reason
    rig.step()
    assert rig.mode is State.IDLE
    assert rig.transitions()[-1] == ("stopped", "recovered", "idle")


def test_controller_idle_to_aiming_on_aim_cue_and_back_after_300_ms() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.cue("nothing")
    assert rig.mode is State.IDLE
    rig.cue("guiding")
    assert rig.mode is State.AIMING
    rig.cue("nothing")
    rig.run(0.2)
    rig.cue("nothing")
    assert rig.mode is State.AIMING  # 200 ms without an object: still aiming
    rig.run(0.15)
    rig.cue("nothing")
    assert rig.mode is State.IDLE


def test_controller_aiming_to_ready_only_on_a_reconstructed_target() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.cue()
    rig.target(ok=False)
    assert rig.mode is State.AIMING
    rig.target(width=None, ok=True)  # reconstructed but no grasp width: not usable
    assert rig.mode is State.AIMING
    rig.target()
    assert rig.mode is State.READY
    assert rig.events()[-1].target_width_mm == 60.0


def test_controller_quick_flexion_ignored_while_aiming() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.cue()
    rig.quick_flexion()
    assert rig.mode is State.AIMING
    last = rig.events()[-1]
    assert last.event == "auto_preshape" and "ignored while aiming" in last.reason


def test_controller_ready_to_preshaping_on_quick_flexion() -> None:
    rig = ready_rig()
    rig.quick_flexion()
    assert rig.mode is State.PRESHAPING
    sp = rig.core.setpoint
    assert sp is not None and sp.aperture_mm == 60.0 + 15.0  # width + slack
    assert sp.wrist_deg == pytest.approx(20.0, abs=1e-6)


def test_controller_preshapes_in_the_targets_grip_and_keeps_it_in_direct_control() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.cue()
    rig.target(width=40.0, grip="tripod")
    assert rig.mode is State.READY and rig.states()[-1].grip == "tripod"
    assert "tripod grip" in rig.states()[-1].reason
    assert rig.commands()[-1].grip == "power"  # not pre-shaped yet: the hand keeps its grip
    rig.quick_flexion()
    assert rig.mode is State.PRESHAPING and rig.core.grip == "tripod"
    entered = [s for s in rig.states() if s.state == "preshaping" and s.previous == "ready"]
    assert entered and entered[0].grip == "tripod"
    assert rig.commands()[-1].grip == "tripod"
    rig.quick_extension()
    assert rig.mode is State.DIRECT and rig.commands()[-1].grip == "tripod"


def test_controller_ready_to_aiming_after_the_target_is_lost_for_300_ms() -> None:
    rig = ready_rig()
    rig.target(ok=False)
    rig.run(0.2)
    rig.target(ok=False)
    assert rig.mode is State.READY  # a 200 ms gap in the reconstructions is not a loss
    rig.run(0.15)
    rig.target(ok=False)
    assert rig.mode is State.AIMING


def test_controller_ready_new_target_only_when_width_changes_beyond_tolerance() -> None:
    rig = ready_rig()
    n = len(rig.states())
    rig.target(width=70.0)  # 10 mm: the same object, the median moved
    assert len(rig.states()) == n
    rig.target(width=90.0)  # 30 mm: another object
    assert rig.events()[-1].event == "new_target" and rig.mode is State.READY


def test_controller_preshape_servos_to_the_target_and_reports_it() -> None:
    rig = ready_rig(aperture_mm=100.0, wrist_deg=-30.0)
    rig.quick_flexion()
    rig.run(2.0)
    at = [s for s in rig.events() if s.event == "at_target"]
    assert len(at) == 1 and at[0].state == "preshaping"
    p = rig.core.params
    assert abs(rig.hand.aperture_mm - 75.0) <= p.aperture_tol_mm
    # camera on the hand: the target is the wrist at the trigger plus the axis angle
    assert abs(rig.hand.wrist_deg - (-30.0 + 20.0)) <= p.wrist_tol_deg
    # at rest within tolerance: the last commands are zero
    assert rig.commands()[-1].grasp == 0.0 and rig.commands()[-1].wrist == 0.0


def test_controller_preshape_keeps_its_shape_when_the_target_is_lost() -> None:
    rig = ready_rig()
    rig.quick_flexion()
    rig.target(ok=False)
    rig.run(0.4)
    rig.target(ok=False)
    assert rig.mode is State.PRESHAPING  # approaching: the object left the capture volume
    assert rig.core.setpoint is not None


def test_controller_preshaping_to_ready_when_the_user_re_aims() -> None:
    rig = ready_rig()
    rig.quick_flexion()
    rig.target(width=65.0)  # same object, still in view: stays
    assert rig.mode is State.PRESHAPING
    rig.target(width=95.0)  # aimed at another object
    assert rig.mode is State.READY
    rig.quick_flexion()
    rig.target(ok=False)
    rig.run(0.35)
    rig.target(ok=False)
    rig.target(width=60.0)  # reconstructed again after a loss: re-aimed
    assert rig.mode is State.READY


def test_controller_take_over_from_idle_ready_and_preshaping() -> None:
    for setup in ("idle", "ready", "preshaping"):
        rig = Rig() if setup == "idle" else ready_rig()
        rig.run(0.05)
        if setup == "preshaping":
            rig.quick_flexion()
        rig.quick_extension()
        assert rig.mode is State.DIRECT, setup
        assert rig.core.dof == "grasp"


def test_controller_direct_is_proportional_and_co_contraction_switches_dof() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.quick_extension()
    rig.run(0.5, flexor=0.5)
    closing = rig.commands()[-1]
    assert closing.grasp > 0.3 and closing.wrist == 0.0
    rig.run(0.5)
    rig.run(0.5, extensor=0.3)
    assert rig.commands()[-1].grasp < 0 and rig.commands()[-1].grasp > -closing.grasp
    rig.run(0.3)
    rig.co_contraction()
    assert rig.core.dof == "wrist" and rig.mode is State.DIRECT
    assert rig.events()[-1].event == "switch_dof" and rig.events()[-1].dof == "wrist"
    rig.run(0.5, flexor=0.5)
    assert rig.commands()[-1].wrist > 0.3 and rig.commands()[-1].grasp == 0.0
    rig.run(0.3)
    rig.co_contraction()
    assert rig.core.dof == "grasp"


def test_controller_co_contraction_commands_no_motion_while_held() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.quick_extension()
    rig.run(0.2, flexor=0.8, extensor=0.8)
    assert rig.commands()[-1].grasp == 0.0


def test_controller_direct_grasp_then_release_returns_to_idle() -> None:
    rig = Rig(aperture_mm=90.0, object_mm=60.0)
    rig.run(0.05)
    rig.quick_extension()
    rig.run(1.0, flexor=0.6)
    assert rig.events()[-1].event == "grasped" and rig.mode is State.DIRECT
    rig.run(1.0)  # holding: nothing changes
    assert rig.mode is State.DIRECT and rig.hand.grip_force_pct > 10
    rig.run(0.5, extensor=0.6)
    assert rig.mode is State.IDLE
    assert rig.transitions()[-1] == ("direct", "released", "idle")


def test_controller_direct_without_activity_returns_to_idle() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.quick_extension()
    rig.run(7.5)
    assert rig.mode is State.DIRECT
    rig.run(1.0)
    assert rig.mode is State.IDLE and rig.events()[-1].event == "inactive"


# --------------------------------------------------------------------------- watchdogs


def test_controller_stale_emg_stops_the_hand_and_recovers() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.quick_extension()
    rig.run(0.3, flexor=0.6)
    assert rig.commands()[-1].grasp > 0
    rig.emg_on = False
    rig.run(0.24)
    assert rig.mode is State.DIRECT  # 240 ms without EMG: within the 250 ms threshold
    assert rig.commands()[-1].grasp == 0.0  # but no longer moving (velocity hold, 30 ms)
    rig.run(0.03)
    assert rig.mode is State.STOPPED
    assert EMG in rig.events()[-1].reason
    assert rig.commands()[-1].grasp == 0.0 and rig.commands()[-1].wrist == 0.0
    rig.emg_on = True
    rig.step()
    assert rig.mode is State.IDLE


def test_controller_direct_velocity_drops_at_once_when_emg_pauses() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.quick_extension()
    rig.run(0.3, flexor=0.6)
    assert rig.commands()[-1].grasp > 0
    rig.emg_on = False
    rig.run(0.03)
    assert rig.commands()[-1].grasp > 0  # 30 ms: within the hold
    rig.run(0.01)
    assert rig.mode is State.DIRECT and rig.commands()[-1].grasp == 0.0  # stopped, not stale


def test_controller_preshape_holds_still_on_an_old_hand_position() -> None:
    rig = ready_rig(aperture_mm=110.0)
    rig.target(width=5.0)  # a thin object: a long way to close, 110 -> 20 mm
    rig.quick_flexion()
    assert rig.hand.aperture_mm > 30.0 and rig.commands()[-1].grasp > 0  # still closing
    rig.hand_on = False
    rig.run(0.04)
    assert rig.mode is State.PRESHAPING  # not stale yet (200 ms)
    assert rig.commands()[-1].grasp == 0.0  # but no servo on a 40 ms old position
    rig.hand_on = True
    rig.run(0.05)
    assert rig.commands()[-1].grasp > 0  # fresh again: on its way


def test_controller_stale_hand_commands_zero_on_every_tick() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.hand_on = False
    rig.run(0.3)
    assert rig.mode is State.STOPPED and HAND in rig.core.stale
    n = len(rig.commands())
    rig.run(0.1)
    assert len(rig.commands()) - n == 10  # 100 Hz of zero commands from the timer
    assert all(c.grasp == 0.0 and c.wrist == 0.0 for c in rig.commands()[n:])


def test_controller_stale_target_stops_only_where_vision_matters() -> None:
    rig = ready_rig()
    rig.vision = None  # the reconstructor dies
    rig.run(0.9)
    assert rig.mode is State.READY
    rig.run(0.2)  # over 1 s without any grasp target message
    assert rig.mode is State.STOPPED and TARGET in rig.core.stale
    rig.run(0.5)
    assert rig.mode is State.STOPPED  # stays stopped until vision is back
    rig.target()  # vision is back: recovered, and the target makes the controller ready
    assert rig.mode is State.READY
    assert rig.transitions()[-2:] == [
        ("stopped", "recovered", "idle"),
        ("idle", "new_target", "ready"),
    ]
    # In direct control the user drives without vision: no stop.
    rig.quick_extension()
    rig.vision = None
    rig.run(2.0, flexor=0.3)
    assert rig.mode is State.DIRECT


def test_controller_gestures_are_ignored_while_stopped() -> None:
    rig = Rig()
    rig.run(0.05)
    rig.hand_on = False
    rig.run(0.3)
    assert rig.mode is State.STOPPED
    rig.quick_extension()
    assert rig.mode is State.STOPPED
    last = rig.events()[-1]
    assert last.event == "take_over" and "ignored while stopped" in last.reason
    assert all(c.grasp == 0.0 and c.wrist == 0.0 for c in rig.commands()[-30:])


def test_controller_per_topic_thresholds_come_from_the_params() -> None:
    params = ControllerParams(profile=PROFILE, stale_ms={EMG: 500.0, HAND: 100.0})
    rig = Rig(params)
    rig.run(0.05)
    rig.emg_on = False
    rig.run(0.45)
    assert rig.mode is State.IDLE  # past the default 250 ms, within this profile's 500 ms
    rig.run(0.1)
    assert rig.mode is State.STOPPED
    with pytest.raises(ValueError, match="stale_ms"):
        ControllerParams(stale_ms={"lpc/bogus": 1.0})


# --------------------------------------------------------------------------- outputs


def test_controller_publishes_every_transition_with_its_reason() -> None:
    rig = ready_rig()
    rig.quick_flexion()
    rig.quick_extension()
    expected = [
        ("stopped", "recovered", "idle"),
        ("idle", "object_seen", "aiming"),
        ("aiming", "new_target", "ready"),
        ("ready", "auto_preshape", "preshaping"),
        ("preshaping", "take_over", "direct"),
    ]
    assert rig.transitions() == expected
    assert all(s.reason for s in rig.states())


def test_controller_heartbeat_at_10_hz_and_one_command_per_hand_state() -> None:
    rig = Rig()
    rig.run(0.05)
    n_states, n_commands = len(rig.states()), len(rig.commands())
    rig.run(1.0)
    assert len(rig.states()) - n_states == 10
    assert len(rig.commands()) - n_commands == 100


def test_controller_timer_fills_in_commands_for_late_hand_status() -> None:
    rig = Rig()
    rig.run(0.05)
    n = len(rig.commands())
    for k in range(60):  # the hand's status arrives only every third step (30 ms apart)
        rig.hand_on = k % 3 == 0
        rig.step()
    assert len(rig.commands()) - n == 60  # still one command per 10 ms


def test_controller_wrist_target_takes_the_nearest_equivalent_axis() -> None:
    rig = ready_rig(wrist_deg=150.0)
    rig.target(width=60.0, angle=80.0)  # 150 + 80 = 230 is out of range; 50 is the same axis
    rig.quick_flexion()
    sp = rig.core.setpoint
    assert sp is not None and sp.wrist_deg == pytest.approx(50.0, abs=1.0)


def test_controller_sphere_keeps_the_wrist() -> None:
    rig = ready_rig(wrist_deg=12.0)
    rig.target(width=60.0, angle=None)
    rig.quick_flexion()
    rig.run(1.5)
    assert rig.core.setpoint is not None and rig.core.setpoint.wrist_deg is None
    assert rig.hand.wrist_deg == pytest.approx(12.0, abs=0.5)


def test_controller_rejects_unknown_messages() -> None:
    with pytest.raises(ValueError, match="message"):
        controller_step(ControllerCore(), "hello", 0)  # type: ignore[arg-type]


def test_controller_step_is_deterministic() -> None:
    def session() -> list:
        rig = ready_rig(aperture_mm=100.0)
        rig.quick_flexion()
        rig.run(1.0)
        rig.quick_extension()
        rig.run(0.5, flexor=0.5)
        return rig.out

    assert session() == session()


def test_controller_core_is_immutable() -> None:
    core = ControllerCore()
    with pytest.raises(dataclasses.FrozenInstanceError):
        core.mode = State.IDLE  # type: ignore[misc]
