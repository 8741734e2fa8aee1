"""MCAP logs of the bus: a writer that rotates by size, and a reader that survives a crash.

Conventions (DESIGN.md): one channel per concrete key, message encoding ``msgpack``, schema
encoding ``jsonschema`` (one schema per message type); ``log_time`` is the recorder's receive
time, ``publish_time`` the producer's ``t_ns``, MCAP's 32-bit ``sequence`` the low bits of
``seq``. A payload whose header does not decode goes, raw, to ``lpc/_rejected/<key>`` (no
schema, encoding ``application/octet-stream``) so that nothing is lost.

The writer is mcap's own (chunked, with indexes and a CRC of the summary; a zstd chunk's
integrity is zstd's own checksum, see ``_ChunkZstd``), so identical input gives a
byte-identical file. It writes straight to the file descriptor, without a user-space buffer:
when the process dies, everything up to the last finished chunk is on disk.

The reader walks the records itself instead of trusting the summary, so that a file cut short
(no footer, a half-written chunk, a chunk that fails its CRC) reads back up to its last good
chunk; ``McapLog.cut`` then says where and why, and the last good time.
"""

from __future__ import annotations

import heapq
import io
import itertools
import json
import os
import queue
import struct
import threading
import time
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import lz4.frame
import mcap.writer
import msgspec
import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError, UnsupportedCompressionError
from mcap.opcode import Opcode
from mcap.records import Channel, Message, MessageIndex, Schema
from mcap.writer import CompressionType, Writer

from schemas import BadMessage, encode, json_schema, topic_for_key
from schemas import decode as decode_message
from services.thread_names import RECORDER_WRITER, name_native_thread

Compression = Literal["none", "lz4", "zstd"]
COMPRESSIONS: dict[str, CompressionType] = {
    "none": CompressionType.NONE,
    "lz4": CompressionType.LZ4,
    "zstd": CompressionType.ZSTD,
}
# Chosen by measurement (``python -m services.cli.bench.recorder write``): see services/recorder.py.
DEFAULT_COMPRESSION: Compression = "zstd"
# zstd's own default is 3; level 1 costs about half the CPU for 15% more bytes (measured in
# services/recorder.py's docstring). Any level reads back with any zstd decoder.
DEFAULT_ZSTD_LEVEL = 1
ZSTD_LEVELS = range(-7, 23)  # the fast negative levels, then zstd's ordinary 1..22
DEFAULT_CHUNK_BYTES = 1024 * 1024
REJECTED_PREFIX = "lpc/_rejected/"
RAW_ENCODING = "application/octet-stream"
PROFILE = "lpc"

MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_CHUNK_TIMES = struct.Struct("<QQ")
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length
_MESSAGE_HEAD = struct.Struct("<HIQQ")
# A message record as mcap's Message.write lays it out: opcode, length, then the message head.
_MESSAGE_RECORD = struct.Struct("<BQHIQQ")


class McapLogError(Exception):
    """A file that cannot be read at all (missing, empty, not MCAP, unsupported)."""


# --------------------------------------------------------------------------- header


class _Header(msgspec.Struct):
    """The two fields every message starts with; decoding ignores the rest of the map."""

    seq: int
    t_ns: int


_HEADER_DECODER = msgspec.msgpack.Decoder(_Header)


def read_header(payload: bytes) -> tuple[int, int] | None:
    """``(seq, t_ns)`` of a bus payload without decoding its body; ``None`` if it has none."""
    try:
        header = _HEADER_DECODER.decode(payload)
    except (msgspec.DecodeError, msgspec.ValidationError):
        return None
    if not (0 <= header.seq < 2**63 and 0 <= header.t_ns < 2**63):
        return None
    return header.seq, header.t_ns


# --------------------------------------------------------------------------- writer


class _FileSink:
    """An unbuffered binary file that knows its size: what mcap's Writer writes to."""

    def __init__(self, path: Path) -> None:
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]
            self._position += n
        return len(data)

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


def free_path(path: Path) -> Path:
    """``path``, or the first ``out-NNN.mcap`` beside it that no earlier log occupies."""
    index = 0
    while rotated_path(path, index).exists():
        index += 1
    return rotated_path(path, index)


def rotated_path(path: Path, index: int) -> Path:
    """The ``index``-th file of a rotated log: ``out.mcap``, ``out-001.mcap``, ``out-002.mcap``."""
    if index == 0:
        return path
    return path.with_name(f"{path.stem}-{index:03d}{path.suffix or '.mcap'}")


