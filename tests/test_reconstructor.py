"""The reconstructor: pool bookkeeping (order, backpressure), the in-process step, the service."""

from __future__ import annotations

import collections
import time

import numpy as np
import pytest
import zenoh

from lpc_core.reconstructor import (
    Dropped,
    PoolParams,
    PoolState,
    ReconstructState,
    Release,
    Submit,
    frame_arrived,
    frame_done,
    reconstruct_message,
    reconstruct_step,
    scan_lines_from_message,
)
from schemas import GraspTarget, Reconstruction, ScanLine, ScanLines, decode, encode, to_wire
from tests.conftest import spawn_service, wait_for
from tests.test_laser import cylinder, scan, sphere


def _message(seq: int, lines, t_ns: int | None = None) -> ScanLines:
    return ScanLines(
        seq=seq,
        t_ns=t_ns if t_ns is not None else 1_000_000_000 + seq * 11_111_111,
        frame_seq=seq,
        lines=[
            ScanLine(angle_deg=float(np.degrees(a)), points=to_wire(p.astype(np.float32)))
            for a, p in zip(lines.angles_rad, lines.points, strict=True)
        ],
    )


BALL = scan(sphere((0.0, 0.002, 0.21), 0.025), seed=1)


# --------------------------------------------------------------------------- bookkeeping


def test_pool_runs_up_to_workers_then_queues_then_drops_oldest() -> None:
    state = PoolState(params=PoolParams(workers=2, max_pending=1))
    state, out = frame_arrived(state, 1, "a")
    assert out == [Submit(1, "a")]
    state, out = frame_arrived(state, 2, "b")
    assert out == [Submit(2, "b")]
    state, out = frame_arrived(state, 3, "c")
    assert out == []  # waits for a worker
    state, out = frame_arrived(state, 4, "d")
    assert out == [Dropped(3, "the pool fell behind")]
    assert state.dropped == 1 and state.pending == ((4, "d"),)


def test_pool_releases_in_seq_order_whatever_the_finish_order() -> None:
    state = PoolState(params=PoolParams(workers=3, max_pending=0))
    for seq in (1, 2, 3):
        state, _ = frame_arrived(state, seq, seq)
    state, out = frame_done(state, 3, "r3")
    assert out == []  # 1 and 2 still running
    state, out = frame_done(state, 1, "r1")
    assert out == [Release(1, "r1")]
    state, out = frame_done(state, 2, "r2")
    assert out == [Release(2, "r2"), Release(3, "r3")]
    assert state.waiting == () and not state.done


def test_pool_done_starts_the_waiting_frame() -> None:
    state = PoolState(params=PoolParams(workers=1, max_pending=2))
    state, _ = frame_arrived(state, 1, "a")
    state, _ = frame_arrived(state, 2, "b")
    state, out = frame_done(state, 1, "r1")
    assert out == [Submit(2, "b"), Release(1, "r1")]
    assert state.running == frozenset({2})


def test_pool_drop_unblocks_later_results() -> None:
    state = PoolState(params=PoolParams(workers=1, max_pending=1))
    state, _ = frame_arrived(state, 1, "a")
    state, _ = frame_arrived(state, 2, "b")  # waits
    state, out = frame_arrived(state, 3, "c")  # 2 dropped, 3 waits
    assert Dropped(2, "the pool fell behind") in out
    state, out = frame_done(state, 1, "r1")
    assert out == [Submit(3, "c"), Release(1, "r1")]
    state, out = frame_done(state, 3, "r3")
    assert out == [Release(3, "r3")]


def test_pool_ignores_out_of_order_and_unknown_frames() -> None:
    state = PoolState()
    state, _ = frame_arrived(state, 5, "a")
    state, out = frame_arrived(state, 4, "old")
    assert out == [Dropped(4, "out of order")]
    same, out = frame_done(state, 99, "x")
    assert out == [] and same == state


