"""``lpc bench latency``: from the capture of a depth frame to its bytes on the serial line.

The bench plays the camera: it publishes depth frames on ``lpc/camera/depth`` at the frame
rate, each stamped with its capture time, and the real services (scans, aim, tactor bridge) run
as separate processes on a private loopback bus. The tactor bridge writes to a simulated EAI
controller on a real pseudo-terminal, which records when each frame's bytes arrive.

Correlation: the scene cycles a small sphere through eight directions around the optical axis
(right, down-right, down, ...), so consecutive frames light different tactor masks and a
mask's arrival names its frame (the same mask recurs only every eight frames, 89 ms at 90 Hz).
The bus stages are timed too, from the capture time each message carries to its arrival here.
The bench lowers its own GIL switch interval so that the controller thread timestamps bytes
as they arrive rather than when the publishing thread yields (the services are untouched).
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass

import msgspec
import numpy as np
import zenoh

from lpc_core.devices.tactor_protocol import Command
from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.pipeline import intrinsics_to_message
from schemas import DepthFrame, encode, to_wire
from services.drivers.tactor_sim import TactorSim
from services.runtime import zenoh_config

SERVICES = ("scans", "aim", "tactor_bridge")
DIRECTIONS = 8
# Default right-arm placement: tactor k means direction k * 90 deg; a diagonal lights two.
MASKS = (0b0001, 0b0011, 0b0010, 0b0110, 0b0100, 0b1100, 0b1000, 0b1001)
TARGET_P99_MS = 15.0


class _Stamp(msgspec.Struct):
    """Only the capture time of a message (msgspec skips the other fields unread)."""

    t_ns: int


_STAMP = msgspec.msgpack.Decoder(_Stamp)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--duration", type=float, default=10.0, help="measured seconds (10)")
    parser.add_argument("--warmup", type=float, default=1.0, help="unmeasured seconds first (1)")
    parser.add_argument("--rate", type=float, default=90.0, help="frame rate in Hz (90)")
    parser.add_argument("--port", type=int, default=0, help="loopback port (default: a free one)")
    parser.add_argument(
        "--check", action="store_true", help=f"exit 1 if p99 exceeds {TARGET_P99_MS} ms"
    )


def sphere_depth(intrinsics: Intrinsics, centre: tuple[float, float, float], radius: float):
    """Z16 depth of one sphere on an empty background (ray-sphere intersection, z of hit)."""
    u, v = intrinsics.pixel_rays()
    cx, cy, cz = centre
    d2 = u * u + v * v + 1.0
    dc = u * cx + v * cy + cz
    disc = dc * dc - d2 * (cx * cx + cy * cy + cz * cz - radius * radius)
    z = np.where(disc >= 0, (dc - np.sqrt(np.maximum(disc, 0.0))) / d2, 0.0)
    return np.round(z / intrinsics.depth_scale).astype(np.uint16)


def scene(intrinsics: Intrinsics) -> list:
    """The eight depth images: a 12 mm sphere 30 mm off-axis at 45-degree steps, z = 200 mm.
    Only the scan line through its centre meets it, so the cue points exactly that way."""
    images = []
    for k in range(DIRECTIONS):
        a = math.radians(45.0 * k)
        images.append(
            to_wire(sphere_depth(intrinsics, (0.03 * math.cos(a), 0.03 * math.sin(a), 0.2), 0.012))
        )
    return images


@dataclass
class Stage:
    name: str
    latencies_ms: list[float]

    def row(self, frames: int) -> str:
        if not self.latencies_ms:
            return f"{self.name:<28} {0:>6} {'-':>8} {'-':>8} {'-':>8}"
        p50, p99 = np.percentile(self.latencies_ms, [50, 99])
        worst = max(self.latencies_ms)
        return f"{self.name:<28} {len(self.latencies_ms):>6} {p50:>8.2f} {p99:>8.2f} {worst:>8.2f}"


def match_serial(captures: list[tuple[int, int]], events: list, period_ns: int) -> list[float]:
    """Latency (ms) of each captured frame ``(t_ns, mask)`` to the first set-tactors write of
    its mask that arrives after its capture and before the same mask's next frame."""
    writes = [(e.arrival_ns, e.mask) for e in events if e.command == Command.SET_TACTORS and e.ok]
    times = np.array([t for t, _ in writes], dtype=np.int64)
    masks = np.array([m for _, m in writes], dtype=np.int64)
    window = DIRECTIONS * period_ns
    out = []
    for t_ns, mask in captures:
        start = int(np.searchsorted(times, t_ns))
        hits = np.flatnonzero((masks[start:] == mask) & (times[start:] < t_ns + window))
        if hits.size:
            out.append((int(times[start + hits[0]]) - t_ns) / 1e6)
    return out


