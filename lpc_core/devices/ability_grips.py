"""How the Ability Hand makes each grip: aperture to joint angles and back, force from currents.

lpc drives a multi-grip hand with one grasp axis, the aperture (mm between the thumb and the
opposing finger pads, as the controller and ``ProsthesisState`` use it). For each grip a table
gives the six joint angles (degrees; index, middle, ring, pinky, thumb flexor, thumb rotator,
the rotator negative as on the wire) at a few apertures; between rows the angles are linear in
the aperture. Back from the hand, the aperture is read off the grip's **lead joint** (the one
with the longest travel in its table, whose angle is monotonic in the aperture).

=========  ===========================================  =========  ==============
grip       joints that move (the others held)           aperture   lead joint
=========  ===========================================  =========  ==============
power      all four fingers and the thumb flexor;        0-110 mm  index
           thumb rotated internally (-80°)
tripod     index, middle, thumb flexor; ring and          0-95 mm  index
           pinky flexed out of the way; thumb at -60°
pinch      index and thumb flexor; the other three        0-90 mm  index
           flexed; thumb at -50°
lateral    thumb flexor onto the side of the flexed       0-60 mm  thumb flexor
           index (key grip); thumb rotator near 0°
=========  ===========================================  =========  ==============

The angles are lpc's choice, within the URDF's joint limits (fingers and thumb flexor 0 to
about 100°, thumb rotator -100° to 0°), and are to be tuned on a real hand; the tests hold the
table to its promises (monotonic lead joint, round trip aperture -> angles -> aperture, joint
limits), not to these numbers.

Grip force: the largest current of the grip's moving joints, above the current the fingers
draw moving freely, as a share of ``FULL_CURRENT_A`` (a placeholder to be measured on a hand,
as for the RoboLimb's 1.2 A).
"""

from __future__ import annotations

import bisect
import functools
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from lpc_core.devices.ability import N_JOINTS

FREE_CURRENT_A = 0.1  # fingers moving without load stay below this
FULL_CURRENT_A = 1.0  # counted as 100 % grip force
JOINT_LIMITS_DEG = (
    np.array([0.0, 0.0, 0.0, 0.0, 0.0, -100.0]),
    np.array([100.0, 100.0, 100.0, 100.0, 100.0, 0.0]),
)


@dataclass(frozen=True)
class GripPosture:
    """Rows of (aperture mm, six joint angles in degrees), apertures increasing."""

    apertures_mm: tuple[float, ...]
    angles_deg: tuple[tuple[float, ...], ...]

    def __post_init__(self) -> None:
        ap = np.asarray(self.apertures_mm)
        angles = np.asarray(self.angles_deg)
        if len(ap) < 2 or not (np.diff(ap) > 0).all():
            raise ValueError("apertures_mm must hold at least two increasing values")
        if angles.shape != (len(ap), N_JOINTS):
            raise ValueError(f"angles_deg must be {len(ap)} rows of {N_JOINTS} angles")
        lo, hi = JOINT_LIMITS_DEG
        if ((angles < lo) | (angles > hi)).any():
            raise ValueError("angles_deg leave the joint limits")
        lead = self.lead
        if not (np.diff(angles[:, lead]) < 0).all():
            raise ValueError("the lead joint must open monotonically with the aperture")

    @functools.cached_property
    def table(self) -> np.ndarray:
        table = np.asarray(self.angles_deg, dtype=np.float64)
        table.flags.writeable = False  # shared by every caller
        return table

    @property
    def lead(self) -> int:
        """The joint with the longest travel: the aperture is read off it."""
        angles = np.asarray(self.angles_deg, dtype=np.float64)
        return int(np.argmax(angles.max(axis=0) - angles.min(axis=0)))

    @property
    def moving(self) -> np.ndarray:
        """Which joints move in this grip (their currents are its grip force)."""
        angles = np.asarray(self.angles_deg, dtype=np.float64)
        return (angles.max(axis=0) - angles.min(axis=0)) > 1.0

    @property
    def range_mm(self) -> tuple[float, float]:
        return self.apertures_mm[0], self.apertures_mm[-1]