def test_pool_params_reject_bad_values() -> None:
    with pytest.raises(ValueError, match="workers"):
        PoolParams(workers=0)
    with pytest.raises(ValueError, match="max_pending"):
        PoolParams(max_pending=-1)


# --------------------------------------------------------------------------- in-process


def test_scan_lines_from_message_round_trip() -> None:
    lines = scan_lines_from_message(_message(1, BALL))
    assert np.allclose(lines.angles_rad, BALL.angles_rad)
    for got, want in zip(lines.points, BALL.points, strict=True):
        assert np.allclose(got, want, atol=1e-6)


def test_reconstruct_step_publishes_reconstruction_then_window() -> None:
    state = ReconstructState()
    outputs = []
    for seq in range(10):
        state, out = reconstruct_step(state, _message(seq, BALL), 0)
        outputs.append(out)
    rec, target = outputs[-1]
    assert isinstance(rec, Reconstruction) and isinstance(target, GraspTarget)
    assert rec.shape == "sphere" and rec.seq == 9 and rec.frame_seq == 9
    assert rec.grasp_width_mm == pytest.approx(50.0, abs=2.0)
    assert len(rec.lines) == 4 and rec.points > 0
    assert target.reconstructed and target.frames == 10 and target.shape == "sphere"
    assert not outputs[0][1].reconstructed
    # The message survives the topic's validating decoder.
    assert decode("lpc/reconstruction", encode(rec)) == rec


def test_reconstruct_message_reports_reason_when_nothing_fits() -> None:
    empty = ScanLines(
        seq=1, t_ns=1, frame_seq=1,
        lines=[ScanLine(angle_deg=a, points=to_wire(np.zeros((0, 3), np.float32)))
               for a in (0.0, 45.0, 90.0, 135.0)],
    )  # fmt: skip
    rec = reconstruct_message(empty)
    assert rec.shape == "none" and "too few points" in rec.reason


# --------------------------------------------------------------------------- the service


def test_reconstructor_service_publishes_in_order(rendezvous: zenoh.Session, endpoint: str) -> None:
    got: dict[str, list] = collections.defaultdict(list)
    subs = [
        rendezvous.declare_subscriber(
            key, lambda s, key=key: got[key].append(decode(key, s.payload.to_bytes()))
        )
        for key in ("lpc/reconstruction", "lpc/grasp/target")
    ]
    scans = rendezvous.declare_publisher("lpc/scans")
    process = spawn_service(
        "services.reconstructor", endpoint, "--workers", "2", "--max-pending", "50"
    )
    can = scan(cylinder((0.0, 0.0, 0.2), (0.0, 1.0, 0.0), 0.02), seed=2)
    try:
        # Until the workers are up, frames may be missed by the subscriber: probe first.
        probe = 1000
        while not got["lpc/reconstruction"]:
            scans.put(encode(_message(probe, BALL)))
            probe += 1
            time.sleep(0.2)
            assert process.poll() is None, process.stderr.read().decode() if process.stderr else ""
        for k in range(12):
            scans.put(encode(_message(2000 + k, can if k % 2 else BALL)))
            time.sleep(0.01)

        def ours() -> list[Reconstruction]:
            return [r for r in got["lpc/reconstruction"] if r.seq >= 2000]

        wait_for(lambda: len(ours()) >= 12, 30.0, "12 results")
        recs = ours()
        assert [r.seq for r in got["lpc/reconstruction"]] == sorted(
            r.seq for r in got["lpc/reconstruction"]
        )
        assert [r.seq for r in recs] == list(range(2000, 2012))
        assert [r.shape for r in recs] == ["cylinder" if k % 2 else "sphere" for k in range(12)]
        assert all(r.compute_ms > 0 for r in recs)
        wait_for(lambda: got["lpc/grasp/target"][-1].frame_seq == 2011, 10.0, "the last target")
    finally:
        process.terminate()
        process.wait(timeout=20)
        for sub in subs:
            sub.undeclare()
    assert process.returncode == 0