def run(args: argparse.Namespace) -> int:
    if not 0 < args.rate <= 1000 or args.duration <= 0 or args.warmup < 0:
        print("lpc bench latency: error: need 0 < --rate <= 1000, --duration > 0", file=sys.stderr)
        return 2
    port = args.port or _free_port()
    switch_interval = sys.getswitchinterval()
    sys.setswitchinterval(0.0005)
    try:
        return _bench(args, port)
    finally:
        sys.setswitchinterval(switch_interval)


def _bench(args: argparse.Namespace, port: int) -> int:
    endpoint = f"tcp/127.0.0.1:{port}"
    intrinsics = Intrinsics()
    images = scene(intrinsics)
    stage_times: dict[str, list[tuple[int, int]]] = {"lpc/scans": [], "lpc/tactors/command": []}
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        received = time.time_ns()
        key = str(sample.key_expr)
        t_ns = _STAMP.decode(sample.payload.to_bytes()).t_ns
        with lock:
            stage_times[key].append((t_ns, received))

    with (
        tempfile.TemporaryFile() as logs,
        TactorSim("eai") as sim,
        zenoh.open(zenoh_config(connect=[], listen=[endpoint])) as session,
    ):
        procs = [_spawn(name, endpoint, sim.port, logs) for name in SERVICES]
        try:
            if not _wait_up(session, sim, procs, timeout=60.0):
                logs.seek(0)
                sys.stderr.write(logs.read().decode(errors="replace")[-4000:])
                print("lpc bench latency: error: services did not come up", file=sys.stderr)
                return 1
            subs = [session.declare_subscriber(k, on_sample) for k in stage_times]
            depth = session.declare_publisher(
                "lpc/camera/depth", congestion_control=zenoh.CongestionControl.DROP
            )
            msg_intrinsics = intrinsics_to_message(intrinsics)
            period_ns = round(1e9 / args.rate)
            warm = round(args.warmup * args.rate)
            total = warm + round(args.duration * args.rate)
            print(
                f"lpc bench latency: {total - warm} frames at {args.rate:g} Hz after {warm} "
                f"warm-up; camera -> scans -> aim -> tactor bridge -> pty ({sim.port})",
                flush=True,
            )
            captures: list[tuple[int, int]] = []
            start = time.time_ns()
            for seq in range(total):
                due = start + seq * period_ns
                while (wait := due - time.time_ns()) > 0:
                    time.sleep(wait / 1e9)
                t_ns = time.time_ns()
                k = seq % DIRECTIONS
                frame = DepthFrame(
                    seq=seq, t_ns=t_ns, intrinsics=msg_intrinsics, depth=images[k], source="bench"
                )
                depth.put(encode(frame))
                if seq >= warm:
                    captures.append((t_ns, MASKS[k]))
            time.sleep(0.3)  # let the last frames drain
            for sub in subs:
                sub.undeclare()
        finally:
            for proc in procs:
                if proc.poll() is None:
                    proc.send_signal(signal.SIGTERM)
            for proc in procs:
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        events = list(sim.events)
    first = captures[0][0] if captures else 0
    stages = []
    with lock:
        for name, key in (
            ("scans on the bus", "lpc/scans"),
            ("tactor command on the bus", "lpc/tactors/command"),
        ):
            stages.append(Stage(name, [(r - t) / 1e6 for t, r in stage_times[key] if t >= first]))
    serial = Stage("bytes on the serial line", match_serial(captures, events, period_ns))
    stages.append(serial)
    print(f"{'stage (from capture)':<28} {'frames':>6} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8}")
    for stage in stages:
        print(stage.row(len(captures)))
    missed = len(captures) - len(serial.latencies_ms)
    print(f"missed: {missed} of {len(captures)} frames never reached the serial line")
    if not serial.latencies_ms:
        return 1
    p99 = float(np.percentile(serial.latencies_ms, 99))
    verdict = "met" if p99 <= TARGET_P99_MS else "NOT met"
    print(f"target p99 <= {TARGET_P99_MS:g} ms at {args.rate:g} Hz: {verdict} (p99 {p99:.2f} ms)")
    return 1 if args.check and p99 > TARGET_P99_MS else 0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _spawn(name: str, endpoint: str, tactor_port: str, log) -> subprocess.Popen[bytes]:
    extra = ["--tactor-port", tactor_port, "--driver", "eai"] if name == "tactor_bridge" else []
    return subprocess.Popen(
        [sys.executable, "-m", f"services.{name}", "--connect", endpoint, "--quiet", *extra],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=log,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def _wait_up(session: zenoh.Session, sim: TactorSim, procs: list, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    wanted = {f"lpc/alive/{name}" for name in SERVICES}
    while time.monotonic() < deadline:
        if any(p.poll() is not None for p in procs):
            return False
        alive = {str(r.ok.key_expr) for r in session.liveliness().get("lpc/alive/*") if r.ok}
        if wanted <= alive and sim.bytes_received > 0:
            return True
        time.sleep(0.05)
    return False
