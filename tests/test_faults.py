"""Fault injection over the real bus: services killed with SIGKILL or frozen with SIGSTOP during
an ``lpc up`` session, the serial port vanishing, the CAN bus failing, the recorder killed.

The hand's side is observed on the CAN bus itself: the prosthesis bridge runs in this process
(python-can's virtual bus connects only the buses of one process) on the bus of an ``lpc up``
session that runs everything else, and a CAN listener timestamps every velocity frame the
bridge sends to the hand. Figures (hand-stop latency, restarts) are printed: run
``pytest tests/test_faults.py -s`` to see them; ``LPC_FAULT_REPEATS`` sets how many freezes the
hand-stop latency is measured over.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import itertools
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import can
import numpy as np
import psutil
import pytest
import zenoh

from lpc_core.devices import can_protocol as cp
from lpc_core.perception.intrinsics import D435_424X240
from schemas import BadMessage, DepthFrame, Health, TactorCommand, decode, encode, to_wire
from services import camera, prosthesis_bridge
from services.cli.up import SERVICES
from services.drivers.depth import DepthReading, SourceUnavailable
from services.drivers.errors import OperationError
from services.drivers.tactor_sim import TactorSim
from services.mcap_log import McapLog
from services.runtime import Bus, zenoh_config
from tests.conftest import free_port, spawn_service, until, wait_for

ROOT = Path(__file__).resolve().parent.parent
REPEATS = int(os.environ.get("LPC_FAULT_REPEATS", "12"))
WATCHDOG_S = 0.04  # the prosthesis bridge's default
# What each service publishes: the session has resumed when it flows again after a restart.
OUTPUT = {
    "camera": "lpc/camera/depth",
    "scans": "lpc/scans",
    "aim": "lpc/aim/cue",
    "controller": "lpc/prosthesis/command",
    "emg": "lpc/emg",
    "reconstructor": "lpc/reconstruction",
}


# --------------------------------------------------------------------------- observers


class BusWatch:
    """Health, logs and message counts per key, from one session on the bus."""

    def __init__(self, session: zenoh.Session) -> None:
        self.lock = threading.Lock()
        self.health: dict[str, Health] = {}
        self.health_times: dict[str, float] = {}
        self.counts: collections.Counter[str] = collections.Counter()
        self.logs: list[str] = []
        self._subs = [
            session.declare_subscriber("lpc/health/*", self._on_health),
            session.declare_subscriber("lpc/**", self._on_any),
        ]

    def _on_health(self, sample: zenoh.Sample) -> None:
        health = decode(str(sample.key_expr), sample.payload.to_bytes())
        with self.lock:
            self.health[health.service] = health
            self.health_times[health.service] = time.monotonic()

    def _on_any(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self.lock:
            self.counts[key] += 1
            if key.startswith("lpc/log/"):
                log = decode(key, sample.payload.to_bytes())
                self.logs.append(f"{log.service}: {log.text}")

    def pid(self, service: str) -> int | None:
        with self.lock:
            h = self.health.get(service)
            return h.pid if h else None

    def count(self, key: str) -> int:
        with self.lock:
            return self.counts[key]

    def logged(self, text: str, times: int = 1) -> bool:
        with self.lock:
            return sum(text in line for line in self.logs) >= times


@dataclass
class CanWatch:
    """Every velocity frame the bridge sends to the hand: (send time, grasp, wrist)."""

    channel: str
    frames: list[tuple[float, float, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            message = self._bus.recv(timeout=0.05)
            if message is None or message.arbitration_id != cp.COMMAND_ID:
                continue
            command, _ = cp.decode_command(cp.Frame(message.arbitration_id, bytes(message.data)))
            with self._lock:
                self.frames.append((message.timestamp, command.grasp, command.wrist))

    def since(self, t: float) -> list[tuple[float, float, float]]:
        with self._lock:
            return [f for f in self.frames if f[0] >= t]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self._bus.shutdown()


class InProcessBridge:
    """``services.prosthesis_bridge`` with its simulated hand, run in this process on a thread
    with its own event loop, so that its CAN bus can be watched here."""

    def __init__(self, endpoint: str, channel: str) -> None:
        self.args = argparse.Namespace(
            hand="can",
            hand_port=None,
            profile="lpc",
            interface="virtual",
            channel=channel,
            watchdog_ms=WATCHDOG_S * 1000,
            sim_hand=True,
            object_mm=60.0,
            quiet=True,
        )
        self.endpoint = endpoint
        self.drivers: list[object] = []
        self.failed: BaseException | None = None
        self._loop = asyncio.new_event_loop()
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._main, daemon=True)

    def __enter__(self) -> InProcessBridge:
        self._thread.start()
        assert self._ready.wait(30), "in-process bridge did not start"
        return self

    def __exit__(self, *exc: object) -> None:
        if self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout=10)

    def _main(self) -> None:
        try:
            self._loop.run_until_complete(self._serve())
        except BaseException as exc:  # reported to the test
            self.failed = exc
            self._ready.set()

    async def _serve(self) -> None:
        self._stop = asyncio.Event()
        original = prosthesis_bridge.open_hand

        def open_hand(*args: object, **kwargs: object) -> object:
            driver = original(*args, **kwargs)  # type: ignore[arg-type]
            self.drivers.append(driver)
            return driver

        with zenoh.open(zenoh_config(connect=[self.endpoint])) as session:
            bus = Bus(session, "prosthesis_bridge", loop=self._loop, quiet=True)
            bus.status = "ok"
            prosthesis_bridge.open_hand = open_hand  # type: ignore[assignment]
            try:
                health = asyncio.create_task(bus.health_loop())
                work = asyncio.create_task(prosthesis_bridge.serve(bus, self.args))
                self._ready.set()
                await self._stop.wait()
                for task in (work, health):
                    task.cancel()
                await asyncio.gather(work, health, return_exceptions=True)
            finally:
                prosthesis_bridge.open_hand = original  # type: ignore[assignment]
                bus.close()


class Up:
    """``lpc up`` as a user runs it, in its own process group."""

    def __init__(self, port: int, services: list[str], *extra: str) -> None:
        argv = [
            sys.executable, "-m", "services.cli", "up", "--port", str(port), "--duration", "600",
            "--status-every", "3600", "--services", *services, *extra,
        ]  # fmt: skip
        self.process = subprocess.Popen(
            argv, cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE, text=True, start_new_session=True,
        )  # fmt: skip
        self.lines: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.process.stderr or []:
            self.lines.append(line.rstrip())

    def said(self, text: str) -> bool:
        return any(text in line for line in self.lines)

    def stop(self) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
        return self.process.returncode


@dataclass
class Session:
    up: Up
    watch: BusWatch
    can: CanWatch
    bridge: InProcessBridge
    endpoint: str
    services: list[str]


@pytest.fixture(scope="module")
def session() -> Iterator[Session]:
    """One ``lpc up`` session for the module: everything but the prosthesis bridge, which runs
    here. Tests share it, in file order, and each leaves it running whole."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    services = [n for n in SERVICES if n not in ("recorder", "foxglove", "prosthesis_bridge")]
    up = Up(port, services)
    channel = f"lpc-faults-{uuid.uuid4().hex[:8]}"
    can_watch = CanWatch(channel)
    try:
        wait_for(lambda: up.said("services up") or up.process.poll() is not None, 90, "lpc up")
        assert up.process.poll() is None, "\n".join(up.lines)
        with (
            zenoh.open(zenoh_config(connect=[endpoint])) as z,
            InProcessBridge(endpoint, channel) as bridge,
        ):
            watch = BusWatch(z)
            wait_for(lambda: all(watch.pid(n) for n in services), 30, "every service's health")
            yield Session(up, watch, can_watch, bridge, endpoint, services)
    finally:
        can_watch.close()
        code = up.stop()
        print(f"\nlpc up exited {code}; restarts logged:", [x for x in up.lines if "restart" in x])


