"""The semi-autonomous controller. Everything that changes the controller's state lives here.

The states follow the paper's "System Operation": the hand waits **idle**; when an object is in
front of the camera the user is **aiming** (the tactors guide); when the object is reconstructed
the controller is **ready** (all tactors pulse); a quick wrist flexion starts **preshaping**
(wrist angle and aperture servoed to the grasp target); a quick extension hands over to
**direct** proportional control, where a co-contraction switches between open/close and
rotation; releasing the object returns to idle. The user can re-aim at any time. **stopped**
is the safe state: a stale input stops the hand.

The transitions are data: ``TRANSITIONS[state][event] -> state`` (h11's style). An event with
no entry raises ``TransitionError`` naming the event and the state; the caller keeps the state
it had. Events are derived from messages by guards (``_events_*``), which never produce an
event the table does not expect in the current state; the table also lists the events a state
accepts and ignores (a self-transition).

``controller_step(state, message, now_ns) -> (state, outputs)`` is pure. Outputs are
``ControllerState`` messages (every transition, with its reason, and a 10 Hz heartbeat) and one
``ProsthesisCommand`` per ``ProsthesisState`` received (the hand's 100 Hz clock), and one on a
``Tick`` (the 100 Hz timer) when no status came since the previous tick: a late or dropped
status does not thin the command stream, and a stale hand is commanded zero velocity.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from lpc_core.control.emg import EmgProfile, Gesture, IntentState, intent_step
from lpc_core.control.state import evolve
from schemas import (
    AimCue,
    ControllerState,
    EmgSample,
    GraspTarget,
    ProsthesisCommand,
    ProsthesisState,
)


class State(enum.Enum):
    IDLE = "idle"
    AIMING = "aiming"
    READY = "ready"
    PRESHAPING = "preshaping"
    DIRECT = "direct"
    STOPPED = "stopped"


class Event(enum.Enum):
    OBJECT_SEEN = "object_seen"  # the aim cue finds an object: tactors guide
    OBJECT_LOST = "object_lost"  # no object in the capture volume for a while
    NEW_TARGET = "new_target"  # a reconstructed grasp target (first, after a loss, or changed)
    TARGET_LOST = "target_lost"  # no reconstruction for a while
    AUTO_PRESHAPE = "auto_preshape"  # quick flexion
    TAKE_OVER = "take_over"  # quick extension
    SWITCH_DOF = "switch_dof"  # co-contraction
    AT_TARGET = "at_target"  # the pre-shape reached the target within tolerance
    GRASPED = "grasped"  # grip force established in direct control
    RELEASED = "released"  # the object was let go
    INACTIVE = "inactive"  # direct control, nothing held, no EMG activity for a while
    STALE = "stale"  # an input topic went stale
    RECOVERED = "recovered"  # every input is fresh again


S, E = State, Event
_IGNORED_BY_USER_STATES = (E.OBJECT_SEEN, E.OBJECT_LOST, E.NEW_TARGET, E.TARGET_LOST)

TRANSITIONS: Mapping[State, Mapping[Event, State]] = MappingProxyType(
    {
        S.IDLE: {
            E.OBJECT_SEEN: S.AIMING,
            E.NEW_TARGET: S.READY,
            E.AUTO_PRESHAPE: S.IDLE,  # nothing reconstructed: ignored
            E.TAKE_OVER: S.DIRECT,
            E.SWITCH_DOF: S.IDLE,
            E.STALE: S.STOPPED,
        },
        S.AIMING: {
            E.OBJECT_SEEN: S.AIMING,
            E.OBJECT_LOST: S.IDLE,
            E.NEW_TARGET: S.READY,
            E.TARGET_LOST: S.AIMING,
            E.AUTO_PRESHAPE: S.AIMING,  # not reconstructed yet: ignored
            E.TAKE_OVER: S.DIRECT,
            E.SWITCH_DOF: S.AIMING,
            E.STALE: S.STOPPED,
        },
        S.READY: {
            E.NEW_TARGET: S.READY,  # re-aimed: the target changed
            E.TARGET_LOST: S.AIMING,
            E.AUTO_PRESHAPE: S.PRESHAPING,
            E.TAKE_OVER: S.DIRECT,
            E.SWITCH_DOF: S.READY,
            E.STALE: S.STOPPED,
        },
        S.PRESHAPING: {
            E.NEW_TARGET: S.READY,  # re-aimed at the same or another object
            E.TARGET_LOST: S.PRESHAPING,  # approaching: the object leaves the capture volume
            E.AUTO_PRESHAPE: S.PRESHAPING,
            E.TAKE_OVER: S.DIRECT,
            E.SWITCH_DOF: S.PRESHAPING,
            E.AT_TARGET: S.PRESHAPING,
            E.STALE: S.STOPPED,
        },
        S.DIRECT: {
            **dict.fromkeys(_IGNORED_BY_USER_STATES, S.DIRECT),  # the user is in control
            E.AUTO_PRESHAPE: S.DIRECT,
            E.TAKE_OVER: S.DIRECT,
            E.SWITCH_DOF: S.DIRECT,
            E.GRASPED: S.DIRECT,
            E.RELEASED: S.IDLE,
            E.INACTIVE: S.IDLE,
            E.STALE: S.STOPPED,
        },
        S.STOPPED: {
            E.AUTO_PRESHAPE: S.STOPPED,
            E.TAKE_OVER: S.STOPPED,
            E.SWITCH_DOF: S.STOPPED,
            E.STALE: S.STOPPED,
            E.RECOVERED: S.IDLE,
        },
    }
)

# Events published even when the state does not change: the user acted, or something the
# record should show happened.
_NOTABLE = frozenset({E.AUTO_PRESHAPE, E.TAKE_OVER, E.SWITCH_DOF, E.AT_TARGET, E.GRASPED})
_GESTURE_EVENTS = {
    Gesture.QUICK_FLEXION: E.AUTO_PRESHAPE,
    Gesture.QUICK_EXTENSION: E.TAKE_OVER,
    Gesture.CO_CONTRACTION: E.SWITCH_DOF,
}
_CUE_ON = frozenset({"guiding", "on_target", "ready"})

EMG, HAND, TARGET = "lpc/emg", "lpc/prosthesis/state", "lpc/grasp/target"
_WATCHED, _WATCHED_WITH_TARGET = (EMG, HAND), (EMG, HAND, TARGET)
_VISION_STATES = (S.AIMING, S.READY, S.PRESHAPING)  # the states that rely on the grasp target


class TransitionError(RuntimeError):
    """An event the table has no entry for in the current state."""

    def __init__(self, event: Event, state: State) -> None:
        super().__init__(f"event {event.value!r} has no transition from state {state.value!r}")
        self.event = event
        self.state = state


def transition(state: State, event: Event) -> State:
    """The table lookup; raises ``TransitionError`` when the event is not expected."""
    try:
        return TRANSITIONS[state][event]
    except KeyError:
        raise TransitionError(event, state) from None


@dataclass(frozen=True)
class Tick:
    """Time passes with no message (the service's 100 Hz timer): staleness and heartbeat."""

    t_ns: int


@dataclass(frozen=True)
class ControllerParams:
    """Tolerances, gains and time limits. Lengths in mm, angles in degrees, times in ms."""

    profile: EmgProfile = field(default_factory=EmgProfile)
    # Per-topic staleness thresholds. The grasp target stops the hand only in the states that
    # act on it (aiming, ready, preshaping): in direct control the user drives without vision.
    # EMG and hand status: motion already holds still when the newest sample is older than
    # ``velocity_hold_ms`` (direct control needs fresh EMG, the pre-shape servo a fresh
    # position); the state machine stops only after a longer silence, so that a hiccup of a
    # loaded machine does not throw the user out of direct control or a pre-shape.
    stale_ms: Mapping[str, float] = field(
        default_factory=lambda: MappingProxyType({EMG: 250.0, HAND: 200.0, TARGET: 1000.0})
    )
    # Pre-shape: open wider than the object by the slack, stop within the tolerances.
    slack_mm: float = 15.0
    aperture_tol_mm: float = 3.0
    wrist_tol_deg: float = 5.0
    aperture_gain_per_mm: float = 1.0 / 25.0
    wrist_gain_per_deg: float = 1.0 / 30.0
    min_speed: float = 0.08
    settle_fraction: float = 0.3
    aperture_range_mm: tuple[float, float] = (0.0, 110.0)
    wrist_range_deg: tuple[float, float] = (-160.0, 160.0)
    wrist_offset_deg: float = 0.0  # hand rotation that aligns the grasp with axis angle 0
    camera_on_hand: bool = True  # target angles are relative to the wrist when triggered
    # Re-aim: a reconstruction after a loss, or a grasp width this different, is a new target.
    reaim_width_mm: float = 15.0
    target_lost_ms: float = 300.0
    object_lost_ms: float = 300.0
    # Direct control: grasp and release from the grip force; give up after inactivity.
    grip_on_pct: float = 10.0
    grip_off_pct: float = 3.0
    release_open_mm: float = 10.0
    direct_idle_s: float = 8.0
    # Motion needs fresh inputs: direct control's velocity drops to zero when the newest EMG
    # sample is older than this, the pre-shape servo when the newest hand status is, well
    # before either topic counts as stale (and stops the state machine).
    velocity_hold_ms: float = 30.0
    heartbeat_ms: float = 100.0

    def __post_init__(self) -> None:
        unknown = set(self.stale_ms) - {EMG, HAND, TARGET}
        if unknown:
            raise ValueError(f"stale_ms: unknown topic(s) {sorted(unknown)}")
        for topic, ms in self.stale_ms.items():
            if not ms > 0:
                raise ValueError(f"stale_ms[{topic!r}] must be positive, got {ms}")
        for name in ("slack_mm", "aperture_tol_mm", "wrist_tol_deg", "heartbeat_ms"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0")
        if not 0 < self.settle_fraction <= 1:
            raise ValueError(f"settle_fraction must be in (0, 1], got {self.settle_fraction}")
        if not self.grip_off_pct < self.grip_on_pct:
            raise ValueError("grip_off_pct must be below grip_on_pct")


@dataclass(frozen=True)
class Setpoint:
    """Where pre-shaping drives the hand."""

    aperture_mm: float
    wrist_deg: float | None  # None: keep the wrist where it is (a sphere has no axis)
    width_mm: float
    shape: str
    grip: str = "power"


@dataclass(frozen=True)
class ControllerCore:
    """The controller's whole state."""

    params: ControllerParams = field(default_factory=ControllerParams)
    mode: State = State.STOPPED
    previous: State | None = None
    event: str = "start"
    reason: str = "waiting for inputs"
    dof: str = "grasp"
    intent: IntentState | None = None
    velocity: float = 0.0  # direct-control drive from the EMG, flexor positive
    seen_ns: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    stale: tuple[str, ...] = ()
    hand: ProsthesisState | None = None
    target: GraspTarget | None = None  # the newest reconstructed target
    target_present: bool = False
    target_missing_since: int | None = None
    cue_on: bool = False
    cue_off_since: int | None = None
    setpoint: Setpoint | None = None
    at_target: bool = False
    # Per axis (aperture, wrist): at rest near the set-point; it moves again only when the
    # error leaves the tolerance.
    holding: tuple[bool, bool] = (False, False)
    grasped: bool = False
    contact_mm: float | None = None
    active_ns: int = 0  # last EMG activity
    state_seq: int = 0
    command_seq: int = 0
    commanded_since_tick: bool = False
    published_ns: int | None = None
    vision_since_ns: int | None = None  # when the controller began relying on the grasp target
    grip: str = "power"  # the hand's grip: the last pre-shape's, kept through direct control

    def __post_init__(self) -> None:
        if self.intent is None:
            object.__setattr__(self, "intent", IntentState(profile=self.params.profile))


Output = ControllerState | ProsthesisCommand
Message = EmgSample | GraspTarget | AimCue | ProsthesisState | Tick


def controller_step(
    core: ControllerCore, message: Message, now_ns: int
) -> tuple[ControllerCore, list[Output]]:
    """One message in; the new state and what to publish. Raises ``TransitionError`` (state
    unchanged, since the caller keeps ``core``) or ``ValueError`` for a bad message."""
    out: list[Output] = []
    topic = _topic_of(message)
    if topic is not None:
        seen = dict(core.seen_ns)
        seen[topic] = now_ns
        core = evolve(core, seen_ns=MappingProxyType(seen))
    core = _check_staleness(core, now_ns, out)

    match message:
        case EmgSample():
            core = _on_emg(core, message, now_ns, out)
        case GraspTarget():
            core = _on_target(core, message, now_ns, out)
        case AimCue():
            core = _on_cue(core, message, now_ns, out)
        case ProsthesisState():
            core = _on_hand(core, message, now_ns, out)
            core = _command(core, now_ns, out)
        case Tick():
            # The hand's status paces the commands; when a status is late or was dropped (a
            # slow moment of this process), or the hand is silent, the timer keeps the
            # command stream at 100 Hz (zero velocity while the hand is stale).
            commanded = any(isinstance(o, ProsthesisCommand) for o in out)
            hand_gone = HAND in core.stale or HAND not in core.seen_ns
            if not commanded and (hand_gone or not core.commanded_since_tick):
                core = _command(core, now_ns, out, since_tick=False)
            elif core.commanded_since_tick:
                core = evolve(core, commanded_since_tick=False)
        case _:
            raise ValueError(f"message: the controller does not take {type(message).__name__}")

    if core.published_ns is None or now_ns - core.published_ns >= core.params.heartbeat_ms * 1e6:
        core = _publish(core, now_ns, out, heartbeat=True)
    return core, out


# --------------------------------------------------------------------------- events


def apply_event(
    core: ControllerCore, event: Event, now_ns: int, reason: str, out: list[Output]
) -> ControllerCore:
    """Take one event through the table, run the entry actions, publish if it matters."""
    new = transition(core.mode, event)
    old = core.mode
    core = evolve(core, previous=old, mode=new, event=event.value, reason=reason)
    if new is not old:
        if new in _VISION_STATES and old not in _VISION_STATES:
            core = evolve(core, vision_since_ns=now_ns)
        elif new not in _VISION_STATES and new is not S.STOPPED:
            core = evolve(core, vision_since_ns=None)
        core = _enter(core, new, now_ns, out)
    if event is E.SWITCH_DOF and new is S.DIRECT:
        core = evolve(core, dof="wrist" if core.dof == "grasp" else "grasp")
    if new is not old or event in _NOTABLE:
        core = _publish(core, now_ns, out)
    return core


def _enter(core: ControllerCore, state: State, now_ns: int, out: list[Output]) -> ControllerCore:
    """Entry actions of a state."""
    if state is S.PRESHAPING:
        setpoint = _setpoint(core)
        grip = setpoint.grip if setpoint is not None else core.grip
        return evolve(core, setpoint=setpoint, at_target=False, holding=(False, False), grip=grip)
    if state is S.DIRECT:
        return evolve(core, dof="grasp", grasped=False, contact_mm=None, active_ns=now_ns)
    if state is S.STOPPED:
        core = evolve(core, setpoint=None)
        return _command(core, now_ns, out)  # zero velocity at once, not at the next sample
    if state in (S.IDLE, S.AIMING):
        return evolve(core, setpoint=None, grasped=False)
    return core


def _check_staleness(core: ControllerCore, now_ns: int, out: list[Output]) -> ControllerCore:
    mode = core.mode
    watched = (
        _WATCHED_WITH_TARGET
        if mode in _VISION_STATES or (mode is S.STOPPED and TARGET in core.stale)
        else _WATCHED
    )
    stale: list[str] = []
    details: list[str] = []
    limits, seen_ns = core.params.stale_ms, core.seen_ns
    for topic in watched:
        limit = limits.get(topic)
        if limit is None:
            continue
        seen = seen_ns.get(topic)
        if topic == TARGET and core.vision_since_ns is not None:
            # Vision gets its threshold's grace from the moment the controller relies on it.
            seen = max(seen if seen is not None else 0, core.vision_since_ns)
        if seen is None:
            stale.append(topic)
            details.append(f"{topic} never received")
        elif now_ns - seen > limit * 1e6:
            stale.append(topic)
            details.append(f"{topic} silent for {(now_ns - seen) / 1e6:.0f} ms > {limit:.0f} ms")
    if stale:
        if core.mode is not S.STOPPED or tuple(stale) != core.stale:
            core = evolve(core, stale=tuple(stale))
            return apply_event(core, E.STALE, now_ns, "stale input: " + "; ".join(details), out)
        return core
    if core.mode is S.STOPPED:
        core = evolve(core, stale=())
        return apply_event(core, E.RECOVERED, now_ns, "all inputs fresh", out)
    return core


def _on_emg(
    core: ControllerCore, sample: EmgSample, now_ns: int, out: list[Output]
) -> ControllerCore:
    assert core.intent is not None
    intent_state, intent = intent_step(core.intent, sample.channels, sample.t_ns)
    core = evolve(
        core,
        intent=intent_state,
        velocity=intent.velocity,
        active_ns=now_ns if intent.active else core.active_ns,
    )
    if intent.gesture is not None:
        event = _GESTURE_EVENTS[intent.gesture]
        reason = f"{intent.gesture.value} ({intent.reason})"
        if transition(core.mode, event) is core.mode and not (
            event is E.SWITCH_DOF and core.mode is S.DIRECT
        ):
            reason += f": ignored while {core.mode.value}"
        core = apply_event(core, event, now_ns, reason, out)
    if (
        core.mode is S.DIRECT
        and not core.grasped
        and now_ns - core.active_ns > core.params.direct_idle_s * 1e9
    ):
        core = apply_event(
            core, E.INACTIVE, now_ns, f"no EMG activity for {core.params.direct_idle_s:.0f} s", out
        )
    return core


def _on_target(
    core: ControllerCore, target: GraspTarget, now_ns: int, out: list[Output]
) -> ControllerCore:
    p = core.params
    usable = target.reconstructed and target.grasp_width_mm is not None
    if not usable:
        since = core.target_missing_since if core.target_missing_since is not None else now_ns
        core = evolve(core, target_missing_since=since)
        lost_for_ms = (now_ns - since) / 1e6
        if core.target_present and lost_for_ms >= p.target_lost_ms:
            core = evolve(core, target_present=False)
            if core.mode in (S.READY, S.PRESHAPING):
                core = apply_event(
                    core, E.TARGET_LOST, now_ns, f"no reconstruction for {lost_for_ms:.0f} ms", out
                )
        return core
    previous, was_present = core.target, core.target_present
    core = evolve(core, target=target, target_present=True, target_missing_since=None)
    width = float(target.grasp_width_mm)  # type: ignore[arg-type]
    desc = (
        f"{target.shape} {width:.0f} mm"
        + (f" at {target.wrist_angle_deg:.0f}°" if target.wrist_angle_deg is not None else "")
        + f", {target.grip} grip"
    )
    if core.mode in (S.IDLE, S.AIMING):
        return apply_event(core, E.NEW_TARGET, now_ns, f"reconstructed {desc}", out)
    if core.mode is S.READY:
        changed = previous is None or _width_changed(previous, target, p)
        if changed:
            return apply_event(core, E.NEW_TARGET, now_ns, f"target changed to {desc}", out)
        return core
    if core.mode is S.PRESHAPING:
        frozen = core.setpoint
        if not was_present:
            return apply_event(core, E.NEW_TARGET, now_ns, f"re-aimed: reconstructed {desc}", out)
        if frozen is not None and abs(width - frozen.width_mm) > p.reaim_width_mm:
            return apply_event(core, E.NEW_TARGET, now_ns, f"re-aimed: target now {desc}", out)
    return core


def _width_changed(a: GraspTarget, b: GraspTarget, p: ControllerParams) -> bool:
    if a.shape != b.shape or a.grasp_width_mm is None or b.grasp_width_mm is None:
        return True
    return abs(a.grasp_width_mm - b.grasp_width_mm) > p.reaim_width_mm


def _on_cue(core: ControllerCore, cue: AimCue, now_ns: int, out: list[Output]) -> ControllerCore:
    if cue.state in _CUE_ON:
        core = evolve(core, cue_on=True, cue_off_since=None)
        if core.mode is S.IDLE:
            return apply_event(core, E.OBJECT_SEEN, now_ns, f"aim cue {cue.state}", out)
        return core
    since = core.cue_off_since if core.cue_off_since is not None else now_ns
    core = evolve(core, cue_on=False, cue_off_since=since)
    off_ms = (now_ns - since) / 1e6
    if core.mode is S.AIMING and off_ms >= core.params.object_lost_ms:
        return apply_event(core, E.OBJECT_LOST, now_ns, f"no object for {off_ms:.0f} ms", out)
    return core


def _on_hand(
    core: ControllerCore, hand: ProsthesisState, now_ns: int, out: list[Output]
) -> ControllerCore:
    p = core.params
    core = evolve(core, hand=hand)
    if core.mode is S.PRESHAPING and core.setpoint is not None:
        ap_err, wr_err = _errors(core.setpoint, hand)
        inside = abs(ap_err) <= p.aperture_tol_mm and abs(wr_err) <= p.wrist_tol_deg
        if inside and all(core.holding) and not core.at_target:  # reached, and come to rest
            sp = core.setpoint
            wrist = f"{sp.wrist_deg:.1f}" if sp.wrist_deg is not None else "kept"
            reason = (
                f"pre-shape reached: aperture {hand.aperture_mm:.1f} mm (target "
                f"{sp.aperture_mm:.1f} ± {p.aperture_tol_mm:g}), wrist "
                f"{hand.wrist_angle_deg:.1f}° (target {wrist} ± {p.wrist_tol_deg:g})"
            )
            core = evolve(core, at_target=True)
            core = apply_event(core, E.AT_TARGET, now_ns, reason, out)
    if core.mode is S.DIRECT:
        if not core.grasped and hand.grip_force_pct >= p.grip_on_pct:
            core = evolve(core, grasped=True, contact_mm=hand.aperture_mm)
            reason = f"grip force {hand.grip_force_pct:.0f} % at {hand.aperture_mm:.1f} mm"
            core = apply_event(core, E.GRASPED, now_ns, reason, out)
        elif (
            core.grasped
            and hand.grip_force_pct <= p.grip_off_pct
            and hand.aperture_mm >= (core.contact_mm or 0.0) + p.release_open_mm
        ):
            reason = f"object released: hand open to {hand.aperture_mm:.1f} mm"
            core = apply_event(core, E.RELEASED, now_ns, reason, out)
    return core


# --------------------------------------------------------------------------- outputs


def _setpoint(core: ControllerCore) -> Setpoint | None:
    p, target, hand = core.params, core.target, core.hand
    if target is None or target.grasp_width_mm is None:
        return None
    lo, hi = p.aperture_range_mm
    aperture = min(max(target.grasp_width_mm + p.slack_mm, lo), hi)
    wrist = None
    if target.wrist_angle_deg is not None:
        current = hand.wrist_angle_deg if hand is not None else 0.0
        base = current if p.camera_on_hand else 0.0
        wrist = _nearest_equivalent(base + target.wrist_angle_deg + p.wrist_offset_deg, current, p)
    return Setpoint(
        aperture_mm=aperture,
        wrist_deg=wrist,
        width_mm=target.grasp_width_mm,
        shape=target.shape,
        grip=target.grip,
    )


def _nearest_equivalent(angle: float, current: float, p: ControllerParams) -> float:
    """A grasp axis is the same every 180°: the equivalent angle nearest the wrist, in range."""
    lo, hi = p.wrist_range_deg
    candidates = [angle + 180.0 * k for k in range(-3, 4)]
    inside = [a for a in candidates if lo <= a <= hi]
    if not inside:
        return min(max(angle, lo), hi)
    return min(inside, key=lambda a: abs(a - current))


def _errors(setpoint: Setpoint, hand: ProsthesisState) -> tuple[float, float]:
    """(aperture error, wrist error): positive aperture error means close."""
    ap = hand.aperture_mm - setpoint.aperture_mm
    wr = 0.0 if setpoint.wrist_deg is None else setpoint.wrist_deg - hand.wrist_angle_deg
    return ap, wr


def _servo(
    error: float, gain: float, tol: float, holding: bool, p: ControllerParams
) -> tuple[float, bool]:
    """(velocity, holding): a moving axis comes to rest within ``settle_fraction`` of the
    tolerance (aiming at the set-point, not the edge of the band); a resting axis moves
    again only when the error leaves the tolerance."""
    if abs(error) <= (tol if holding else tol * p.settle_fraction):
        return 0.0, True
    v = error * gain
    v = math.copysign(max(abs(v), p.min_speed), v)
    return max(min(v, 1.0), -1.0), False


def _command(
    core: ControllerCore, now_ns: int, out: list[Output], since_tick: bool = True
) -> ControllerCore:
    """One ``ProsthesisCommand``; ``since_tick=False`` for the tick's own, which the tick then
    clears (``commanded_since_tick``) in the same copy."""
    grasp = wrist = 0.0
    p = core.params
    holding = core.holding
    hand_ns = core.seen_ns.get(HAND)
    hand_fresh = hand_ns is not None and now_ns - hand_ns <= p.velocity_hold_ms * 1e6
    if core.mode is S.PRESHAPING and core.setpoint is not None and core.hand is not None:
        ap_err, wr_err = _errors(core.setpoint, core.hand)
        if not hand_fresh:
            ap_err = wr_err = 0.0  # never servo on an old position: hold still
        hold_ap, hold_wr = core.holding
        grasp, hold_ap = _servo(ap_err, p.aperture_gain_per_mm, p.aperture_tol_mm, hold_ap, p)
        wrist, hold_wr = _servo(wr_err, p.wrist_gain_per_deg, p.wrist_tol_deg, hold_wr, p)
        holding = (hold_ap, hold_wr)
    elif core.mode is S.DIRECT:
        emg_ns = core.seen_ns.get(EMG)
        fresh = emg_ns is not None and now_ns - emg_ns <= p.velocity_hold_ms * 1e6
        velocity = core.velocity if fresh else 0.0
        if core.dof == "grasp":
            grasp = velocity
        else:
            wrist = velocity
    seq = core.command_seq + 1
    out.append(
        ProsthesisCommand(
            seq=seq,
            t_ns=now_ns,
            grasp=float(grasp),
            wrist=float(wrist),
            grip=core.grip,  # type: ignore[arg-type]
        )
    )
    # One copy for the servo's rest flags and the count: this runs on every hand status.
    return evolve(core, holding=holding, command_seq=seq, commanded_since_tick=since_tick)


def _publish(
    core: ControllerCore, now_ns: int, out: list[Output], heartbeat: bool = False
) -> ControllerCore:
    """A transition names its event and the state it left; a heartbeat has no event and
    ``previous == state``, and repeats the reason of the last transition."""
    seq = core.state_seq + 1
    previous = core.mode if heartbeat else core.previous
    sp = core.setpoint
    target = core.target if core.target_present else None
    out.append(
        ControllerState(
            seq=seq,
            t_ns=now_ns,
            state=core.mode.value,  # type: ignore[arg-type]
            previous=previous.value if previous is not None else "",
            event="" if heartbeat else core.event,
            reason=core.reason,
            dof=core.dof,  # type: ignore[arg-type]
            target_width_mm=sp.width_mm
            if sp is not None
            else (target.grasp_width_mm if target is not None else None),
            target_angle_deg=sp.wrist_deg if sp is not None else None,
            grip=(  # type: ignore[arg-type]
                sp.grip
                if sp is not None
                else (target.grip if target is not None and core.mode is S.READY else core.grip)
            ),
        )
    )
    return evolve(core, state_seq=seq, published_ns=now_ns)


def _topic_of(message: object) -> str | None:
    match message:
        case EmgSample():
            return EMG
        case ProsthesisState():
            return HAND
        case GraspTarget():
            return TARGET
    return None