def check_zstd_level(level: int) -> int:
    """``level`` if zstd has it, else ``ValueError`` saying the range."""
    if level not in ZSTD_LEVELS:
        raise ValueError(
            f"zstd_level must lie in {ZSTD_LEVELS.start}..{ZSTD_LEVELS.stop - 1}, not {level}"
        )
    return level


class _ChunkZstd(threading.local):
    """Stands in for the ``zstandard`` module inside ``mcap.writer``, whose Writer compresses
    each chunk with ``zstandard.compress(data)`` and takes no level. A LogWriter sets ``level``
    for the length of each call into its Writer; any other Writer in the process gets zstd's
    default level, as before. Thread-local, so writers in two threads keep their own.

    A LogWriter's zstd chunk carries zstd's own content checksum (XXH64 of the uncompressed
    chunk, checked by every zstd decoder, the stock ``mcap`` reader's included) in place of
    MCAP's chunk CRC, which it leaves 0 ("not computed", as the spec allows): the CRC took 8 %
    of the writer's CPU (zlib's crc32, 5 GB/s), the checksum adds 3 % to zstd's. zstd alone
    does not notice a flipped bit: of 300 single-bit flips in a compressed chunk, it decoded
    299 to wrong bytes without a word, and with the checksum none."""

    def __init__(self) -> None:
        self.level: int | None = None
        self._compressors: dict[tuple[int, bool], zstandard.ZstdCompressor] = {}
        self.checksummed: bytes | None = None  # the chunk compressed last with a checksum

    def compress(self, data: bytes) -> bytes:
        checksum = self.level is not None
        level = 3 if self.level is None else self.level
        compressor = self._compressors.get((level, checksum))
        if compressor is None:
            compressor = self._compressors[level, checksum] = zstandard.ZstdCompressor(
                level=level, write_checksum=checksum
            )
        self.checksummed = data if checksum else None
        return compressor.compress(data)


class _ChunkCrc:
    """Stands in for the ``zlib`` module inside ``mcap.writer``: the CRC of the chunk that
    ``_ChunkZstd`` has just compressed with a checksum is 0, every other CRC (the summary's,
    any other Writer's chunks) zlib's."""

    @staticmethod
    def crc32(data: bytes, value: int = 0) -> int:
        if value == 0 and data is _CHUNK_ZSTD.checksummed:
            _CHUNK_ZSTD.checksummed = None
            return 0
        return zlib.crc32(data, value)


_CHUNK_ZSTD = _ChunkZstd()
mcap.writer.zstandard = _CHUNK_ZSTD  # type: ignore[attr-defined]
mcap.writer.zlib = _ChunkCrc  # type: ignore[attr-defined]


class _ChunkBuffer:
    """The buffer a chunk's records are written into (what mcap's ``RecordBuilder`` holds as
    its ``_buffer``), allocated once and reused for every chunk. In a ``BytesIO`` each depth
    payload grew the chunk to its exact size, and glibc moved it to grow it: about 450 kB
    copied per recorded depth frame on top of the 204 kB written (callgrind, ``_int_realloc``).
    ``getvalue`` returns a view of the chunk, valid until the next chunk's first write: mcap
    compresses and CRCs it, or copies it into its record, before it returns."""

    def __init__(self, capacity: int) -> None:
        # Written through a view: a bytearray's own slice assignment copies a bytes value
        # twice (into a temporary bytearray first), the view's once.
        self._data = memoryview(bytearray(capacity))
        self._size = 0
        self._position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        if not isinstance(data, bytes):
            data = memoryview(data).cast("B")  # a view assigns only from its own format
        n = len(data)
        end = self._position + n
        if end > len(self._data):
            self._grow(end)
        self._data[self._position : end] = data
        self._position = end
        self._size = max(self._size, end)
        return n

    def write_message(
        self, channel: int, sequence: int, log_time: int, publish_time: int, data: bytes
    ) -> int:
        """Append one message record (as mcap's ``Message.write`` lays it out), its head packed
        in place; returns the record's offset in the chunk."""
        if not isinstance(data, bytes):
            data = memoryview(data).cast("B")
        offset = self._position
        start = offset + _MESSAGE_RECORD.size
        end = start + len(data)
        if end > len(self._data):
            self._grow(end)
        _MESSAGE_RECORD.pack_into(
            self._data,
            offset,
            Opcode.MESSAGE,
            _MESSAGE_HEAD.size + len(data),
            channel,
            sequence & 0xFFFFFFFF,
            log_time,
            publish_time,
        )
        self._data[start:end] = data
        self._position = end
        if end > self._size:
            self._size = end
        return offset

    def _grow(self, end: int) -> None:
        # A new array, not a resize: a view handed out earlier may still be alive.
        grown = memoryview(bytearray(max(end, 2 * len(self._data))))
        grown[: self._size] = self._data[: self._size]
        self._data = grown

    def tell(self) -> int:
        return self._position

    def seek(self, position: int) -> int:
        self._position = position
        return position

    def getvalue(self) -> memoryview:
        return self._data[: self._size]

    def close(self) -> None:
        self._size = self._position = 0

    def adopt(self, data: bytes) -> None:
        """Start over with ``data``: what mcap wrote into a fresh buffer of its own since the
        last chunk ended (a channel registered in between)."""
        self.close()
        if data:
            self.write(data)


