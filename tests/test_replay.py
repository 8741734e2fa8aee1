"""Deterministic replay: the pure engine with scripted nodes, the check, and ``lpc replay`` on
real MCAP files with the pipeline's own step functions."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest

from lpc_core.perception.cloud import CloudParams
from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.pipeline import ScansState, intrinsics_to_message, scans_step
from lpc_core.perception.reconstructor import ReconstructState, reconstruct_cloud_step
from lpc_core.perception.scans import ScanParams
from lpc_core.replay import (
    TICK,
    Node,
    Recorded,
    Replay,
    Route,
    Tick,
    check,
    default_nodes,
    first_difference,
    plan,
)
from lpc_core.sim import scene as sc
from schemas import (
    AimCue,
    DepthFrame,
    EmgSample,
    GraspTarget,
    Health,
    ProsthesisState,
    ScanLines,
    TactorCommand,
    to_wire,
)
from services.cli import main as lpc
from services.cli import replay as replay_cli
from services.mcap_log import LogWriter, McapLog

T0 = 1_700_000_000_000_000_000
MS = 1_000_000

# --------------------------------------------------------------------------- scripted nodes


@dataclass
class Tape:
    """A scripted node's state: every (what, seq, now_ns) it handled."""

    seen: list[tuple[str, int, int]] = field(default_factory=list)


def scan_of(frame: DepthFrame, seq: int) -> ScanLines:
    return ScanLines(seq=seq, t_ns=frame.t_ns, frame_seq=frame.seq, lines=[])


def fake_scans(state: Tape, frame: DepthFrame, now_ns: int) -> tuple[Tape, ScanLines]:
    state.seen.append(("depth", frame.seq, now_ns))
    return state, scan_of(frame, len(state.seen))


def fake_aim(state: Tape, message: Any, now_ns: int) -> tuple[Tape, list[Any]]:
    if isinstance(message, EmgSample):
        state.seen.append(("emg", message.seq, now_ns))
        return state, []
    state.seen.append(("scans", message.frame_seq, now_ns))
    cue = AimCue(
        seq=len(state.seen), t_ns=message.t_ns, frame_seq=message.frame_seq, state="nothing"
    )
    return state, [cue]


def scripted_nodes() -> tuple[Node, ...]:
    return (
        Node(
            "scans",
            Tape,
            (Route("lpc/camera/depth", fake_scans, gated=True),),
            ("lpc/scans",),
            gate="lpc/scans",
        ),
        Node(
            "aim",
            Tape,
            (Route("lpc/scans", fake_aim, gated=True), Route("lpc/emg", fake_aim)),
            ("lpc/aim/cue",),
            gate="lpc/aim/cue",
        ),
    )


def depth(seq: int, t: int) -> DepthFrame:
    intrinsics = intrinsics_to_message(
        Intrinsics(width=2, height=1, fx=1.0, fy=1.0, ppx=1.0, ppy=0.5)
    )
    return DepthFrame(
        seq=seq, t_ns=t, intrinsics=intrinsics, depth=to_wire(np.zeros((1, 2), np.uint16))
    )


def emg(seq: int, t: int) -> EmgSample:
    return EmgSample(seq=seq, t_ns=t, channels=[0.0, 0.0])


def test_plan_depth_makes_recorded_scans_an_output() -> None:
    nodes = scripted_nodes()
    p = plan(nodes, {"lpc/camera/depth", "lpc/scans", "lpc/emg"})
    assert p.inputs == {"lpc/camera/depth", "lpc/emg"}
    assert p.outputs == {"lpc/scans", "lpc/aim/cue"}
    p = plan(nodes, {"lpc/scans", "lpc/aim/cue"})
    assert [n.name for n in p.nodes] == ["aim"]
    assert p.inputs == {"lpc/scans"} and p.outputs == {"lpc/aim/cue"}
    assert plan(nodes, {"lpc/health/x"}).inputs == frozenset()


