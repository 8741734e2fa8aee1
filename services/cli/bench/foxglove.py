"""``python -m services.cli.bench.foxglove``: what the Foxglove conversion costs.

Prints three figures: conversion + JSON encoding per message (in-process), ``lpc export`` speed
on a synthetic 90 Hz recording, and the live bridge at 90 Hz over loopback (capture -> client
latency, bridge CPU with a client watching and with none).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgspec
import numpy as np
import zenoh

from lpc_core.foxglove_convert import convert
from schemas import (
    CameraIntrinsics,
    DepthFrame,
    EmgSample,
    LineModel,
    Message,
    Reconstruction,
    ScanLine,
    ScanLines,
    encode,
    to_wire,
)
from services.mcap_log import LogWriter
from services.runtime import zenoh_config

INTRINSICS = CameraIntrinsics(width=424, height=240, fx=213.0, fy=213.0, ppx=212.0, ppy=120.0)
RATE_HZ = 90.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=900, help="frames to export (default 900)")
    parser.add_argument(
        "--seconds", type=float, default=10.0, help="live bridge run per case (default 10 s)"
    )


def synthetic_depth(rng: np.random.Generator) -> np.ndarray:
    """A table-top view in mm: a tilted plane at ~40 cm, a 30 mm ball at 20 cm, sensor noise
    and 2% holes (what compression sees in a real recording, unlike uniform noise)."""
    v, u = np.mgrid[0:240, 0:424].astype(np.float64)
    x, y = (u - INTRINSICS.ppx) / INTRINSICS.fx, (v - INTRINSICS.ppy) / INTRINSICS.fy
    depth = 400.0 / (1.0 + 0.4 * y)
    # Ray-sphere intersection, centre (0, 0, 200 mm), radius 30 mm.
    norm2 = x * x + y * y + 1.0
    b = 200.0 / norm2
    disc = b * b - (200.0**2 - 30.0**2) / norm2
    hit = disc > 0
    depth[hit] = np.minimum(depth[hit], b[hit] - np.sqrt(disc[hit]))
    depth += rng.normal(0.0, 0.0004 * depth**2 / 100.0)
    depth[rng.random(depth.shape) < 0.02] = 0
    return np.clip(np.round(depth), 0, 65535).astype(np.uint16)


def frame_set(seq: int, t_ns: int) -> list[tuple[str, Message]]:
    """One camera frame's worth of messages: depth, scans, a reconstruction, EMG."""
    rng = np.random.default_rng(seq)
    depth = synthetic_depth(rng)
    lines = []
    for angle in (0.0, 45.0, 90.0, 135.0):
        s = np.linspace(-0.05, 0.05, 170)
        phi = np.radians(angle)
        z = 0.2 + 0.001 * rng.standard_normal(s.size)
        points = np.column_stack([s * np.cos(phi), s * np.sin(phi), z]).astype(np.float32)
        lines.append(ScanLine(angle_deg=angle, points=to_wire(points)))
    models = [LineModel(angle_deg=a, model="circle", params=[0.0, 0.22, 0.02]) for a in (0, 45)]
    return [
        (
            "lpc/camera/depth",
            DepthFrame(seq=seq, t_ns=t_ns, intrinsics=INTRINSICS, depth=to_wire(depth)),
        ),
        ("lpc/scans", ScanLines(seq=seq, t_ns=t_ns, frame_seq=seq, lines=lines)),
        (
            "lpc/reconstruction",
            Reconstruction(
                seq=seq,
                t_ns=t_ns,
                frame_seq=seq,
                shape="cylinder",
                grasp_width_mm=40.0,
                center_m=[0.0, 0.0, 0.22],
                axis=[0.0, 1.0, 0.0],
                lines=models,
            ),
        ),
        ("lpc/emg", EmgSample(seq=seq, t_ns=t_ns, channels=[0.1, 0.2])),
    ]


def bench_convert(n: int = 300) -> None:
    encode_json = msgspec.json.Encoder().encode
    for key, message in frame_set(0, 1):
        times = []
        size = 0
        for _ in range(n):
            start = time.perf_counter()
            size = sum(len(encode_json(o.payload)) for o in convert(key, message))
            times.append(time.perf_counter() - start)
        p50, p99 = np.percentile(np.array(times) * 1e3, [50, 99])
        print(f"convert  {key:<20} p50 {p50:6.3f} ms  p99 {p99:6.3f} ms  {size / 1e3:7.1f} KB JSON")


