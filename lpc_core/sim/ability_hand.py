"""A simulated PSYONIC Ability Hand: six joints under the hand's own position control.

- Each joint follows its target angle with first-order dynamics, ``dq/dt = (q_target - q) /
  tau`` (exact over each step, the target held across it).
- Position commands set the targets; velocity commands move the targets at the commanded
  rates; a read-only command changes nothing. With no command for ``api_timeout_s`` (the
  vendor's 300 ms) the hand leaves API mode and holds where it is.
- An object of width ``object_mm`` between the fingers: when the commanded pose is one of
  lpc's grips (``lpc_core.devices.ability_grips``, recognised from the angles alone) and the
  hand was open at least that wide, the joints stop on the object's surface, and the aperture
  commanded beyond it becomes current in the grip's moving joints (``squeeze_mm`` for the full
  current) and pressure on their fingertip sensors.
- Currents of free motion stay below ``ability_grips.FREE_CURRENT_A``.

``ability_step(state, now_ns) -> state`` advances time; ``ability_command(state, command,
now_ns)`` applies a decoded host frame; ``ability_reply(state, variant)`` builds the reply.
All pure: the pty server (``services.drivers.ability_sim``) calls them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from lpc_core.devices import ability as ab
from lpc_core.devices import ability_grips as ag


@dataclass(frozen=True)
class AbilityParams:
    tau_s: float = 0.05
    api_timeout_s: float = 0.3
    squeeze_mm: float = 20.0
    contact_tol_deg: float = 2.0  # a commanded pose this close to a grip's path is that grip
    max_step_s: float = 0.1

    def __post_init__(self) -> None:
        for name in ("tau_s", "api_timeout_s", "squeeze_mm", "max_step_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive")


def _open_pose() -> tuple[float, ...]:
    return tuple(float(x) for x in ag.positions_for("power", 80.0))


@dataclass(frozen=True)
class AbilityState:
    params: AbilityParams = field(default_factory=AbilityParams)
    t_ns: int | None = None
    positions: tuple[float, ...] = field(default_factory=_open_pose)
    speeds: tuple[float, ...] = (0.0,) * ab.N_JOINTS  # deg/s
    target: tuple[float, ...] = field(default_factory=_open_pose)
    rates: tuple[float, ...] | None = None  # velocity mode: deg/s the targets move at
    squeeze_mm: float = 0.0
    grip: str | None = None  # the grip recognised in the target pose
    object_mm: float | None = None
    last_command_ns: int | None = None
    api_mode: bool = False
    reply_header: int = ab.Mode.POSITION  # the last format header: replies use its variant


def ability_step(state: AbilityState, now_ns: int) -> AbilityState:
    """Advance the joints from ``state.t_ns`` to ``now_ns``."""
    p = state.params
    if state.t_ns is None:
        return dataclasses.replace(state, t_ns=now_ns)
    dt = (now_ns - state.t_ns) / 1e9
    if dt < 0:
        raise ValueError(f"now_ns goes back in time: {now_ns} < {state.t_ns}")
    dt = min(dt, p.max_step_s)
    q = np.asarray(state.positions)
    target = np.asarray(state.target)
    api_mode = state.api_mode
    rates = state.rates
    last = state.last_command_ns
    if api_mode and last is not None and (now_ns - last) / 1e9 > p.api_timeout_s:
        api_mode, target, rates = False, q.copy(), None  # out of API mode: hold still
    if rates is not None:
        target = np.clip(target + np.asarray(rates) * dt, *ag.JOINT_LIMITS_DEG)
    effective, grip, squeeze = _contact(state, q, target)
    k = 1.0 - math.exp(-dt / p.tau_s) if dt > 0 else 0.0
    new_q = q + (effective - q) * k
    speeds = (new_q - q) / dt if dt > 0 else np.zeros_like(q)
    return dataclasses.replace(
        state,
        t_ns=now_ns,
        positions=tuple(float(x) for x in new_q),
        speeds=tuple(float(x) for x in speeds),
        target=tuple(float(x) for x in target),
        rates=rates,
        squeeze_mm=squeeze,
        grip=grip,
        api_mode=api_mode,
    )


def _contact(
    state: AbilityState, q: np.ndarray, target: np.ndarray
) -> tuple[np.ndarray, str | None, float]:
    """(the joints' effective target, the grip recognised, mm squeezed beyond the object)."""
    grip, target_mm, residual = ag.classify(target)
    if residual > state.params.contact_tol_deg:
        return target, None, 0.0
    obj = state.object_mm
    if obj is None or ag.aperture_of(grip, q) < obj - 0.5 or target_mm >= obj:
        return target, grip, 0.0
    # The fingers stop on the surface; the rest of the command presses on it.
    return ag.positions_for(grip, obj), grip, obj - target_mm


def ability_command(state: AbilityState, command: ab.Command, now_ns: int) -> AbilityState:
    """Apply one host frame addressed to this hand (the caller checks the address)."""
    state = ability_step(state, now_ns)
    changes: dict[str, object] = {"last_command_ns": now_ns}
    mode = command.mode
    if command.header == ab.GRIP_HEADER:
        grip = _GRIP_POSES.get(command.values[0])
        if grip is not None:
            name, aperture = grip
            aperture = aperture if aperture is not None else ag.posture(name).range_mm[1]
            pose = ag.positions_for(name, aperture)
            changes.update(target=tuple(float(x) for x in pose), rates=None, api_mode=True)
    elif mode == ab.Mode.POSITION and len(command.values) == ab.N_JOINTS:
        target = np.clip(command.positions_deg, *ag.JOINT_LIMITS_DEG)
        changes.update(target=tuple(float(x) for x in target), rates=None, api_mode=True)
        changes["reply_header"] = command.header
    elif mode == ab.Mode.VELOCITY and len(command.values) == ab.N_JOINTS:
        changes.update(rates=tuple(float(x) for x in command.velocities_deg_s), api_mode=True)
        changes["reply_header"] = command.header
    elif command.reply_variant is not None:
        changes["reply_header"] = command.header  # read only, torque, voltage: reply only
    return dataclasses.replace(state, **changes)  # type: ignore[arg-type]


# The hand's own grips that lpc's tables also make: grip index -> (grip, aperture or open).
_GRIP_POSES: dict[int, tuple[str, float | None]] = {
    ab.Grip.OPEN: ("power", None),
    ab.Grip.POWER: ("power", 0.0),
    ab.Grip.KEY: ("lateral", 0.0),
    ab.Grip.PINCH: ("pinch", 0.0),
    ab.Grip.TRIPOD_OPEN: ("tripod", 0.0),
    ab.Grip.TRIPOD_CLOSED: ("tripod", 0.0),
}


def _int16(x: np.ndarray) -> tuple[int, ...]:
    return tuple(int(v) for v in np.trunc(np.clip(x, -ab.LIMIT, ab.LIMIT)))


def ability_reply(state: AbilityState, variant: int | None = None) -> ab.Reply:
    """The reply frame's content for the hand's state, in ``variant`` (default: the variant of
    the last format header)."""
    header = state.reply_header if variant is None else (state.reply_header & 0xF0) | variant
    q = np.asarray(state.positions)
    speeds = np.asarray(state.speeds)
    free = ag.FREE_CURRENT_A * 0.8 * np.minimum(np.abs(speeds) / 200.0, 1.0)
    currents = free * np.sign(speeds)
    touch = np.zeros(ab.N_TOUCH, dtype=np.int64)
    if state.squeeze_mm > 0 and state.grip is not None:
        share = min(state.squeeze_mm / state.params.squeeze_mm, 1.0)
        moving = ag.posture(state.grip).moving
        press = ag.FREE_CURRENT_A + (ag.FULL_CURRENT_A - ag.FREE_CURRENT_A) * share
        currents = np.where(moving, np.maximum(np.abs(currents), press), currents)
        for finger in np.flatnonzero(moving[:5]):  # six touch sites per finger, thumb last
            touch[6 * finger : 6 * finger + 6] = int(4095 * share)
    rotor = np.radians(speeds) * np.asarray(ab.GEAR_RATIO) * ab.ROTOR_COUNTS_PER_RAD_S
    v = header & 0x0F
    return ab.Reply(
        header=header,
        position=_int16(q * ab.POSITION_COUNTS_PER_DEG),
        current=None if v == 1 else _int16(currents * ab.CURRENT_COUNTS_PER_A),
        rotor_velocity=None if v == 0 else _int16(rotor),
        touch=None if v == 2 else tuple(int(t) for t in touch),
        hot_cold=0,
    )
