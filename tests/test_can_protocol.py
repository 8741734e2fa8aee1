"""CAN frame layouts: lpc's own and the RoboLimb profile, byte for byte."""

from __future__ import annotations

import pytest

from lpc_core.devices.can_protocol import (
    COMMAND_ID,
    EMG_IDS,
    STATUS_ID,
    Frame,
    FrameError,
    decode_command,
    decode_emg,
    decode_robolimb_digit,
    decode_robolimb_feedback,
    decode_status,
    encode_command,
    encode_robolimb_digit,
    encode_robolimb_feedback,
    encode_robolimb_grasp,
    encode_robolimb_quick_grip,
    encode_status,
    robolimb_velocity,
)
from lpc_core.devices.hand import HandCommand, HandStatus


def test_command_layout_is_big_endian_int16_counter_and_enable() -> None:
    frame = encode_command(HandCommand(grasp=1.0, wrist=-0.5), counter=258)
    assert frame.arbitration_id == COMMAND_ID == 0x210
    assert frame.data == bytes([0x7F, 0xFF, 0xC0, 0x00, 0x02, 0x01, 0, 0])  # -16384


def test_command_round_trips_within_one_count() -> None:
    command = HandCommand(grasp=0.123, wrist=-0.987)
    decoded, counter = decode_command(encode_command(command, counter=7))
    assert counter == 7
    assert decoded.grasp == pytest.approx(0.123, abs=1 / 32767)
    assert decoded.wrist == pytest.approx(-0.987, abs=1 / 32767)


def test_command_without_enable_decodes_as_stop() -> None:
    frame = encode_command(HandCommand(grasp=0.8), counter=0, enable=False)
    assert decode_command(frame)[0] == HandCommand()


def test_command_decode_rejects_wrong_id_length_and_range() -> None:
    good = encode_command(HandCommand(grasp=0.5), counter=0)
    with pytest.raises(FrameError, match="expected 0x210"):
        decode_command(Frame(0x211, good.data))
    with pytest.raises(FrameError, match="8 bytes"):
        decode_command(Frame(COMMAND_ID, good.data[:6]))
    with pytest.raises(FrameError, match="out of range"):
        decode_command(Frame(COMMAND_ID, bytes([0x80, 0x00, 0, 0, 0, 1, 0, 0])))


def test_status_layout_and_round_trip() -> None:
    status = HandStatus(
        wrist_angle_deg=-12.34, aperture_mm=75.5, grip_force_pct=42, moving=True, counter=9
    )
    frames = encode_status(status)
    assert [f.arbitration_id for f in frames] == [STATUS_ID]
    assert frames[0].data == bytes([0xFB, 0x2E, 0x1D, 0x7E, 42, 9, 0x01, 0])
    assert decode_status(frames[0]) == status


def test_status_clips_to_the_field_ranges() -> None:
    frames = encode_status(HandStatus(wrist_angle_deg=500.0, aperture_mm=-3.0, grip_force_pct=120))
    decoded = decode_status(frames[0])
    assert decoded.wrist_angle_deg == 327.67
    assert decoded.aperture_mm == 0.0 and decoded.grip_force_pct == 100.0


def test_status_with_emg_adds_emg_frames() -> None:
    status = HandStatus(wrist_angle_deg=0.0, aperture_mm=50.0, emg=(1, 2, 856, 4, 5))
    frames = encode_status(status)
    assert [f.arbitration_id for f in frames] == [*EMG_IDS, STATUS_ID]  # STATUS closes a cycle
    assert decode_emg(frames[0]) == (0, (1, 2, 856, 4))
    assert decode_emg(frames[1]) == (4, (5, 0, 0, 0))


def test_frame_rejects_extended_ids_and_long_data() -> None:
    with pytest.raises(ValueError, match="arbitration_id"):
        Frame(0x800, b"")
    with pytest.raises(ValueError, match="data"):
        Frame(0x100, bytes(9))


def test_robolimb_digit_command_layout() -> None:
    frame = encode_robolimb_digit(2, 1, 297)
    assert frame.arbitration_id == 0x102
    assert frame.data == bytes([0, 1, 0x01, 0x29])
    assert decode_robolimb_digit(frame) == (2, 1, 297)


def test_robolimb_velocity_maps_speed_to_10_297() -> None:
    assert robolimb_velocity(0.0) == 10
    assert robolimb_velocity(1.0) == 297
    with pytest.raises(ValueError, match="speed"):
        robolimb_velocity(1.2)


def test_robolimb_grasp_commands_five_fingers() -> None:
    frames = encode_robolimb_grasp(HandCommand(grasp=-1.0))
    assert [f.arbitration_id for f in frames] == [0x101, 0x102, 0x103, 0x104, 0x105]
    assert all(decode_robolimb_digit(f)[1:] == (2, 297) for f in frames)
    stops = encode_robolimb_grasp(HandCommand(grasp=0.01))
    assert all(decode_robolimb_digit(f)[1] == 0 for f in stops)


def test_robolimb_rejects_bad_digit_action_velocity() -> None:
    with pytest.raises(ValueError, match="digit"):
        encode_robolimb_digit(7, 1, 100)
    with pytest.raises(ValueError, match="action"):
        encode_robolimb_digit(1, 3, 100)
    with pytest.raises(ValueError, match="velocity"):
        encode_robolimb_digit(1, 1, 5)
    with pytest.raises(FrameError):
        decode_robolimb_digit(Frame(0x101, bytes([0, 1, 0, 5])))


def test_robolimb_quick_grip_and_feedback() -> None:
    assert encode_robolimb_quick_grip(3) == Frame(0x301, bytes([0, 3]))
    frame = encode_robolimb_feedback(1, 3, 1.0)
    assert frame.arbitration_id == 0x201
    digit, status, current = decode_robolimb_feedback(frame)
    assert (digit, status) == (1, 3)
    assert current == pytest.approx(1.0, abs=1 / 21.825)
