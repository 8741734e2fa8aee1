"""Recorder: round trips over a real Zenoh session on loopback, and a clean finish on SIGTERM."""

from __future__ import annotations

import argparse
import asyncio
import signal
from pathlib import Path

import pytest
import zenoh

from schemas import EmgSample, Health, ProsthesisState, decode, encode
from services import recorder
from services.mcap_log import REJECTED_PREFIX, LogWriter, McapLog
from services.runtime import Bus, zenoh_config
from tests.conftest import spawn_service, until, wait_for

T0 = 1_700_000_000_000_000_000


def payloads(n: int) -> list[tuple[str, bytes]]:
    """EMG and prosthesis state interleaved, and one payload with no readable header."""
    out: list[tuple[str, bytes]] = []
    for i in range(n):
        out.append(("lpc/emg", encode(EmgSample(seq=i, t_ns=T0 + i, channels=[0.1, i / n]))))
        state = ProsthesisState(seq=i, t_ns=T0 + i, wrist_angle_deg=0.5 * i, aperture_mm=80.0)
        out.append(("lpc/prosthesis/state", encode(state)))
    out.insert(n, ("lpc/emg", b"\xc1 garbage"))
    return out


def test_recorder_round_trip_keeps_every_message_in_order(
    tmp_path: Path, endpoint: str, rendezvous: zenoh.Session, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Batches in slices of 7: the task is cancelled once every message is received (taken
    # from the subscription), which may be between two slices of a batch not yet queued.
    monkeypatch.setattr(recorder, "SLICE", 7)
    sent = payloads(300)
    out = tmp_path / "rec.mcap"

    async def main() -> Bus:
        loop = asyncio.get_running_loop()
        with zenoh.open(zenoh_config(connect=[endpoint])) as session:
            bus = Bus(session, "recorder", loop=loop, quiet=True)
            args = argparse.Namespace(out=out, compression="zstd", zstd_level=1, max_mb=None)
            task = asyncio.create_task(recorder.serve(bus, args))
            # Both keys on one publisher-side session; BLOCK so the sender never drops.
            pubs = {
                key: rendezvous.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.BLOCK
                )
                for key in ("lpc/emg", "lpc/prosthesis/state")
            }
            await until(
                lambda: all(p.matching_status.matching for p in pubs.values()),
                what="the recorder's subscriber",
            )
            for key, payload in sent:
                pubs[key].put(payload)
            await until(
                lambda: sum(bus.health.received[k].count for k in pubs) >= len(sent),
                what="every message received",
            )
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            bus.close()
            for pub in pubs.values():
                pub.undeclare()
            return bus

    bus = asyncio.run(main())
    assert sum(s.dropped for s in bus.health.received.values()) == 0
    with McapLog(out) as log:
        everything = list(log.messages(ordered=False))
        assert log.complete and log.cut is None
    got = [m for m in everything if not m.key.startswith("lpc/log/")]
    # The health counters as the recorder leaves them: each message counted once as written,
    # one file, no gap (each key's seq runs 0, 1, 2...).
    counters = bus.health.counters
    assert counters["written"] == len(everything)
    assert (counters["files"], counters["gaps"], counters["missing"]) == (1, 0, 0)
    # One subscriber keeps per-key order; the file holds exactly what was sent.
    for key in ("lpc/emg", "lpc/prosthesis/state"):
        assert [m.payload for m in got if m.key == key] == [
            p for k, p in sent if k == key and p[0] != 0xC1
        ]
    (rejected,) = [m for m in got if m.key.startswith(REJECTED_PREFIX)]
    assert rejected.key == REJECTED_PREFIX + "lpc/emg" and rejected.payload == b"\xc1 garbage"
    assert bus.health.received["lpc/emg"].rejected == 1
    for m in got:
        if not m.key.startswith(REJECTED_PREFIX):
            message = decode(m.key, m.payload)
            assert m.publish_time == message.t_ns and m.sequence == message.seq


def test_recorder_identical_input_gives_identical_bytes(tmp_path: Path) -> None:
    received = [(key, payload, T0 + 1000 * i) for i, (key, payload) in enumerate(payloads(200))]
    for name in ("a.mcap", "b.mcap"):
        with LogWriter(tmp_path / name) as writer:
            for key, payload, t in received:
                writer.write_received(key, payload, t)
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


def test_recorder_process_finishes_file_on_sigterm(
    tmp_path: Path, endpoint: str, rendezvous: zenoh.Session
) -> None:
    out = tmp_path / "proc.mcap"
    health: list[Health] = []
    sub = rendezvous.declare_subscriber(
        "lpc/health/recorder",
        lambda s: health.append(decode(str(s.key_expr), s.payload.to_bytes())),
    )
    process = spawn_service(
        "services.recorder", endpoint, "--out", str(out), "--compression", "lz4", "--max-mb", "64"
    )
    try:
        pub = rendezvous.declare_publisher(
            "lpc/emg", congestion_control=zenoh.CongestionControl.BLOCK
        )
        wait_for(lambda: pub.matching_status.matching, what="the recorder's subscriber")
        n = 100
        for i in range(n):
            pub.put(encode(EmgSample(seq=i, t_ns=T0 + i, channels=[0.0, 1.0])))
        # One publisher keeps its order: once the recorder has counted this last, headerless
        # payload as rejected (its health, once a second), it has received all the others.
        pub.put(b"\xc1 end")
        wait_for(
            lambda: any(h.counters.get("rejected", 0) == 1 for h in health),
            what="the recorder's health to count the last message",
        )
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=5) == 0
    finally:
        if process.poll() is None:
            process.kill()
        sub.undeclare()
    with McapLog(out) as log:
        emg = [m.message for m in log.messages(["lpc/emg"], decode=True)]
        assert log.complete and log.cut is None
        assert log.compressions == {"lz4"}
        rejected = list(log.messages([REJECTED_PREFIX + "lpc/emg"]))
    assert [m.seq for m in emg] == list(range(n))
    assert [m.payload for m in rejected] == [b"\xc1 end"]
    assert all(h.counters["dropped"] == 0 for h in health)
