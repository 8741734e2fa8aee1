"""The reconstructor: pool bookkeeping (order, backpressure), the in-process steps of both
methods, the service with either method."""

from __future__ import annotations

import asyncio
import collections

import msgspec
import numpy as np
import pytest
import zenoh

from lpc_core.perception.cloud import reconstruct_cloud
from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.laser import reconstruct_laser
from lpc_core.perception.pipeline import ScansState, intrinsics_to_message, scans_step
from lpc_core.perception.reconstruction import LineSummary
from lpc_core.perception.reconstruction import Reconstruction as CoreReconstruction
from lpc_core.perception.reconstructor import (
    Dropped,
    PoolParams,
    PoolState,
    ReconstructState,
    Release,
    Submit,
    _scan_lines,
    frame_arrived,
    frame_done,
    reconstruct_cloud_message,
    reconstruct_cloud_step,
    reconstruct_message,
    reconstruct_step,
    reconstruction_message,
    scan_lines_from_message,
    warmup_frame,
)
from lpc_core.sim.scene import Plane, Scene, cylinder_object, render_depth, sphere_object
from schemas import (
    BadMessage,
    DepthFrame,
    GraspTarget,
    ObjectTruth,
    Reconstruction,
    ScanLine,
    ScanLines,
    decode,
    encode,
    from_wire,
    to_wire,
)
from services import reconstructor as reconstructor_service
from services.runtime import Bus, zenoh_config
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

# Depth frames for the cloud method: a 40 mm ball or a 65 mm can (axis along y) before a wall,
# rendered with the D435 noise model (range noise, flying pixels, holes, shadow).
INTR = Intrinsics()
WALL = Plane(np.array([0.0, 0.0, 0.26]), np.array([0.0, 0.0, -1.0]))
OBJECTS = {
    "ball": sphere_object("ball", (0.0, 0.005, 0.2), 0.02),
    "can": cylinder_object("can", (0.0, 0.0, 0.21), (0.0, 1.0, 0.0), 0.0325, 0.12),
}


def _depth(seq: int, name: str) -> np.ndarray:
    scene = Scene((OBJECTS[name],), WALL)
    return render_depth(scene, INTR, np.eye(4), np.random.default_rng(seq))


def _depth_frame(seq: int, name: str) -> DepthFrame:
    obj, depth = OBJECTS[name], _depth(seq, name)
    assert obj.grasp_width_m is not None
    truth = ObjectTruth(name=name, shape=obj.shape, grasp_width_mm=1000 * obj.grasp_width_m)
    return DepthFrame(
        seq=seq,
        t_ns=1_000_000_000 + seq * 11_111_111,
        intrinsics=intrinsics_to_message(INTR),
        depth=to_wire(depth),
        truth=truth,
    )


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


def test_pool_hands_a_frame_ahead_to_a_busy_worker_before_queueing() -> None:
    # One worker, one frame ahead: the second frame goes to the worker's pipe at once (it
    # starts there when the first is done, without waiting for the service), the third waits
    # in the service, where the fourth replaces it.
    state = PoolState(params=PoolParams(workers=1, max_pending=1, ahead=1))
    state, out = frame_arrived(state, 1, "a")
    assert out == [Submit(1, "a")]
    state, out = frame_arrived(state, 2, "b")
    assert out == [Submit(2, "b")]
    state, out = frame_arrived(state, 3, "c")
    assert out == []
    state, out = frame_arrived(state, 4, "d")
    assert out == [Dropped(3, "the pool fell behind")]
    # The first result hands the waiting frame on behind the second, and is released.
    state, out = frame_done(state, 1, "r1")
    assert out == [Submit(4, "d"), Release(1, "r1")]
    assert state.running == frozenset({2, 4}) and state.pending == ()
    state, out = frame_done(state, 2, "r2")
    assert out == [Release(2, "r2")]
    state, out = frame_done(state, 4, "r4")
    assert out == [Release(4, "r4")] and state.dropped == 1


