"""A simulated prosthetic hand: two velocity-controlled degrees of freedom.

- **Grasp** (palmar aperture, 0–110 mm as on the Michelangelo hand): a command in [-1, 1]
  (> 0 closes) sets the target speed ``command * max_grasp_mm_s``; the motor follows it with
  first-order dynamics, ``dv/dt = (v_cmd - v) / tau``.
- **Wrist rotation** (±160°, Michelangelo's range): the same, with ``max_wrist_deg_s``.
- **Grip force**: when an object of width ``object_mm`` lies between the fingers, the aperture
  stops at the object's surface; further closing squeezes it and the grip force (0–100 %)
  builds in proportion to the closing command; opening relieves the force first.

``hand_step(state, command, now_ns) -> (state, HandStatus)`` is pure: the command is the last
one received (or ``None`` for none yet), and time advances from ``state.t_ns`` to ``now_ns``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from lpc_core.devices.hand import HandCommand, HandStatus


@dataclass(frozen=True)
class HandParams:
    aperture_min_mm: float = 0.0
    aperture_max_mm: float = 110.0
    wrist_min_deg: float = -160.0
    wrist_max_deg: float = 160.0
    max_grasp_mm_s: float = 120.0
    max_wrist_deg_s: float = 180.0
    tau_s: float = 0.05
    force_pct_s: float = 150.0  # force build-up at full closing command while in contact
    max_step_s: float = 0.1  # longer gaps (a stalled caller) are integrated as this

    def __post_init__(self) -> None:
        if not self.aperture_min_mm < self.aperture_max_mm:
            raise ValueError("aperture_min_mm must be below aperture_max_mm")
        if not self.wrist_min_deg < self.wrist_max_deg:
            raise ValueError("wrist_min_deg must be below wrist_max_deg")
        for name in ("max_grasp_mm_s", "max_wrist_deg_s", "tau_s", "force_pct_s", "max_step_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive")


@dataclass(frozen=True)
class HandState:
    params: HandParams = field(default_factory=HandParams)
    t_ns: int | None = None
    aperture_mm: float = 80.0
    wrist_deg: float = 0.0
    grasp_speed: float = 0.0  # mm/s, > 0 closing
    wrist_speed: float = 0.0  # deg/s
    grip_force_pct: float = 0.0
    object_mm: float | None = None
    counter: int = 0


def hand_step(
    state: HandState, command: HandCommand | None, now_ns: int
) -> tuple[HandState, HandStatus]:
    """Advance the hand to ``now_ns`` under ``command`` (held since the previous step)."""
    p = state.params
    command = command or HandCommand()
    dt = 0.0 if state.t_ns is None else (now_ns - state.t_ns) / 1e9
    if dt < 0:
        raise ValueError(f"now_ns goes back in time: {now_ns} < {state.t_ns}")
    dt = min(dt, p.max_step_s)
    # Exact first-order response over the step (the command is held constant across it).
    k = 1.0 - math.exp(-dt / p.tau_s) if dt > 0 else 0.0
    grasp_speed = state.grasp_speed + (command.grasp * p.max_grasp_mm_s - state.grasp_speed) * k
    wrist_speed = state.wrist_speed + (command.wrist * p.max_wrist_deg_s - state.wrist_speed) * k

    wrist = state.wrist_deg + wrist_speed * dt
    if not p.wrist_min_deg <= wrist <= p.wrist_max_deg:
        wrist = min(max(wrist, p.wrist_min_deg), p.wrist_max_deg)
        wrist_speed = 0.0  # the end stop absorbs the motion

    aperture = state.aperture_mm - grasp_speed * dt
    force = state.grip_force_pct
    # The object is between the fingers only if the hand was at least that wide.
    obj = state.object_mm
    if obj is not None and state.aperture_mm >= obj - 1e-6:
        if aperture < obj:
            # At the surface: squeezing builds the grip instead of moving the fingers.
            aperture, grasp_speed = obj, min(grasp_speed, 0.0)
            force += p.force_pct_s * max(command.grasp, 0.0) * dt
        if force > 0 and grasp_speed < 0:
            # Opening relieves the grip before the fingers leave the surface.
            force = max(force + 2.0 * p.force_pct_s * grasp_speed / p.max_grasp_mm_s * dt, 0.0)
        if force > 0:
            aperture = obj
    if aperture < p.aperture_min_mm:
        aperture, grasp_speed = p.aperture_min_mm, min(grasp_speed, 0.0)
    if aperture > p.aperture_max_mm:
        aperture, grasp_speed = p.aperture_max_mm, max(grasp_speed, 0.0)
    force = min(max(force, 0.0), 100.0)
    moving = abs(grasp_speed) > 0.5 or abs(wrist_speed) > 0.5
    counter = (state.counter + 1) & 0xFF
    # Built whole: dataclasses.replace, which looks the fields up by name on every call, was
    # a third of the step's time (cProfile, 20000 steps).
    new_state = HandState(
        params=p,
        t_ns=now_ns,
        aperture_mm=aperture,
        wrist_deg=wrist,
        grasp_speed=grasp_speed,
        wrist_speed=wrist_speed,
        grip_force_pct=force,
        object_mm=obj,
        counter=counter,
    )
    status = HandStatus(
        wrist_angle_deg=wrist,
        aperture_mm=aperture,
        grip_force_pct=force,
        moving=moving,
        counter=counter,
    )
    return new_state, status
