"""Tactor wire protocols, pure: values in, bytes out; bytes in, events out (h11's way).

Nothing here opens a port or reads a clock. The drivers (``services.drivers.tactors``) write
what these functions build and feed what they read to the parsers below; the simulated
controller (``services.drivers.tactor_sim``) does the same from the other end.

EAI serial framing (the older EAI tactor controller, 115200 baud, 8N1)
======================================================================

Host to controller::

    0x02  board  command  length  data[length]  checksum  0x03

Controller to host (no board byte)::

    0x02  0xC8  length  command  extra[length - 1]  checksum  0x03     ACK
    0x02  0xC4  0x01    code                        checksum  0x03     NAK

``checksum`` is the XOR of every preceding byte of the frame, XORed with 0xEA. Board 0x00 is
the master board. Commands used here (bit ``k`` of a mask is tactor ``k``, tactor 0 first):

    0x00  all off              no data
    0x11  on-time              mask, duration / 10 ms
    0x12  sine frequency 1     Hz, 16 bits LSB first   (0x14: sine generator 2)
    0x15  signal source        a nibble per group of four tactors: 1 sine 1, 2 sine 2, 3 both
    0x20  gain                 level << 6, level 0..3 (one gain for every tactor)
    0x42  firmware version     no data; the ACK carries the version bytes
    0x80  set tactors          mask: the tactors that vibrate from now on

NAK codes: 1 end byte not where expected, 2 bad checksum, 3 insufficient data, 4 unknown
command, 5 invalid data for a valid command, 6 data longer than the maximum payload.

The old controller has one gain for all tactors, so a per-tactor amplitude becomes a mask (the
tactors within ``mask_ratio`` of the strongest) and the strongest level quantised to gains 1..3.
Gain 0 is never sent for an active output (EAI's own library rejects it).

Line protocol for DIY boards (any baud rate; 115200 by default)
================================================================

ASCII lines ending in ``\\n`` (a board should also accept ``\\r\\n``). Host to board::

    T a0 a1 a2 a3      PWM duty of tactors 0..3, decimal integers 0..255 (0 = off)

The board answers every line with ``OK`` or ``ERR <reason>``. ``T 0 0 0 0`` is all off; the
host sends it at start-up (the first ``OK`` is the handshake) and on shutdown. The host repeats
the current line at least every 200 ms, so a board should switch everything off when no line
has arrived for 500 ms (the same fail-safe as a hand that leaves API mode without commands).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

N_TACTORS = 4

START = 0x02
END = 0x03
CHECKSUM_KEY = 0xEA
MASTER_BOARD = 0x00
ACK = 0xC8
NAK = 0xC4
MAX_PAYLOAD = 32


class Command(enum.IntEnum):
    ALL_OFF = 0x00
    ON_TIME = 0x11
    SINE_FREQUENCY_1 = 0x12
    SINE_FREQUENCY_2 = 0x14
    SIGNAL_SOURCE = 0x15
    GAIN = 0x20
    FIRMWARE_VERSION = 0x42
    SET_TACTORS = 0x80


class NakCode(enum.IntEnum):
    END_MISSING = 1
    BAD_CHECKSUM = 2
    INSUFFICIENT_DATA = 3
    INVALID_COMMAND = 4
    INVALID_DATA = 5
    PAYLOAD_TOO_LONG = 6


# --------------------------------------------------------------------------- outputs


@dataclass(frozen=True)
class TactorOutput:
    """What the tactors should do now: a drive level 0..1 per tactor (after the user's gain
    limits) and the vibration frequency. All levels zero is all off."""

    levels: tuple[float, ...]
    frequency_hz: float = 250.0

    def __post_init__(self) -> None:
        if len(self.levels) != N_TACTORS:
            raise ValueError(f"levels must hold {N_TACTORS} values, got {len(self.levels)}")
        if not all(0.0 <= x <= 1.0 for x in self.levels):
            raise ValueError(f"levels must lie in [0, 1], got {self.levels}")
        if not 0.0 < self.frequency_hz <= 65535.0:
            raise ValueError(f"frequency_hz must lie in (0, 65535], got {self.frequency_hz}")

    @property
    def is_off(self) -> bool:
        return not any(self.levels)


OFF = TactorOutput((0.0,) * N_TACTORS)


# --------------------------------------------------------------------------- EAI frames


def checksum(body: bytes) -> int:
    """XOR of ``body`` (every byte before the checksum), XORed with 0xEA."""
    value = CHECKSUM_KEY
    for byte in body:
        value ^= byte
    return value


def frame(command: int, data: bytes = b"", board: int = MASTER_BOARD) -> bytes:
    """One host-to-controller frame."""
    if not 0 <= command <= 0xFF:
        raise ValueError(f"command must be a byte, got {command}")
    if not 0 <= board <= 0xFF:
        raise ValueError(f"board must be a byte, got {board}")
    if len(data) > MAX_PAYLOAD:
        raise ValueError(f"data must be at most {MAX_PAYLOAD} bytes, got {len(data)}")
    body = bytes((START, board, command, len(data))) + data
    return body + bytes((checksum(body), END))


def _mask(mask: int) -> int:
    if not 0 <= mask <= 0xFF:
        raise ValueError(f"mask must be a byte, got {mask}")
    return mask


def all_off() -> bytes:
    return frame(Command.ALL_OFF)


def on_time(mask: int, duration_ms: int) -> bytes:
    """Vibrate the tactors of ``mask`` for ``duration_ms`` (10 ms steps, at most 2550 ms)."""
    if not 0 <= duration_ms <= 2550:
        raise ValueError(f"duration_ms must lie in [0, 2550], got {duration_ms}")
    return frame(Command.ON_TIME, bytes((_mask(mask), duration_ms // 10)))


def sine_frequency(generator: int, frequency_hz: int) -> bytes:
    if generator not in (1, 2):
        raise ValueError(f"generator must be 1 or 2, got {generator}")
    if not 0 <= frequency_hz <= 0xFFFF:
        raise ValueError(f"frequency_hz must fit 16 bits, got {frequency_hz}")
    command = Command.SINE_FREQUENCY_1 if generator == 1 else Command.SINE_FREQUENCY_2
    return frame(command, int(frequency_hz).to_bytes(2, "little"))


def signal_source(source: int = 1) -> bytes:
    """The same source for both groups of four tactors: 1 sine 1, 2 sine 2, 3 their sum."""
    if not 0 <= source <= 3:
        raise ValueError(f"source must lie in [0, 3], got {source}")
    return frame(Command.SIGNAL_SOURCE, bytes(((source << 4) | source,)))


def set_gain(level: int) -> bytes:
    if not 0 <= level <= 3:
        raise ValueError(f"level must lie in [0, 3], got {level}")
    return frame(Command.GAIN, bytes((level << 6,)))


def set_tactors(mask: int) -> bytes:
    return frame(Command.SET_TACTORS, bytes((_mask(mask),)))


def firmware_version() -> bytes:
    return frame(Command.FIRMWARE_VERSION)


def ack_frame(command: int, extra: bytes = b"") -> bytes:
    """The controller's ACK of ``command``, with the extra bytes some commands return."""
    data = bytes((command,)) + extra
    body = bytes((START, ACK, len(data))) + data
    return body + bytes((checksum(body), END))