# --------------------------------------------------------------------------- the hand


def _stop_after(
    frames: list[tuple[float, float, float]], t_fault: float
) -> tuple[float, float] | None:
    """(last command, watchdog stop) after a fault at ``t_fault``: the stop is the first frame
    after ``t_fault`` that follows a silence of at least the watchdog period (the bridge sends
    nothing else after such a silence); ``None`` until it has come."""
    gap = WATCHDOG_S * 0.9
    for (t0, *_), (t1, grasp, wrist) in itertools.pairwise(frames):
        if t1 > t_fault and t1 - t0 >= gap:
            assert grasp == 0.0 and wrist == 0.0, "the frame after a silence is a stop"
            return t0, t1
    return None


def test_faults_controller_frozen_hand_stops(session: Session) -> None:
    """SIGSTOP the controller REPEATS times: each time the bridge's watchdog stops the hand."""
    pid = session.watch.pid("controller")
    assert pid is not None
    latencies, after_freeze = [], []
    for _ in range(REPEATS):
        wait_for(lambda: len(session.can.since(time.time() - 0.1)) >= 3, 10, "commands to flow")
        t_freeze = time.time()
        os.kill(pid, signal.SIGSTOP)
        try:
            wait_for(
                lambda t=t_freeze: _stop_after(session.can.since(t - 0.2), t) is not None,
                10,
                "the watchdog's stop frame",
            )
        finally:
            os.kill(pid, signal.SIGCONT)
        found = _stop_after(session.can.since(t_freeze - 0.2), t_freeze)
        assert found is not None
        last, stop = found
        latencies.append(stop - last)
        after_freeze.append(stop - t_freeze)
    ms = np.array(latencies) * 1000
    print(
        f"\nhand stop after the last command ({REPEATS} controller freezes): "
        f"p50 {np.percentile(ms, 50):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms, "
        f"max {ms.max():.1f} ms (watchdog {WATCHDOG_S * 1000:.0f} ms); after the freeze: "
        f"p99 {np.percentile(np.array(after_freeze) * 1000, 99):.1f} ms"
    )
    assert session.watch.pid("controller") == pid, "a frozen controller is not restarted"


