"""Grip selection: which grip a multi-grip hand pre-shapes for, from the grasp target's shape,
width and orientation. A small rule table, first match wins, each rule with its reason.

==  ==========================================  ========  =====================================
#   when                                        grip      why
==  ==========================================  ========  =====================================
1   nothing reconstructed (no shape or width)   power     the paper's palmar grasp is the default
2   width <= 18 mm, any shape                   pinch     very small: thumb and index tips
                                                          (20 % of the pinch's 90 mm aperture)
3   cuboid with a known axis, width <= 42 mm    lateral   a thin flat object: the thumb closes
                                                          across the axis onto the side of the
                                                          index (70 % of the lateral's 60 mm)
4   sphere or cylinder, width <= 47 mm          tripod    a small round object: thumb, index and
                                                          middle (50 % of the tripod's 95 mm)
5   anything else                               power     the whole hand around a large object
==  ==========================================  ========  =====================================

Orientation enters rule 3: the lateral grip needs the object's axis (the wrist turns the thumb's
path across it), and a sphere has none. Thresholds are set relative to each grip's largest
aperture, in the style of Došen et al. 2010's rule tree; the numbers are lpc's, not taken from
the literature. The README says which papers select grips from object geometry.

``choose_grip`` is pure; the reconstructor attaches its result to every grasp target.
"""

from __future__ import annotations

from dataclasses import dataclass

GRIP_NAMES = ("power", "tripod", "lateral", "pinch")
DEFAULT_GRIP = "power"


@dataclass(frozen=True, kw_only=True)
class GripRules:
    """The widths (mm) of the rule table's thresholds."""

    pinch_max_mm: float = 18.0
    lateral_max_mm: float = 42.0
    tripod_max_mm: float = 47.0

    def __post_init__(self) -> None:
        for name in ("pinch_max_mm", "lateral_max_mm", "tripod_max_mm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


@dataclass(frozen=True)
class GripChoice:
    grip: str
    rule: int
    reason: str


def choose_grip(
    shape: str,
    width_mm: float | None,
    wrist_angle_deg: float | None,
    rules: GripRules | None = None,
) -> GripChoice:
    """The grip for an object of ``shape`` and grasp ``width_mm``, whose principal axis is at
    ``wrist_angle_deg`` (``None``: no axis, as for a sphere)."""
    r = rules or GripRules()
    if shape == "none" or width_mm is None:
        return GripChoice("power", 1, "no object reconstructed: default palmar grasp")
    size = f"{shape} {width_mm:.0f} mm"
    if width_mm <= r.pinch_max_mm:
        return GripChoice("pinch", 2, f"{size} <= {r.pinch_max_mm:g} mm: very small")
    if shape == "cuboid" and wrist_angle_deg is not None and width_mm <= r.lateral_max_mm:
        return GripChoice(
            "lateral",
            3,
            f"{size} <= {r.lateral_max_mm:g} mm, axis at {wrist_angle_deg:.0f}°: thin and flat",
        )
    if shape in ("sphere", "cylinder") and width_mm <= r.tripod_max_mm:
        return GripChoice("tripod", 4, f"{size} <= {r.tripod_max_mm:g} mm: small and round")
    return GripChoice("power", 5, f"{size}: large")
