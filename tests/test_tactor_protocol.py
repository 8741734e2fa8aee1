"""EAI framing and the line protocol, byte for byte against frames computed by hand."""

from __future__ import annotations

import pytest

from lpc_core.devices import tactor_protocol as tp
from lpc_core.devices.tactor_protocol import (
    OFF,
    EaiCommand,
    EaiParser,
    EaiSettings,
    FrameError,
    LineParser,
    NakCode,
    Reply,
    TactorOutput,
)

# Each checksum worked out on paper: XOR of the bytes before it, then XOR 0xEA.
HAND_FRAMES = [
    # 02^00^00^00 = 02; ^EA = E8
    (tp.all_off(), "02 00 00 00 e8 03"),
    # 02^80^01^05 = 86; ^EA = 6C
    (tp.set_tactors(0b0101), "02 00 80 01 05 6c 03"),
    # gain level 2 travels as 2 << 6 = 0x80: 02^20^01^80 = A3; ^EA = 49
    (tp.set_gain(2), "02 00 20 01 80 49 03"),
    # 250 Hz = 0x00FA, LSB first: 02^12^02^FA^00 = E8; ^EA = 02
    (tp.sine_frequency(1, 250), "02 00 12 02 fa 00 02 03"),
    # 300 Hz = 0x012C on generator 2: 02^14^02^2C^01 = 39; ^EA = D3
    (tp.sine_frequency(2, 300), "02 00 14 02 2c 01 d3 03"),
    # tactors 0 and 1 for 100 ms = 10 steps: 02^11^02^03^0A = 18; ^EA = F2
    (tp.on_time(0b0011, 100), "02 00 11 02 03 0a f2 03"),
    # sine 1 for both groups, 0x11: 02^15^01^11 = 07; ^EA = ED
    (tp.signal_source(1), "02 00 15 01 11 ed 03"),
    # 02^42^00 = 40; ^EA = AA
    (tp.firmware_version(), "02 00 42 00 aa 03"),
    # ACK of set-tactors: 02^C8^01^80 = 4B; ^EA = A1
    (tp.ack_frame(0x80), "02 c8 01 80 a1 03"),
    # NAK bad checksum: 02^C4^01^02 = C5; ^EA = 2F
    (tp.nak_frame(2), "02 c4 01 02 2f 03"),
]


@pytest.mark.parametrize(("built", "expected"), HAND_FRAMES)
def test_frame_matches_hand_computed_bytes(built: bytes, expected: str) -> None:
    assert built == bytes.fromhex(expected)


