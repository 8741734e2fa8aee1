"""lpc's Ability Hand codec against the vendor's own code (PyPI ``ability-hand``, ``ah_wrapper``).

The vendor package writes a ``config.py`` into the working directory when imported, so it is
imported from a temporary directory. Commands are compared byte for byte with the vendor's
encoders; every reply lpc's simulated hand sends over a pty is decoded by the vendor's
unstuffer and parser and compared value for value; damaged frames are rejected and counted by
lpc's parser. The counts compared are printed (``pytest -s``).
"""

from __future__ import annotations

import importlib
import os
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest
import serial

from lpc_core.devices import ability as ab
from lpc_core.devices import ability_grips as ag
from lpc_core.sim.ability_hand import AbilityState, ability_reply
from services.drivers.ability_sim import AbilitySim

N_COMMANDS = 300


def _report(capsys: pytest.CaptureFixture[str], line: str) -> None:
    """The counts compared, shown in CI's log too (outside pytest's capture)."""
    with capsys.disabled():
        print(f"\n{line}")


@pytest.fixture(scope="module")
def vendor(tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    where = tmp_path_factory.mktemp("ability-hand-cwd")
    cwd = os.getcwd()
    os.chdir(where)
    try:
        api = importlib.import_module("ah_wrapper.ah_api")
        parser = importlib.import_module("ah_wrapper.ah_parser")
        ppp = importlib.import_module("ah_wrapper.ppp_stuffing")
        config = importlib.import_module("config")
    finally:
        os.chdir(cwd)
    assert (where / "config.py").exists()  # written there, not in the repository
    config.write_log = False
    config.velocity_warning = False
    yield SimpleNamespace(api=api, parser=parser, ppp=ppp)
    if sys.path and sys.path[0] == str(where):
        sys.path.pop(0)


def test_position_frames_match_the_vendor(
    vendor: SimpleNamespace, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(16)
    for _ in range(N_COMMANDS):
        positions = rng.uniform(-200.0, 200.0, 6)  # beyond +-150 deg: both clamp
        variant = int(rng.integers(0, 3))
        address = int(rng.choice([0x50, 0x7E, 0x7D, int(rng.integers(0, 256))]))
        ours = ab.position_frame(positions, variant, address)
        theirs = bytes(vendor.api.create_pos_msg(variant, positions.tolist(), address))
        assert ours == theirs, (positions, variant, address)
    _report(capsys, f"conformance: {N_COMMANDS} position commands byte-identical to create_pos_msg")


def test_velocity_frames_match_the_vendor(
    vendor: SimpleNamespace, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(17)
    for _ in range(N_COMMANDS):
        velocities = rng.uniform(-2999.0, 2999.0, 6)  # the vendor does not clamp velocities
        variant = int(rng.integers(0, 3))
        ours = ab.velocity_frame(velocities, variant)
        theirs = bytes(vendor.api.create_vel_msg(variant, velocities.tolist()))
        assert ours == theirs, (velocities, variant)
    _report(capsys, f"conformance: {N_COMMANDS} velocity commands byte-identical to create_vel_msg")


def test_grip_frames_match_the_vendor(
    vendor: SimpleNamespace, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(18)
    n = 0
    for grip in range(256):
        speed = int(rng.integers(0, 256))
        assert ab.grip_frame(grip, speed) == bytes(vendor.api.create_grip_msg(grip, speed))
        n += 1
    assert ab.grip_frame(ab.Grip.KEY) == bytes(vendor.api.create_grip_msg(ab.Grip.KEY))
    _report(capsys, f"conformance: {n + 1} grip commands byte-identical to create_grip_msg")


def _vendor_frames(vendor: SimpleNamespace, data: bytes) -> list:
    unstuffer = vendor.ppp.PPPUnstuff()
    frames = []
    for b in data:
        frame = unstuffer.unstuff_byte(b)
        if frame:
            frames.append(vendor.parser.parse_packet(frame))
    return frames


def _compare(theirs: object, ours: ab.Reply) -> None:
    assert theirs is not None and theirs.valid
    assert theirs.pos == list(ours.positions_deg)
    if ours.current is not None:
        assert theirs.cur == list(ours.currents_a)
    if ours.rotor_velocity is not None:
        # The vendor scales rotor counts by 3000 / 32767 / 4; compare the counts themselves.
        counts = [round(v / (ab.VELOCITY_COUNTS_PER_DEG_S**-1 / 4)) for v in theirs.vel]
        assert counts == list(ours.rotor_velocity)
    if ours.touch is not None:
        assert theirs.fsr == pytest.approx(list(ours.touch_force_n), rel=1e-12, abs=0)
    assert theirs.hot_cold & 0xFF == ours.hot_cold


def test_vendor_parser_decodes_every_reply_of_the_simulated_hand(
    vendor: SimpleNamespace, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(19)
    counts = dict.fromkeys((0, 1, 2), 0)
    with AbilitySim(object_mm=40.0) as sim:
        port = serial.Serial(sim.port, baudrate=ab.BAUDRATE, timeout=0)
        try:
            parser = ab.FrameParser()
            grips = list(ag.GRIPS)
            for i in range(N_COMMANDS):
                variant = i % 3
                if i % 4 == 0:  # some poses of lpc's grips, pressing on the object
                    pose = ag.positions_for(grips[i % len(grips)], rng.uniform(0, 110))
                else:
                    pose = rng.uniform([0, 0, 0, 0, 0, -100], [100, 100, 100, 100, 100, 0])
                port.write(ab.position_frame(pose, variant))
                data = b""
                deadline = time.monotonic() + 2.0
                replies: list = []
                while not replies and time.monotonic() < deadline:
                    chunk = port.read(4096)
                    data += chunk
                    replies = [e for e in parser.feed(chunk) if isinstance(e, bytes)]
                    if not chunk:
                        time.sleep(0.0005)
                assert len(replies) == 1, f"no reply to command {i}"
                ours = ab.decode_reply(replies[0])
                assert ours.variant == variant
                (theirs,) = _vendor_frames(vendor, data)
                _compare(theirs, ours)
                counts[variant] += 1
        finally:
            port.close()
        assert sum(sim.errors.values()) == 0
    total = sum(counts.values())
    assert total == N_COMMANDS
    _report(
        capsys,
        f"conformance: {total} replies of the simulated hand decoded alike by ah_parser "
        f"(variant 1: {counts[0]}, 2: {counts[1]}, 3: {counts[2]})",
    )


def test_damaged_frames_are_rejected_and_counted(
    vendor: SimpleNamespace, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(20)
    state = AbilityState(squeeze_mm=5.0, grip="power")
    good = [ab.encode_reply(ability_reply(state, v)) for v in (0, 1, 2)]
    stream = bytearray()
    expected = {"good": 0, "bad": 0}
    kinds = {"corrupt": 0, "truncated": 0, "unstuffed": 0}
    for i in range(N_COMMANDS):
        frame = bytearray(good[i % 3])
        damage = i % 4
        if damage == 1:  # one byte changed inside the frame
            k = int(rng.integers(1, len(frame) - 1))
            frame[k] = (frame[k] + int(rng.integers(1, 256))) & 0xFF
            if frame[k] == ab.FRAME_CHAR:  # would split the frame in two: make it plain
                frame[k] = 0x11
            kinds["corrupt"] += 1
        elif damage == 2:  # cut short, still closed by a frame character
            frame = frame[: int(rng.integers(2, len(frame) - 2))] + bytes((ab.FRAME_CHAR,))
            kinds["truncated"] += 1
        elif damage == 3:  # the hand with stuffing off: raw bytes, no frame characters
            raw = bytes(b for b in good[i % 3][1:-1] if b != ab.ESC_CHAR)
            frame = bytearray(raw * 8)  # more than one frame's worth before the next 0x7E
            kinds["unstuffed"] += 1
        stream += frame
        expected["bad" if damage else "good"] += 1
    stream += good[0]  # a last good frame closes whatever came before it
    expected["good"] += 1
    parser = ab.FrameParser()
    decoded, rejected = 0, 0
    for k in range(0, len(stream), 37):  # in chunks, as reads come
        for event in parser.feed(bytes(stream[k : k + 37])):
            if isinstance(event, ab.FrameError):
                rejected += 1
                continue
            try:
                ab.decode_reply(event)
                decoded += 1
            except ab.FrameError:
                rejected += 1
    assert decoded == expected["good"]
    assert rejected == expected["bad"]
    _report(
        capsys,
        f"conformance: {len(stream)} bytes, {expected['good']} good replies decoded, "
        f"{rejected} rejections for {expected['bad']} damaged frames {kinds}",
    )