def _alive(process: psutil.Process) -> bool:
    try:
        return process.is_running() and process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def test_faults_kill_each_service_in_turn(session: Session) -> None:
    """SIGKILL every service of the session in turn: the others keep running, the killed one
    comes back (lpc up restarts it), its output flows again, and killing the controller stops
    the hand."""
    watch, survived, report = session.watch, [], []
    for name in session.services:
        old = watch.pid(name)
        assert old is not None, name
        others = {n: watch.pid(n) for n in session.services if n != name}
        # A service's own children (the reconstructor's pool) must not outlive it.
        children = psutil.Process(old).children(recursive=True)
        t_kill = time.time()
        os.kill(old, signal.SIGKILL)
        if name == "controller":
            wait_for(
                lambda t=t_kill: _stop_after(session.can.since(t - 0.2), t) is not None,
                10,
                "the hand stopped by the watchdog",
            )
            found = _stop_after(session.can.since(t_kill - 0.2), t_kill)
            assert found is not None
            last, stop = found
            report.append(
                f"controller killed: hand stopped {1000 * (stop - last):.1f} ms after "
                f"the last command, {1000 * (stop - t_kill):.1f} ms after the kill"
            )
        wait_for(lambda c=children: not any(_alive(p) for p in c), 10, f"{name}'s children gone")
        wait_for(lambda n=name, o=old: watch.pid(n) not in (None, o), 60, f"{name} restarted")
        assert session.up.said(f"restarting {name}")
        key = OUTPUT.get(name)
        if key is not None:
            before = watch.count(key)
            wait_for(lambda k=key, b=before: watch.count(k) > b + 5, 30, f"{key} again")
        if name == "controller":
            wait_for(lambda: len(session.can.since(time.time() - 0.2)) >= 5, 30, "commands")
        for other, pid in others.items():
            assert pid is not None and psutil.pid_exists(pid), f"{other} died with {name}"
            assert watch.pid(other) == pid, f"{other} was restarted when {name} was killed"
        survived.append(name)
        report.append(f"{name}: killed (pid {old}), back as pid {watch.pid(name)}")
    assert session.bridge.failed is None
    print("\n" + "\n".join(report))
    print(f"faults injected {len(session.services)}, survived {len(survived)}")
    assert survived == session.services