def test_pool_without_ahead_keeps_one_frame_per_worker() -> None:
    assert PoolParams(workers=3).in_flight == 3
    assert PoolParams(workers=2, ahead=1).in_flight == 4


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
    with pytest.raises(ValueError, match="ahead"):
        PoolParams(ahead=-1)


# --------------------------------------------------------------------------- in-process


def test_scan_lines_from_message_round_trip() -> None:
    lines = scan_lines_from_message(_message(1, BALL))
    assert np.allclose(lines.angles_rad, BALL.angles_rad)
    for got, want in zip(lines.points, BALL.points, strict=True):
        assert np.allclose(got, want, atol=1e-6)


def test_reconstruct_message_passes_the_joined_rows_through() -> None:
    """reconstruct_message hands the laser method the scans' rows joined and checked once:
    the lines' models, the solid and every figure are those of the lines taken one by one,
    to the bit, and the rows handed over stay read-only."""
    for seq, lines in ((3, BALL), (4, scan(cylinder((0.0, 0.0, 0.22), (0.0, 1.0, 0.0), 0.03), 2))):
        message = _message(seq, lines)
        joined = reconstruct_message(message)
        alone = reconstruct_laser(scan_lines_from_message(message), seed=seq)
        assert joined.shape == alone.shape != "none"
        assert encode(joined) == encode(reconstruction_message(alone, message))
    read, rows = _scan_lines(message)
    assert rows is not None and not rows.flags.writeable
    assert np.concatenate(read.points).tobytes() == rows.tobytes()


def test_scan_lines_from_message_reads_float32_lines_as_each_line_alone() -> None:
    """The scans service's float32 lines are read in one pass over all of them: each line's
    points are the float64 values from_wire gives for it alone, to the bit, and NaN or inf
    in any line is refused as from_wire refuses it. Lines of other dtypes are read one by
    one, with the same checks."""
    message = _message(1, BALL)
    lines = scan_lines_from_message(message)
    assert len(lines.points) == len(message.lines) == 4
    for got, line in zip(lines.points, message.lines, strict=True):
        alone = from_wire(line.points).astype(np.float64)
        assert got.dtype == np.float64 and got.shape == alone.shape
        assert got.tobytes() == alone.tobytes()
    wide = [
        msgspec.structs.replace(ln, points=to_wire(from_wire(ln.points).astype(np.float64)))
        for ln in message.lines
    ]
    mixed = msgspec.structs.replace(message, lines=[wide[0], *message.lines[1:]])
    for other in (msgspec.structs.replace(message, lines=wide), mixed):
        assert [p.tobytes() for p in scan_lines_from_message(other).points] == [
            p.tobytes() for p in lines.points
        ]
    for source in (message, mixed):
        bad = from_wire(source.lines[2].points).copy()
        bad[5, 1] = np.nan
        broken = msgspec.structs.replace(
            source,
            lines=[
                *source.lines[:2],
                msgspec.structs.replace(source.lines[2], points=to_wire(bad)),
                source.lines[3],
            ],
        )
        with pytest.raises(ValueError, match="NaN or inf"):
            scan_lines_from_message(broken)
    flat = msgspec.structs.replace(
        message,
        lines=[
            msgspec.structs.replace(message.lines[0], points=to_wire(np.zeros(6, np.float32))),
            *message.lines[1:],
        ],
    )
    with pytest.raises(ValueError, match=r"must be \(N, 3\)"):
        scan_lines_from_message(flat)