def test_plan_feedback_route_alone_does_not_enable_its_node() -> None:
    # A controller-only recording: the aim step (fed the controller's state back) stays off,
    # so the recorded cues remain the controller's input.
    keys = {"lpc/emg", "lpc/prosthesis/state", "lpc/aim/cue", "lpc/controller/state"}
    p = plan(default_nodes(), keys)
    assert [n.name for n in p.nodes] == ["controller"]
    assert p.inputs == {"lpc/emg", "lpc/prosthesis/state", "lpc/aim/cue"}
    # With scans, the aim step runs and takes the replayed controller state, not the recorded.
    p = plan(default_nodes(), keys | {"lpc/scans"})
    assert [n.name for n in p.nodes] == ["reconstructor", "aim", "controller"]
    assert "lpc/controller/state" in p.outputs and "lpc/controller/state" not in p.inputs


def test_replay_merges_by_log_time_then_file_order_with_recorded_clock() -> None:
    inputs = [
        Recorded("lpc/emg", emg(0, T0), T0 + 1 * MS, 0),
        Recorded("lpc/camera/depth", depth(0, T0), T0 + 2 * MS, 1),
        Recorded("lpc/emg", emg(1, T0), T0 + 2 * MS, 2),  # same log time: file order decides
        Recorded("lpc/emg", emg(2, T0), T0 + 3 * MS, 3),
    ]
    replay = Replay(scripted_nodes(), {"lpc/camera/depth", "lpc/emg"})
    events = list(replay.run(inputs))
    assert [(e.key, e.log_time) for e in events] == [
        ("lpc/emg", T0 + 1 * MS),
        ("lpc/camera/depth", T0 + 2 * MS),
        ("lpc/scans", T0 + 2 * MS),  # nothing recorded: delivered at once, before what follows
        ("lpc/aim/cue", T0 + 2 * MS),
        ("lpc/emg", T0 + 2 * MS),
        ("lpc/emg", T0 + 3 * MS),
    ]
    assert replay.states["aim"].seen == [
        ("emg", 0, T0 + 1 * MS),
        ("scans", 0, T0 + 2 * MS),
        ("emg", 1, T0 + 2 * MS),
        ("emg", 2, T0 + 3 * MS),
    ]
    assert events[1].source is inputs[1] and events[2].source is None


def test_replay_gating_handles_only_frames_handled_live() -> None:
    inputs = [
        Recorded("lpc/camera/depth", depth(i, T0 + i * 11 * MS), T0 + i * 11 * MS, i)
        for i in range(6)
    ]
    recorded = {
        "lpc/scans": {0: (T0 + 1 * MS, 100), 2: (T0 + 23 * MS, 101), 5: (T0 + 56 * MS, 102)}
    }
    keys = {"lpc/camera/depth", "lpc/scans"}
    replay = Replay(scripted_nodes(), keys, recorded)
    outputs = [e for e in replay.run(inputs) if e.key == "lpc/scans"]
    assert [e.message.frame_seq for e in outputs] == [0, 2, 5]
    assert replay.gated == {"scans": 3}
    assert replay.offered["lpc/scans"] == set(range(6))
    every = Replay(scripted_nodes(), keys, recorded, all_frames=True)
    assert len([e for e in every.run(inputs) if e.key == "lpc/scans"]) == 6


def test_replay_delivers_outputs_at_their_recorded_time() -> None:
    # Live, the scans of frame 0 reached the recorder 5 ms after the depth, after two EMG
    # samples; the aim step must see them in that order again.
    inputs = [
        Recorded("lpc/camera/depth", depth(0, T0), T0, 0),
        Recorded("lpc/emg", emg(0, T0), T0 + 2 * MS, 1),
        Recorded("lpc/emg", emg(1, T0), T0 + 4 * MS, 2),
        Recorded("lpc/emg", emg(2, T0), T0 + 6 * MS, 4),
    ]
    recorded = {"lpc/scans": {0: (T0 + 5 * MS, 3)}}
    replay = Replay(scripted_nodes(), {"lpc/camera/depth", "lpc/emg", "lpc/scans"}, recorded)
    events = list(replay.run(inputs))
    assert [(e.key, e.log_time) for e in events] == [
        ("lpc/camera/depth", T0),
        ("lpc/emg", T0 + 2 * MS),
        ("lpc/emg", T0 + 4 * MS),
        ("lpc/scans", T0 + 5 * MS),
        ("lpc/aim/cue", T0 + 5 * MS),
        ("lpc/emg", T0 + 6 * MS),
    ]
    assert replay.states["aim"].seen[2] == ("scans", 0, T0 + 5 * MS)