def test_faults_can_bus_failure_reconnects(session: Session) -> None:
    """The hand's CAN bus fails under the driver (python-can's virtual bus has no bus-off
    state, so the driver's bus is shut down under it: every send and receive then fails as on
    a bus-off controller). The bridge reports it, reopens the bus and drives the hand again;
    commands that came while it was down are counted, not queued."""
    watch, bridge = session.watch, session.bridge
    wait_for(lambda: bool(bridge.drivers), 10, "the hand driver")
    driver = bridge.drivers[-1]
    count = len(bridge.drivers)
    t_fail = time.time()
    driver._bus.shutdown()  # type: ignore[attr-defined]
    wait_for(lambda: len(bridge.drivers) > count, 30, "the bridge to reopen the bus")
    wait_for(lambda: watch.logged("hand bus error"), 10, "the error reported on lpc/log")
    wait_for(lambda: watch.logged("hand connected again"), 10, "the reconnection reported")
    wait_for(lambda: len(session.can.since(t_fail)) >= 20, 10, "commands on the new bus")
    before = watch.count("lpc/prosthesis/state")
    wait_for(lambda: watch.count("lpc/prosthesis/state") > before + 20, 10, "hand state again")
    assert bridge.failed is None


# --------------------------------------------------------------------------- serial port


def test_faults_serial_port_vanishes_and_comes_back(endpoint: str, tmp_path: Path) -> None:
    """The tactor controller's port disappears (the pty hangs up, its path is removed) and
    later reappears at the same path: the bridge keeps running, reports the loss, reopens the
    port and drives the new controller."""
    link = tmp_path / "ttyTACTORS"
    sim = TactorSim("eai")
    link.symlink_to(sim.port)
    with zenoh.open(zenoh_config(connect=[], listen=[endpoint])) as z:
        watch = BusWatch(z)
        bridge = spawn_service("services.tactor_bridge", endpoint, "--tactor-port", str(link))
        publisher = z.declare_publisher("lpc/tactors/command")
        stop = threading.Event()

        def drive() -> None:
            seq = 0
            while not stop.wait(0.02):
                seq += 1
                amplitudes = [0.5, 0.0, 0.0, 0.5] if seq % 20 < 10 else [0.0, 0.5, 0.5, 0.0]
                publisher.put(
                    encode(TactorCommand(seq=seq, t_ns=time.time_ns(), amplitudes=amplitudes))
                )

        driver = threading.Thread(target=drive, daemon=True)
        driver.start()
        try:
            # Commands from the bus reach the controller (not just the bridge's opening).
            wait_for(lambda: sim.mask != 0, 30, "the bridge driving the port")
            sim.close()
            link.unlink()
            wait_for(lambda: watch.logged("tactor port lost"), 20, "the loss reported")
            assert bridge.poll() is None, "the bridge survives a vanished port"
            back = TactorSim("eai")
            link.symlink_to(back.port)
            wait_for(lambda: back.bytes_received > 20, 30, "the bridge writing to the new port")
            wait_for(lambda: watch.logged(f"tactor port {link} open", 2), 10, "the reopening")
            assert bridge.poll() is None
            back.close()
        finally:
            stop.set()
            driver.join(timeout=2)
            bridge.send_signal(signal.SIGINT)
            bridge.wait(timeout=10)
            sim.close()


