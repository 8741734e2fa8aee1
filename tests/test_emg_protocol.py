"""The serial EMG frame: layout, CRC, resynchronisation; the serial source on pyserial's loop://."""

from __future__ import annotations

import time

import pytest

from lpc_core.devices.emg_protocol import FrameParser, crc16, encode_frame
from services.drivers.emg import SerialEmg
from services.drivers.errors import DeviceUnavailable, OperationError


def test_frame_layout_two_channels() -> None:
    frame = encode_frame(0x0102, [12.3e-6, 0.5e-6], flags=0x02)
    assert frame[:2] == b"\xa5\x5a"
    assert frame[2:6] == bytes([0x02, 0x01, 2, 0x02])  # seq LE, n, flags
    assert frame[6:10] == bytes([123, 0, 5, 0])  # 0.1 uV units, LE
    assert int.from_bytes(frame[10:12], "little") == crc16(frame[2:10])
    assert len(frame) == 12


def test_crc16_is_ccitt_false() -> None:
    assert crc16(b"123456789") == 0x29B1  # the standard check value


def test_parser_round_trip_and_clipping() -> None:
    parser = FrameParser()
    frames = parser.feed(encode_frame(7, [1e-3, 1.0]) + encode_frame(8, [0.0, -1.0]))
    assert [f.seq for f in frames] == [7, 8]
    assert frames[0].channels == pytest.approx((1e-3, 6.5535e-3))  # clipped at 0xFFFF counts
    assert frames[1].channels == (0.0, 0.0)


def test_parser_survives_noise_split_reads_bad_crc_and_counts_losses() -> None:
    good = [encode_frame(i, [i * 1e-6, 2e-6]) for i in range(10)]
    corrupt = bytearray(good[3])
    corrupt[7] ^= 0xFF
    stream = b"\x00\xa5\x11" + good[0] + good[1] + bytes(corrupt) + good[4] + good[6]
    stream += good[7][:5]
    parser = FrameParser()
    out = []
    for i in range(0, len(stream), 3):  # arbitrary read boundaries
        out += parser.feed(stream[i : i + 3])
    out += parser.feed(good[7][5:])
    assert [f.seq for f in out] == [0, 1, 4, 6, 7]
    assert parser.bad_crc == 1
    assert parser.lost == 3  # seq 2, 3 (the corrupt one) and 5
    assert parser.skipped_bytes > 0


def test_parser_rejects_a_bad_channel_count_and_resyncs() -> None:
    bogus = b"\xa5\x5a\x00\x00\x00\x00"  # n = 0: not a frame
    parser = FrameParser()
    out = parser.feed(bogus + encode_frame(1, [1e-6]))
    assert [f.seq for f in out] == [1] and parser.bad_header == 1


def test_encode_frame_rejects_bad_channel_counts() -> None:
    with pytest.raises(ValueError, match="channels_v"):
        encode_frame(0, [])
    with pytest.raises(ValueError, match="channels_v"):
        encode_frame(0, [0.0] * 9)


def test_serial_source_reads_frames_from_the_loop_backend() -> None:
    source = SerialEmg("loop://", channels=(1, 0))
    try:
        assert source.recv(timeout=0.02) is None
        for i in range(3):
            source._serial.write(encode_frame(i, [1e-6 * i, 5e-6, 9e-6]))
        got = [source.recv(timeout=1.0) for _ in range(3)]
        assert all(g is not None for g in got)
        assert got[2][0] == pytest.approx([5e-6, 2e-6])  # (flexor, extensor) = channels (1, 0)
        assert abs(got[2][1] - time.time_ns()) < 10e9
    finally:
        source.shutdown()
        source.shutdown()
    with pytest.raises(OperationError):
        source.recv(timeout=0.01)


def test_serial_source_unavailable_port() -> None:
    with pytest.raises(DeviceUnavailable, match="/dev/no-such-port"):
        SerialEmg("/dev/no-such-port")
