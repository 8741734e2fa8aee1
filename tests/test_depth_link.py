"""The depth device's wire (lpc_core.devices.depth_link): records survive any split of the
stream, and bytes that are not a record are skipped and reported once per run."""

from __future__ import annotations

import struct
import tracemalloc

import numpy as np

from lpc_core.devices.depth_link import (
    MAGIC,
    DeviceFrame,
    DeviceHello,
    LinkParser,
    Rejected,
    encode,
)
from schemas import CameraIntrinsics, ObjectTruth, to_wire

INTRINSICS = CameraIntrinsics(width=8, height=4, fx=213.0, fy=213.0, ppx=4.0, ppy=2.0)


def _frame(seq: int) -> DeviceFrame:
    depth = np.arange(32, dtype=np.uint16).reshape(4, 8) + seq
    truth = ObjectTruth(name="sphere_large", shape="sphere", grasp_width_mm=70.0)
    return DeviceFrame(seq=seq, t_ns=1_000 + seq, depth=to_wire(depth), truth=truth)


def test_depth_link_records_survive_any_split_of_the_stream() -> None:
    messages = [DeviceHello(intrinsics=INTRINSICS, rate_hz=90.0), _frame(0), _frame(1)]
    stream = b"".join(encode(m) for m in messages)
    for size in (1, 3, 7, 64, len(stream)):
        parser = LinkParser()
        out = []
        for i in range(0, len(stream), size):
            out += parser.feed(stream[i : i + size])
        assert out == messages, size
        assert parser.pending == 0 and parser.flush() is None


def test_depth_link_garbage_is_skipped_as_one_rejection_per_run() -> None:
    garbage = b"\x00not a record\xff" * 5  # no magic in them
    bad_body = MAGIC + struct.pack("<I", 3) + b"\xc1\xc1\xc1"  # msgpack's never-used byte
    stream = encode(_frame(0)) + garbage + encode(_frame(1)) + bad_body + encode(_frame(2))
    parser = LinkParser()
    out = []
    for i in range(0, len(stream), 1000):
        out += parser.feed(stream[i : i + 1000])
    assert out[0] == _frame(0)
    assert out[1] == Rejected(len(garbage), "bytes that are not a record")
    assert out[2] == _frame(1)
    assert isinstance(out[3], Rejected) and out[3].nbytes == 11
    assert "does not decode" in out[3].reason
    assert out[4] == _frame(2) and len(out) == 5


def test_depth_link_a_length_beyond_the_bound_is_garbage_not_a_wait() -> None:
    parser = LinkParser(max_body=1000)
    huge = MAGIC + struct.pack("<I", 10**9) + b"xyz"
    out = parser.feed(huge + encode(_frame(4)))
    assert out == [Rejected(11, "a record of 1000000000 bytes (at most 1000)"), _frame(4)]


def test_depth_link_a_truncated_record_is_reported_at_the_end() -> None:
    record = encode(_frame(0))
    parser = LinkParser()
    assert parser.feed(record[:-5]) == []
    assert parser.pending == len(record) - 5
    assert parser.flush() == Rejected(len(record) - 5, "a truncated record")
    assert parser.pending == 0


def test_depth_link_whole_records_are_decoded_where_they_lie() -> None:
    # A 200 KB frame arriving in one piece is decoded from the piece, not copied into the
    # parser's buffer first: one copy of the depth (the decoded frame's), not two.
    depth = np.arange(240 * 424, dtype=np.uint16).reshape(240, 424)
    frame = DeviceFrame(seq=5, t_ns=1, depth=to_wire(depth))
    record = encode(frame)
    piece = memoryview(bytearray(record + encode(_frame(6))[:10]))  # and a partial record
    parser = LinkParser()
    tracemalloc.start()
    try:
        out = parser.feed(piece)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert out == [frame]
    assert parser.pending == 10
    assert peak < 1.2 * len(record), peak  # main: 2.0 (buffer and frame)


def test_depth_link_frames_do_not_view_the_reused_receive_buffer() -> None:
    # The socket's receive buffer is refilled with the next piece while the camera still
    # holds the frame parsed from it; and the parser's own buffer shrinks after each record.
    first, second = _frame(0), _frame(1)
    receive = bytearray(encode(first))
    parser = LinkParser()
    out = parser.feed(memoryview(receive))
    receive[:] = encode(second)
    assert out == [first]
    record = encode(second)
    out = parser.feed(record[:10]) + parser.feed(record[10:])  # through the parser's buffer
    assert out == [second] and parser.pending == 0


def test_depth_link_frames_view_a_piece_nothing_writes_again() -> None:
    # bytes, or a buffer handed over, are decoded in place: the depth is a view of the piece
    # (no copy of the frame), and ``viewing`` tells the caller not to refill that buffer.
    record = encode(_frame(3))
    for piece, handed_over, views in (
        (record, False, True),
        (bytearray(record), True, True),
        (bytearray(record), False, False),
    ):
        parser = LinkParser()
        (frame,) = parser.feed(memoryview(piece) if handed_over else piece, handed_over=handed_over)
        assert frame == _frame(3) and parser.viewing is views
        depth = np.frombuffer(frame.depth.data, dtype=np.uint16)
        assert np.shares_memory(depth, np.frombuffer(piece, dtype=np.uint8)) is views
    parser.feed(record[:10])
    assert parser.feed(record[10:]) == [_frame(3)] and not parser.viewing  # through its buffer