# --------------------------------------------------------------------------- recorder


def _depth_frame(seq: int) -> bytes:
    # Noise, so that compressed chunks are as big as raw ones and fill at a known rate.
    depth = np.random.default_rng(seq).integers(150, 250, (240, 424), dtype=np.uint16)
    frame = DepthFrame(
        seq=seq,
        t_ns=time.time_ns(),
        intrinsics=_intrinsics(),
        depth=to_wire(depth),
    )
    return encode(frame)


def _intrinsics():  # type: ignore[no-untyped-def]
    from schemas import CameraIntrinsics

    return CameraIntrinsics(width=424, height=240, fx=213.0, fy=213.0, ppx=212.0, ppy=120.0)


def _record_until_killed(endpoint: str, out: Path, z: zenoh.Session) -> int:
    """Start a recorder on ``out``, publish depth frames until a few chunks are on disk, kill it
    with SIGKILL; return how many frames were published."""
    alive: list[bool] = []
    token_sub = z.liveliness().declare_subscriber(
        "lpc/alive/recorder", lambda s: alive.append(s.kind == zenoh.SampleKind.PUT), history=True
    )
    recorder = spawn_service("services.recorder", endpoint, "--out", str(out))
    try:
        wait_for(lambda: alive and alive[-1], 30, "the recorder")
        publisher = z.declare_publisher("lpc/camera/depth")
        seq = 0
        # A few chunks of about 1 MB on disk, whatever the compression.
        while not (out.exists() and out.stat().st_size > 3 * 2**20) and seq < 2000:
            publisher.put(_depth_frame(seq))
            seq += 1
            time.sleep(0.005)  # pacing a producer, not synchronisation
        recorder.send_signal(signal.SIGKILL)
        recorder.wait(timeout=10)
    finally:
        token_sub.undeclare()
        if recorder.poll() is None:
            recorder.kill()
            recorder.wait()
    return seq


def test_faults_recorder_killed_reads_back_to_its_last_chunk(endpoint: str, tmp_path: Path) -> None:
    out = tmp_path / "cut.mcap"
    with zenoh.open(zenoh_config(connect=[], listen=[endpoint])) as z:
        published = _record_until_killed(endpoint, out, z)
    with McapLog(out) as log:
        seqs = [
            decode(m.key, m.payload).seq for m in log.messages(["lpc/camera/depth"], ordered=False)
        ]
        cut = log.cut
    assert not log.complete and cut is not None, "a killed recorder leaves no footer"
    assert seqs, "the chunks written before the kill read back"
    # Everything up to the last complete chunk, in order, nothing missing before it.
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    print(
        f"\nrecorder killed after {published} frames published: {len(seqs)} read back "
        f"({out.stat().st_size / 2**20:.1f} MB), {cut.describe()}"
    )


def test_faults_restarted_recorder_keeps_the_cut_file(endpoint: str, tmp_path: Path) -> None:
    out = tmp_path / "session.mcap"
    with zenoh.open(zenoh_config(connect=[], listen=[endpoint])) as z:
        _record_until_killed(endpoint, out, z)
        with McapLog(out) as log:
            before = sum(1 for _ in log.messages(["lpc/camera/depth"], ordered=False))
        assert before > 0
        # What lpc up does next: the same command line again.
        again = spawn_service("services.recorder", endpoint, "--out", str(out))
        try:
            fresh = tmp_path / "session-001.mcap"
            wait_for(fresh.exists, 30, "the restarted recorder's own file")
        finally:
            again.send_signal(signal.SIGINT)
            again.wait(timeout=10)
    after = 0
    for path in sorted(tmp_path.glob("session*.mcap")):
        with McapLog(path) as log, contextlib.suppress(Exception):
            after += sum(1 for _ in log.messages(["lpc/camera/depth"], ordered=False))
    assert after >= before, f"{before} messages before the restart, {after} after"
    with McapLog(out) as log:  # the predecessor's file is untouched
        assert sum(1 for _ in log.messages(["lpc/camera/depth"], ordered=False)) == before


