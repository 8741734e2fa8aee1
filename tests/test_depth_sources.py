"""Depth sources: a RealSense recording written by pyrealsense2's software device (no camera)
read back through ``RealSenseSource`` and through the camera service, and the clear
``SourceUnavailable`` errors when the file, the package or its shared library is missing."""

from __future__ import annotations

import importlib.abc
import os
import re
import signal
import socket
import sys
import threading
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import zenoh

from lpc_core.devices.depth_link import MAGIC, DeviceFrame, DeviceHello, encode
from lpc_core.perception.intrinsics import D435_424X240, Intrinsics
from lpc_core.perception.pipeline import depth_image, intrinsics_from_message
from schemas import CameraIntrinsics, decode, to_wire
from services.drivers.depth import (
    EndOfStream,
    MalformedFrame,
    RealSenseSource,
    SimDeviceSource,
    SourceUnavailable,
    skip_missed_slots,
)
from services.drivers.errors import DeviceUnavailable, OperationError
from tests.conftest import spawn_service, wait_for
from tests.realsense_fixture import plane_frames, recording_suffix, write_recording

# Not the D435 default on purpose: every field, the distortion and the 100 µm depth unit must
# come from the recording, not from a default that happens to match.
ODD_INTRINSICS = Intrinsics(
    width=424,
    height=240,
    fx=212.87,
    fy=213.11,
    ppx=211.64,
    ppy=119.38,
    model="brown_conrady",
    coeffs=(0.01, -0.02, 0.001, -0.002, 0.003),
    depth_scale=0.0001,
)
FPS = 90


def require_pyrealsense2() -> ModuleType:
    """pyrealsense2, or a skip saying why; with LPC_REQUIRE_REALSENSE=1 (CI) a failure instead,
    so a CI image that lost the extra or libusb cannot pass by skipping."""
    try:
        import pyrealsense2
    except ImportError as exc:  # not installed, or installed without libusb-1.0-0
        reason = f"pyrealsense2 unavailable ({exc}): pip install 'lpc[realsense]', apt libusb-1.0-0"
        if os.environ.get("LPC_REQUIRE_REALSENSE") == "1":
            pytest.fail(reason)
        pytest.skip(reason)
    return pyrealsense2


def recording(directory: Path, count: int, intrinsics: Intrinsics) -> tuple[Path, list]:
    require_pyrealsense2()
    frames = plane_frames(count, intrinsics, seed=7)
    path = write_recording(directory / f"fixture{recording_suffix()}", frames, intrinsics, FPS)
    return path, frames


def read_all(source: RealSenseSource) -> list:
    readings = []
    while True:
        try:
            reading = source.read(5.0)
        except EndOfStream:
            return readings
        assert reading is not None, f"timed out after {len(readings)} frames"
        readings.append(reading)


def test_realsense_source_round_trips_a_recording(tmp_path: Path) -> None:
    path, frames = recording(tmp_path, 10, ODD_INTRINSICS)
    source = RealSenseSource(path)
    try:
        assert source.intrinsics == ODD_INTRINSICS
        assert source.fps == FPS
        readings = read_all(source)
        with pytest.raises(EndOfStream):  # the end stays the end
            source.read(0.1)
    finally:
        source.shutdown()
    assert len(readings) == 10
    for reading, frame in zip(readings, frames, strict=True):
        assert reading.depth.dtype == np.uint16 and reading.depth.shape == (240, 424)
        np.testing.assert_array_equal(reading.depth, frame)  # exact: Z16 is stored raw
        assert reading.truth is None
    # Frame i was stamped i / 90 s (a float64 in milliseconds): within 1 µs.
    t_ns = np.array([r.t_ns for r in readings])
    np.testing.assert_allclose(t_ns, np.arange(10) * 1e9 / FPS, rtol=0, atol=1e3)


def test_realsense_source_shutdown_is_idempotent_and_ends_reading(tmp_path: Path) -> None:
    path, _ = recording(tmp_path, 3, D435_424X240)
    source = RealSenseSource(path)
    assert source.read(5.0) is not None
    source.shutdown()
    source.shutdown()
    with pytest.raises(OperationError, match="RealSense read failed"):
        source.read(0.1)


