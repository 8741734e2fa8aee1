"""MCAP writer and reader: conventions, ordering, rotation, determinism and cut-short files."""

from __future__ import annotations

import io
import json
from pathlib import Path

import mcap.writer
import numpy as np
import pytest
import zstandard
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

import services.mcap_log
from schemas import CameraIntrinsics, DepthFrame, EmgSample, Health, decode, encode, to_wire
from services.mcap_log import (
    REJECTED_PREFIX,
    BackgroundLogWriter,
    LogWriter,
    McapLog,
    McapLogError,
    read_header,
    read_messages,
    rotated_path,
)

T0 = 1_700_000_000_000_000_000
INTRINSICS = CameraIntrinsics(width=424, height=240, fx=213.0, fy=213.0, ppx=212.0, ppy=120.0)


def depth_frame(seq: int) -> DepthFrame:
    rng = np.random.default_rng(seq)
    depth = rng.integers(150, 250, size=(240, 424)).astype(np.uint16)
    return DepthFrame(
        seq=seq, t_ns=T0 + seq * 11_111_111, intrinsics=INTRINSICS, depth=to_wire(depth)
    )


def session(n_frames: int = 20) -> list[tuple[str, bytes, int]]:
    """What a recorder receives: depth at 90 Hz and EMG at 100 Hz, as (key, payload, time)."""
    items = []
    for i in range(n_frames):
        frame = depth_frame(i)
        items.append(("lpc/camera/depth", encode(frame), frame.t_ns + 300_000))
    for i in range(n_frames * 100 // 90):
        emg = EmgSample(seq=i, t_ns=T0 + i * 10_000_000, channels=[0.1 * i, 0.2])
        items.append(("lpc/emg", encode(emg), emg.t_ns + 100_000))
    items.sort(key=lambda item: item[2])
    return items


def write_session(path: Path, items: list[tuple[str, bytes, int]], **kwargs) -> LogWriter:
    with LogWriter(path, **kwargs) as writer:
        for key, payload, t in items:
            writer.write_received(key, payload, t)
    return writer


def test_writer_conventions_as_mcap_reads_them(tmp_path: Path) -> None:
    items = session(5)
    write_session(tmp_path / "a.mcap", items)
    with open(tmp_path / "a.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: c for c in summary.channels.values()}
        assert set(channels) == {"lpc/camera/depth", "lpc/emg"}
        for channel in channels.values():
            assert channel.message_encoding == "msgpack"
            schema = summary.schemas[channel.schema_id]
            assert schema.encoding == "jsonschema"
            assert "$defs" in json.loads(schema.data)
        assert summary.schemas[channels["lpc/emg"].schema_id].name == "EmgSample"
        got = list(reader.iter_messages(log_time_order=True))
    assert len(got) == len(items)
    for (_, channel, message), (key, payload, t) in zip(got, items, strict=True):
        assert channel.topic == key
        assert message.data == payload
        assert message.log_time == t
        decoded = decode(key, payload)
        assert message.publish_time == decoded.t_ns
        assert message.sequence == decoded.seq


def test_writer_identical_input_gives_identical_bytes(tmp_path: Path) -> None:
    items = session(12)
    for compression in ("none", "lz4", "zstd"):
        write_session(tmp_path / f"a-{compression}.mcap", items, compression=compression)
        write_session(tmp_path / f"b-{compression}.mcap", items, compression=compression)
        a = (tmp_path / f"a-{compression}.mcap").read_bytes()
        assert a == (tmp_path / f"b-{compression}.mcap").read_bytes()


def test_writer_zstd_level_is_used_and_stock_mcap_reads_every_level(tmp_path: Path) -> None:
    items = session(12)
    sizes = {}
    for level in (-5, 1, 19):
        path = tmp_path / f"z{level}.mcap"
        write_session(path, items, zstd_level=level)
        sizes[level] = path.stat().st_size
        with open(path, "rb") as f:
            got = [m.data for _, _, m in make_reader(f).iter_messages(log_time_order=True)]
        assert got == [payload for _, payload, _ in items]
    assert sizes[19] < sizes[1] < sizes[-5]


def test_writer_zstd_level_leaves_other_mcap_writers_at_zstd_default(tmp_path: Path) -> None:
    def stock(path: Path) -> bytes:
        with open(path, "wb") as f:
            writer = Writer(f)  # mcap's own, zstd at its default level
            writer.start()
            channel = writer.register_channel("lpc/camera/depth", "msgpack", 0)
            for i, (_, payload, t) in enumerate(session(6)):
                writer.add_message(channel, log_time=t, data=payload, publish_time=t, sequence=i)
            writer.finish()
        return path.read_bytes()

    before = stock(tmp_path / "before.mcap")
    write_session(tmp_path / "z19.mcap", session(6), zstd_level=19)
    assert stock(tmp_path / "after.mcap") == before
    # What mcap's Writer calls is zstandard's own compress at its default level.
    chunk = b"".join(payload for _, payload, _ in session(3))
    assert mcap.writer.zstandard.compress(chunk) == zstandard.compress(chunk)


def test_writer_sequence_keeps_low_32_bits(tmp_path: Path) -> None:
    big = 2**40 + 7
    with LogWriter(tmp_path / "s.mcap") as writer:
        writer.write("lpc/emg", EmgSample(seq=big, t_ns=T0, channels=[0.0, 0.0]), T0 + 1)
    (message,) = read_messages(tmp_path / "s.mcap")
    assert message.sequence == 7
    assert message.message.seq == big


def test_writer_bad_header_goes_raw_to_rejected_channel(tmp_path: Path) -> None:
    with LogWriter(tmp_path / "r.mcap") as writer:
        assert not writer.write_received("lpc/emg", b"\xc1 not msgpack", T0)
        assert writer.write_received(
            "lpc/health/cam", encode(Health(seq=1, t_ns=T0, service="cam", pid=1)), T0 + 1
        )
    with McapLog(tmp_path / "r.mcap") as log:
        rejected, health = log.messages(decode=True)
        assert log.cut is None
    assert rejected.key == REJECTED_PREFIX + "lpc/emg"
    assert rejected.payload == b"\xc1 not msgpack"
    assert rejected.encoding == "application/octet-stream"
    assert rejected.message is None and rejected.error
    assert health.key == "lpc/health/cam" and health.message.service == "cam"


def test_read_header_fields_only() -> None:
    assert read_header(encode(depth_frame(3))) == (3, T0 + 3 * 11_111_111)
    assert read_header(b"\x80") is None  # an empty map: no seq
    assert read_header(b"") is None


def test_reader_orders_by_log_time_then_file_order(tmp_path: Path) -> None:
    emg = [EmgSample(seq=i, t_ns=T0, channels=[float(i), 0.0]) for i in range(6)]
    log_times = [T0 + 5, T0 + 1, T0 + 5, T0 + 3, T0 + 1, T0 + 9]
    # Tiny chunks so that the out-of-order times straddle chunk boundaries.
    with LogWriter(tmp_path / "o.mcap", chunk_bytes=64) as writer:
        for message, t in zip(emg, log_times, strict=True):
            writer.write("lpc/emg", message, t)
    got = [m.message.seq for m in read_messages(tmp_path / "o.mcap")]
    assert got == [1, 4, 3, 0, 2, 5]
    with McapLog(tmp_path / "o.mcap") as log:
        assert [m.order for m in log.messages(ordered=False)] == list(range(6))


def test_reader_topic_filter_and_decode(tmp_path: Path) -> None:
    write_session(tmp_path / "f.mcap", session(4))
    depth = list(read_messages(tmp_path / "f.mcap", topics=["lpc/camera/depth"]))
    assert [m.message.seq for m in depth] == [0, 1, 2, 3]
    assert np.array_equal(
        np.frombuffer(depth[2].message.depth.data, np.uint16).reshape(240, 424),
        np.frombuffer(depth_frame(2).depth.data, np.uint16).reshape(240, 424),
    )


def test_writer_rotates_by_size(tmp_path: Path) -> None:
    items = session(30)
    writer = write_session(
        tmp_path / "big.mcap", items, max_bytes=2 * 1024 * 1024, compression="none"
    )
    assert len(writer.paths) >= 2
    assert writer.paths[1] == rotated_path(tmp_path / "big.mcap", 1) == tmp_path / "big-001.mcap"
    got = []
    for path in writer.paths:
        with McapLog(path) as log:
            got += [(m.key, m.payload, m.log_time) for m in log.messages()]
            assert log.complete and log.cut is None
    assert got == items


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_reader_cut_short_reads_to_last_complete_chunk(tmp_path: Path, compression: str) -> None:
    items = session(30)
    write_session(tmp_path / "full.mcap", items, compression=compression)
    data = (tmp_path / "full.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) * 2 // 3])
    with McapLog(tmp_path / "cut.mcap") as log:
        got = list(log.messages())
        assert not log.complete
        cut = log.cut
    assert cut is not None
    assert 0 < len(got) < len(items)
    assert [(m.key, m.payload, m.log_time) for m in got] == items[: len(got)]
    assert cut.last_good_ns == got[-1].log_time
    assert "incomplete" in cut.reason and str(cut.offset) in cut.describe()
    assert "last good time" in cut.describe()


def test_reader_missing_footer_is_a_cut_with_every_message(tmp_path: Path) -> None:
    items = session(6)
    write_session(tmp_path / "full.mcap", items)
    data = (tmp_path / "full.mcap").read_bytes()
    (tmp_path / "nofoot.mcap").write_bytes(data[:-12])
    with McapLog(tmp_path / "nofoot.mcap") as log:
        assert len(list(log.messages())) == len(items)
        assert log.cut is not None and log.cut.last_good_ns == items[-1][2]


def test_reader_corrupt_chunk_stops_at_crc(tmp_path: Path) -> None:
    items = session(30)
    write_session(tmp_path / "full.mcap", items, compression="none")
    data = bytearray((tmp_path / "full.mcap").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (tmp_path / "bad.mcap").write_bytes(bytes(data))
    with McapLog(tmp_path / "bad.mcap") as log:
        got = list(log.messages())
        assert log.cut is not None and "CRC" in log.cut.reason
    assert [(m.key, m.payload) for m in got] == [(k, p) for k, p, _ in items[: len(got)]]


def test_zstd_chunks_carry_zstd_checksum_instead_of_crc(tmp_path: Path) -> None:
    items = session(30)
    write_session(tmp_path / "full.mcap", items)
    with open(tmp_path / "full.mcap", "rb") as f:
        chunks = [r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
        f.seek(0)
        reader = make_reader(f, validate_crcs=True)
        assert [m.data for _, _, m in reader.iter_messages()] == [p for _, p, _ in items]
    assert len(chunks) > 2 and {c.compression for c in chunks} == {"zstd"}
    assert {c.uncompressed_crc for c in chunks} == {0}  # "not computed" (MCAP spec)
    assert all(zstandard.get_frame_parameters(c.data).has_checksum for c in chunks)
    # A flipped bit in the second chunk's compressed data: zstd alone decodes it to wrong bytes.
    with McapLog(tmp_path / "full.mcap") as log:
        second = [item for item in log._items if item.opcode == Opcode.CHUNK][1]
    data = bytearray((tmp_path / "full.mcap").read_bytes())
    data[second.offset + second.length // 2] ^= 0x10
    (tmp_path / "bad.mcap").write_bytes(bytes(data))
    with McapLog(tmp_path / "bad.mcap") as log:
        got = list(log.messages())
        assert log.cut is not None and "zstd checksum" in log.cut.reason
    assert 0 < len(got) < len(items)
    assert [(m.key, m.payload) for m in got] == [(k, p) for k, p, _ in items[: len(got)]]


def test_reader_not_mcap_raises_clear_error(tmp_path: Path) -> None:
    (tmp_path / "x.mcap").write_bytes(b"hello world, not a log")
    with pytest.raises(McapLogError, match="not an MCAP file"):
        McapLog(tmp_path / "x.mcap")
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(McapLogError, match="empty"):
        McapLog(tmp_path / "empty.mcap")
    with pytest.raises(McapLogError, match="cannot open"):
        McapLog(tmp_path / "missing.mcap")


def test_writer_rejects_bad_parameters(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="compression"):
        LogWriter(tmp_path / "p.mcap", compression="gzip")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="max_bytes"):
        LogWriter(tmp_path / "p.mcap", max_bytes=0)
    with pytest.raises(ValueError, match="zstd_level"):
        LogWriter(tmp_path / "p.mcap", zstd_level=30)
    writer = LogWriter(tmp_path / "p.mcap")
    writer.finish()
    writer.finish()  # twice is fine
    with pytest.raises(ValueError, match="after finish"):
        writer.write("lpc/emg", EmgSample(seq=1, t_ns=T0, channels=[0.0, 0.0]), T0)


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_writer_fast_message_path_writes_what_mcaps_add_message_writes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compression: str
) -> None:
    """LogWriter appends messages without mcap's ``Writer.add_message`` when it can: the files,
    rotated ones and a rejected payload included, are byte for byte the ones it writes."""
    items = session(30)
    items.insert(7, ("lpc/emg", b"\xc1 not msgpack", items[6][2]))
    # A new channel after each depth frame: some land just after a chunk ended, where mcap
    # writes the channel into a buffer of its own and the fast path takes it over.
    for i in reversed([i for i, (key, _, _) in enumerate(items) if key == "lpc/camera/depth"]):
        items.insert(i + 1, (f"lpc/x{i}", b"\xc1 not msgpack", items[i][2]))
    fast = write_session(tmp_path / "fast.mcap", items, compression=compression, max_bytes=2**21)
    monkeypatch.setattr(services.mcap_log._FastMessages, "of", classmethod(lambda cls, w: None))
    plain = write_session(tmp_path / "plain.mcap", items, compression=compression, max_bytes=2**21)
    assert len(fast.paths) == len(plain.paths) > 1, "rotated"
    for a, b in zip(fast.paths, plain.paths, strict=True):
        assert a.read_bytes() == b.read_bytes()


def test_writer_reuses_one_chunk_buffer(tmp_path: Path) -> None:
    """The chunks are built in one buffer, allocated once, not in a BytesIO per chunk that
    grows (and moves) with each depth payload."""
    with LogWriter(tmp_path / "b.mcap") as writer:
        assert writer._fast is not None
        buffer = writer._fast._buffer
        capacity = len(buffer._data)
        for key, payload, t in session(30):
            writer.write_received(key, payload, t)
            # Ours, or mcap's fresh one right after a chunk ended, until the next message.
            current = writer._fast._stream._buffer
            assert current is buffer or (isinstance(current, io.BytesIO) and not current.tell())
        assert len(buffer._data) == capacity
    with McapLog(tmp_path / "b.mcap") as log:
        assert sum(item.opcode == Opcode.CHUNK for item in log._items) >= 4


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_background_writer_writes_what_log_writer_writes(tmp_path: Path, compression: str) -> None:
    """The thread writes the calls in the order they were made: the same files, rotated ones and
    a rejected payload included, byte for byte, whether a batch is handed over after every
    message, now and then, or only at the end."""
    items = session(30)
    items.insert(7, ("lpc/emg", b"\xc1 not msgpack", items[6][2]))
    plain = write_session(tmp_path / "plain.mcap", items, compression=compression, max_bytes=2**21)
    assert len(plain.paths) > 1, "rotated"
    for every in (1, 5, len(items) + 1):
        path = tmp_path / f"every{every}.mcap"
        with BackgroundLogWriter(path, compression=compression, max_bytes=2**21) as writer:
            headers = []
            for i, (key, payload, t) in enumerate(items):
                headers.append(writer.write_received(key, payload, t))
                if i % every == every - 1:
                    writer.hand_over()
        assert headers[7] is None and headers[8] == read_header(items[8][1])
        assert writer.messages == writer.written == len(items) and writer.backlog == 0
        assert len(writer.paths) == len(plain.paths)
        for a, b in zip(writer.paths, plain.paths, strict=True):
            assert a.read_bytes() == b.read_bytes()
        writer.finish()  # twice is fine
        with pytest.raises(ValueError, match="after finish"):
            writer.write("lpc/emg", EmgSample(seq=1, t_ns=T0, channels=[0.0, 0.0]), T0)


def test_background_writer_drain_writes_what_is_queued(tmp_path: Path) -> None:
    items = session(10)
    with BackgroundLogWriter(tmp_path / "d.mcap") as writer:
        for key, payload, t in items[:20]:
            writer.write_received(key, payload, t)
        assert writer.backlog == 20
        writer.drain()
        assert writer.written == 20 and writer.backlog == 0


def test_background_writer_error_is_raised_by_the_callers_next_call(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A failed write on the thread (here: a full disk) reaches the caller as LogWriter would
    have raised it: at the next write, a drain or the finish."""

    def full(self: object, data: bytes) -> int:
        raise OSError(28, "No space left on device")

    writer = BackgroundLogWriter(tmp_path / "full.mcap", compression="none", chunk_bytes=1024)
    monkeypatch.setattr(services.mcap_log._FileSink, "write", full)
    frame = depth_frame(0)  # more than a chunk: written at once
    writer.write("lpc/camera/depth", frame, frame.t_ns)
    with pytest.raises(OSError, match="No space"):
        writer.drain()
    with pytest.raises(OSError, match="No space"):
        writer.finish()  # the footer cannot be written either