def bench_export(frames: int) -> None:
    from services.cli import export

    with tempfile.TemporaryDirectory() as tmp:
        source, target = Path(tmp) / "in.mcap", Path(tmp) / "out.mcap"
        with LogWriter(source) as writer:
            for seq in range(frames):
                t_ns = 1_700_000_000_000_000_000 + int(seq * 1e9 / RATE_HZ)
                for key, message in frame_set(seq, t_ns):
                    writer.write(key, message, log_time=t_ns)
        parser = argparse.ArgumentParser()
        export.add_arguments(parser)
        start = time.perf_counter()
        code = export.run(
            parser.parse_args(["--foxglove", "--no-progress", str(source), str(target)])
        )
        elapsed = time.perf_counter() - start
        print(
            f"export   {frames} frames ({frames / RATE_HZ:.1f} s at 90 Hz, "
            f"{source.stat().st_size / 1e6:.1f} MB in, {target.stat().st_size / 1e6:.1f} MB out): "
            f"{elapsed:.2f} s, {frames / elapsed:.0f} frames/s, "
            f"{elapsed / frames * 1e3:.2f} ms per frame; exit {code}"
        )


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


async def _watch(port: int, seconds: float) -> list[float]:
    import websockets

    latencies: list[float] = []
    deadline = time.monotonic() + 30
    while True:
        try:
            ws = await websockets.connect(
                f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], max_size=None
            )
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.1)
    subs: dict[int, str] = {}  # subscription id -> topic
    async with ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                async with asyncio.timeout(1.0):
                    frame = await ws.recv()
            except TimeoutError:
                continue
            arrived = time.time_ns()
            if isinstance(frame, str):
                op = json.loads(frame)
                if op["op"] == "advertise":
                    wanted = []
                    for channel in op["channels"]:
                        subs[len(subs) + 1] = channel["topic"]
                        wanted.append({"id": len(subs), "channelId": channel["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": wanted}))
                continue
            sub_id = int.from_bytes(frame[1:5], "little")
            if subs.get(sub_id) == "/lpc/camera/depth":
                stamp = json.loads(frame[13:])["timestamp"]
                latencies.append((arrived - stamp["sec"] * 10**9 - stamp["nsec"]) / 1e6)
    return latencies


def bench_bridge(seconds: float) -> None:
    def free_port() -> int:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]

    endpoint, ws_port = f"tcp/127.0.0.1:{free_port()}", free_port()
    with zenoh.open(zenoh_config(connect=[], listen=[endpoint])) as session:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.foxglove_bridge",
                "--connect",
                endpoint,
                "--quiet",
                "--port",
                str(ws_port),
            ],
            stdin=subprocess.DEVNULL,
        )
        stop = threading.Event()
        sent = [0]

        def publish() -> None:
            period, seq, next_t = 1.0 / RATE_HZ, 0, time.monotonic()
            payload_sets = [[(k, m) for k, m in frame_set(i, 0)] for i in range(4)]
            while not stop.is_set():
                t_ns = time.time_ns()
                for key, message in payload_sets[seq % 4]:
                    session.put(key, encode(msgspec.structs.replace(message, seq=seq, t_ns=t_ns)))
                seq += 1
                sent[0] = seq
                next_t += period
                stop.wait(max(0.0, next_t - time.monotonic()))

        thread = threading.Thread(target=publish, daemon=True)
        thread.start()
        try:
            time.sleep(3.0)  # start-up: the bridge imports, opens the bus and the server
            cpu0, t0 = _cpu_s(proc.pid), time.monotonic()
            time.sleep(seconds)
            idle = (_cpu_s(proc.pid) - cpu0) / (time.monotonic() - t0)
            cpu0, t0 = _cpu_s(proc.pid), time.monotonic()
            latencies = asyncio.run(_watch(ws_port, seconds))
            busy = (_cpu_s(proc.pid) - cpu0) / (time.monotonic() - t0)
        finally:
            stop.set()
            thread.join()
            proc.terminate()
            proc.wait(timeout=10)
    lat = np.array(latencies[int(RATE_HZ) :])  # the first second includes subscription set-up
    print(f"bridge   no viewer: {100 * idle:.1f}% of a core at 90 Hz (depth, scans, rec, EMG)")
    if lat.size:
        p50, p99 = np.percentile(lat, [50, 99])
        print(
            f"bridge   one viewer: {100 * busy:.1f}% of a core; depth capture -> client "
            f"p50 {p50:.2f} ms p99 {p99:.2f} ms; {lat.size / (seconds - 1):.1f} depth frames/s "
            f"received of {RATE_HZ:.0f}"
        )
    else:
        print("bridge   one viewer: no depth frame received")


def run(args: argparse.Namespace) -> int:
    bench_convert()
    bench_export(args.frames)
    bench_bridge(args.seconds)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m services.cli.bench.foxglove", description=__doc__
    )
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
