"""CAN frame layouts for the hand: lpc's own, and the Touch Bionics RoboLimb profile.

Pure encode/decode between frames (``Frame``: 11-bit identifier and up to 8 data bytes) and
hand commands/status. The drivers turn frames into python-can messages.

lpc layout (classic CAN, 11-bit identifiers, 1 Mbit/s, integers big-endian)
---------------------------------------------------------------------------

``0x210`` COMMAND, controller -> hand, DLC 8, sent at 100 Hz::

    bytes 0-1  int16   grasp velocity, 1/32767 of full speed, > 0 closes
    bytes 2-3  int16   wrist velocity, 1/32767 of full speed, > 0 toward positive angle
    byte  4    uint8   rolling counter (a repeated counter means a stuck sender)
    byte  5    uint8   flags: bit 0 = enable (0 = stop regardless of velocities)
    bytes 6-7          reserved, 0

``0x220`` STATUS, hand -> controller, DLC 8, 100 Hz::

    bytes 0-1  int16   wrist angle, 0.01 degree
    bytes 2-3  uint16  palmar aperture, 0.01 mm
    byte  4    uint8   grip force, percent (0-100)
    byte  5    uint8   rolling counter
    byte  6    uint8   flags: bit 0 moving, bit 1 fault, bit 2 stopped by the hand's watchdog
    byte  7            reserved, 0

``0x221``, ``0x222`` EMG, hand -> controller, DLC 8, just before each STATUS when the hand has
electrodes: four uint16 raw envelopes each, channels 0-3 then 4-7 (a Michelangelo-style
socket reports eight channels, 0-856). STATUS closes a cycle, so a receiver pairs it with the
EMG frames that preceded it.

RoboLimb profile (public facts, as the Touch Bionics manual and open drivers use them)
-------------------------------------------------------------------------------------

- Command ``0x100 + digit`` (1 thumb, 2 index, 3 middle, 4 ring, 5 little, 6 thumb
  rotator), DLC 4: ``[0, action, velocity hi, velocity lo]``, action 0 stop, 1 close, 2 open,
  velocity 10-297.
- Quick grip ``0x301``, DLC 2: ``[0, grip]`` (grip 0 = normal; check the layout against the
  hand's manual before use on a real hand).
- Feedback ``0x200 + digit``, DLC 4: ``[0, status, current hi, current lo]``, status 0 stop,
  1 closing, 2 opening, 3 stalled closed, 4 stalled open; current in amperes = raw / 21.825.
  The hand reports no aperture and has no powered wrist.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from lpc_core.devices.hand import HandCommand, HandStatus

COMMAND_ID = 0x210
STATUS_ID = 0x220
EMG_IDS = (0x221, 0x222)
FULL_SCALE = 32767

_COMMAND = struct.Struct(">hhBB2x")
_STATUS = struct.Struct(">hHBBBx")
_EMG = struct.Struct(">4H")

FLAG_ENABLE = 0x01
FLAG_MOVING, FLAG_FAULT, FLAG_WATCHDOG = 0x01, 0x02, 0x04


class FrameError(ValueError):
    """A frame that does not match its layout; the message says what is wrong."""


@dataclass(frozen=True)
class Frame:
    """One classic CAN frame."""

    arbitration_id: int
    data: bytes

    def __post_init__(self) -> None:
        if not 0 <= self.arbitration_id <= 0x7FF:
            raise ValueError(
                f"arbitration_id must be an 11-bit identifier, got {self.arbitration_id:#x}"
            )
        if len(self.data) > 8:
            raise ValueError(f"data must be at most 8 bytes, got {len(self.data)}")


def _velocity_to_int(v: float, name: str) -> int:
    if not (math.isfinite(v) and -1.0 <= v <= 1.0):
        raise ValueError(f"{name} must be in [-1, 1], got {v}")
    return round(v * FULL_SCALE)


# --------------------------------------------------------------------------- lpc layout


def encode_command(command: HandCommand, counter: int, enable: bool = True) -> Frame:
    data = _COMMAND.pack(
        _velocity_to_int(command.grasp, "grasp"),
        _velocity_to_int(command.wrist, "wrist"),
        counter & 0xFF,
        FLAG_ENABLE if enable else 0,
    )
    return Frame(COMMAND_ID, data)


def decode_command(frame: Frame) -> tuple[HandCommand, int]:
    """(command, counter); a frame without the enable flag decodes as zero velocity."""
    _expect(frame, COMMAND_ID, _COMMAND.size)
    grasp, wrist, counter, flags = _COMMAND.unpack(frame.data)
    if abs(grasp) > FULL_SCALE or abs(wrist) > FULL_SCALE:
        raise FrameError(f"velocity out of range in {frame.data.hex()}")
    if not flags & FLAG_ENABLE:
        return HandCommand(), counter
    return HandCommand(grasp=grasp / FULL_SCALE, wrist=wrist / FULL_SCALE), counter


def encode_status(status: HandStatus) -> list[Frame]:
    """The EMG frames when the status carries EMG, then the STATUS frame that closes the cycle."""
    flags = (
        (FLAG_MOVING if status.moving else 0)
        | (FLAG_FAULT if status.fault else 0)
        | (FLAG_WATCHDOG if status.watchdog else 0)
    )
    frames: list[Frame] = []
    if status.emg:
        if len(status.emg) > 4 * len(EMG_IDS):
            raise ValueError(f"emg carries at most {4 * len(EMG_IDS)} channels")
        channels = [_clip_int(x, 0, 65535) for x in status.emg]
        channels += [0] * (-len(channels) % 4)
        for i in range(len(channels) // 4):
            frames.append(Frame(EMG_IDS[i], _EMG.pack(*channels[4 * i : 4 * i + 4])))
    frames.append(
        Frame(
            STATUS_ID,
            _STATUS.pack(
                _clip_int(status.wrist_angle_deg * 100, -32768, 32767),
                _clip_int(status.aperture_mm * 100, 0, 65535),
                _clip_int(status.grip_force_pct, 0, 100),
                status.counter & 0xFF,
                flags,
            ),
        )
    )
    return frames


def decode_status(frame: Frame) -> HandStatus:
    _expect(frame, STATUS_ID, _STATUS.size)
    wrist, aperture, force, counter, flags = _STATUS.unpack(frame.data)
    if force > 100:
        raise FrameError(f"grip force {force} % out of range")
    return HandStatus(
        wrist_angle_deg=wrist / 100.0,
        aperture_mm=aperture / 100.0,
        grip_force_pct=float(force),
        moving=bool(flags & FLAG_MOVING),
        fault=bool(flags & FLAG_FAULT),
        watchdog=bool(flags & FLAG_WATCHDOG),
        counter=counter,
    )


def decode_emg(frame: Frame) -> tuple[int, tuple[int, ...]]:
    """(first channel index, four raw values) from an EMG frame."""
    if frame.arbitration_id not in EMG_IDS:
        raise FrameError(f"id {frame.arbitration_id:#x} is not an EMG frame")
    if len(frame.data) != _EMG.size:
        raise FrameError(f"EMG frame needs {_EMG.size} bytes, got {len(frame.data)}")
    return 4 * EMG_IDS.index(frame.arbitration_id), _EMG.unpack(frame.data)


def _expect(frame: Frame, arbitration_id: int, size: int) -> None:
    if frame.arbitration_id != arbitration_id:
        raise FrameError(f"id {frame.arbitration_id:#x}, expected {arbitration_id:#x}")
    if len(frame.data) != size:
        raise FrameError(f"frame {arbitration_id:#x} needs {size} bytes, got {len(frame.data)}")


def _clip_int(x: float, lo: int, hi: int) -> int:
    if not math.isfinite(x):
        raise ValueError(f"non-finite value {x}")
    return int(min(max(round(x), lo), hi))


# --------------------------------------------------------------------------- RoboLimb

ROBOLIMB_COMMAND_BASE = 0x100
ROBOLIMB_FEEDBACK_BASE = 0x200
ROBOLIMB_QUICK_GRIP_ID = 0x301
ROBOLIMB_FINGERS = (1, 2, 3, 4, 5)  # thumb .. little: what "grasp" closes
ROBOLIMB_THUMB_ROTATOR = 6
ROBOLIMB_VELOCITY = (10, 297)
ROBOLIMB_AMPS_PER_UNIT = 1.0 / 21.825
STOP, CLOSE, OPEN = 0, 1, 2
ROBOLIMB_STATUS = ("stop", "closing", "opening", "stalled closed", "stalled open")


def robolimb_velocity(speed: float) -> int:
    """|speed| in (0, 1] of full speed to the hand's 10-297 velocity units."""
    if not (math.isfinite(speed) and 0.0 <= speed <= 1.0):
        raise ValueError(f"speed must be in [0, 1], got {speed}")
    lo, hi = ROBOLIMB_VELOCITY
    return round(lo + speed * (hi - lo))


