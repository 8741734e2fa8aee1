"""The serial EMG amplifier's binary frame, pure: values in, bytes out; bytes in, frames out.

One frame per sample (100 Hz), 115200 baud 8N1, integers little-endian::

    offset  size  field
    0       2     sync 0xA5 0x5A
    2       2     seq, uint16, +1 per sample, wraps (a gap counts lost samples)
    4       1     n, number of channels, 1..8 (lpc reads channel 0 flexor, 1 extensor)
    5       1     flags: bit 0 electrode off, bit 1 saturated
    6       2n    envelopes, uint16, rectified and smoothed, in units of 0.1 µV (max 6.5535 mV)
    6+2n    2     CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) of bytes 2 .. 5+2n

A two-channel frame is 12 bytes: 1.2 kB/s at 100 Hz, a tenth of the line's capacity. The
parser resynchronises on the sync bytes after noise, a bad CRC or a truncated frame, and
counts each case.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass

SYNC = b"\xa5\x5a"
MAX_CHANNELS = 8
UNIT_V = 1e-7  # one count is 0.1 µV
FLAG_ELECTRODE_OFF, FLAG_SATURATED = 0x01, 0x02
_HEADER = struct.Struct("<HBB")


@dataclass(frozen=True)
class EmgFrame:
    seq: int
    channels: tuple[float, ...]  # volts
    flags: int = 0


def crc16(data: bytes) -> int:
    return binascii.crc_hqx(data, 0xFFFF)


def encode_frame(seq: int, channels_v: tuple[float, ...] | list[float], flags: int = 0) -> bytes:
    n = len(channels_v)
    if not 1 <= n <= MAX_CHANNELS:
        raise ValueError(f"channels_v needs 1..{MAX_CHANNELS} values, got {n}")
    counts = []
    for v in channels_v:
        if not v == v:  # NaN
            raise ValueError("channels_v contains NaN")
        counts.append(min(max(round(v / UNIT_V), 0), 0xFFFF))
    body = _HEADER.pack(seq & 0xFFFF, n, flags & 0xFF) + struct.pack(f"<{n}H", *counts)
    return SYNC + body + struct.pack("<H", crc16(body))


class FrameParser:
    """Feed bytes as they come; complete frames come out. Counters say what was thrown away."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._last_seq: int | None = None
        self.frames = 0
        self.bad_crc = 0
        self.bad_header = 0
        self.skipped_bytes = 0
        self.lost = 0

    def feed(self, data: bytes) -> list[EmgFrame]:
        self._buffer += data
        out: list[EmgFrame] = []
        buf = self._buffer
        while True:
            start = buf.find(SYNC)
            if start < 0:
                # Keep a trailing first sync byte: the second may be in the next read.
                keep = 1 if buf[-1:] == SYNC[:1] else 0
                self.skipped_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if start:
                self.skipped_bytes += start
                del buf[:start]
            if len(buf) < 2 + _HEADER.size:
                break
            seq, n, flags = _HEADER.unpack_from(buf, 2)
            if not 1 <= n <= MAX_CHANNELS:
                self.bad_header += 1
                del buf[:1]  # not a frame start after all: look for the next sync
                continue
            size = 2 + _HEADER.size + 2 * n + 2
            if len(buf) < size:
                break
            body = bytes(buf[2 : size - 2])
            (crc,) = struct.unpack_from("<H", buf, size - 2)
            if crc != crc16(body):
                self.bad_crc += 1
                del buf[:1]
                continue
            counts = struct.unpack_from(f"<{n}H", body, _HEADER.size)
            del buf[:size]
            if self._last_seq is not None:
                self.lost += (seq - self._last_seq - 1) & 0xFFFF
            self._last_seq = seq
            self.frames += 1
            out.append(EmgFrame(seq=seq, channels=tuple(c * UNIT_V for c in counts), flags=flags))
        return out