class _FastMessages:
    """``Writer.add_message`` of a chunked mcap ``Writer``, the same bytes and bookkeeping, in
    one place: mcap builds each message record through a dataclass and eight small stream
    writes (11 us of the recorder's CPU a message; this: 4 us). It reaches into the Writer's
    private state, so it is used only when that state is there as mcap 1.x has it; otherwise
    ``LogWriter`` calls ``add_message``. ``tests/test_mcap_log.py`` holds the two to the same
    file, byte for byte."""

    def __init__(self, writer: Writer) -> None:
        self._writer = writer
        self._statistics = writer._Writer__statistics  # type: ignore[attr-defined]
        self._chunks = writer._Writer__chunk_builder  # type: ignore[attr-defined]
        self._chunk_size = writer._Writer__chunk_size  # type: ignore[attr-defined]
        self._finalize = writer._Writer__finalize_chunk  # type: ignore[attr-defined]
        self._stream = self._chunks.record_writer
        self._buffer = _ChunkBuffer(self._chunk_size + self._chunk_size // 4)

    @classmethod
    def of(cls, writer: Writer) -> _FastMessages | None:
        try:
            fast = cls(writer)
            fast._stream._buffer.tell()
            fast._statistics.channel_message_counts  # noqa: B018 - present, or no fast path
            fast._chunks.message_indices  # noqa: B018
        except AttributeError:
            return None
        return fast if fast._chunks is not None else None

    def add(self, channel: int, log_time: int, data: bytes, publish_time: int, seq: int) -> None:
        # mcap's min and max, as comparisons: the same values, a call fewer each.
        stats = self._statistics
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        stats.channel_message_counts[channel] += 1
        stats.message_count += 1
        chunks = self._chunks
        if chunks.num_messages == 0 or log_time < chunks.message_start_time:
            chunks.message_start_time = log_time
        if log_time > chunks.message_end_time:
            chunks.message_end_time = log_time
        chunks.num_messages += 1
        index = chunks.message_indices.get(channel)
        if index is None:
            index = chunks.message_indices[channel] = _MessageIndex(channel_id=channel, records=[])
        # mcap gives its record builder a new BytesIO whenever a chunk ends: ours goes back in.
        stream = self._stream
        buffer = self._buffer
        if stream._buffer is not buffer:
            buffer.adopt(stream._buffer.getvalue())
            stream._buffer = buffer
        index.records.append(
            (log_time, buffer.write_message(channel, seq, log_time, publish_time, data))
        )
        if buffer._position > self._chunk_size:
            self._finalize()


class _MessageIndex(MessageIndex):
    """A chunk's message index for one channel, written as mcap's ``MessageIndex.write`` writes
    it (opcode, length, channel, entries' length, then each entry's log time and offset), in
    one pack instead of two stream writes an entry."""

    def write(self, stream: RecordBuilder) -> None:
        n = 2 * len(self.records)
        stream.write(
            struct.pack(
                f"<BQHI{n}Q",
                Opcode.MESSAGE_INDEX,
                6 + 8 * n,
                self.channel_id,
                8 * n,
                *itertools.chain.from_iterable(self.records),
            )
        )


class _Payloads:
    """How a payload off the bus, or a message, becomes a ``write_raw`` call: shared by the
    writer that writes in place and the one that queues for its thread."""

    def write_raw(
        self, key: str, payload: bytes, *, log_time: int, publish_time: int, sequence: int = 0
    ) -> None:
        raise NotImplementedError

    def write_received(self, key: str, payload: bytes, received_ns: int) -> tuple[int, int] | None:
        """Log a payload as received off the bus. Returns its header ``(seq, t_ns)``, or ``None``
        if that did not decode, in which case it went raw to ``lpc/_rejected/<key>`` with the
        receive time."""
        header = read_header(payload)
        if header is None:
            self.write_raw(
                REJECTED_PREFIX + key, payload, log_time=received_ns, publish_time=received_ns
            )
            return None
        seq, t_ns = header
        self.write_raw(key, payload, log_time=received_ns, publish_time=t_ns, sequence=seq)
        return header

    def write(self, key: str, message: Any, log_time: int) -> None:
        """Encode a message and log it, with its own ``t_ns`` and ``seq``."""
        self.write_raw(
            key, encode(message), log_time=log_time, publish_time=message.t_ns, sequence=message.seq
        )


class LogWriter(_Payloads):
    """Write bus messages to MCAP, one channel per key, rotating to a new file past ``max_bytes``.

    ``write_raw`` takes a payload as it came off the bus; ``write`` encodes a message first.
    ``finish()`` writes the summary and footer; it is safe to call twice, and the context
    manager calls it.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        compression: Compression = DEFAULT_COMPRESSION,
        chunk_bytes: int = DEFAULT_CHUNK_BYTES,
        max_bytes: int | None = None,
        zstd_level: int = DEFAULT_ZSTD_LEVEL,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise ValueError(
                f"compression must be one of {sorted(COMPRESSIONS)}, not {compression!r}"
            )
        check_zstd_level(zstd_level)
        if chunk_bytes <= 0:
            raise ValueError(f"chunk_bytes must be positive, not {chunk_bytes}")
        if max_bytes is not None and max_bytes <= 0:
            raise ValueError(f"max_bytes must be positive, not {max_bytes}")
        self.path = Path(path)
        self.compression = compression
        self.zstd_level = zstd_level
        self.chunk_bytes = chunk_bytes
        self.max_bytes = max_bytes
        self.paths: list[Path] = []
        self.messages = 0
        self._sink: _FileSink | None = None
        self._writer: Writer | None = None
        self._fast: _FastMessages | None = None
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._open()

    def _open(self) -> None:
        path = rotated_path(self.path, len(self.paths))
        path.parent.mkdir(parents=True, exist_ok=True)
        self._sink = _FileSink(path)
        self._writer = Writer(
            self._sink,
            chunk_size=self.chunk_bytes,
            compression=COMPRESSIONS[self.compression],
        )
        self._writer.start(profile=PROFILE)
        self._fast = _FastMessages.of(self._writer)
        self._schemas.clear()
        self._channels.clear()
        self.paths.append(path)

    def _channel(self, key: str) -> int:
        channel = self._channels.get(key)
        if channel is not None:
            return channel
        assert self._writer is not None
        if key.startswith(REJECTED_PREFIX):
            schema_id, encoding = 0, RAW_ENCODING
        else:
            try:
                message_type = topic_for_key(key).type
            except KeyError:
                schema_id = 0  # not in the registry: keep it, undescribed
            else:
                name = message_type.__name__
                schema_id = self._schemas.get(name, 0)
                if not schema_id:
                    data = json.dumps(json_schema(message_type), sort_keys=True).encode()
                    schema_id = self._writer.register_schema(name, "jsonschema", data)
                    self._schemas[name] = schema_id
            encoding = "msgpack"
        channel = self._writer.register_channel(key, encoding, schema_id)
        self._channels[key] = channel
        return channel

    def declare(self, key: str) -> None:
        """Register ``key``'s channel now, even if no message comes: a reader then knows the
        topic was recorded, and empty."""
        if self._writer is None:
            raise ValueError(f"{self.path}: declare after finish()")
        self._channel(key)

    def write_raw(
        self,
        key: str,
        payload: bytes,
        *,
        log_time: int,
        publish_time: int,
        sequence: int = 0,
    ) -> None:
        """Append one payload; ``sequence`` keeps its low 32 bits (MCAP's field is 32-bit)."""
        self.write_many(((key, payload, log_time, publish_time, sequence),))

    def write_many(self, items: Iterable[tuple[str, bytes, int, int, int]]) -> None:
        """``write_raw`` for each ``(key, payload, log_time, publish_time, sequence)`` in turn:
        the same file, with the per-call bookkeeping once for all (the background writer's
        batches)."""
        _CHUNK_ZSTD.level = self.zstd_level  # a full chunk is compressed inside add_message
        try:
            for key, payload, log_time, publish_time, sequence in items:
                if self._writer is None:
                    raise ValueError(f"{self.path}: write after finish()")
                channel = self._channels.get(key)
                if channel is None:
                    channel = self._channel(key)
                if self._fast is not None:
                    self._fast.add(channel, log_time, payload, publish_time, sequence)
                else:
                    self._writer.add_message(
                        channel,
                        log_time=log_time,
                        data=payload,
                        publish_time=publish_time,
                        sequence=sequence & 0xFFFFFFFF,
                    )
                self.messages += 1
                if (
                    self.max_bytes is not None
                    and self._sink
                    and self._sink.tell() >= self.max_bytes
                ):
                    self._close_file()
                    self._open()
        finally:
            _CHUNK_ZSTD.level = None

    def _close_file(self) -> None:
        if self._writer is not None:
            level, _CHUNK_ZSTD.level = _CHUNK_ZSTD.level, self.zstd_level
            try:
                self._writer.finish()
            finally:
                _CHUNK_ZSTD.level = level  # inside write_many: still this writer's
                self._writer = None
                if self._sink is not None:
                    self._sink.close()
                    self._sink = None

    def finish(self) -> None:
        self._close_file()

    @property
    def finished(self) -> bool:
        return self._writer is None

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()


class BackgroundLogWriter(_Payloads):
    """A ``LogWriter`` driven from a thread of its own, for a writer on a busy event loop.

    ``LogWriter`` compresses a full chunk (1 MiB: about five depth frames) and writes it to the
    file inside the ``write_raw`` call that fills it, which on the container's shared loop held
    every other task (the camera's read, scans, aim's cue) for the chunk's compression and the
    write. Here the caller only queues what to write: its messages are handed to the thread in
    batches (``hand_over``, or every ``BATCH`` messages), which writes them in the order given,
    so the file is the one ``LogWriter`` writes for the same calls, byte for byte; zstd and the
    file writes release the GIL while they run. The file's rotation is the ``LogWriter``'s.

    An error of the thread (a full disk) is raised by the caller's next call, as ``LogWriter``
    would have raised it. ``finish()`` writes what is queued, then the summary and footer, and
    waits for the thread; it is safe to call twice. What is still queued when the process is
    killed is lost, as the messages in a subscription's queue were.
    """

    BATCH = 256

    def __init__(self, path: str | os.PathLike[str], **kwargs: Any) -> None:
        self._log = LogWriter(path, **kwargs)  # opened here: a bad path fails the caller
        self.path = self._log.path
        self.messages = 0
        self.written = 0  # by the thread
        self.cpu_ns = 0  # the thread's CPU time, as of its last batch
        self._batch: list[tuple[str, bytes, int, int, int]] = []
        self._queue: queue.SimpleQueue[
            list[tuple[str, bytes, int, int, int]] | threading.Event | None
        ] = queue.SimpleQueue()
        self._error: BaseException | None = None
        self._finished = False
        self._thread = threading.Thread(target=self._run, name=RECORDER_WRITER, daemon=True)
        self._thread.start()

    @property
    def paths(self) -> list[Path]:
        return self._log.paths

    @property
    def finished(self) -> bool:
        return self._finished

    def write_raw(
        self,
        key: str,
        payload: bytes,
        *,
        log_time: int,
        publish_time: int,
        sequence: int = 0,
    ) -> None:
        """Queue one payload; written by the thread after those queued before it."""
        if self._finished:
            raise ValueError(f"{self.path}: write after finish()")
        self._raise_error()
        self._batch.append((key, payload, log_time, publish_time, sequence))
        self.messages += 1
        if len(self._batch) >= self.BATCH:
            self.hand_over()

    def hand_over(self) -> None:
        """Give the thread what was queued since the last hand-over (the caller has no more for
        now): one wake-up of the thread for a batch instead of one a message."""
        if self._batch:
            self._queue.put(self._batch)
            self._batch = []

    @property
    def backlog(self) -> int:
        """Messages queued and not yet written."""
        return self.messages - self.written

    def drain(self) -> None:
        """Block until the thread has written everything queued so far (a writer far behind
        holds its caller back here, as a slow disk held ``LogWriter``'s)."""
        self.hand_over()
        if not self._finished:
            done = threading.Event()
            self._queue.put(done)
            done.wait()
        self._raise_error()

    def finish(self) -> None:
        """Write everything queued, finish the file and stop the thread (blocks until done)."""
        if not self._finished:
            self._finished = True
            self.hand_over()
            self._queue.put(None)
        self._thread.join()
        self._raise_error()

    def _raise_error(self) -> None:
        error, self._error = self._error, None
        if error is not None:
            raise error

    def _run(self) -> None:
        name_native_thread(RECORDER_WRITER)  # its CPU apart in lpc bench footprint
        log = self._log
        failed = False
        while True:
            batch = self._queue.get()
            if batch is None:
                break
            if isinstance(batch, threading.Event):
                batch.set()
                continue
            if failed:
                continue  # the caller hears of the first error; the rest would repeat it
            before = log.messages
            try:
                log.write_many(batch)
            except BaseException as exc:  # handed to the caller's thread
                self._error, failed = exc, True
            self.written += log.messages - before
            self.cpu_ns = time.thread_time_ns()
        try:
            log.finish()
        except BaseException as exc:  # handed to the caller's thread
            self._error = self._error or exc
        self.cpu_ns = time.thread_time_ns()

    def __enter__(self) -> BackgroundLogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()


# --------------------------------------------------------------------------- reader


@dataclass(frozen=True)
class LoggedMessage:
    """One message of a log. ``order`` is its position in the file (ties in ``log_time``)."""

    key: str
    log_time: int
    publish_time: int
    sequence: int
    payload: bytes
    order: int
    encoding: str = "msgpack"
    message: Any = None  # the decoded message, when asked for and it decodes
    error: str = ""  # why it did not decode, when asked for


@dataclass(frozen=True)
class Cut:
    """Where a log stops being readable: byte offset, reason, and the last good log time."""

    offset: int
    reason: str
    last_good_ns: int | None
    first_ns: int | None

    def describe(self) -> str:
        if self.last_good_ns is None:
            when = "no message before the cut"
        else:
            span = (self.last_good_ns - (self.first_ns or self.last_good_ns)) / 1e9
            when = f"last good time {format_time(self.last_good_ns)} ({span:.3f} s after the start)"
        return f"cut short at byte {self.offset}: {self.reason}; {when}"


def format_time(t_ns: int) -> str:
    """Seconds since the epoch with nanoseconds: what a person can compare across tools."""
    return f"{t_ns // 1_000_000_000}.{t_ns % 1_000_000_000:09d}"


@dataclass(frozen=True)
class _Item:
    """A data-section record worth loading: a chunk, or a loose schema/channel/message."""

    offset: int
    length: int  # of the record body
    opcode: int
    start_ns: int  # earliest log time inside (chunks, messages); max for others


class McapLog:
    """Read an MCAP log, complete or cut short.

    ``messages()`` yields in ``(log_time, file order)``; ``messages(ordered=False)`` in file
    order. After iterating, ``cut`` is ``None`` for a complete, sound file, or a ``Cut``.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        try:
            self._file = open(self.path, "rb")  # noqa: SIM115 - closed by close()/__exit__
        except OSError as exc:
            raise McapLogError(f"cannot open {self.path}: {exc.strerror or exc}") from exc
        self.size = os.fstat(self._file.fileno()).st_size
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.compressions: set[str] = set()
        self.profile = ""
        self.library = ""
        self.complete = False  # a footer and the closing magic were found
        self.cut: Cut | None = None
        self._first_ns: int | None = None
        self._last_ns: int | None = None
        self._scan_cut: tuple[int, str] | None = None
        self._summary_topics: set[str] = set()
        self._zstd = zstandard.ZstdDecompressor()
        self._items = self._scan()

    # -- structure

    def _scan(self) -> list[_Item]:
        """Walk the records' headers (without decompressing) up to the footer or the cut."""
        f = self._file
        head = f.read(len(MAGIC))
        if head != MAGIC:
            what = "empty" if not head else "not an MCAP file (bad magic)"
            raise McapLogError(f"{self.path}: {what}")
        items: list[_Item] = []
        offset = len(MAGIC)
        summary = False
        while True:
            f.seek(offset)
            raw = f.read(_RECORD_HEAD.size)
            if len(raw) < _RECORD_HEAD.size:
                self._scan_cut = (offset, "no footer (the writer did not finish)")
                break
            opcode, length = _RECORD_HEAD.unpack(raw)
            body = offset + _RECORD_HEAD.size
            if body + length > self.size:
                self._scan_cut = (offset, f"{_opname(opcode)} record is incomplete")
                break
            if opcode == Opcode.HEADER:
                self._read_header_record(body, length)
            elif opcode == Opcode.CHUNK:
                start_ns, _ = _CHUNK_TIMES.unpack(f.read(_CHUNK_TIMES.size))
                items.append(_Item(body, length, opcode, start_ns))
            elif opcode == Opcode.MESSAGE:
                _, _, log_time, _ = _MESSAGE_HEAD.unpack(f.read(_MESSAGE_HEAD.size))
                items.append(_Item(body, length, opcode, log_time))
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL) and not summary:
                items.append(_Item(body, length, opcode, 2**64))
            elif opcode == Opcode.CHANNEL:
                f.seek(body)
                try:
                    channel = Channel.read(ReadDataStream(io.BytesIO(f.read(length))))
                except (McapError, struct.error, UnicodeDecodeError):
                    pass  # topics() then reads the data section instead
                else:
                    self._summary_topics.add(channel.topic)
            elif opcode == Opcode.DATA_END:
                summary = True  # what follows repeats what the data section said
            elif opcode == Opcode.FOOTER:
                f.seek(body + length)
                if f.read(len(MAGIC)) == MAGIC:
                    self.complete = True
                else:
                    self._scan_cut = (body + length, "the closing magic is missing")
                break
            elif opcode == 0 or (opcode < 0x80 and opcode not in _KNOWN):
                self._scan_cut = (offset, f"invalid record opcode 0x{opcode:02x}")
                break
            offset = body + length
        return items

    def _read_header_record(self, body: int, length: int) -> None:
        self._file.seek(body)
        stream = ReadDataStream(io.BytesIO(self._file.read(length)))
        try:
            self.profile = stream.read_prefixed_string()
            self.library = stream.read_prefixed_string()
        except (McapError, UnicodeDecodeError, struct.error):
            pass

    def _load(self, item: _Item) -> list[Any]:
        """The records of one item; raises on any corruption."""
        self._file.seek(item.offset)
        body = self._file.read(item.length)
        if item.opcode == Opcode.CHUNK:
            return self._chunk_records(body)
        stream = ReadDataStream(io.BytesIO(body))
        if item.opcode == Opcode.MESSAGE:
            return [Message.read(stream, item.length)]
        if item.opcode == Opcode.SCHEMA:
            return [Schema.read(stream)]
        return [Channel.read(stream)]

    def _chunk_records(self, body: bytes) -> list[Any]:
        # mcap's breakup_chunk, with one reused zstd context and no per-field stream reads:
        # decompression is most of a replay's reading cost.
        _, _, size, crc, name_length = _CHUNK_HEAD.unpack_from(body, 0)
        p = _CHUNK_HEAD.size
        compression = body[p : p + name_length].decode()
        p += name_length
        (data_length,) = struct.unpack_from("<Q", body, p)
        p += 8
        if p + data_length > len(body):
            raise ValueError("chunk data overruns its record")
        data = memoryview(body)[p : p + data_length]
        self.compressions.add(compression or "none")
        if compression == "zstd":
            raw: bytes | memoryview = self._zstd.decompress(data, max_output_size=size)
        elif compression == "lz4":
            raw = lz4.frame.decompress(data)
        elif compression == "":
            raw = data
        else:
            raise UnsupportedCompressionError(compression)
        if len(raw) != size:
            raise ValueError(f"chunk holds {len(raw)} bytes, its header says {size}")
        if crc and zlib.crc32(raw) != crc:
            raise ValueError("chunk fails its CRC")
        records: list[Any] = []
        view = memoryview(raw)
        p = 0
        while p < size:
            opcode, length = _RECORD_HEAD.unpack_from(view, p)
            p += _RECORD_HEAD.size
            if p + length > size:
                raise ValueError("a record overruns its chunk")
            if opcode == Opcode.MESSAGE:
                channel_id, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(view, p)
                records.append(
                    Message(
                        channel_id=channel_id,
                        sequence=sequence,
                        log_time=log_time,
                        publish_time=publish_time,
                        data=bytes(view[p + _MESSAGE_HEAD.size : p + length]),
                    )
                )
            elif opcode == Opcode.CHANNEL:
                records.append(Channel.read(ReadDataStream(io.BytesIO(view[p : p + length]))))
            elif opcode == Opcode.SCHEMA:
                records.append(Schema.read(ReadDataStream(io.BytesIO(view[p : p + length]))))
            p += length
        return records

    def topics(self) -> set[str]:
        """The topics of the log's channels (a channel may hold no message): from the summary
        of a complete file, otherwise by reading the file through."""
        if self.complete and self._summary_topics:
            return set(self._summary_topics)
        for _ in self.messages(ordered=False):
            pass
        return {c.topic for c in self.channels.values()}

    # -- messages

    def messages(
        self,
        topics: Iterable[str] | None = None,
        *,
        decode: bool = False,
        ordered: bool = True,
    ) -> Iterator[LoggedMessage]:
        """Messages of the log (of ``topics`` only, if given), decoded if ``decode``."""
        wanted = None if topics is None else set(topics)
        items = self._items
        # Chunks are loaded in file order (so channels are defined before use) but a message
        # leaves the heap only when no unloaded chunk can hold an earlier one.
        later_start = [2**64] * (len(items) + 1)
        for i in range(len(items) - 1, -1, -1):
            later_start[i] = min(items[i].start_ns, later_start[i + 1])
        heap: list[tuple[int, int, Message]] = []
        order = 0
        index = 0
        self.cut = None
        failure: tuple[int, str] | None = None
        while True:
            while index < len(items) and (
                not heap or (ordered and heap[0][0] > later_start[index])
            ):
                item = items[index]
                index += 1
                try:
                    records = self._load(item)
                except _UNREADABLE as exc:
                    failure = (item.offset - _RECORD_HEAD.size, _describe_error(item, exc))
                    items = items[: index - 1]  # nothing after a bad chunk is trusted
                    break
                for record in records:
                    if isinstance(record, Message):
                        heapq.heappush(heap, (record.log_time if ordered else 0, order, record))
                        order += 1
                    elif isinstance(record, Schema):
                        self.schemas[record.id] = record
                    elif isinstance(record, Channel):
                        self.channels[record.id] = record
            if not heap:
                break
            _, position, record = heapq.heappop(heap)
            logged = self._logged(record, position, wanted, decode)
            if logged is not None:
                yield logged
        failure = failure or self._scan_cut
        if failure is not None:
            self._set_cut(*failure)

    def _logged(
        self, record: Message, position: int, wanted: set[str] | None, decode: bool
    ) -> LoggedMessage | None:
        channel = self.channels.get(record.channel_id)
        key = channel.topic if channel is not None else f"<channel {record.channel_id}>"
        self._first_ns = (
            record.log_time if self._first_ns is None else min(self._first_ns, record.log_time)
        )
        self._last_ns = (
            record.log_time if self._last_ns is None else max(self._last_ns, record.log_time)
        )
        if wanted is not None and key not in wanted:
            return None
        message, error = None, ""
        encoding = channel.message_encoding if channel is not None else ""
        if decode:
            try:
                if encoding != "msgpack":
                    raise BadMessage(key, f"message encoding {encoding!r} is not msgpack")
                message = decode_message(key, record.data)
            except BadMessage as exc:
                error = exc.reason
            except KeyError as exc:
                error = str(exc)
        return LoggedMessage(
            key=key,
            log_time=record.log_time,
            publish_time=record.publish_time,
            sequence=record.sequence,
            payload=record.data,
            order=position,
            encoding=encoding,
            message=message,
            error=error,
        )

    def _set_cut(self, offset: int, reason: str) -> None:
        self.cut = Cut(offset, reason, self._last_ns, self._first_ns)

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> McapLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_KNOWN = {int(op) for op in Opcode}
# What loading a damaged record raises; zstd's error too (a chunk that fails its checksum).
_UNREADABLE = (McapError, ValueError, struct.error, EOFError, OSError, zstandard.ZstdError)


def _opname(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower().replace("_", " ")
    except ValueError:
        return f"opcode 0x{opcode:02x}"


def _describe_error(item: _Item, exc: Exception) -> str:
    what = _opname(item.opcode)
    text = str(exc) or type(exc).__name__
    if "crc" in text.lower():
        return f"{what} fails its CRC"
    if "checksum" in text.lower():
        return f"{what} fails its zstd checksum"
    if isinstance(exc, zstandard.ZstdError) or "lz4" in type(exc).__module__:
        return f"{what} does not decompress ({text})"
    return f"{what} is unreadable ({text})"


def read_messages(
    path: str | os.PathLike[str], topics: Iterable[str] | None = None, *, decode: bool = True
) -> Iterator[LoggedMessage]:
    """Messages of a log in ``(log_time, file order)``, decoded; stops quietly at a cut."""
    with McapLog(path) as log:
        yield from log.messages(topics, decode=decode)