def encode_robolimb_digit(digit: int, action: int, velocity: int) -> Frame:
    if not 1 <= digit <= 6:
        raise ValueError(f"digit must be 1..6, got {digit}")
    if action not in (STOP, CLOSE, OPEN):
        raise ValueError(f"action must be 0 stop, 1 close or 2 open, got {action}")
    lo, hi = ROBOLIMB_VELOCITY
    if not lo <= velocity <= hi:
        raise ValueError(f"velocity must be {lo}..{hi}, got {velocity}")
    return Frame(ROBOLIMB_COMMAND_BASE + digit, bytes([0, action, velocity >> 8, velocity & 0xFF]))


def decode_robolimb_digit(frame: Frame) -> tuple[int, int, int]:
    """(digit, action, velocity) of a digit command."""
    digit = frame.arbitration_id - ROBOLIMB_COMMAND_BASE
    if not 1 <= digit <= 6 or len(frame.data) != 4:
        raise FrameError(
            f"not a RoboLimb digit command: {frame.arbitration_id:#x} {frame.data.hex()}"
        )
    action, velocity = frame.data[1], (frame.data[2] << 8) | frame.data[3]
    lo, hi = ROBOLIMB_VELOCITY
    if action not in (STOP, CLOSE, OPEN) or not lo <= velocity <= hi:
        raise FrameError(f"bad RoboLimb digit command {frame.data.hex()}")
    return digit, action, velocity


