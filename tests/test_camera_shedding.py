"""The camera service sheds frames when the control path reports late ticks: the real service
on a loopback bus, a scripted stand-in for the controller's health, the camera's health and
frames watched. Nothing waits on a duration: every step waits for what the camera reports."""

from __future__ import annotations

import tempfile
import threading
import time
import uuid
from pathlib import Path

import pytest
import zenoh

from schemas import Health, decode, encode
from services.children import stop
from tests.conftest import spawn_service, wait_for
from tests.test_faults import BusWatch
from tests.test_sim_camera import _device


class Seqs:
    """The ``seq`` of every ``lpc/camera/depth`` frame."""

    def __init__(self, session: zenoh.Session) -> None:
        self.lock = threading.Lock()
        self.seqs: list[int] = []
        self._sub = session.declare_subscriber("lpc/camera/depth", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        seq = decode("lpc/camera/depth", sample.payload.to_bytes()).seq
        with self.lock:
            self.seqs.append(seq)

    def __len__(self) -> int:
        with self.lock:
            return len(self.seqs)


def _counter(watch: BusWatch, name: str) -> int | None:
    with watch.lock:
        health = watch.health.get("camera")
        return health.counters.get(name) if health else None


# A simulated frame is shed before it is rendered, in the camera's task; a device's frame where
# the socket's reader callback parses it (services.drivers.depth.SimDeviceSource.deliver_async).
@pytest.mark.parametrize("source", ["sim", "sim-device"])
def test_camera_sheds_frames_while_the_controller_reports_late_ticks(
    endpoint: str, rendezvous: zenoh.Session, source: str
) -> None:
    device = None
    flags = ["--source", source, "--rate", "30"]
    if source == "sim-device":
        # Short: a Unix socket's path is limited to 107 bytes.
        sock = Path(tempfile.gettempdir()) / f"lpc-test-{uuid.uuid4().hex[:8]}.sock"
        device = _device(sock, "--rate", "30")
        flags += ["--socket", str(sock)]
    watch = BusWatch(rendezvous)
    frames = Seqs(rendezvous)
    # Only to other processes: its matching status then says when the camera subscribes.
    controller = rendezvous.declare_publisher(
        "lpc/health/controller", allowed_destination=zenoh.Locality.REMOTE
    )

    def report(seq: int, ticks: int, late: int) -> None:
        counters = {"ticks": ticks, "late_ticks": late}
        health = Health(seq=seq, t_ns=0, service="controller", pid=1, counters=counters)
        controller.put(encode(health))

    camera = spawn_service("services.camera", endpoint, *flags)
    try:
        wait_for(lambda: len(frames) >= 10 or camera.poll() is not None, 60, "10 frames")
        wait_for(lambda: controller.matching_status.matching, 30, "the camera's subscriber")
        wait_for(lambda: _counter(watch, "shed_rate_hz") is not None, 30, "the camera's health")
        assert _counter(watch, "shed_frames") == 0 and _counter(watch, "shed_rate_hz") == 30
        # A baseline, then two windows with half the ticks late: 30 Hz halves to 15.
        report(1, 100, 0)
        report(2, 200, 50)
        report(3, 300, 100)
        wait_for(lambda: _counter(watch, "shed_rate_hz") == 15, 30, "the camera at 15 Hz")
        assert watch.logged("frame rate 30.0 -> 15.0 Hz: controller late in 50% of its ticks")
        # At 15 Hz of 30, every other frame is shed. Meanwhile the stand-in goes on reporting
        # a quarter of its ticks late, between the thresholds: the rate holds.
        ticks, late = 300, 100
        last_report = time.monotonic()

        def thirty_shed_while_holding() -> bool:
            nonlocal ticks, late, last_report
            if time.monotonic() - last_report > 0.5:
                ticks, late = ticks + 100, late + 25
                report(ticks // 100, ticks, late)
                last_report = time.monotonic()
            return (_counter(watch, "shed_frames") or 0) >= 30

        wait_for(thirty_shed_while_holding, 60, "30 frames shed")
        assert _counter(watch, "shed_rate_hz") == 15
        # A clean window of a second (its length is the input, not a wait): +1.5 Hz.
        time.sleep(1.0)
        report(ticks // 100 + 1, ticks + 100, late)
        wait_for(lambda: (_counter(watch, "shed_rate_hz") or 0) > 15, 30, "the rate to climb")
        shed = _counter(watch, "shed_frames") or 0
    finally:
        stop(camera)
        if device is not None:
            stop(device)
            sock.unlink(missing_ok=True)
    with frames.lock:
        seqs = list(frames.seqs)
    # What is shed is never published: the frames on the bus keep consecutive numbers.
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    assert shed >= 30