def nak_frame(code: int) -> bytes:
    body = bytes((START, NAK, 1, code))
    return body + bytes((checksum(body), END))


# --------------------------------------------------------------------------- EAI parsing


@dataclass(frozen=True)
class EaiCommand:
    """A well-formed host-to-controller frame."""

    board: int
    command: int
    data: bytes


@dataclass(frozen=True)
class Reply:
    """A controller's answer: ``ok`` for ACK (``command`` says which) or NAK with ``code``.

    The line protocol's ``OK`` / ``ERR text`` map to the same type (``text`` set, no codes).
    """

    ok: bool
    command: int | None = None
    code: int | None = None
    data: bytes = b""
    text: str = ""


@dataclass(frozen=True)
class FrameError:
    """Bytes that did not make a frame; ``code`` is the NAK code a controller would answer."""

    code: NakCode
    raw: bytes


class EaiParser:
    """Incremental EAI frame parser. ``feed(bytes)`` returns the events completed so far.

    ``side="controller"`` parses what a host sends (frames with a board byte) into
    ``EaiCommand``; ``side="host"`` parses what a controller sends into ``Reply``. Bytes
    before a start byte are skipped; a frame with a wrong end byte, a bad checksum or an
    oversized length yields ``FrameError`` and parsing resumes after its start byte.
    """

    def __init__(self, side: str = "host") -> None:
        if side not in ("host", "controller"):
            raise ValueError(f"side must be 'host' or 'controller', got {side!r}")
        self._header = 4 if side == "controller" else 3  # bytes up to and including length
        self._side = side
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[EaiCommand | Reply | FrameError]:
        self._buffer += data
        events: list[EaiCommand | Reply | FrameError] = []
        buf = self._buffer
        while buf:
            start = buf.find(START)
            if start < 0:
                buf.clear()
                break
            del buf[:start]
            if len(buf) < self._header:
                break
            length = buf[self._header - 1]
            if length > MAX_PAYLOAD:
                events.append(FrameError(NakCode.PAYLOAD_TOO_LONG, bytes(buf[: self._header])))
                del buf[:1]
                continue
            size = self._header + length + 2
            if len(buf) < size:
                break
            raw = bytes(buf[:size])
            if raw[-1] != END:
                events.append(FrameError(NakCode.END_MISSING, raw))
                del buf[:1]
                continue
            if checksum(raw[:-2]) != raw[-2]:
                events.append(FrameError(NakCode.BAD_CHECKSUM, raw))
                del buf[:size]
                continue
            del buf[:size]
            events.append(self._event(raw))
        return events

    def _event(self, raw: bytes) -> EaiCommand | Reply | FrameError:
        data = raw[self._header : -2]
        if self._side == "controller":
            return EaiCommand(board=raw[1], command=raw[2], data=data)
        if raw[1] == ACK and data:
            return Reply(ok=True, command=data[0], data=data[1:])
        if raw[1] == NAK and data:
            return Reply(ok=False, code=data[0], data=data[1:])
        return FrameError(NakCode.INVALID_COMMAND, raw)

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a frame."""
        return len(self._buffer)


# --------------------------------------------------------------------------- EAI outputs


@dataclass(frozen=True)
class EaiSettings:
    """What the old controller can hold: one gain (1..3), an active mask and a frequency."""

    gain: int
    mask: int
    frequency_hz: int


def eai_settings(output: TactorOutput, mask_ratio: float = 0.5) -> EaiSettings | None:
    """The controller settings closest to ``output``; ``None`` for all off.

    Tactors at least ``mask_ratio`` times the strongest level vibrate; the strongest level sets
    the gain, quantised up to 1..3 so that a weak cue is never silent.
    """
    if not 0.0 < mask_ratio <= 1.0:
        raise ValueError(f"mask_ratio must lie in (0, 1], got {mask_ratio}")
    levels = np.asarray(output.levels, dtype=float)
    strongest = float(levels.max())
    if strongest <= 0.0:
        return None
    on = levels >= mask_ratio * strongest - 1e-9
    mask = int(np.sum(np.where(on, 1 << np.arange(N_TACTORS), 0)))
    gain = min(3, max(1, math.ceil(strongest * 3 - 1e-9)))
    return EaiSettings(gain=gain, mask=mask, frequency_hz=round(output.frequency_hz))


def eai_initialisation(frequency_hz: int = 250) -> list[bytes]:
    """Frames that bring a controller to a known state: sine 1 on every tactor, all off."""
    return [signal_source(1), sine_frequency(1, frequency_hz), all_off()]


def eai_update(target: EaiSettings | None, current: EaiSettings | None) -> list[bytes]:
    """Frames that take the controller from ``current`` (``None``: unknown) to ``target``.

    The mask is always sent, so that a repeated output refreshes the controller; frequency and
    gain only when they change.
    """
    if target is None:
        return [all_off()]
    frames = []
    if current is None or current.frequency_hz != target.frequency_hz:
        frames.append(sine_frequency(1, target.frequency_hz))
    if current is None or current.gain != target.gain:
        frames.append(set_gain(target.gain))
    frames.append(set_tactors(target.mask))
    return frames


# --------------------------------------------------------------------------- line protocol


def line_duties(output: TactorOutput) -> tuple[int, ...]:
    """PWM duties 0..255; a level above zero never rounds down to off."""
    return tuple(0 if x <= 0.0 else max(1, round(x * 255)) for x in output.levels)


def line_command(output: TactorOutput) -> bytes:
    return ("T " + " ".join(str(d) for d in line_duties(output)) + "\n").encode("ascii")


def parse_line_command(line: bytes) -> tuple[int, ...] | str:
    """A board's view of one line (without its newline): the four duties, or the reason
    (for ``ERR``) it is not a valid command."""
    parts = line.strip().split()
    if not parts or parts[0] != b"T":
        return "unknown command"
    if len(parts) != 1 + N_TACTORS:
        return f"expected {N_TACTORS} duties"
    try:
        duties = tuple(int(p) for p in parts[1:])
    except ValueError:
        return "duties must be integers"
    if not all(0 <= d <= 255 for d in duties):
        return "duties must lie in 0..255"
    return duties


class LineParser:
    """Incremental parser of ``\\n``-terminated lines. ``side="host"`` turns ``OK`` / ``ERR``
    lines into ``Reply``; ``side="controller"`` returns the raw lines."""

    def __init__(self, side: str = "host", max_line: int = 256) -> None:
        if side not in ("host", "controller"):
            raise ValueError(f"side must be 'host' or 'controller', got {side!r}")
        self._side = side
        self._max_line = max_line
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[Reply | bytes]:
        self._buffer += data
        events: list[Reply | bytes] = []
        while True:
            end = self._buffer.find(b"\n")
            if end < 0:
                if len(self._buffer) > self._max_line:  # no newline in sight: drop the junk
                    self._buffer.clear()
                break
            line = bytes(self._buffer[:end]).rstrip(b"\r")
            del self._buffer[: end + 1]
            if self._side == "controller":
                events.append(line)
            elif line == b"OK":
                events.append(Reply(ok=True, text="OK"))
            elif line:
                text = line.decode("ascii", "replace")
                events.append(Reply(ok=False, text=text.removeprefix("ERR").strip()))
        return events