def test_scans_carry_the_depth_past_the_line_ends_and_old_scans_decode_without_it() -> None:
    """The scans step sends each line's depth past its ends and the first pixel there that
    shows the background beyond the capture volume (the 40 mm ball before the wall at 0.26
    m: the wall past every end); scans recorded before the fields existed decode with none,
    and their scan lines carry none."""
    frame = _depth_frame(3, "ball")
    scans = scans_step(ScansState(), frame, 0)[1]
    decoded = decode("lpc/scans", encode(scans))
    assert decoded == scans
    past = scan_lines_from_message(decoded).past_ends_m
    assert past is not None and past.shape == (4, 2)
    assert np.allclose(past, 0.26, atol=0.003), past
    # And the first pixel past each end that shows the wall beyond the capture volume.
    far = scan_lines_from_message(decoded).far_past_m
    assert far is not None and far.shape == (4, 2, 3)
    assert np.allclose(far[:, :, 2], 0.26, atol=0.003), far
    # Where each line leaves the face past an end at the capture volume's side: the ball
    # lies inside it, so none; the message carries the cut's zeros as they are.
    edge = scan_lines_from_message(decoded).edge_past_m
    assert edge is not None and np.array_equal(edge, np.zeros((4, 2, 3)))

    class OldScanLine(msgspec.Struct, frozen=True, kw_only=True):
        angle_deg: float
        points: object

    class OldScanLines(msgspec.Struct, frozen=True, kw_only=True, tag="scans"):
        seq: int
        t_ns: int
        version: int
        frame_seq: int
        lines: list[OldScanLine]
        capture_points: int = 0

    old = OldScanLines(
        seq=scans.seq,
        t_ns=scans.t_ns,
        version=scans.version,
        frame_seq=scans.frame_seq,
        lines=[OldScanLine(angle_deg=ln.angle_deg, points=ln.points) for ln in scans.lines],
        capture_points=scans.capture_points,
    )
    from_old = decode("lpc/scans", msgspec.msgpack.encode(old))
    assert all(ln.past_ends_m is None for ln in from_old.lines)
    lines = scan_lines_from_message(from_old)
    assert lines.past_ends_m is None and lines.far_past_m is None and lines.edge_past_m is None
    assert [p.tolist() for p in lines.points] == [
        p.tolist() for p in scan_lines_from_message(decoded).points
    ]


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


def test_reconstruction_message_encodes_as_what_it_decodes_to() -> None:
    # The service publishes a worker's bytes as they are, after decoding them for the window:
    # an int in a float field (a confidence of exactly 1) would decode as 1.0 and the bytes
    # would no longer be the encoding of the message the window saw.
    core = CoreReconstruction(
        shape="sphere",
        grasp_width_m=0.05,
        center_m=(0.0, 0.0, 0.2),
        lines=(
            LineSummary(angle_deg=0.0, model="circle", params=(0.0, 0.2, 0.025), inlier_fraction=1),
        ),
        confidence=1,
        points=40,
    )
    payload = encode(reconstruction_message(core, _message(1, BALL), compute_ms=0))
    assert encode(decode("lpc/reconstruction", payload)) == payload


def test_reconstruct_message_reports_reason_when_nothing_fits() -> None:
    empty = ScanLines(
        seq=1, t_ns=1, frame_seq=1,
        lines=[ScanLine(angle_deg=a, points=to_wire(np.zeros((0, 3), np.float32)))
               for a in (0.0, 45.0, 90.0, 135.0)],
    )  # fmt: skip
    rec = reconstruct_message(empty)
    assert rec.shape == "none" and "too few points" in rec.reason


def test_reconstruct_cloud_step_equals_reconstruct_cloud_then_window() -> None:
    state = ReconstructState()
    for seq in range(100, 110):
        frame = _depth_frame(seq, "ball")
        state, (rec, target) = reconstruct_cloud_step(state, frame, 0)
        direct = reconstruct_cloud(_depth(seq, "ball"), INTR, seed=seq)
        assert rec.method == "cloud" and rec.shape == direct.shape == "sphere"
        assert rec.grasp_width_mm == direct.grasp_width_mm
        assert rec.center_m == list(direct.center_m or ())
        assert (rec.points, rec.confidence) == (direct.points, direct.confidence)
        assert (rec.seq, rec.frame_seq, rec.t_ns, rec.truth) == (seq, seq, frame.t_ns, frame.truth)
        assert rec.compute_ms == 0.0 and rec.lines == []
        assert decode("lpc/reconstruction", encode(rec)) == rec
    assert isinstance(target, GraspTarget) and target.reconstructed and target.frames == 10
    assert target.shape == "sphere" and target.frame_seq == 109
    assert target.grasp_width_mm == pytest.approx(40.0, abs=5.0)


