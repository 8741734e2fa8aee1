"""The wire between a depth device and the camera service, pure: values in, bytes out; bytes in,
messages out. The simulated camera device (``lpc sim-camera``) writes it on a Unix stream socket
and ``services.drivers.depth.SimDeviceSource`` reads it.

Every message is one record::

    b"LPCD"  length (uint32, little-endian)  body[length]

``body`` is msgpack: a ``DeviceHello`` first on every connection (the intrinsics, once), then
one ``DeviceFrame`` per finished frame (depth, its capture time and the scene's truth). The
magic lets a reader find the next record after bytes that are not one (a corrupted or foreign
writer): ``LinkParser`` skips them and reports each run of them as one ``Rejected``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Annotated

import msgspec
from msgspec import Meta, Struct

from schemas import CameraIntrinsics, NDArray, ObjectTruth

MAGIC = b"LPCD"
_HEADER = struct.Struct("<4sI")
HEADER_BYTES = _HEADER.size
# A hello, or a frame of at most 4096 x 4096 uint16 (the intrinsics' limit) and its fields.
MAX_BODY_BYTES = 4096 * 4096 * 2 + 65536


class DeviceHello(Struct, frozen=True, kw_only=True, tag="hello"):
    """First on each connection: what every following frame is."""

    intrinsics: CameraIntrinsics
    rate_hz: Annotated[float, Meta(gt=0)]
    detail: str = ""  # the device's settings, for the camera's health


class DeviceFrame(Struct, frozen=True, kw_only=True, tag="frame"):
    """One finished frame: ``seq`` counts the device's frames, ``t_ns`` is when it was
    complete (wall clock of the host, nanoseconds)."""

    seq: Annotated[int, Meta(ge=0)]
    t_ns: int
    depth: NDArray
    truth: ObjectTruth | None = None


DeviceMessage = DeviceHello | DeviceFrame

_ENCODER = msgspec.msgpack.Encoder()
_DECODER = msgspec.msgpack.Decoder(DeviceMessage)


@dataclass(frozen=True)
class Rejected:
    """Bytes the parser skipped: ``nbytes`` of them, and why."""

    nbytes: int
    reason: str


def encode(message: DeviceMessage) -> bytes:
    """One record: header and body."""
    body = _ENCODER.encode(message)
    return _HEADER.pack(MAGIC, len(body)) + body


class LinkParser:
    """Records from a byte stream fed in pieces of any size.

    ``feed`` returns the messages completed by the piece, in order, with a ``Rejected`` for a
    record that does not decode (its body is skipped) and for each run of bytes before the
    next magic. ``max_body`` bounds a record (a larger length is taken for garbage).
    """

    def __init__(self, max_body: int = MAX_BODY_BYTES) -> None:
        self.max_body = max_body
        self._buffer = bytearray()
        self._skipped = 0  # garbage bytes dropped since the last record
        self._why = ""
        self.viewing = False  # whether messages of the last ``feed`` view its ``data``

    @property
    def pending(self) -> int:
        """Bytes held for a record not yet complete (a truncated record, at the end)."""
        return len(self._buffer)

    def feed(
        self, data: bytes | memoryview, *, handed_over: bool = False
    ) -> list[DeviceMessage | Rejected]:
        """``handed_over``: nothing writes ``data`` after this call (as nothing writes
        ``bytes``), so a frame decoded from it may view it; ``viewing`` then says whether one
        does, and a caller that reuses its receive buffer takes a new one if so."""
        out: list[DeviceMessage | Rejected] = []
        self.viewing = False
        if not self._buffer and not self._skipped:
            # Nothing held: the whole records at the piece's start are decoded where they lie
            # (a 200 KB frame usually arrives in one piece), and only what follows them is
            # kept. Copying each frame into the buffer first cost a memcpy of the frame.
            data = self._whole_records(data, out, handed_over or isinstance(data, bytes))
        self._buffer += data
        buffer = self._buffer
        while True:
            start = buffer.find(MAGIC)
            if start != 0:
                # No record here: drop up to the next magic, or all but a magic's partial head.
                drop = start if start > 0 else max(0, len(buffer) - len(MAGIC) + 1)
                if drop:
                    self._skip(buffer, drop, "bytes that are not a record")
                if start < 0:
                    break
            if len(buffer) < HEADER_BYTES:
                break
            _, length = _HEADER.unpack_from(buffer)
            if length > self.max_body:
                self._skip(
                    buffer, len(MAGIC), f"a record of {length} bytes (at most {self.max_body})"
                )
                continue
            if len(buffer) < HEADER_BYTES + length:
                break
            if self._skipped:
                out.append(Rejected(self._skipped, self._why))
                self._skipped = 0
            # Copied once out of the buffer, which shrinks and refills: the decoded depth views
            # these bytes (NDArray) instead of being copied out by msgspec.
            try:
                with memoryview(buffer) as view, view[HEADER_BYTES : HEADER_BYTES + length] as body:
                    out.append(_DECODER.decode(bytes(body)))
            except (msgspec.DecodeError, msgspec.ValidationError) as exc:
                out.append(Rejected(HEADER_BYTES + length, f"a record that does not decode: {exc}"))
            del buffer[: HEADER_BYTES + length]
        return out

    def _whole_records(
        self, data: bytes | memoryview, out: list[DeviceMessage | Rejected], kept: bool
    ) -> bytes | memoryview:
        """The complete, well-formed records at the start of ``data`` decoded into ``out``, as
        ``feed``'s loop does them; the rest of ``data`` (from the first byte that is not such a
        record) returned for that loop. ``kept``: nothing writes ``data`` again, so the frames
        view it (NDArray) instead of a copy of each record (200 KB, 6 us a frame here)."""
        with memoryview(data) as view:
            start, size = 0, len(view)
            while size - start >= HEADER_BYTES:
                magic, length = _HEADER.unpack_from(view, start)
                end = start + HEADER_BYTES + length
                if magic != MAGIC or length > self.max_body or end > size:
                    break
                try:
                    with view[start + HEADER_BYTES : end] as body:
                        # Else copied: ``data`` may be a receive buffer refilled after this.
                        out.append(_DECODER.decode(body if kept else bytes(body)))
                        self.viewing = kept
                except (msgspec.DecodeError, msgspec.ValidationError) as exc:
                    out.append(Rejected(end - start, f"a record that does not decode: {exc}"))
                start = end
        return data[start:] if start else data

    def flush(self) -> Rejected | None:
        """At the end of the stream: what was skipped or left incomplete, as one rejection."""
        nbytes = self._skipped + len(self._buffer)
        why = "a truncated record" if self._buffer else self._why
        self._buffer.clear()
        self._skipped = 0
        return Rejected(nbytes, why) if nbytes else None

    def _skip(self, buffer: bytearray, count: int, why: str) -> None:
        del buffer[:count]
        if not self._skipped:
            self._why = why
        self._skipped += count
