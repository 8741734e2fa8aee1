"""The PSYONIC Ability Hand's serial protocol (UART/RS485, 460800 baud), pure: no I/O, no clock.

From the vendor's public interface control document (ICD, "Extended Mode API Interface") and
its Python package ``ability-hand`` (``ah_wrapper``), against which ``tests/
test_ability_conformance.py`` checks these frames byte for byte.

Host to hand (one frame, then PPP stuffing)::

    address  header  payload  checksum

- ``address``: the hand's slave address, 0x50 by default.
- ``header``: the control mode plus the reply variant wanted (0, 1, 2 for variants 1, 2, 3):
  0x10 position, 0x20 velocity, 0x30 torque, 0x40 voltage, 0xA0 read only (no control).
  Miscellaneous commands are a header alone.
- ``payload`` for a control mode: six little-endian int16, one per joint in the order index,
  middle, ring, pinky, thumb flexor, thumb rotator. Position: ``degrees * 32767 / 150``,
  clamped to ±32767 and truncated toward zero; velocity: ``degrees/s * 32767 / 3000``. The
  thumb rotator's sign is reversed (negative angles rotate it away from fully extended).
- The grip command (the "standard" interface, header 0x1D) carries a grip index and a speed
  byte instead (``Grip``).
- ``checksum``: the two's-complement negation of the 8-bit sum of every preceding byte, so
  that all bytes of a sound frame sum to 0 modulo 256.

Hand to host (reply variant ``v`` chosen by the header's low nibble; no address byte)::

    header  (position, current)  x6            touch (45 bytes)  hot/cold  checksum   v1: 72
    header  (position, rotor velocity) x6      touch (45 bytes)  hot/cold  checksum   v2: 72
    header  (position, current) x6  rotor velocity x6            hot/cold  checksum   v3: 39

Positions as above; currents in counts of ``CURRENT_COUNTS_PER_A`` (the ICD's C, which depends
on the hardware version: the vendor package's 620.606079 is used); rotor velocities in
``rad/s * 4`` (the ICD; the vendor's parser scales them by ``3000 / 32767 / 4`` instead, and
the conformance test compares raw counts); touch: 30 unsigned 12-bit values packed
little-endian two per three bytes (six sites per finger, index first); hot/cold: a bit per
joint whose motion the hand's thermal protection is limiting.

PPP (HDLC) byte stuffing, which the hand does when its toggles 46 and 47 are on: a frame is
enclosed in 0x7E, and a 0x7E or 0x7D inside it is sent as 0x7D followed by the byte XOR 0x20.

``FrameParser`` takes bytes as they come off the line and gives the unstuffed frames, and a
``FrameError`` (counted by the caller) for anything that is not one: a bad escape, an overlong
run with no frame character (an unstuffed stream), a wrong length or checksum.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

ADDRESS = 0x50
BAUDRATE = 460_800
JOINTS = ("index", "middle", "ring", "pinky", "thumb_flexor", "thumb_rotator")
N_JOINTS = len(JOINTS)
N_TOUCH = 30

POSITION_COUNTS_PER_DEG = 32767 / 150
VELOCITY_COUNTS_PER_DEG_S = 32767 / 3000
CURRENT_COUNTS_PER_A = 620.606079
ROTOR_COUNTS_PER_RAD_S = 4.0
LIMIT = 32767
# Touch force from a 12-bit reading (ICD 3.4.6): V = D * 3.3 / 4096, R = 33000 / V + 10000,
# F = C1 / R + C2 newtons (the vendor's placeholder calibration).
TOUCH_C1, TOUCH_C2 = 121591.0, 0.878894
GEAR_RATIO = (649.0, 649.0, 649.0, 649.0, 649.0, 162.45)

FRAME_CHAR, ESC_CHAR, ESC_MASK = 0x7E, 0x7D, 0x20
MAX_FRAME = 512  # the vendor's unstuffing buffer; longer runs are not frames


class Mode(enum.IntEnum):
    """Format-header bases; add the reply variant index (0, 1, 2)."""

    POSITION = 0x10
    VELOCITY = 0x20
    TORQUE = 0x30
    VOLTAGE = 0x40
    READ_ONLY = 0xA0


GRIP_HEADER = 0x1D


class Grip(enum.IntEnum):
    """Grip indices of the grip command (ICD 2.2, "Grip Commands"); 0x13-0x1F are user slots."""

    OPEN = 0x00
    POWER = 0x01
    KEY = 0x02  # lateral
    PINCH = 0x03
    TRIPOD_OPEN = 0x04
    HORNS = 0x05
    CYLINDER = 0x06
    MOUSE = 0x07
    POWER_KEY_SWITCH = 0x08
    POINT = 0x09
    RUDE_POINT = 0x0A
    HOOK = 0x0B
    RELAX = 0x0C
    SLEEVE = 0x0D
    PEACE = 0x0E
    TRIPOD_CLOSED = 0x0F
    HANG_LOOSE = 0x10
    HANDSHAKE = 0x11
    FIXED_PINCH = 0x12
    TRIGGER = 0x18
    FINGER_WAVE = 0x20


# Reply variant index -> (frame length with header and checksum, second int16 of each pair).
REPLY_LENGTHS = {0: 72, 1: 72, 2: 39}


class FrameError(ValueError):
    """Bytes that are not a frame; ``kind`` names the fault for the caller's counters."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