def test_reconstruct_cloud_message_rejects_depth_not_matching_intrinsics() -> None:
    frame = _depth_frame(1, "ball")
    small = msgspec.structs.replace(frame, depth=to_wire(np.zeros((10, 10), np.uint16)))
    with pytest.raises(ValueError, match="expected uint16"):
        reconstruct_cloud_message(small)


def test_warmup_frame_is_a_50_mm_ball_for_both_methods() -> None:
    frame = warmup_frame()
    cloud = reconstruct_cloud_message(frame)
    laser = reconstruct_message(scans_step(ScansState(), frame, 0)[1])
    for rec in (cloud, laser):
        assert rec.shape == "sphere"
        assert rec.grasp_width_mm == pytest.approx(50.0, abs=1.0)


# --------------------------------------------------------------------------- the service


def _wait_last_target(got: dict[str, list], frame_seq: int) -> None:
    """The target is published after its reconstruction: wait until the last one is here."""
    targets = got["lpc/grasp/target"]
    wait_for(lambda: bool(targets) and targets[-1].frame_seq == frame_seq, 10.0, "the last target")


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
        # The service subscribes once its workers are warm.
        _wait_subscribed(scans, process)
        for k in range(12):
            scans.put(encode(_message(2000 + k, can if k % 2 else BALL)))

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
        _wait_last_target(got, 2011)
    finally:
        process.terminate()
        process.wait(timeout=20)
        for sub in subs:
            sub.undeclare()
    assert process.returncode == 0


def test_reconstructor_service_cloud_publishes_newest_frames_in_order(
    rendezvous: zenoh.Session, endpoint: str
) -> None:
    got: dict[str, list] = collections.defaultdict(list)
    subs = [
        rendezvous.declare_subscriber(
            key, lambda s, key=key: got[key].append(decode(key, s.payload.to_bytes()))
        )
        for key in ("lpc/reconstruction", "lpc/grasp/target")
    ]
    # BLOCK: the test's frames must reach the service, whose own subscriber skips stale ones.
    depth = rendezvous.declare_publisher(
        "lpc/camera/depth", congestion_control=zenoh.CongestionControl.BLOCK
    )
    process = spawn_service(
        "services.reconstructor", endpoint, "--method", "cloud", "--workers", "2"
    )
    frames = [_depth_frame(3000 + k, "can" if k % 2 else "ball") for k in range(12)]
    try:
        _wait_subscribed(depth, process)
        for frame in frames:
            depth.put(encode(frame))
        # Depth is a sensor topic: frames may be skipped, but never the newest.
        wait_for(
            lambda: any(r.seq == frames[-1].seq for r in got["lpc/reconstruction"]),
            30.0,
            "the last frame's reconstruction",
        )
        recs = list(got["lpc/reconstruction"])
        _wait_last_target(got, frames[-1].seq)
    finally:
        process.terminate()
        process.wait(timeout=20)
        for sub in subs:
            sub.undeclare()
    assert process.returncode == 0
    seqs = [r.seq for r in recs]
    assert seqs == sorted(set(seqs)) and set(seqs) <= {f.seq for f in frames}
    sent = {f.seq: f for f in frames}
    for rec in recs:
        truth = sent[rec.seq].truth
        assert rec.method == "cloud" and rec.frame_seq == rec.seq
        assert rec.t_ns == sent[rec.seq].t_ns and rec.truth == truth
        assert truth is not None and rec.shape == truth.shape
        assert rec.grasp_width_mm == pytest.approx(truth.grasp_width_mm, abs=5.0)
        assert rec.points > 1000 and rec.compute_ms > 0