GRIPS: Mapping[str, GripPosture] = MappingProxyType(
    {
        "power": GripPosture(
            (0.0, 60.0, 110.0),
            (
                (95.0, 95.0, 95.0, 95.0, 70.0, -80.0),
                (50.0, 50.0, 50.0, 50.0, 35.0, -80.0),
                (5.0, 5.0, 5.0, 5.0, 5.0, -80.0),
            ),
        ),
        "tripod": GripPosture(
            (0.0, 95.0),
            ((80.0, 80.0, 100.0, 100.0, 60.0, -60.0), (5.0, 5.0, 100.0, 100.0, 5.0, -60.0)),
        ),
        "pinch": GripPosture(
            (0.0, 90.0),
            ((75.0, 100.0, 100.0, 100.0, 55.0, -50.0), (5.0, 100.0, 100.0, 100.0, 5.0, -50.0)),
        ),
        "lateral": GripPosture(
            (0.0, 60.0),
            ((90.0, 90.0, 90.0, 90.0, 65.0, -10.0), (90.0, 90.0, 90.0, 90.0, 0.0, -10.0)),
        ),
    }
)


def posture(grip: str) -> GripPosture:
    try:
        return GRIPS[grip]
    except KeyError:
        raise ValueError(f"grip must be one of {', '.join(GRIPS)}, got {grip!r}") from None


def positions_for(grip: str, aperture_mm: float) -> np.ndarray:
    """The six joint angles (degrees) that make ``grip`` at ``aperture_mm`` (clamped to its
    range)."""
    p = posture(grip)
    ap = p.apertures_mm
    a = min(max(float(aperture_mm), ap[0]), ap[-1])
    k = min(bisect.bisect_right(ap, a), len(ap) - 1)  # the row above a (the top row at the end)
    w = (a - ap[k - 1]) / (ap[k] - ap[k - 1])
    table = p.table
    return table[k - 1] + w * (table[k] - table[k - 1])


def aperture_of(grip: str, positions_deg: np.ndarray) -> float:
    """The aperture (mm) that the lead joint's reported angle means in ``grip``."""
    p = posture(grip)
    table = p.table
    lead = p.lead
    # np.interp wants increasing x: the lead angle falls as the aperture grows.
    return float(np.interp(-positions_deg[lead], -table[:, lead], p.apertures_mm))


def grip_force_pct(grip: str, currents_a: np.ndarray) -> float:
    """Grip force (0-100 %) from the moving joints' currents."""
    moving = posture(grip).moving
    current = float(np.abs(np.asarray(currents_a, dtype=np.float64)[moving]).max())
    share = (current - FREE_CURRENT_A) / (FULL_CURRENT_A - FREE_CURRENT_A)
    return 100.0 * min(max(share, 0.0), 1.0)


def classify(positions_deg: np.ndarray) -> tuple[str, float, float]:
    """(grip, aperture mm, residual degrees): the grip whose posture path passes nearest to a
    pose, for the simulated hand, which sees joint angles only. The residual is the largest
    joint's distance from that grip's posture at the pose's aperture."""
    return _classify(tuple(float(x) for x in positions_deg))


@functools.lru_cache(maxsize=256)
def _classify(pose_deg: tuple[float, ...]) -> tuple[str, float, float]:
    # Cached: the simulated hand asks about the same commanded pose at every step.
    best: tuple[str, float, float] | None = None
    pose = np.asarray(pose_deg, dtype=np.float64)
    for name in GRIPS:
        aperture = aperture_of(name, pose)
        residual = float(np.abs(positions_for(name, aperture) - pose).max())
        if best is None or residual < best[2]:
            best = (name, aperture, residual)
    assert best is not None
    return best