def encode_robolimb_grasp(command: HandCommand, deadband: float = 0.02) -> list[Frame]:
    """The five finger commands for a grasp velocity (the RoboLimb has no wrist rotator)."""
    speed = abs(command.grasp)
    if speed < deadband:
        return [encode_robolimb_digit(d, STOP, ROBOLIMB_VELOCITY[0]) for d in ROBOLIMB_FINGERS]
    action = CLOSE if command.grasp > 0 else OPEN
    velocity = robolimb_velocity(speed)
    return [encode_robolimb_digit(d, action, velocity) for d in ROBOLIMB_FINGERS]


def encode_robolimb_quick_grip(grip: int) -> Frame:
    if not 0 <= grip <= 0xFF:
        raise ValueError(f"grip must be 0..255, got {grip}")
    return Frame(ROBOLIMB_QUICK_GRIP_ID, bytes([0, grip]))


def encode_robolimb_feedback(digit: int, status: int, current_a: float) -> Frame:
    if not 1 <= digit <= 6:
        raise ValueError(f"digit must be 1..6, got {digit}")
    if not 0 <= status < len(ROBOLIMB_STATUS):
        raise ValueError(f"status must be 0..{len(ROBOLIMB_STATUS) - 1}, got {status}")
    raw = _clip_int(current_a / ROBOLIMB_AMPS_PER_UNIT, 0, 65535)
    return Frame(ROBOLIMB_FEEDBACK_BASE + digit, bytes([0, status, raw >> 8, raw & 0xFF]))


def decode_robolimb_feedback(frame: Frame) -> tuple[int, int, float]:
    """(digit, status, current in amperes)."""
    digit = frame.arbitration_id - ROBOLIMB_FEEDBACK_BASE
    if not 1 <= digit <= 6 or len(frame.data) < 4:
        raise FrameError(f"not RoboLimb feedback: {frame.arbitration_id:#x} {frame.data.hex()}")
    status = frame.data[1]
    if status >= len(ROBOLIMB_STATUS):
        raise FrameError(f"unknown RoboLimb status {status}")
    current = ((frame.data[2] << 8) | frame.data[3]) * ROBOLIMB_AMPS_PER_UNIT
    return digit, status, current