def _wait_subscribed(publisher: zenoh.Publisher, process) -> None:
    """Until the service's subscriber matches ``publisher`` (after its workers warmed up)."""

    def matching() -> bool:
        assert process.poll() is None, process.stderr.read().decode() if process.stderr else ""
        return publisher.matching_status.matching

    wait_for(matching, 60.0, "the reconstructor's subscriber")


class _PromptPool:
    """Stands in for ``PipePool`` in the service: each job is worked out at once, in this
    process (the real worker's ``work``, or ``answer``), and reported either from inside
    ``submit`` (as ``PipePool`` reports the jobs of a worker it finds dead there) or from a
    loop callback (as its pipe reader reports results)."""

    inline = False
    answer: bytes | None = None

    def __init__(self, workers, initializer, initargs, on_done) -> None:
        self._work = initializer(*initargs)
        self._on_done = on_done
        self._loop = asyncio.get_running_loop()
        self.restarts = 0
        self.pids: list[int] = []

    async def ready(self) -> None:
        pass

    def submit(self, tag, job: bytes) -> None:
        result = self.answer if self.answer is not None else self._work(job)
        if self.inline:
            self._on_done(tag, result)
        else:
            self._loop.call_soon(self._on_done, tag, result)

    def close(self) -> None:
        pass


def _serve_in_process(
    endpoint: str, monkeypatch: pytest.MonkeyPatch, frames: int
) -> tuple[dict[str, list[int]], BaseException | None]:
    """The service on this process's loop with a ``_PromptPool``: ``frames`` scans put; the
    seqs it published on each key, in the order they came, and what it raised."""
    monkeypatch.setattr(reconstructor_service, "PipePool", _PromptPool)
    published: dict[str, list[int]] = collections.defaultdict(list)

    async def run() -> BaseException | None:
        loop = asyncio.get_running_loop()
        with zenoh.open(zenoh_config(connect=[], listen=[endpoint])) as session:
            bus = Bus(session, "reconstructor", loop=loop, quiet=True)
            subs = [
                session.declare_subscriber(
                    key,
                    lambda s, key=key: published[key].append(decode(key, s.payload.to_bytes()).seq),
                )
                for key in ("lpc/reconstruction", "lpc/grasp/target")
            ]
            args = reconstructor_service.parser().parse_args(["--max-pending", "50"])
            task = asyncio.create_task(reconstructor_service.serve(bus, args))
            scans = bus.publisher("lpc/scans")
            await asyncio.sleep(0.2)  # the pump subscribes
            for k in range(frames):
                scans.put(_message(4000 + k, BALL))
                await asyncio.sleep(0.01)
            await asyncio.sleep(0.5)
            task.cancel()
            (error,) = await asyncio.gather(task, return_exceptions=True)
            for sub in subs:
                sub.undeclare()
            bus.close()
            return None if isinstance(error, asyncio.CancelledError) else error

    return published, asyncio.run(run())


@pytest.mark.parametrize("inline", [False, True])
def test_reconstructor_service_releases_results_reported_in_or_out_of_a_submit_in_order(
    endpoint: str, monkeypatch: pytest.MonkeyPatch, inline: bool
) -> None:
    monkeypatch.setattr(_PromptPool, "inline", inline)
    published, error = _serve_in_process(endpoint, monkeypatch, 4)
    assert error is None
    # Zenoh keeps the order of each key's samples, not across keys.
    assert published == {
        "lpc/reconstruction": [4000, 4001, 4002, 4003],
        "lpc/grasp/target": [4000, 4001, 4002, 4003],
    }


def test_reconstructor_service_stops_on_a_result_it_cannot_decode(
    endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Handled where the pool reports it (a loop callback), the error still stops the service,
    # for its supervisor to restart it.
    monkeypatch.setattr(_PromptPool, "answer", b"not msgpack")
    published, error = _serve_in_process(endpoint, monkeypatch, 1)
    assert isinstance(error, BadMessage)
    assert not published