def test_frame_board_byte_enters_checksum() -> None:
    # board 1: 02^01^00^00 = 03; ^EA = E9
    assert tp.frame(0x00, board=1) == bytes.fromhex("02 01 00 00 e9 03")


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: tp.set_gain(4), "level"),
        (lambda: tp.set_tactors(256), "mask"),
        (lambda: tp.on_time(1, 3000), "duration_ms"),
        (lambda: tp.sine_frequency(3, 250), "generator"),
        (lambda: tp.sine_frequency(1, 70000), "frequency_hz"),
        (lambda: tp.frame(0x80, bytes(40)), "data"),
    ],
)
def test_frame_bad_parameter_raises_naming_it(call, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        call()


def test_parser_controller_side_decodes_commands_split_anywhere() -> None:
    stream = b"\xff\x00" + tp.set_gain(3) + tp.set_tactors(0b1001) + tp.all_off()
    parser = EaiParser("controller")
    events = []
    for i in range(len(stream)):  # one byte at a time, as a slow serial line delivers them
        events += parser.feed(stream[i : i + 1])
    assert events == [
        EaiCommand(board=0, command=0x20, data=b"\xc0"),
        EaiCommand(board=0, command=0x80, data=b"\x09"),
        EaiCommand(board=0, command=0x00, data=b""),
    ]
    assert parser.pending == 0


def test_parser_bad_checksum_reports_and_resynchronises() -> None:
    bad = bytearray(tp.set_tactors(1))
    bad[-2] ^= 0x01
    events = EaiParser("controller").feed(bytes(bad) + tp.all_off())
    assert isinstance(events[0], FrameError) and events[0].code == NakCode.BAD_CHECKSUM
    assert events[1] == EaiCommand(board=0, command=0x00, data=b"")


def test_parser_missing_end_byte_reports_and_resynchronises() -> None:
    bad = bytearray(tp.set_tactors(1))
    bad[-1] = 0x04
    events = EaiParser("controller").feed(bytes(bad) + tp.all_off())
    assert isinstance(events[0], FrameError) and events[0].code == NakCode.END_MISSING
    assert events[-1] == EaiCommand(board=0, command=0x00, data=b"")


def test_parser_oversized_length_reports_too_long() -> None:
    events = EaiParser("controller").feed(bytes((0x02, 0x00, 0x80, 200)))
    assert [e.code for e in events if isinstance(e, FrameError)] == [NakCode.PAYLOAD_TOO_LONG]


def test_parser_host_side_decodes_ack_and_nak() -> None:
    events = EaiParser("host").feed(tp.ack_frame(0x42, b"\x01\x07") + tp.nak_frame(4))
    assert events == [
        Reply(ok=True, command=0x42, data=b"\x01\x07"),
        Reply(ok=False, code=4),
    ]


def test_eai_settings_single_tactor_and_diagonal_pair() -> None:
    # Strongest level 0.9 -> ceil(2.7) = gain 3; tactor 1 at 0.2 < 0.5 * 0.9 stays off.
    assert tp.eai_settings(TactorOutput((0.9, 0.2, 0.0, 0.0))) == EaiSettings(3, 0b0001, 250)
    # A diagonal shares equally: both tactors on; 0.3 -> ceil(0.9) = gain 1.
    assert tp.eai_settings(TactorOutput((0.0, 0.3, 0.3, 0.0))) == EaiSettings(1, 0b0110, 250)
    assert tp.eai_settings(OFF) is None


def test_eai_update_sends_only_what_changed() -> None:
    now = EaiSettings(gain=2, mask=0b0001, frequency_hz=250)
    moved = EaiSettings(gain=2, mask=0b0010, frequency_hz=250)
    assert tp.eai_update(moved, now) == [tp.set_tactors(0b0010)]
    assert tp.eai_update(moved, None) == [
        tp.sine_frequency(1, 250),
        tp.set_gain(2),
        tp.set_tactors(0b0010),
    ]
    assert tp.eai_update(None, now) == [tp.all_off()]


def test_line_command_formats_duties() -> None:
    out = TactorOutput((1.0, 0.5, 0.001, 0.0))
    # 0.5 * 255 = 127.5 -> 128; a tiny level still gets duty 1, never silently off.
    assert tp.line_command(out) == b"T 255 128 1 0\n"
    assert tp.line_command(OFF) == b"T 0 0 0 0\n"


def test_line_parse_command_accepts_and_explains() -> None:
    assert tp.parse_line_command(b"T 1 2 3 255") == (1, 2, 3, 255)
    assert tp.parse_line_command(b"T 1 2 3") == "expected 4 duties"
    assert tp.parse_line_command(b"T 1 2 3 256") == "duties must lie in 0..255"
    assert tp.parse_line_command(b"X") == "unknown command"


def test_line_parser_host_side_replies() -> None:
    parser = LineParser("host")
    assert parser.feed(b"OK\r\nER") == [Reply(ok=True, text="OK")]
    assert parser.feed(b"R duty\n") == [Reply(ok=False, text="duty")]


def test_output_rejects_bad_levels() -> None:
    with pytest.raises(ValueError, match="levels"):
        TactorOutput((0.0, 0.0, 1.5, 0.0))
    with pytest.raises(ValueError, match="levels"):
        TactorOutput((0.0, 0.0))
