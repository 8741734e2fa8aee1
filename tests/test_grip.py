"""Grip selection: the rule table, its reasons, and the grip carried from the grasp target
through the controller to the hand."""

from __future__ import annotations

import msgspec
import pytest

from lpc_core.devices import ability_grips as ag
from lpc_core.perception.grip import GRIP_NAMES, GripRules, choose_grip
from lpc_core.perception.reconstructor import grasp_target_message
from lpc_core.perception.window import WindowResult
from schemas import Reconstruction, decode, encode


@pytest.mark.parametrize(
    ("shape", "width", "angle", "grip", "rule"),
    [
        ("none", None, None, "power", 1),
        ("sphere", None, None, "power", 1),
        ("cylinder", 12.0, 30.0, "pinch", 2),
        ("cuboid", 18.0, None, "pinch", 2),
        ("cuboid", 35.0, 10.0, "lateral", 3),
        ("cuboid", 42.0, -80.0, "lateral", 3),
        ("cuboid", 35.0, None, "power", 5),  # no axis: the thumb has nothing to close across
        ("cuboid", 45.0, 0.0, "power", 5),
        ("sphere", 40.0, None, "tripod", 4),
        ("cylinder", 47.0, 90.0, "tripod", 4),
        ("cylinder", 60.0, 0.0, "power", 5),
        ("sphere", 70.0, None, "power", 5),
    ],
)
def test_rule_table(
    shape: str, width: float | None, angle: float | None, grip: str, rule: int
) -> None:
    choice = choose_grip(shape, width, angle)
    assert (choice.grip, choice.rule) == (grip, rule)
    assert choice.reason and choice.grip in GRIP_NAMES
    if width is not None:
        assert f"{width:.0f} mm" in choice.reason


def test_every_grip_reaches_its_rule_widths_on_the_ability_hand() -> None:
    # The controller opens 15 mm wider than the object: each grip's widest object must fit.
    rules = GripRules()
    widest = {"pinch": rules.pinch_max_mm, "lateral": rules.lateral_max_mm}
    widest["tripod"] = rules.tripod_max_mm
    for grip, width in widest.items():
        assert ag.posture(grip).range_mm[1] >= width + 15.0
    assert set(ag.GRIPS) == set(GRIP_NAMES)


def test_bad_rule_thresholds_are_rejected() -> None:
    with pytest.raises(ValueError, match="pinch_max_mm"):
        GripRules(pinch_max_mm=0.0)


def test_grasp_target_carries_the_grip_and_old_messages_decode_with_power() -> None:
    window = WindowResult(
        seq=3,
        t_ns=10,
        shape="sphere",
        grasp_width_m=0.04,
        wrist_angle_rad=None,
        reconstructed=True,
        frames=10,
        agreement=1.0,
    )
    rec = Reconstruction(seq=3, t_ns=10, frame_seq=3, shape="sphere", grasp_width_mm=40.0)
    target = grasp_target_message(window, rec)
    assert target.grip == "tripod" and "small and round" in target.grip_reason
    # A message from before the field existed (as in old recordings) decodes with the default.
    legacy = msgspec.msgpack.decode(encode(target))
    del legacy["grip"], legacy["grip_reason"]
    decoded = decode("lpc/grasp/target", msgspec.msgpack.encode(legacy))
    assert decoded.grip == "power" and decoded.grip_reason == ""