def test_replay_ticks_a_node_between_messages() -> None:
    @dataclass(frozen=True)
    class Beat:
        t_ns: int

    def heart(state: list[int], message: Any, now_ns: int) -> tuple[list[int], None]:
        return [*state, now_ns if isinstance(message, Beat) else -message.seq], None

    node = Node(
        "heart", list, (Route("lpc/emg", heart), Route(TICK, heart)), (), tick=Tick(10 * MS, Beat)
    )
    inputs = [Recorded("lpc/emg", emg(i, T0), T0 + i * 25 * MS, i) for i in (1, 2)]
    replay = Replay([node], {"lpc/emg"})
    list(replay.run(inputs))
    assert replay.states["heart"] == [-1, T0 + 35 * MS, T0 + 45 * MS, -2]


def test_replay_refused_message_is_counted_and_state_kept() -> None:
    def picky(state: int, message: EmgSample, now_ns: int) -> tuple[int, None]:
        if message.seq == 1:
            raise ValueError("seq 1 is bad")
        return state + 1, None

    node = Node("picky", int, (Route("lpc/emg", picky),), ())
    replay = Replay([node], {"lpc/emg"})
    list(replay.run(Recorded("lpc/emg", emg(i, T0), T0 + i, i) for i in range(3)))
    assert replay.states["picky"] == 2
    assert replay.errors == {"picky": 1}
    assert "seq 1 is bad" in replay.first_error["picky"]


# --------------------------------------------------------------------------- the check


def target(frame: int, width: float, seq: int = 1) -> GraspTarget:
    return GraspTarget(
        seq=seq, t_ns=T0 + frame, frame_seq=frame, shape="sphere", grasp_width_mm=width
    )


def test_first_difference_names_the_field() -> None:
    a = ScanLines(seq=1, t_ns=T0, frame_seq=3, lines=[], capture_points=10)
    assert first_difference(a, msgspec.structs.replace(a, seq=2), {"seq"}) is None
    changed = msgspec.structs.replace(a, capture_points=11)
    assert first_difference(a, changed) == ("capture_points", "10", "11")
    assert first_difference(target(1, 40.0), target(1, 41.5)) == ("grasp_width_mm", "40.0", "41.5")


def test_first_difference_tolerates_round_off_only() -> None:
    width = 74.67085219126126
    ulp = math.ulp(width)
    assert first_difference(target(1, width), target(1, width + ulp)) is not None
    assert first_difference(target(1, width), target(1, width + 30 * ulp), rel_tol=1e-9) is None
    # A tenth of a micrometre is a change of the method, not round-off.
    moved = first_difference(target(1, width), target(1, width + 1e-4), rel_tol=1e-9)
    assert moved is not None and moved[0] == "grasp_width_mm"
    recorded = {"lpc/grasp/target": [target(1, width), target(2, 40.0)]}
    replayed = {"lpc/grasp/target": [target(1, width * (1 + 1e-12)), target(2, 40.001)]}
    assert check(recorded, replayed, rel_tol=1e-9).total == 1
    assert check(recorded, replayed).total == 2


def test_check_matches_by_frame_and_skips_volatile_fields() -> None:
    recorded = {
        "lpc/grasp/target": [target(1, 40.0, seq=7), target(2, 40.0, seq=8), target(3, 40.0, seq=9)]
    }
    replayed = {"lpc/grasp/target": [target(1, 40.0), target(2, 42.0), target(4, 40.0)]}
    volatile = {"lpc/grasp/target": frozenset({"seq"})}
    result = check(recorded, replayed, volatile=volatile)
    assert not result.ok and result.total == 3
    got = [(d.where, d.path) for d in result.differences]
    assert got == [("frame 2", "grasp_width_mm"), ("frame 3", ""), ("frame 4", "")]
    assert "recorded 40.0, replayed 42.0" in result.differences[0].describe()
    # Frames whose input the recording lacks are not held against the replay.
    offered = {"lpc/grasp/target": {1, 2, 4}}
    assert check(recorded, replayed, volatile=volatile, offered=offered).total == 2
    same = check(recorded, {"lpc/grasp/target": recorded["lpc/grasp/target"]}, volatile=volatile)
    assert same.ok and same.compared["lpc/grasp/target"] == 3