# --------------------------------------------------------------------------- camera


class UnpluggedCamera:
    """Stands in for a live RealSense (``RealSenseSource`` with no file): open by open, ``SCRIPT``
    says how many frames the camera gives before it is unplugged, or ``None`` when no camera
    is there at that open, with the driver's own errors. It paces itself, as a camera does."""

    SCRIPT: ClassVar[list[int | None]] = []

    unsupported: ClassVar[list[str]] = []

    def __init__(self, file: str | None, rate: int = 90, **settings: object) -> None:
        assert file is None
        assert settings == {"preset": "default", "depth_units": 0.001, "filters": ()}
        frames = self.SCRIPT.pop(0)
        if frames is None:
            raise SourceUnavailable("no RealSense camera found: is it plugged in (USB 3)?")
        self.left = frames
        self.period_s = 1 / rate
        self.intrinsics = D435_424X240
        self.shut = False

    def read(self, timeout: float) -> DepthReading | None:
        if self.left == 0:
            raise OperationError("RealSense read failed: Frame didn't arrive within 5000")
        self.left -= 1
        time.sleep(self.period_s)
        return DepthReading(depth=np.full((240, 424), 200, np.uint16))

    def settings_text(self) -> str:
        return "rs_preset=default rs_depth_units=0.001 rs_filters=none"

    def shutdown(self) -> None:
        self.shut = True