def test_realsense_source_missing_file_is_unavailable(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere.db3"
    with pytest.raises(
        SourceUnavailable, match=re.escape(f"no such RealSense recording: {missing}")
    ):
        RealSenseSource(missing)


def test_realsense_source_unreadable_file_is_unavailable(tmp_path: Path) -> None:
    require_pyrealsense2()
    garbage = tmp_path / "garbage.db3"
    garbage.write_bytes(b"not a recording\n")
    with pytest.raises(
        SourceUnavailable, match=re.escape(f"cannot open RealSense recording {garbage}")
    ):
        RealSenseSource(garbage)


def test_realsense_source_without_a_camera_is_unavailable() -> None:
    rs = require_pyrealsense2()
    if len(rs.context().query_devices()) > 0:
        pytest.skip("a RealSense camera is attached")
    with pytest.raises(SourceUnavailable, match="no RealSense camera found"):
        RealSenseSource()


def test_realsense_source_without_pyrealsense2_is_unavailable(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # import raises ModuleNotFoundError
    path = tmp_path / "any.db3"
    path.write_bytes(b"")
    with pytest.raises(SourceUnavailable, match=r"pip install 'lpc\[realsense\]'") as info:
        RealSenseSource(path)
    assert isinstance(info.value, DeviceUnavailable)
    assert isinstance(info.value.__cause__, ImportError)


class _NoLibusb(importlib.abc.MetaPathFinder):
    """Fails pyrealsense2's import the way a machine without libusb does."""

    def find_spec(self, name: str, path: object, target: object = None) -> None:
        if name.split(".")[0] == "pyrealsense2":
            raise ImportError("libusb-1.0.so.0: cannot open shared object file")
        return None


def test_realsense_source_without_libusb_is_unavailable(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    for name in [m for m in sys.modules if m.split(".")[0] == "pyrealsense2"]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setattr(sys, "meta_path", [_NoLibusb(), *sys.meta_path])
    path = tmp_path / "any.db3"
    path.write_bytes(b"")
    with pytest.raises(SourceUnavailable, match=re.escape("apt-get install libusb-1.0-0")):
        RealSenseSource(path)


def test_camera_service_publishes_every_frame_of_a_realsense_file(
    rendezvous: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    path, frames = recording(tmp_path, 10, D435_424X240)
    received: list = []
    logs: list[str] = []

    def on_depth(sample: zenoh.Sample) -> None:
        received.append(decode("lpc/camera/depth", sample.payload.to_bytes()))

    def on_log(sample: zenoh.Sample) -> None:
        logs.append(decode("lpc/log/camera", sample.payload.to_bytes()).text)

    subs = [
        rendezvous.declare_subscriber("lpc/camera/depth", on_depth),
        rendezvous.declare_subscriber("lpc/log/camera", on_log),
    ]
    process = spawn_service(
        "services.camera", endpoint, "--source", "realsense", "--file", str(path)
    )
    try:
        # At the end of the file the service says so and stays up until it is stopped.
        wait_for(lambda: any("end of" in text for text in logs), 60.0, "the end-of-file log")
        assert process.poll() is None
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=10)
        assert process.returncode == 0, stderr.decode()
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        for sub in subs:
            sub.undeclare()
    assert f"end of {path} after 10 frames" in logs
    assert [m.seq for m in received] == list(range(10))
    for message, frame in zip(received, frames, strict=True):
        assert message.source == "realsense"
        assert intrinsics_from_message(message.intrinsics) == D435_424X240
        np.testing.assert_array_equal(depth_image(message), frame)


def test_realsense_source_runs_librealsense_filters_and_reports_refused_settings(
    tmp_path: Path,
) -> None:
    path, frames = recording(tmp_path, 6, D435_424X240)
    plain = RealSenseSource(path, filters=("hole_filling",))
    try:
        filled = read_all(plain)
    finally:
        plain.shutdown()
    smoothed_source = RealSenseSource(
        path, preset="high_accuracy", depth_units=0.0001, filters=("spatial", "temporal")
    )
    try:
        smoothed = read_all(smoothed_source)
    finally:
        smoothed_source.shutdown()
    # A recording's sensor has no visual preset and read-only depth units: both are reported,
    # the recorded unit stays in force, and the frames still come.
    assert smoothed_source.settings["rs_preset"] == "high_accuracy (not set)"
    assert smoothed_source.settings["rs_depth_units"] == "0.001"
    assert smoothed_source.settings["rs_filters"] == "spatial,temporal"
    assert [u.split(":")[0] for u in smoothed_source.unsupported] == [
        "visual_preset high_accuracy",
        "depth_units 0.0001",
    ]
    assert "not applied: visual_preset high_accuracy" in smoothed_source.settings_text()
    assert plain.settings == {
        "rs_preset": "unknown",
        "rs_depth_units": "0.001",
        "rs_filters": "hole_filling",
    }
    assert plain.unsupported == []
    assert len(filled) == len(smoothed) == len(frames)
    for reading, frame in zip(filled, frames, strict=True):
        holes = frame == 0
        assert holes.mean() > 0.01
        # Hole filling fills every hole and leaves every measured pixel as it was.
        assert np.count_nonzero(reading.depth == 0) <= 0.001 * frame.size
        np.testing.assert_array_equal(reading.depth[~holes], frame[~holes])
    for reading, frame in zip(smoothed[1:], frames[1:], strict=True):
        # Smoothing over time on a plane that comes 1 mm closer each frame: the filtered
        # plane lags behind, a few mm farther than the frame, never nearer.
        inner = (frame > 0) & (frame < 65535)
        lag = np.median(reading.depth[inner].astype(int) - frame[inner])
        assert 1 <= lag <= 6


def test_camera_service_records_the_realsense_settings_in_its_health(
    rendezvous: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    path, _ = recording(tmp_path, 10, D435_424X240)
    received: list = []
    health: list = []
    subs = [
        rendezvous.declare_subscriber(
            "lpc/camera/depth",
            lambda s: received.append(decode("lpc/camera/depth", s.payload.to_bytes())),
        ),
        rendezvous.declare_subscriber(
            "lpc/health/camera",
            lambda s: health.append(decode("lpc/health/camera", s.payload.to_bytes())),
        ),
    ]
    args = ["--source", "realsense", "--file", str(path), "--rs-preset", "high_density"]
    process = spawn_service("services.camera", endpoint, *args, "--rs-filters", "hole_filling")
    try:
        wait_for(lambda: len(received) >= 10 and health, 60.0, "10 frames and a health report")
    finally:
        process.send_signal(signal.SIGTERM)
        process.communicate(timeout=10)
        for sub in subs:
            sub.undeclare()
    last = health[-1]
    assert "rs_preset=high_density (not set)" in last.detail
    assert "rs_depth_units=0.001 rs_filters=hole_filling" in last.detail
    assert "not applied: visual_preset high_density" in last.detail
    assert last.counters["rs_option_unsupported"] == 2  # the preset and the depth units
    assert "--rs-preset" in last.argv
    assert all(np.count_nonzero(depth_image(m) == 0) <= 0.001 * 424 * 240 for m in received)


def test_a_frame_clock_behind_skips_the_slots_it_missed() -> None:
    # Frame 3 of a 10 ms clock is due at 30 ms: on time up to a period late, then whole slots go.
    assert skip_missed_slots(0, 3, 10, 40) == (0, 0)
    assert skip_missed_slots(0, 3, 10, 41) == (10, 1)
    assert skip_missed_slots(0, 3, 10, 75) == (40, 4)
    assert skip_missed_slots(5, 3, 10, 20) == (5, 0)  # early is no skip


def _sim_device(tmp_path: Path) -> tuple[SimDeviceSource, socket.socket, socket.socket]:
    """A ``SimDeviceSource`` connected to a device socket this test plays: the source, the
    device's end of the connection (its hello already sent) and the listening socket."""
    intrinsics = CameraIntrinsics(width=8, height=4, fx=213.0, fy=213.0, ppx=4.0, ppy=2.0)
    path = str(tmp_path / "device.sock")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(path)
    server.listen(1)
    accepted: list[socket.socket] = []

    def hello() -> None:
        conn, _ = server.accept()
        conn.sendall(encode(DeviceHello(intrinsics=intrinsics, rate_hz=90.0)))
        accepted.append(conn)

    greeter = threading.Thread(target=hello)
    greeter.start()
    source = SimDeviceSource(path)
    greeter.join()
    return source, accepted[0], server


def test_sim_device_frames_read_on_the_loop_stay_intact_while_later_ones_arrive(
    tmp_path: Path,
) -> None:
    """``read_async`` decodes a frame that arrived whole where it lies in the receive buffer:
    frames kept while the next pieces arrive (three to a piece here) keep their own depth."""
    import asyncio

    source, device, server = _sim_device(tmp_path)
    sent = [np.arange(32, dtype=np.uint16).reshape(4, 8) * (k + 1) for k in range(9)]

    async def read_all() -> list:
        kept = []
        try:
            for first in range(0, 9, 3):
                device.sendall(
                    b"".join(
                        encode(DeviceFrame(seq=k, t_ns=100 + k, depth=to_wire(sent[k])))
                        for k in range(first, first + 3)
                    )
                )
                for _ in range(3):
                    kept.append(await source.read_async(5.0))
        finally:
            source.shutdown()
        return kept

    try:
        kept = asyncio.run(read_all())
    finally:
        device.close()
        server.close()
    assert [r.t_ns for r in kept] == [100 + k for k in range(9)]
    for reading, depth in zip(kept, sent, strict=True):
        np.testing.assert_array_equal(reading.depth, depth)
        assert reading.wire is not None and bytes(reading.wire.data) == depth.tobytes()


def test_sim_device_frames_are_delivered_in_the_reader_callback_and_failures_in_the_task(
    tmp_path: Path,
) -> None:
    """``deliver_async`` hands frames that arrive while it waits to the receiver outside any
    task (the socket's callback), in order and intact; what the receiver raises and a record
    that is not a frame are raised in the waiting task, and the frames after them are
    delivered by the next call, which returns once its timeout passes with no frame."""
    import asyncio

    source, device, server = _sim_device(tmp_path)
    sent = [np.arange(32, dtype=np.uint16).reshape(4, 8) * (k + 1) for k in range(4)]
    records = [encode(DeviceFrame(seq=k, t_ns=100 + k, depth=to_wire(sent[k]))) for k in range(4)]
    got: list[tuple[int | None, bool]] = []

    def on_frame(reading) -> None:
        got.append((reading.t_ns, asyncio.current_task() is None))
        np.testing.assert_array_equal(reading.depth, sent[len(got) - 1])
        if reading.t_ns == 102:
            raise RuntimeError("the publisher failed")

    async def deliver() -> tuple[str, str, float]:
        loop = asyncio.get_running_loop()
        try:
            loop.call_later(0.05, device.sendall, b"".join(records[:3]))
            with pytest.raises(RuntimeError) as first:
                await source.deliver_async(on_frame, 5.0)
            garbage = os.urandom(3000).replace(MAGIC, b"")
            loop.call_later(0.05, device.sendall, garbage + records[3])
            with pytest.raises(MalformedFrame) as second:
                await source.deliver_async(on_frame, 5.0)
            began = loop.time()
            await source.deliver_async(on_frame, 0.3)
            return str(first.value), str(second.value), loop.time() - began
        finally:
            source.shutdown()

    try:
        first, second, waited = asyncio.run(deliver())
    finally:
        device.close()
        server.close()
    assert first == "the publisher failed"
    assert "skipped" in second
    # Frame 103 came after the garbage: queued, and handed over by the third call's task.
    assert got == [(100, True), (101, True), (102, True), (103, False)]
    assert waited >= 0.3 - 0.001


def test_sim_device_read_times_out_at_its_own_deadline_on_a_stalled_device(
    tmp_path: Path,
) -> None:
    """``read_async`` gives ``None`` no sooner than its timeout after it began when the device
    sends nothing, also when a timer set for an earlier read's deadline fires first; a frame
    sent after a timeout is read."""
    import asyncio

    source, device, server = _sim_device(tmp_path)
    depth = np.arange(32, dtype=np.uint16).reshape(4, 8)

    async def reads() -> list[tuple[bool, float, float]]:
        loop = asyncio.get_running_loop()
        out = []
        try:
            for timeout, send in ((0.1, False), (0.3, True), (0.6, False), (0.1, True)):
                if send:
                    device.sendall(encode(DeviceFrame(seq=1, t_ns=7, depth=to_wire(depth))))
                began = loop.time()
                reading = await source.read_async(timeout)
                out.append((reading is not None, loop.time() - began, timeout))
        finally:
            source.shutdown()
        return out

    try:
        got = asyncio.run(reads())
    finally:
        device.close()
        server.close()
    assert [read for read, _, _ in got] == [False, True, False, True]
    for read, waited, timeout in got:
        if not read:  # the third outlives the timer the second set (0.3 s); the loop's
            # timers may run up to its clock's resolution early
            assert waited >= timeout - 0.001, (waited, timeout)
