"""``lpc bench recorder``: what recording and replaying cost on this machine.

Three figures, each printed with how it was measured:

- ``write``: MCAP write (and read-back) CPU time per 203 KB depth frame for each compression
  (zstd at each of ``--zstd-levels``), 1 MiB chunks, simulated frames (distinct noise per
  frame, so chunks do not compress unrealistically).
- ``recorder``: the recorder service as a separate process on a private loopback bus, fed the
  live mix (depth and scans at 90 Hz, EMG and hand state at 100 Hz, cue and tactor command at
  90 Hz) for ``--duration`` seconds; messages sent against messages in the file (loss), and the
  recorder's CPU time as a share of one core.
- ``replay``: ``lpc replay --fast`` on that recording (depth, EMG and hand state in; the scans
  step gated by the recorded scans): recorded seconds per wall second.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import msgspec
import zenoh

from lpc_core.perception.pipeline import ScansState, intrinsics_to_message, scans_step
from lpc_core.sim.simcam import SimCamera
from schemas import (
    AimCue,
    DepthFrame,
    EmgSample,
    ProsthesisState,
    TactorCommand,
    decode,
    encode,
    to_wire,
)
from services.mcap_log import COMPRESSIONS, DEFAULT_ZSTD_LEVEL, McapLog, check_zstd_level
from services.runtime import zenoh_config

RATE_HZ = 90.0
DISTINCT_FRAMES = 24
FIGURES = ("write", "recorder", "replay")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "what", nargs="*", metavar="FIGURE", help="write, recorder, replay (default: all three)"
    )
    parser.add_argument("--frames", type=int, default=270, help="frames per compression (270)")
    parser.add_argument(
        "--zstd-levels",
        metavar="N,N,...",
        type=_levels,
        default=[3, DEFAULT_ZSTD_LEVEL, -1, -5],
        help=f"zstd levels the write figure compares (3,{DEFAULT_ZSTD_LEVEL},-1,-5)",
    )
    parser.add_argument("--duration", type=float, default=10.0, help="recorder run in s (10)")
    parser.add_argument(
        "--compression", choices=sorted(COMPRESSIONS), default="zstd", help="recorder's (zstd)"
    )
    parser.add_argument("--keep", metavar="PATH", help="keep the recorder's file here")
    parser.add_argument(
        "--tx-queue",
        type=int,
        metavar="N",
        help="the publisher's data queue in 64 KB batches (Zenoh's default: 2)",
    )
    parser.add_argument(
        "--wait-before-drop-ms",
        type=float,
        metavar="MS",
        help="how long a full queue may hold a sensor sample before dropping it (default 1)",
    )


def _levels(text: str) -> list[int]:
    try:
        levels = [int(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a list of integers: {text!r}") from None
    try:
        return [check_zstd_level(level) for level in levels]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _frames(n: int) -> list[DepthFrame]:
    camera = SimCamera(seed=1)
    intrinsics = intrinsics_to_message(camera.intrinsics)
    frames = []
    for i in range(n):
        depth, truth = camera.frame(3.0 + i / RATE_HZ, i)
        frames.append(
            DepthFrame(seq=i, t_ns=i, intrinsics=intrinsics, depth=to_wire(depth), truth=truth)
        )
    return frames


def _retimed(frame: DepthFrame, seq: int, t_ns: int) -> DepthFrame:
    return DepthFrame(
        seq=seq, t_ns=t_ns, intrinsics=frame.intrinsics, depth=frame.depth, truth=frame.truth
    )


def bench_write(
    frames: list[DepthFrame], n: int, workdir: Path, zstd_levels: list[int] | None = None
) -> None:
    from services.heap import keep_freed_memory
    from services.mcap_log import LogWriter

    keep_freed_memory()  # as the recorder does
    payloads = [encode(_retimed(frames[i % len(frames)], i, i)) for i in range(n)]
    size = len(payloads[0])
    print(f"write: {n} depth frames of {size / 1e3:.0f} KB per compression, 1 MiB chunks, to disk")
    print(
        f"  {'compression':<11} {'write CPU ms/frame':>18} {'read ms/frame':>13} {'ratio':>6} "
        f"{'MB/s at 90 Hz':>13} {'core at 90 Hz':>13}"
    )
    levels = [DEFAULT_ZSTD_LEVEL] if zstd_levels is None else zstd_levels
    runs = [("none", 0), ("lz4", 0)] + [("zstd", level) for level in levels]
    for compression, level in runs:
        name = f"zstd {level}" if compression == "zstd" else compression
        path = workdir / f"write-{compression}{level}.mcap"
        # CPU time, not wall: the machine is shared, and zstd's work is all in this thread.
        start = time.process_time()
        with LogWriter(path, compression=compression, zstd_level=level) as writer:  # type: ignore[arg-type]
            for i, payload in enumerate(payloads):
                writer.write_raw("lpc/camera/depth", payload, log_time=i + 1, publish_time=i)
        write_s = (time.process_time() - start) / n
        start = time.process_time()
        with McapLog(path) as log:
            count = sum(1 for _ in log.messages(ordered=False))
        read_s = (time.process_time() - start) / count
        ratio = n * size / path.stat().st_size
        print(
            f"  {name:<11} {write_s * 1e3:18.2f} {read_s * 1e3:13.2f} {ratio:6.2f} "
            f"{RATE_HZ * size / ratio / 1e6:13.1f} {100 * RATE_HZ * write_s:12.1f}%"
        )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_recorder(frames: list[DepthFrame], args: argparse.Namespace, out: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    scans = [scans_step(ScansState(), f, 0)[1] for f in frames]
    conf = zenoh_config(connect=[], listen=[endpoint])
    if args.tx_queue:
        conf.insert_json5("transport/link/tx/queue/size/data", str(args.tx_queue))
    if args.wait_before_drop_ms:
        conf.insert_json5(
            "transport/link/tx/queue/congestion_control/drop/wait_before_drop",
            str(int(args.wait_before_drop_ms * 1000)),
        )
    with zenoh.open(conf) as session:
        recorder = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.recorder",
                "--connect",
                endpoint,
                "--quiet",
                "--out",
                str(out),
                "--compression",
                args.compression,
            ],
            stdin=subprocess.DEVNULL,
        )
        received: list[int] = []
        health = session.declare_subscriber(
            "lpc/health/recorder",
            lambda sample: received.append(
                decode(str(sample.key_expr), sample.payload.to_bytes()).counters["received"]
            ),
        )
        try:
            sent = _publish(session, frames, scans, args.duration, recorder.pid)
            # As 'lpc up' does, stop the recorder once the sources are quiet: here, once its
            # health (1 Hz) counts all that was sent, or after 5 s.
            total = sum(sent["count"].values())
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline and not (received and received[-1] >= total):
                time.sleep(0.05)
        finally:
            health.undeclare()
            recorder.send_signal(signal.SIGTERM)
            code = recorder.wait(timeout=30)
    with McapLog(out) as log:
        got = Counter(m.key for m in log.messages(ordered=False))
        complete = log.complete
    print(
        f"recorder: {args.duration:.0f} s of the live mix, compression {args.compression}, "
        f"recorder exit {code}, file {out.stat().st_size / 1e6:.1f} MB, complete {complete}"
    )
    for key in sorted(sent["count"]):
        lost = sent["count"][key] - got[key]
        print(f"  {key:<24} sent {sent['count'][key]:>6}  recorded {got[key]:>6}  lost {lost}")
    print(
        f"  recorder CPU {sent['cpu_s']:.2f} s in {sent['wall_s']:.2f} s: "
        f"{100 * sent['cpu_s'] / sent['wall_s']:.1f}% of one core "
        f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)"
    )


def _publish(
    session: zenoh.Session,
    frames: list[DepthFrame],
    scans: list[Any],
    duration: float,
    recorder_pid: int,
) -> dict[str, Any]:
    sensor = {"congestion_control": zenoh.CongestionControl.DROP, "priority": zenoh.Priority.DATA}
    command = {"congestion_control": zenoh.CongestionControl.BLOCK, "express": True}
    pubs = {
        "lpc/camera/depth": session.declare_publisher("lpc/camera/depth", **sensor),
        "lpc/scans": session.declare_publisher("lpc/scans", **sensor),
        "lpc/aim/cue": session.declare_publisher("lpc/aim/cue", **sensor),
        "lpc/emg": session.declare_publisher("lpc/emg", **sensor),
        "lpc/prosthesis/state": session.declare_publisher("lpc/prosthesis/state", **sensor),
        "lpc/tactors/command": session.declare_publisher("lpc/tactors/command", **command),
    }
    deadline = time.monotonic() + 30
    while not all(p.matching_status.matching for p in pubs.values()):
        if time.monotonic() > deadline:
            raise SystemExit("bench: the recorder never subscribed")
        time.sleep(0.01)
    count: Counter[str] = Counter()
    cpu0, wall0 = _cpu_s(recorder_pid), time.monotonic()
    t0 = time.time_ns()
    events = sorted(
        [(i / RATE_HZ, "frame", i) for i in range(int(duration * RATE_HZ))]
        + [(i / 100.0, "emg", i) for i in range(int(duration * 100))]
    )
    for at, kind, i in events:
        delay = wall0 + at - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        t = t0 + int(at * 1e9)
        if kind == "frame":
            k = i % len(frames)
            messages = [
                ("lpc/camera/depth", _retimed(frames[k], i, t)),
                ("lpc/scans", msgspec.structs.replace(scans[k], seq=i, t_ns=t, frame_seq=i)),
                ("lpc/tactors/command", TactorCommand(seq=i, t_ns=t, amplitudes=[0.2] * 4)),
                ("lpc/aim/cue", AimCue(seq=i, t_ns=t, frame_seq=i, state="guiding")),
            ]
        else:
            messages = [
                ("lpc/emg", EmgSample(seq=i, t_ns=t, channels=[0.05, 0.02])),
                (
                    "lpc/prosthesis/state",
                    ProsthesisState(seq=i, t_ns=t, wrist_angle_deg=0.0, aperture_mm=80.0),
                ),
            ]
        for key, message in messages:
            pubs[key].put(encode(message))
            count[key] += 1
    wall = time.monotonic() - wall0
    cpu = _cpu_s(recorder_pid) - cpu0
    for pub in pubs.values():
        pub.undeclare()
    return {"count": count, "cpu_s": cpu, "wall_s": wall}


def bench_replay(path: Path) -> None:
    from services.cli import replay

    print(f"replay: lpc replay {path} --fast")
    parser = argparse.ArgumentParser()
    replay.add_arguments(parser)
    args = parser.parse_args([str(path), "--fast"])
    replay.run(args)


def run(args: argparse.Namespace) -> int:
    what = args.what or list(FIGURES)
    unknown = set(what) - set(FIGURES)
    if unknown:
        print(f"lpc bench recorder: unknown figure(s) {sorted(unknown)}; know {FIGURES}")
        return 2
    with tempfile.TemporaryDirectory(prefix="lpc-bench-") as tmp:
        workdir = Path(tmp)
        frames = _frames(DISTINCT_FRAMES)
        if "write" in what:
            bench_write(frames, args.frames, workdir, args.zstd_levels)
        out = Path(args.keep) if args.keep else workdir / "recorder.mcap"
        if "recorder" in what or "replay" in what:
            bench_recorder(frames, args, out)
        if "replay" in what:
            bench_replay(out)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="lpc bench recorder", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