def test_faults_camera_unplugged_and_plugged_back(
    endpoint: str, rendezvous: zenoh.Session, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Missing at the start, then 5 frames, unplugged, two looks that find nothing, back: the
    camera service never stops, counts each, and the frames go on with the next seq."""
    UnpluggedCamera.SCRIPT[:] = [None, 5, None, None, 1000]
    monkeypatch.setattr(camera, "RealSenseSource", UnpluggedCamera)
    seqs: list[int] = []
    sub = rendezvous.declare_subscriber(
        "lpc/camera/depth",
        lambda s: seqs.append(decode("lpc/camera/depth", s.payload.to_bytes()).seq),
    )
    args = argparse.Namespace(
        source="realsense",
        file=None,
        rate=200.0,
        seed=0,
        reopen_every=0.05,
        rs_preset="default",
        rs_depth_units=0.001,
        rs_filters=(),
    )

    async def main() -> Bus:
        loop = asyncio.get_running_loop()
        with zenoh.open(zenoh_config(connect=[endpoint])) as session:
            bus = Bus(session, "camera", loop=loop, quiet=True)
            task = asyncio.create_task(camera.serve(bus, args))
            await until(lambda: len(seqs) >= 20, 10.0, "20 frames")
            assert not task.done() and bus.status == "ok"
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            bus.close()
            return bus

    bus = asyncio.run(main())
    sub.undeclare()
    assert UnpluggedCamera.SCRIPT == []
    counters = bus.health.counters
    assert (counters["camera_missing"], counters["camera_lost"]) == (1, 1)
    assert counters["camera_reopen_failures"] == 2
    assert bus.health.detail == "rs_preset=default rs_depth_units=0.001 rs_filters=none"
    # Nothing lost on the bus, nothing repeated: seq goes on across the reconnection.
    assert seqs == list(range(len(seqs)))


def test_faults_service_survives_a_payload_with_broken_text(endpoint: str) -> None:
    good = _depth_frame(1)
    bad = good.replace(b"\xa3sim", b"\xa3s\x80m")  # the 'source' string, no longer UTF-8
    assert bad != good
    with pytest.raises(BadMessage, match="malformed"):
        decode("lpc/camera/depth", bad)
    with zenoh.open(zenoh_config(connect=[], listen=[endpoint])) as z:
        watch = BusWatch(z)
        scans = spawn_service("services.scans", endpoint)
        try:
            wait_for(lambda: watch.pid("scans") is not None, 30, "the scans service")
            publisher = z.declare_publisher("lpc/camera/depth")

            def rejected() -> int:
                with watch.lock:
                    return watch.health["scans"].counters.get("rejected", 0)

            # Health can come before the subscription is declared: send until it is answered.
            wait_for(
                lambda: (publisher.put(bad), scans.poll() is not None or rejected() > 0)[1],
                30,
                "the bad payload rejected, or the service gone",
            )
            assert scans.poll() is None, "the scans service died of one bad payload"
        finally:
            if scans.poll() is None:
                scans.send_signal(signal.SIGINT)
            scans.wait(timeout=10)


# --------------------------------------------------------------------------- together


def test_faults_together_container_frozen_then_killed() -> None:
    """``lpc up --together``: every service but the prosthesis bridge shares one process. Freeze
    it (SIGSTOP), then kill it (SIGKILL): each time the bridge's watchdog stops the hand; after
    the kill ``lpc up`` restarts the process, the reconstructor's workers die with it, and every
    service comes back (one new pid for all) with its output flowing again."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    services = [n for n in SERVICES if n not in ("recorder", "foxglove", "prosthesis_bridge")]
    up = Up(port, services, "--together")
    channel = f"lpc-together-{uuid.uuid4().hex[:8]}"
    can_watch = CanWatch(channel)
    report = []
    try:
        wait_for(lambda: up.said("services up") or up.process.poll() is not None, 90, "lpc up")
        assert up.process.poll() is None, "\n".join(up.lines)
        with (
            zenoh.open(zenoh_config(connect=[endpoint])) as z,
            InProcessBridge(endpoint, channel) as bridge,
        ):
            watch = BusWatch(z)
            wait_for(lambda: all(watch.pid(n) for n in services), 30, "every service's health")
            # Warm workers (their initializer asks to die with the parent) reconstruct.
            wait_for(lambda: watch.count("lpc/reconstruction") > 0, 60, "reconstructions")
            pid = watch.pid("controller")
            assert {watch.pid(n) for n in services} == {pid}, "one process for all"
            workers = psutil.Process(pid).children(recursive=True)
            assert workers, "the reconstructor's pool is made of processes"
            for fault in (signal.SIGSTOP, signal.SIGKILL):
                wait_for(lambda: len(can_watch.since(time.time() - 0.1)) >= 3, 20, "commands")
                t_fault = time.time()
                os.kill(pid, fault)
                try:
                    wait_for(
                        lambda t=t_fault: _stop_after(can_watch.since(t - 0.2), t) is not None,
                        10,
                        "the watchdog's stop frame",
                    )
                finally:
                    if fault == signal.SIGSTOP:
                        os.kill(pid, signal.SIGCONT)
                found = _stop_after(can_watch.since(t_fault - 0.2), t_fault)
                assert found is not None
                last, stop = found
                report.append(
                    f"container {signal.Signals(fault).name}: hand stopped "
                    f"{1000 * (stop - last):.1f} ms after the last command"
                )
            wait_for(lambda: not any(_alive(p) for p in workers), 30, "the workers gone")
            wait_for(lambda: all(watch.pid(n) not in (None, pid) for n in services), 90, "all back")
            assert up.said("restarting container")
            assert len({watch.pid(n) for n in services}) == 1
            for key in OUTPUT.values():
                before = watch.count(key)
                wait_for(lambda k=key, b=before: watch.count(k) > b + 5, 30, f"{key} again")
            wait_for(lambda: len(can_watch.since(time.time() - 0.2)) >= 5, 30, "commands again")
            assert bridge.failed is None
    finally:
        can_watch.close()
        code = up.stop()
    print("\n" + "\n".join(report) + f"\nlpc up --together exited {code}")
