"""What any hand takes and reports, whatever carries it (CAN, serial, the simulator).

Velocity set-points go in; aperture, wrist angle, grip force and flags come back. The wire
codecs beside this module turn these into frames; ``lpc_core.sim.hand`` moves a simulated hand
under them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lpc_core.perception.grip import GRIP_NAMES


@dataclass(frozen=True)
class HandCommand:
    """Velocity set-points in [-1, 1]: ``grasp`` > 0 closes, ``wrist`` > 0 turns positive.
    ``grip``: the grip a multi-grip hand closes in (one-grip hands ignore it); ``None`` keeps
    the grip it has (the watchdog's stop must not change the hand's shape)."""

    grasp: float = 0.0
    wrist: float = 0.0
    grip: str | None = None

    def __post_init__(self) -> None:
        for name in ("grasp", "wrist"):
            value = getattr(self, name)
            if not (math.isfinite(value) and -1.0 <= value <= 1.0):
                raise ValueError(f"{name} must be in [-1, 1], got {value}")
        if self.grip is not None and self.grip not in GRIP_NAMES:
            raise ValueError(f"grip must be one of {', '.join(GRIP_NAMES)}, got {self.grip!r}")


@dataclass(frozen=True)
class HandStatus:
    """What the hand reports."""

    wrist_angle_deg: float
    aperture_mm: float
    grip_force_pct: float = 0.0
    emg: tuple[float, ...] = ()
    moving: bool = False
    fault: bool = False
    watchdog: bool = False  # the hand itself stopped for want of commands
    counter: int = 0
    grip: str = "power"
