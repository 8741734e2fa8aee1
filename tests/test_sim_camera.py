"""The simulated camera as a device (``lpc sim-camera``) and the camera service reading it
(``--source sim-device``): real processes, a real Unix socket, Zenoh on loopback."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from lpc_core.devices.depth_link import MAGIC, DeviceFrame, DeviceHello, encode
from lpc_core.perception.intrinsics import D435_424X240
from lpc_core.perception.pipeline import intrinsics_to_message
from schemas import DepthFrame, ObjectTruth, decode, to_wire
from services.children import stop
from services.drivers.depth import SimSource
from tests.conftest import spawn_service, wait_for
from tests.test_faults import BusWatch

ROOT = Path(__file__).resolve().parent.parent
RATE = 90.0


@pytest.fixture
def sock() -> Iterator[Path]:
    # Short: a Unix socket's path is limited to 107 bytes, more than pytest's tmp_path may take.
    path = Path(tempfile.gettempdir()) / f"lpc-test-{uuid.uuid4().hex[:8]}.sock"
    yield path
    path.unlink(missing_ok=True)


def _device(path: Path, *args: str) -> subprocess.Popen[bytes]:
    device = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "sim-camera", "--socket", str(path), *args],
        cwd=ROOT, stdin=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    wait_for(lambda: path.exists() or device.poll() is not None, 30, "the device's socket")
    assert device.poll() is None, device.stderr.read().decode() if device.stderr else ""
    return device


class Frames:
    """Every ``lpc/camera/depth`` frame the camera publishes, decoded."""

    def __init__(self, session: zenoh.Session) -> None:
        self.lock = threading.Lock()
        self.frames: list[DepthFrame] = []
        self._sub = session.declare_subscriber("lpc/camera/depth", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        frame = decode("lpc/camera/depth", sample.payload.to_bytes())
        with self.lock:
            self.frames.append(frame)

    def __len__(self) -> int:
        with self.lock:
            return len(self.frames)

    def seqs(self) -> list[int]:
        with self.lock:
            return [f.seq for f in self.frames]


def _counter(watch: BusWatch, name: str) -> int:
    with watch.lock:
        health = watch.health.get("camera")
        return health.counters.get(name, 0) if health else 0


def _status(watch: BusWatch) -> str | None:
    with watch.lock:
        health = watch.health.get("camera")
        return health.status if health else None


def test_sim_camera_frames_and_truth_reach_the_bus_as_sim_source_renders_them(
    endpoint: str, rendezvous: zenoh.Session, sock: Path
) -> None:
    frames = Frames(rendezvous)
    device = _device(sock, "--rate", f"{RATE:g}", "--seed", "3")
    camera = spawn_service(
        "services.camera", endpoint, "--source", "sim-device", "--socket", str(sock)
    )
    try:
        wait_for(lambda: len(frames) >= 40 or camera.poll() is not None, 60, "40 frames")
    finally:
        stop(camera)
        stop(device)
    with frames.lock:
        got = list(frames.frames)
    # One reader from the device's first frame on: the camera's seq is the device's.
    reference = SimSource(seed=3)
    period_ns = round(1e9 / RATE)
    for frame in got[:40]:
        expected = reference.render(frame.seq * period_ns / 1e9, frame.seq)
        depth = np.frombuffer(frame.depth.data, np.uint16).reshape(frame.depth.shape)
        assert np.array_equal(depth, expected.depth), frame.seq
        # The device's wire array is published as it came: what packing the depth would give.
        assert frame.depth == to_wire(expected.depth), frame.seq
        assert frame.truth == expected.truth, frame.seq
        assert frame.source == "sim-device"
    assert [f.seq for f in got] == list(range(len(got)))
    assert sum(f.truth is not None for f in got[:40]) > 0  # the truth travelled, not only None
    # Stamped by the device when complete: before the camera published it, never after.
    stamps = [f.t_ns for f in got]
    assert stamps == sorted(stamps)


def _camera(endpoint: str, sock: Path) -> subprocess.Popen[bytes]:
    """The camera service on the device at ``sock``, looking for it every 0.2 s."""
    return spawn_service(
        "services.camera", endpoint, "--source", "sim-device", "--socket", str(sock),
        "--reopen-every", "0.2",
    )  # fmt: skip


def test_sim_camera_missing_or_killed_makes_the_camera_degraded_until_it_is_back(
    endpoint: str, rendezvous: zenoh.Session, sock: Path
) -> None:
    frames = Frames(rendezvous)
    watch = BusWatch(rendezvous)
    camera = _camera(endpoint, sock)
    device = None
    try:
        wait_for(lambda: _status(watch) == "degraded", 30, "the camera degraded, no device")
        assert _counter(watch, "camera_missing") == 1 and len(frames) == 0
        device = _device(sock)
        wait_for(lambda: len(frames) >= 20, 30, "frames from the device")
        wait_for(lambda: _status(watch) == "ok", 10, "the camera ok again")
        device.kill()  # no goodbye, and its socket file is left behind
        device.wait()
        wait_for(lambda: _status(watch) == "degraded", 10, "the camera degraded, device lost")
        assert _counter(watch, "camera_lost") == 1
        before = len(frames)
        wait_for(lambda: _counter(watch, "camera_reopen_failures") >= 2, 10, "looks for it")
        assert len(frames) == before  # nothing while the device is gone
        device = _device(sock)  # replaces the stale socket file
        wait_for(lambda: len(frames) >= before + 20, 30, "frames after the device came back")
        wait_for(lambda: _status(watch) == "ok", 10, "the camera ok again")
        assert camera.poll() is None
    finally:
        stop(camera)
        if device is not None:
            stop(device)
    # The camera's seq goes on across the device's restart: nothing repeated, nothing skipped.
    seqs = frames.seqs()
    assert seqs == list(range(len(seqs)))
    assert watch.logged("camera back", 2)


def _serve_once(path: Path, records: list[bytes], then_close: threading.Event) -> threading.Thread:
    """A stand-in device: accepts one reader, writes ``records``, closes once told to."""
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(path))
    server.listen(1)

    def run() -> None:
        with server:
            conn, _ = server.accept()
            with conn:
                for record in records:
                    conn.sendall(record)
                then_close.wait(30)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_sim_camera_garbage_and_truncated_records_are_counted_and_skipped(
    endpoint: str, rendezvous: zenoh.Session, sock: Path
) -> None:
    truth = ObjectTruth(name="cuboid", shape="cuboid", grasp_width_mm=40.0)

    def frame(seq: int, shape: tuple[int, int] = (240, 424)) -> bytes:
        depth = np.full(shape, 200 + seq, np.uint16)
        return encode(DeviceFrame(seq=seq, t_ns=0, depth=to_wire(depth), truth=truth))

    hello = encode(DeviceHello(intrinsics=intrinsics_to_message(D435_424X240), rate_hz=90.0))
    undecodable = MAGIC + (3).to_bytes(4, "little") + b"\xc1\xc1\xc1"
    close = threading.Event()
    records = [
        hello, frame(0), os.urandom(5000).replace(MAGIC, b""), frame(1), undecodable,
        frame(2, shape=(120, 424)), frame(3), frame(4)[:-100],
    ]  # fmt: skip
    device = _serve_once(sock, records, close)
    frames = Frames(rendezvous)
    watch = BusWatch(rendezvous)
    camera = _camera(endpoint, sock)
    try:
        wait_for(lambda: len(frames) >= 3, 30, "the three good frames")
        wait_for(lambda: _counter(watch, "malformed_frames") == 3, 10, "three rejections")
        close.set()  # the device goes away in the middle of frame 4
        device.join(10)
        wait_for(lambda: _counter(watch, "camera_lost") == 1, 10, "the device lost")
        assert _counter(watch, "malformed_frames") == 4  # the truncated frame 4
        assert _status(watch) == "degraded" and camera.poll() is None
    finally:
        stop(camera)
    assert camera.returncode == 0
    with frames.lock:
        got = [(f.seq, int(f.depth.data[0]) + 256 * int(f.depth.data[1])) for f in frames.frames]
    assert got == [(0, 200), (1, 201), (2, 203)]  # frames 0, 1, 3; nothing else
    assert watch.logged("bytes that are not a record") and watch.logged("does not decode")
    assert watch.logged("expected uint16 (240, 424)") and watch.logged("a truncated record")