# --------------------------------------------------------------------------- lpc replay

INTRINSICS = Intrinsics(width=424, height=240, fx=213.0, fy=213.0, ppx=212.0, ppy=120.0)


@pytest.fixture(scope="module")
def depth_images() -> list[np.ndarray]:
    """Four renders of a 40 mm ball on a table, approached from 230 to 200 mm."""
    ball = sc.sphere_object("ball", (0.0, 0.0, 0.04), 0.04)
    scene = sc.Scene(objects=(ball,), support=sc.table())
    return [
        sc.render_depth(
            scene, INTRINSICS, sc.aim_pose(ball, 0.23 - 0.01 * i), np.random.default_rng(i)
        )
        for i in range(4)
    ]


def record_session(
    path: Path,
    images: list[np.ndarray],
    n_frames: int = 24,
    params: ScanParams | None = None,
    declare: tuple[str, ...] = (),
) -> None:
    """A live-like session: depth at 90 Hz, EMG and hand state at 100 Hz, and the scans of
    two frames in three (the live service skipped the rest) reaching the recorder 2 ms late."""
    state = ScansState(params=params or ScanParams())
    events: list[tuple[int, str, Any]] = []
    for i in range(n_frames):
        t = T0 + i * 11_111_111
        frame = DepthFrame(
            seq=i,
            t_ns=t,
            intrinsics=intrinsics_to_message(INTRINSICS),
            depth=to_wire(images[i % len(images)]),
        )
        events.append((t + 300_000, "lpc/camera/depth", frame))
        if i % 3 != 2:
            state, scans = scans_step(state, frame, t)
            events.append((t + 2 * MS, "lpc/scans", scans))
    for i in range(n_frames * 100 // 90):
        t = T0 + i * 10 * MS
        events.append((t + 100_000, "lpc/emg", emg(i, t)))
        hand = ProsthesisState(seq=i, t_ns=t, wrist_angle_deg=0.0, aperture_mm=80.0)
        events.append((t + 200_000, "lpc/prosthesis/state", hand))
    events.sort(key=lambda e: e[0])
    with LogWriter(path) as writer:
        for key in declare:  # recorded, but the live service published nothing
            writer.declare(key)
        for t, key, message in events:
            writer.write(key, message, t)


def test_replay_cli_check_passes_and_output_replays_byte_identical(
    tmp_path: Path, depth_images: list[np.ndarray], capsys: pytest.CaptureFixture[str]
) -> None:
    record_session(tmp_path / "rec.mcap", depth_images)
    assert (
        lpc(
            [
                "replay",
                str(tmp_path / "rec.mcap"),
                "--check",
                "--fast",
                "--out",
                str(tmp_path / "out1.mcap"),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "check: no differences (compared lpc/scans 16" in out
    assert "inputs the live services skipped: {'scans': 8}" in out
    # The replay's own output is a recording: replaying it reproduces it byte for byte.
    assert (
        lpc(
            ["replay", str(tmp_path / "out1.mcap"), "--check", "--out", str(tmp_path / "out2.mcap")]
        )
        == 0
    )
    assert "check: no differences" in capsys.readouterr().out
    assert (tmp_path / "out1.mcap").read_bytes() == (tmp_path / "out2.mcap").read_bytes()
    with McapLog(tmp_path / "out1.mcap") as log:
        keys = log.topics()
    assert {"lpc/camera/depth", "lpc/emg", "lpc/prosthesis/state", "lpc/scans"} <= keys
    assert {n.outputs[0] for n in default_nodes()} <= keys


def test_replay_cli_catches_a_changed_algorithm(
    tmp_path: Path,
    depth_images: list[np.ndarray],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    record_session(tmp_path / "rec.mcap", depth_images, n_frames=6)

    def wider_band(controller_params: Any = None, **kwargs: Any) -> tuple[Node, ...]:
        nodes = default_nodes(controller_params, **kwargs)
        scans = replace(nodes[0], init=lambda: ScansState(params=ScanParams(band_m=0.002)))
        return (scans, *nodes[1:])

    monkeypatch.setattr(replay_cli, "default_nodes", wider_band)
    assert lpc(["replay", str(tmp_path / "rec.mcap"), "--check"]) == 1
    out = capsys.readouterr().out
    assert "check: 4 differences" in out
    assert "lpc/scans frame 0 " in out and "recorded" in out and "replayed" in out


def with_health(path: Path, out: Path, service: str, argv: list[str]) -> None:
    """``path`` again, with one health message of ``service`` holding ``argv``."""
    with McapLog(path) as log:
        events = [(m.log_time, m.key, m.message) for m in log.messages(decode=True)]
    health = Health(seq=1, t_ns=T0, service=service, pid=1, argv=argv)
    events.insert(0, (T0, f"lpc/health/{service}", health))
    with LogWriter(out) as writer:
        for t, key, message in events:
            writer.write(key, message, t)


def test_replay_cli_runs_each_service_with_its_recorded_flags(
    tmp_path: Path, depth_images: list[np.ndarray], capsys: pytest.CaptureFixture[str]
) -> None:
    """A session whose scans service ran with --band-mm 2 replays without differences: its
    health holds its flags; without them (or with flags that do not apply) the defaults give
    other scan lines, and the replay says so."""
    record_session(
        tmp_path / "base.mcap", depth_images, n_frames=6, params=ScanParams(band_m=0.002)
    )
    with_health(tmp_path / "base.mcap", tmp_path / "rec.mcap", "scans", ["--band-mm", "2"])
    out1 = tmp_path / "out1.mcap"
    assert lpc(["replay", str(tmp_path / "rec.mcap"), "--check", "--out", str(out1)]) == 0
    out = capsys.readouterr().out
    assert "scans: the recorded flags (--band-mm 2)" in out and "check: no differences" in out
    # The output keeps the flags: replaying it reproduces it.
    assert lpc(["replay", str(out1), "--check", "--out", str(tmp_path / "out2.mcap")]) == 0
    assert out1.read_bytes() == (tmp_path / "out2.mcap").read_bytes()
    capsys.readouterr()

    assert lpc(["replay", str(tmp_path / "base.mcap"), "--check"]) == 1
    assert "check: 4 differences" in capsys.readouterr().out
    with_health(tmp_path / "base.mcap", tmp_path / "bad.mcap", "scans", ["--band-mm", "99"])
    assert lpc(["replay", str(tmp_path / "bad.mcap"), "--check"]) == 1
    out = capsys.readouterr().out
    assert "scans: the recorded flags ['--band-mm', '99'] do not apply here" in out
    assert "--band-mm must be in (0, 10]" in out


def test_replay_cli_cut_file_replays_readable_part_and_names_last_good_time(
    tmp_path: Path, depth_images: list[np.ndarray], capsys: pytest.CaptureFixture[str]
) -> None:
    record_session(tmp_path / "rec.mcap", depth_images)
    data = (tmp_path / "rec.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    assert lpc(["replay", str(tmp_path / "cut.mcap"), "--check"]) == 0
    captured = capsys.readouterr()
    assert "cut short at byte" in captured.err and "last good time" in captured.err
    assert "replayed the readable part" in captured.err
    assert "check: no differences" in captured.out
    (tmp_path / "stub.mcap").write_bytes(data[:100])
    assert lpc(["replay", str(tmp_path / "stub.mcap")]) == 2
    err = capsys.readouterr().err
    assert "cut short at byte" in err and "Traceback" not in err


def test_replay_cli_bad_files_are_clear_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    assert lpc(["replay", str(tmp_path / "junk.mcap")]) == 2
    assert "not an MCAP file" in capsys.readouterr().err
    assert lpc(["replay", str(tmp_path / "missing.mcap")]) == 2
    assert "cannot open" in capsys.readouterr().err
    with LogWriter(tmp_path / "health.mcap") as writer:
        writer.write("lpc/emg", emg(0, T0), T0)
    with LogWriter(tmp_path / "nothing.mcap"):
        pass
    assert lpc(["replay", str(tmp_path / "nothing.mcap")]) == 2
    assert "holds none of the replay inputs" in capsys.readouterr().err
    assert lpc(["replay", str(tmp_path / "health.mcap"), "--check"]) == 1
    assert "nothing to compare" in capsys.readouterr().out


def test_replay_cli_without_depth_replays_from_recorded_scans(
    tmp_path: Path, depth_images: list[np.ndarray], capsys: pytest.CaptureFixture[str]
) -> None:
    record_session(tmp_path / "rec.mcap", depth_images, n_frames=9)
    args = ["replay", str(tmp_path / "rec.mcap"), "--without", "lpc/camera/depth"]
    assert lpc([*args, "--out", str(tmp_path / "scans.mcap")]) == 0
    out = capsys.readouterr().out
    # 6 recorded scans (two frames in three of 9), 10 EMG samples, 10 hand states.
    assert "26 inputs (lpc/emg, lpc/prosthesis/state, lpc/scans)" in out
    with McapLog(tmp_path / "scans.mcap") as log:
        assert "lpc/camera/depth" not in log.topics()


def test_replay_cli_worker_processes_give_the_same_bytes_and_count_refusals(
    tmp_path: Path, depth_images: list[np.ndarray], capsys: pytest.CaptureFixture[str]
) -> None:
    """Reconstructions made by two worker processes, ahead of the replay, come out as the
    in-process ones, byte for byte; a frame a worker refuses is counted like one refused
    in-process, and the frames after it go on."""
    record_session(tmp_path / "base.mcap", depth_images, n_frames=30)
    with McapLog(tmp_path / "base.mcap") as log:
        events = [(m.log_time, m.key, m.message) for m in log.messages(decode=True)]
    bad = 0
    with LogWriter(tmp_path / "rec.mcap") as writer:
        for t, key, message in events:
            if key == "lpc/scans" and message.frame_seq == 10:
                flat = to_wire(np.zeros((5, 2)))  # decodes, but a scan line is (N, 3)
                lines = [msgspec.structs.replace(message.lines[0], points=flat)]
                message = msgspec.structs.replace(message, lines=lines + message.lines[1:])
                bad += 1
            if key != "lpc/camera/depth":
                writer.write(key, message, t)
    assert bad == 1
    outputs = {}
    for jobs in ("0", "2"):
        out_path = tmp_path / f"jobs{jobs}.mcap"
        assert (
            lpc(["replay", str(tmp_path / "rec.mcap"), "--jobs", jobs, "--out", str(out_path)]) == 0
        )
        out = capsys.readouterr().out
        where = "in this process" if jobs == "0" else "2 worker processes"
        assert f"reconstructor: laser (the default: no lpc/reconstruction recorded), {where}" in out
        assert (
            "reconstructor refused 1 messages; first: ValueError: scan line points must be" in out
        )
        assert "lpc/reconstruction            19" in out  # 20 scans recorded, one refused
        outputs[jobs] = out_path.read_bytes()
    assert outputs["0"] == outputs["2"]


def test_replay_cli_workers_start_from_recorded_depth(
    tmp_path: Path,
    depth_images: list[np.ndarray],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Where the replay cuts the scans from recorded depth, the workers cut them and go on
    with every frame's reconstruction and object search: none is left to this process, and
    the bytes are those of the in-process replay."""
    from lpc_core.control import aim
    from lpc_core.perception import pipeline, reconstructor

    record_session(tmp_path / "rec.mcap", depth_images, n_frames=30)
    in_process: Counter[str] = Counter()

    def counted(name: str, step: Any) -> Any:
        def step_(state: Any, message: Any, now_ns: int) -> Any:
            in_process[name] += isinstance(message, ScanLines | DepthFrame)
            return step(state, message, now_ns)

        return step_

    monkeypatch.setattr(
        reconstructor, "reconstruct_step", counted("reconstructor", reconstructor.reconstruct_step)
    )
    monkeypatch.setattr(aim, "aim_step", counted("aim", aim.aim_step))
    monkeypatch.setattr(pipeline, "scans_step", counted("scans", pipeline.scans_step))
    outputs, steps = {}, {}
    for jobs in ("0", "2"):
        in_process.clear()
        out_path = tmp_path / f"jobs{jobs}.mcap"
        assert (
            lpc(["replay", str(tmp_path / "rec.mcap"), "--jobs", jobs, "--out", str(out_path)]) == 0
        )
        out = capsys.readouterr().out
        assert "lpc/reconstruction            20" in out  # the scans of 20 frames in 30
        outputs[jobs], steps[jobs] = out_path.read_bytes(), dict(+in_process)
    # The scans node is offered 30 frames; the live service cut 20 of them.
    assert steps == {"0": {"scans": 20, "reconstructor": 20, "aim": 20}, "2": {}}
    assert outputs["0"] == outputs["2"]


def test_replay_cli_rejects_negative_jobs(capsys: pytest.CaptureFixture[str]) -> None:
    assert lpc(["replay", "missing.mcap", "--jobs", "-1"]) == 2
    assert "--jobs must be >= 0" in capsys.readouterr().err


def test_check_pairs_messages_without_frame_by_a_named_field() -> None:
    def command(t: int, amplitude: float) -> TactorCommand:
        return TactorCommand(seq=t, t_ns=T0 + t, amplitudes=[amplitude] * 4)

    recorded = {"lpc/tactors/command": [command(1, 0.5), command(2, 0.5), command(3, 0.5)]}
    replayed = {"lpc/tactors/command": [command(2, 0.5), command(3, 0.25)]}  # 1 skipped live
    by_position = check(recorded, replayed)
    assert by_position.total == 3
    by_time = check(recorded, replayed, match_by={"lpc/tactors/command": "t_ns"})
    assert [(d.where, d.path) for d in by_time.differences] == [
        (f"t_ns={T0 + 1}", ""),
        (f"t_ns={T0 + 3}", "amplitudes[0]"),
    ]


def test_replay_cli_recorded_empty_topic_gates_its_node_off(
    tmp_path: Path, depth_images: list[np.ndarray], capsys: pytest.CaptureFixture[str]
) -> None:
    # The reconstructor ran live but kept up with no frame: replay must not reconstruct any,
    # and its own output, replayed with --until, must come back byte for byte.
    record_session(
        tmp_path / "rec.mcap", depth_images, n_frames=12, declare=("lpc/reconstruction",)
    )
    out1, out2 = tmp_path / "out1.mcap", tmp_path / "out2.mcap"
    assert lpc(["replay", str(tmp_path / "rec.mcap"), "--until", "0.1", "--out", str(out1)]) == 0
    out = capsys.readouterr().out
    assert "inputs the live services skipped: {'reconstructor': 6, 'scans': 3}" in out
    assert lpc(["replay", str(out1), "--check", "--out", str(out2)]) == 0
    assert "check: no differences (compared lpc/aim/cue 6" in capsys.readouterr().out
    assert out1.read_bytes() == out2.read_bytes()
    with McapLog(out1) as log:
        assert {"lpc/reconstruction", "lpc/grasp/target"} <= log.topics()


def record_cloud_session(path: Path, images: list[np.ndarray], n_frames: int = 9) -> None:
    """A live-like ``--method cloud`` session: ``record_session``'s frames and scans, and the
    cloud reconstruction of one frame in three (the pool was busy with the others), recorded
    5 ms late with a measured compute time, then its window's grasp target."""
    record_session(path.with_suffix(".base.mcap"), images, n_frames=n_frames)
    state = ReconstructState()
    events: list[tuple[int, str, Any]] = []
    with McapLog(path.with_suffix(".base.mcap")) as log:
        for m in log.messages(decode=True):
            events.append((m.log_time, m.key, m.message))
            if m.key == "lpc/camera/depth" and m.message.seq % 3 == 0:
                state, (rec, target) = reconstruct_cloud_step(state, m.message, m.log_time)
                live = msgspec.structs.replace(rec, compute_ms=30.0 + m.message.seq)
                events.append((m.log_time + 5 * MS, "lpc/reconstruction", live))
                events.append((m.log_time + 5 * MS, "lpc/grasp/target", target))
    events.sort(key=lambda e: e[0])
    with LogWriter(path) as writer:
        for t, key, message in events:
            writer.write(key, message, t)


def test_replay_cli_cloud_recording_replays_by_the_cloud_method(
    tmp_path: Path,
    depth_images: list[np.ndarray],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    record_cloud_session(tmp_path / "cloud.mcap", depth_images)
    assert lpc(["replay", str(tmp_path / "cloud.mcap"), "--check"]) == 0
    out = capsys.readouterr().out
    assert "reconstructor: cloud (the recorded lpc/reconstruction's)" in out
    assert "check: no differences" in out and "lpc/reconstruction 3," in out
    assert "inputs the live services skipped: {'reconstructor': 6, 'scans': 3}" in out
    # The laser method on the same recording reconstructs other frames, from the scans.
    assert lpc(["replay", str(tmp_path / "cloud.mcap"), "--check", "--method", "laser"]) == 1
    capsys.readouterr()

    def coarser_voxel(controller_params: Any = None, **kwargs: Any) -> tuple[Node, ...]:
        nodes = default_nodes(controller_params, **kwargs)
        cloud = ReconstructState(cloud=CloudParams(voxel_m=0.004))
        changed = replace(nodes[1], init=lambda: cloud)
        return (nodes[0], changed, *nodes[2:])

    monkeypatch.setattr(replay_cli, "default_nodes", coarser_voxel)
    assert lpc(["replay", str(tmp_path / "cloud.mcap"), "--check"]) == 1
    out = capsys.readouterr().out
    assert "lpc/reconstruction frame 0 " in out


def test_default_nodes_reject_an_unknown_reconstructor_method() -> None:
    with pytest.raises(ValueError, match="reconstructor_method"):
        default_nodes(reconstructor_method="mesh")


# --------------------------------------------------------------------------- the goldens

RECORDINGS = Path(__file__).resolve().parent.parent / "recordings"
SESSIONS = ("depth", "shapes", "grasp", "faults")


@pytest.mark.parametrize("name", SESSIONS)
def test_recording_replays_without_differences(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every recorded session replays to the same outputs, up to round-off (another machine's
    BLAS kernel may round a sum differently in the last bit; byte identity on one machine is
    test_replay_cli_check_passes_and_output_replays_byte_identical's). When an algorithm
    changes on purpose, regenerate them (recordings/README.md):

        for f in recordings/*.mcap; do .venv/bin/lpc replay "$f" --out "$f"; done
    """
    path = RECORDINGS / f"{name}.mcap"
    assert path.is_file(), f"{path} is missing: see recordings/README.md"
    assert path.stat().st_size < 5_000_000
    code = lpc(["replay", str(path), "--check", "--out", str(tmp_path / "again.mcap")])
    out = capsys.readouterr().out
    assert code == 0, out[out.find("check:") :]
    assert "check: no differences" in out


def test_recording_catches_a_changed_algorithm(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    def blind_aim(controller_params: Any = None, **kwargs: Any) -> tuple[Node, ...]:
        from lpc_core.control.aim import AimParams, AimState

        nodes = default_nodes(controller_params, **kwargs)
        aim = next(n for n in nodes if n.name == "aim")
        changed = replace(aim, init=lambda: AimState(params=AimParams(min_points=100_000)))
        return tuple(changed if n is aim else n for n in nodes)

    monkeypatch.setattr(replay_cli, "default_nodes", blind_aim)
    assert lpc(["replay", str(RECORDINGS / "depth.mcap"), "--check"]) == 1
    out = capsys.readouterr().out
    assert "lpc/aim/cue frame" in out and "differences" in out


def test_replayed_frames_keep_their_depth_as_the_reader_moves_on() -> None:
    # A decoded frame views its payload: each must own bytes of its own, not a view into the
    # reader's chunk, which the next chunk's read replaces.
    kept = []
    with McapLog(Path(__file__).parents[1] / "recordings" / "depth.mcap") as log:
        for m in log.messages(["lpc/camera/depth"], decode=True):
            assert type(m.message.depth.data.obj) is bytes
            kept.append((m.message, bytes(m.message.depth.data)))
    assert len(kept) == 41
    assert all(frame.depth.data == snapshot for frame, snapshot in kept)