# --------------------------------------------------------------------------- framing


def checksum(body: bytes | Sequence[int]) -> int:
    """The byte that makes the frame's 8-bit sum zero."""
    return -sum(body) & 0xFF


def stuff(body: bytes) -> bytes:
    """PPP-stuff one frame: escape 0x7E and 0x7D, enclose in 0x7E."""
    out = bytearray([FRAME_CHAR])
    for b in body:
        if b in (FRAME_CHAR, ESC_CHAR):
            out += bytes((ESC_CHAR, b ^ ESC_MASK))
        else:
            out.append(b)
    out.append(FRAME_CHAR)
    return bytes(out)


def _int16s(values: Sequence[float] | np.ndarray, scale: float, name: str) -> bytes:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (N_JOINTS,):
        raise ValueError(f"{name} must hold {N_JOINTS} values, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    counts = np.trunc(np.clip(arr * scale, -LIMIT, LIMIT)).astype("<i2")
    return counts.tobytes()


def _command(header: int, payload: bytes, address: int) -> bytes:
    if not 0 <= address <= 0xFF:
        raise ValueError(f"address must be a byte, got {address}")
    body = bytes((address, header)) + payload
    return stuff(body + bytes((checksum(body),)))


def _header(mode: Mode, reply_variant: int) -> int:
    if reply_variant not in REPLY_LENGTHS:
        raise ValueError(f"reply_variant must be 0, 1 or 2, got {reply_variant}")
    return int(mode) + reply_variant


def position_frame(
    positions_deg: Sequence[float] | np.ndarray, reply_variant: int = 0, address: int = ADDRESS
) -> bytes:
    """Six joint positions (degrees, thumb rotator negative), stuffed."""
    payload = _int16s(positions_deg, POSITION_COUNTS_PER_DEG, "positions_deg")
    return _command(_header(Mode.POSITION, reply_variant), payload, address)


def velocity_frame(
    velocities_deg_s: Sequence[float] | np.ndarray,
    reply_variant: int = 0,
    address: int = ADDRESS,
) -> bytes:
    """Six joint velocities (degrees per second), stuffed."""
    payload = _int16s(velocities_deg_s, VELOCITY_COUNTS_PER_DEG_S, "velocities_deg_s")
    return _command(_header(Mode.VELOCITY, reply_variant), payload, address)


def read_only_frame(reply_variant: int = 0, address: int = ADDRESS) -> bytes:
    """Ask for a reply without taking control (ICD 3.3.2)."""
    return _command(_header(Mode.READ_ONLY, reply_variant), b"", address)


def grip_frame(grip: int, speed: int = 0xFF, address: int = ADDRESS) -> bytes:
    """Select one of the hand's own grips (``Grip``) at ``speed`` 1-255."""
    if not 0 <= grip <= 0xFF or not 0 <= speed <= 0xFF:
        raise ValueError(f"grip and speed must be bytes, got {grip}, {speed}")
    return _command(GRIP_HEADER, bytes((grip, speed)), address)


# --------------------------------------------------------------------------- decoded frames


@dataclass(frozen=True)
class Command:
    """A host frame as the hand reads it: ``values`` are the six raw int16 (empty for a
    miscellaneous command; for a grip command, ``(grip, speed)``)."""

    address: int
    header: int
    values: tuple[int, ...] = ()

    @property
    def mode(self) -> int:
        return self.header & 0xF0

    @property
    def reply_variant(self) -> int | None:
        low = self.header & 0x0F
        return low if self.header != GRIP_HEADER and low in REPLY_LENGTHS else None

    @property
    def positions_deg(self) -> np.ndarray:
        return np.asarray(self.values, dtype=np.float64) * (150 / 32767)

    @property
    def velocities_deg_s(self) -> np.ndarray:
        return np.asarray(self.values, dtype=np.float64) * (3000 / 32767)


@dataclass(frozen=True)
class Reply:
    """A reply frame in raw counts; the properties give SI and the ICD's units."""

    header: int
    position: tuple[int, ...]
    current: tuple[int, ...] | None = None
    rotor_velocity: tuple[int, ...] | None = None
    touch: tuple[int, ...] | None = None
    hot_cold: int = 0

    @property
    def variant(self) -> int:
        return self.header & 0x0F

    @property
    def positions_deg(self) -> np.ndarray:
        return np.asarray(self.position, dtype=np.float64) * (150 / 32767)

    @property
    def currents_a(self) -> np.ndarray | None:
        if self.current is None:
            return None
        return np.asarray(self.current, dtype=np.float64) / CURRENT_COUNTS_PER_A

    @property
    def rotor_velocity_rad_s(self) -> np.ndarray | None:
        if self.rotor_velocity is None:
            return None
        return np.asarray(self.rotor_velocity, dtype=np.float64) / ROTOR_COUNTS_PER_RAD_S

    @property
    def touch_force_n(self) -> np.ndarray | None:
        if self.touch is None:
            return None
        d = np.asarray(self.touch, dtype=np.float64)
        with np.errstate(divide="ignore"):
            r = 33000.0 / (d * (3.3 / 4096.0)) + 10000.0
        return np.where(d > 0, TOUCH_C1 / r + TOUCH_C2, 0.0)


def pack_touch(values: Sequence[int]) -> bytes:
    """30 12-bit readings, two per three bytes, least significant bits first."""
    v = np.asarray(values, dtype=np.int64)
    if v.shape != (N_TOUCH,) or ((v < 0) | (v > 0xFFF)).any():
        raise ValueError(f"touch must hold {N_TOUCH} values in 0..4095")
    a, b = v[0::2], v[1::2]
    out = np.stack([a & 0xFF, (a >> 8) | ((b & 0x0F) << 4), b >> 4], axis=1)
    return out.astype(np.uint8).tobytes()


def unpack_touch(data: bytes) -> tuple[int, ...]:
    raw = np.frombuffer(data, dtype=np.uint8).reshape(-1, 3).astype(np.int64)
    a = raw[:, 0] | ((raw[:, 1] & 0x0F) << 8)
    b = (raw[:, 1] >> 4) | (raw[:, 2] << 4)
    return tuple(int(x) for x in np.stack([a, b], axis=1).reshape(-1))


def _pairs(data: bytes) -> tuple[tuple[int, ...], tuple[int, ...]]:
    values = struct.unpack(f"<{2 * N_JOINTS}h", data)
    return values[0::2], values[1::2]


def decode_reply(body: bytes) -> Reply:
    """One unstuffed reply frame (header .. checksum); ``FrameError`` if it is not one."""
    if len(body) < 2:
        raise FrameError("truncated", f"reply of {len(body)} bytes")
    variant = body[0] & 0x0F
    if variant not in REPLY_LENGTHS:
        raise FrameError("unknown", f"reply header {body[0]:#04x} names no reply variant")
    if len(body) != REPLY_LENGTHS[variant]:
        kind = "truncated" if len(body) < REPLY_LENGTHS[variant] else "length"
        need = REPLY_LENGTHS[variant]
        raise FrameError(kind, f"reply variant {variant + 1} needs {need} bytes, got {len(body)}")
    if sum(body) & 0xFF:
        raise FrameError("checksum", f"reply checksum fails (sum {sum(body) & 0xFF:#04x})")
    position, second = _pairs(body[1:25])
    if variant == 2:
        velocity = struct.unpack(f"<{N_JOINTS}h", body[25:37])
        return Reply(body[0], position, current=second, rotor_velocity=velocity, hot_cold=body[37])
    touch = unpack_touch(body[25:70])
    if variant == 0:
        return Reply(body[0], position, current=second, touch=touch, hot_cold=body[70])
    return Reply(body[0], position, rotor_velocity=second, touch=touch, hot_cold=body[70])


def encode_reply(reply: Reply) -> bytes:
    """A reply frame, stuffed (the simulated hand's side)."""
    variant = reply.variant
    if variant not in REPLY_LENGTHS:
        raise ValueError(f"header {reply.header:#04x} names no reply variant")
    second = reply.rotor_velocity if variant == 1 else reply.current
    if second is None or len(reply.position) != N_JOINTS or len(second) != N_JOINTS:
        raise ValueError(f"reply variant {variant + 1} needs six positions and six of its data")
    pairs = [x for pair in zip(reply.position, second, strict=True) for x in pair]
    body = bytes((reply.header,)) + struct.pack(f"<{2 * N_JOINTS}h", *pairs)
    if variant == 2:
        if reply.rotor_velocity is None:
            raise ValueError("reply variant 3 needs rotor velocities")
        body += struct.pack(f"<{N_JOINTS}h", *reply.rotor_velocity)
    else:
        body += pack_touch(reply.touch if reply.touch is not None else (0,) * N_TOUCH)
    body += bytes((reply.hot_cold & 0xFF,))
    return stuff(body + bytes((checksum(body),)))


def decode_command(body: bytes) -> Command:
    """One unstuffed host frame (address .. checksum); ``FrameError`` if it is not one."""
    if len(body) < 3:
        raise FrameError("truncated", f"command of {len(body)} bytes")
    if sum(body) & 0xFF:
        raise FrameError("checksum", f"command checksum fails (sum {sum(body) & 0xFF:#04x})")
    address, header, payload = body[0], body[1], body[2:-1]
    if header == GRIP_HEADER:
        if len(payload) != 2:
            raise FrameError("length", f"grip command needs 2 data bytes, got {len(payload)}")
        return Command(address, header, (payload[0], payload[1]))
    if header & 0xF0 in (Mode.POSITION, Mode.VELOCITY, Mode.TORQUE, Mode.VOLTAGE):
        if len(payload) != 2 * N_JOINTS:
            raise FrameError("length", f"control command needs 12 data bytes, got {len(payload)}")
        return Command(address, header, struct.unpack(f"<{N_JOINTS}h", payload))
    return Command(address, header)  # read only or miscellaneous: any payload is ignored


# --------------------------------------------------------------------------- unstuffing


class FrameParser:
    """Bytes off the line in, unstuffed frames (``bytes``) or ``FrameError`` out.

    A frame ends at a 0x7E that follows data; empty frames (back-to-back 0x7E) are skipped. An
    escape followed by anything but an escaped 0x7E or 0x7D, or more than ``MAX_FRAME`` bytes
    without a frame character (an unstuffed stream), is an error and the parser resynchronises
    on the next 0x7E. Frames are not checked here: ``decode_reply``/``decode_command`` do it.
    """

    def __init__(self, max_frame: int = MAX_FRAME) -> None:
        self.max_frame = max_frame
        self._buffer = bytearray()
        self._escape = False
        self._discard = False

    def feed(self, data: bytes) -> list[bytes | FrameError]:
        out: list[bytes | FrameError] = []
        for b in data:
            if b == FRAME_CHAR:
                if self._escape:
                    out.append(FrameError("escape", "frame ends right after an escape"))
                elif self._buffer and not self._discard:
                    out.append(bytes(self._buffer))
                self._buffer.clear()
                self._escape = self._discard = False
                continue
            if self._discard:
                continue
            if self._escape:
                self._escape = False
                if b ^ ESC_MASK not in (FRAME_CHAR, ESC_CHAR):
                    out.append(FrameError("escape", f"escape before {b:#04x}"))
                    self._discard = True
                    continue
                b ^= ESC_MASK
            elif b == ESC_CHAR:
                self._escape = True
                continue
            self._buffer.append(b)
            if len(self._buffer) > self.max_frame:
                out.append(
                    FrameError("unframed", f"{self.max_frame} bytes without a frame character")
                )
                self._buffer.clear()
                self._discard = True
        return out

    @property
    def pending(self) -> int:
        return len(self._buffer)
