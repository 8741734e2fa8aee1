"""The hand drivers, the simulated hand and the bridge's watchdog, on python-can's virtual bus;
and the bridge service over the real Zenoh bus."""

from __future__ import annotations

import asyncio
import itertools
import select
import threading
import time
from pathlib import Path

import can
import pytest
import zenoh

from lpc_core.devices import can_protocol as cp
from lpc_core.devices.hand import HandCommand, HandStatus
from schemas import ProsthesisCommand, decode, encode
from services.drivers.errors import DeviceUnavailable, DriverError, OperationError
from services.drivers.hand import BACKENDS, HandLink, LpcHand, open_hand, serial_port_url
from services.drivers.hand_sim import PERIOD_S, SimulatedHand, _next_tick, open_pty_bus
from tests.conftest import spawn_service, wait_for

_channels = itertools.count()


@pytest.fixture
def channel() -> str:
    """A virtual CAN channel of its own per test."""
    return f"lpc-test-{next(_channels)}-{time.monotonic_ns()}"


class Recorder:
    """A passive listener on the virtual bus: every frame with python-can's timestamp."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.frames: list[can.Message] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            message = self.bus.recv(timeout=0.01)
            if message is not None:
                self.frames.append(message)

    def commands(self) -> list[tuple[float, HandCommand]]:
        return [
            (m.timestamp, cp.decode_command(cp.Frame(m.arbitration_id, bytes(m.data)))[0])
            for m in list(self.frames)
            if m.arbitration_id == cp.COMMAND_ID
        ]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.bus.shutdown()


# --------------------------------------------------------------------------- drivers


@pytest.mark.parametrize("profile", sorted(BACKENDS))
def test_driver_contract_on_the_virtual_bus(profile: str, channel: str) -> None:
    with SimulatedHand(profile, channel=channel, aperture_mm=80.0) as sim:
        driver = open_hand(profile, channel=channel)
        try:
            statuses: list[HandStatus] = []
            deadline = time.monotonic() + 5.0
            while len(statuses) < 30 and time.monotonic() < deadline:
                driver.send(HandCommand(grasp=-1.0), timeout=0.01)
                status = driver.recv(timeout=0.05)
                if status is not None:
                    statuses.append(status)
            assert len(statuses) == 30
            assert sim.commands_received > 0 and sim.command.grasp < -0.9
            assert statuses[-1].aperture_mm > 80.0  # opening, as commanded
        finally:
            driver.shutdown()
            driver.shutdown()  # safe twice
        with pytest.raises(OperationError, match="shut down"):
            driver.send(HandCommand())


def test_driver_recv_times_out_with_none(channel: str) -> None:
    with LpcHand(channel=channel) as driver:
        t0 = time.monotonic()
        assert driver.recv(timeout=0.02) is None
        assert time.monotonic() - t0 < 1.0


def test_driver_counts_error_frames_and_skips_garbage(channel: str) -> None:
    peer = can.Bus(interface="virtual", channel=channel)
    try:
        with LpcHand(channel=channel) as driver:
            peer.send(can.Message(is_error_frame=True, arbitration_id=0x40, dlc=8))
            peer.send(
                can.Message(arbitration_id=cp.STATUS_ID, data=b"\x00\x01", is_extended_id=False)
            )
            status = HandStatus(wrist_angle_deg=10.0, aperture_mm=55.0, grip_force_pct=20)
            for frame in cp.encode_status(status):
                peer.send(
                    can.Message(
                        arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=False
                    )
                )
            got = driver.recv(timeout=1.0)
            assert got is not None and got.aperture_mm == 55.0
            assert driver.error_frames == 1
            assert "needs 8 bytes" in driver.last_error
    finally:
        peer.shutdown()


def test_driver_carries_emg_from_the_hand(channel: str) -> None:
    with (
        SimulatedHand("lpc", channel=channel, emg=lambda: (12, 800, 3)),
        LpcHand(channel=channel) as driver,
    ):
        status = None
        deadline = time.monotonic() + 2.0
        while status is None and time.monotonic() < deadline:
            status = driver.recv(timeout=0.1)
        assert status is not None and status.emg[:3] == (12.0, 800.0, 3.0)


def test_driver_poll_reads_a_whole_status_cycle_in_one_call(channel: str) -> None:
    """``recv(timeout=0)`` (``HandLink.poll``, the loop's reader) reads on through a cycle's
    EMG frames to its status while the bus holds frames: one call a cycle, then ``None``
    (main: ``None`` after the first EMG frame, the status only at the third call)."""
    device = can.Bus(interface="virtual", channel=channel)
    with LpcHand(channel=channel) as driver:
        emg = tuple(float(v) for v in range(100, 108))
        sent = HandStatus(wrist_angle_deg=-20.0, aperture_mm=61.0, emg=emg, counter=9)
        frames = cp.encode_status(sent)
        assert len(frames) == 3  # two EMG frames, then the status
        for frame in frames:
            device.send(
                can.Message(
                    arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=False
                )
            )
        got = driver.recv(timeout=0.0)
        assert driver.recv(timeout=0.0) is None
    device.shutdown()
    assert got is not None and (got.aperture_mm, got.emg, got.counter) == (61.0, emg, 9)


def test_open_hand_unknown_profile_or_interface_is_unavailable(channel: str) -> None:
    with pytest.raises(DeviceUnavailable, match="unknown hand profile"):
        open_hand("michelangelo", channel=channel)
    with pytest.raises(DeviceUnavailable):
        open_hand("lpc", interface="no-such-interface", channel=channel)


def test_open_hand_missing_socketcan_device_is_a_driver_error() -> None:
    # No such interface (or no AF_CAN in this kernel): a DriverError, never a python-can error.
    with pytest.raises(DriverError, match="socketcan:lpc-no-such-can"):
        open_hand("lpc", interface="socketcan", channel="lpc-no-such-can")


def test_driver_reads_the_serial_bus_without_a_select_per_field(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """python-can's serial bus reads a frame in six reads; on pyserial's default port each
    selects first. The driver's port (``serial_port_url``) reads without: no select at all for
    a status frame and the empty read after it, the same status."""
    device, path = open_pty_bus()
    driver = LpcHand(interface="serial", channel=path)
    try:
        sent = HandStatus(wrist_angle_deg=12.0, aperture_mm=55.0, grip_force_pct=3.0, counter=7)
        for frame in cp.encode_status(sent):
            message = can.Message(
                arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=False
            )
            device.send(message)
        assert select.select([driver.fileno()], [], [], 2.0)[0]
        time.sleep(0.01)  # the pty hands the writes over on a kernel worker
        selects = []
        real = select.select
        monkeypatch.setattr(select, "select", lambda *a: selects.append(a) or real(*a))
        got = driver.recv(timeout=0.0)
        assert driver.recv(timeout=0.0) is None
    finally:
        driver.shutdown()
        device.shutdown()
    assert got is not None
    assert (got.wrist_angle_deg, got.aperture_mm, got.counter) == (12.0, 55.0, 7)
    assert selects == []  # pyserial's default port: 7 (one per read)
    assert serial_port_url("/dev/pts/3") == "alt:///dev/pts/3?class=VTIMESerial"
    assert serial_port_url("socket://localhost:1") == "socket://localhost:1"


def test_simulated_hand_stops_on_its_own_watchdog(channel: str) -> None:
    with (
        SimulatedHand("lpc", channel=channel, hand_watchdog_s=0.1) as sim,
        LpcHand(channel=channel) as driver,
    ):
        driver.send(HandCommand(wrist=1.0))
        wait_for(lambda: sim.state.wrist_speed > 10.0, 5.0, "the wrist to turn")
        # No more commands: the hand stops by itself and says so.
        status = None
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            status = driver.recv(timeout=0.1)
            if status is not None and status.watchdog and not status.moving:
                break
        assert status is not None and status.watchdog and not status.moving


def test_simulated_hand_skips_the_ticks_a_stall_missed() -> None:
    # On time or a little late: the 10 ms grid holds.
    assert _next_tick(1.0, 1.0) == pytest.approx(1.0 + PERIOD_S)
    assert _next_tick(1.0, 1.008) == pytest.approx(1.0 + PERIOD_S)
    # Run 55 ms late (a stall): the next tick is a period after now, not the five missed ones.
    assert _next_tick(1.0, 1.055) == pytest.approx(1.055 + PERIOD_S)


# --------------------------------------------------------------------------- the link's watchdog


def test_link_watchdog_sends_zero_velocity_after_50_ms(channel: str) -> None:
    recorder = Recorder(channel)
    link = HandLink(lambda: LpcHand(channel=channel), on_status=lambda s: None, watchdog_s=0.05)
    link.start()
    try:
        wait_for(lambda: link.connected, 5.0, "the link to connect")
        assert link.command(HandCommand(grasp=0.5, wrist=-0.25))
        wait_for(
            lambda: (
                any(c.grasp == 0.0 for _, c in recorder.commands()[1:])
                and any(c.grasp > 0 for _, c in recorder.commands())
            ),
            5.0,
            "a zero command after the moving one",
        )
        commands = recorder.commands()
        moving = max(t for t, c in commands if c.grasp > 0)
        zero = min(t for t, c in commands if c.grasp == 0.0 and t > moving)
        # The watchdog never fires early: 50 ms after the command at the earliest.
        assert zero - moving >= 0.05 - 0.002
        print(f"watchdog: zero velocity {1000 * (zero - moving):.1f} ms after the last command")
        assert link.counters["watchdog_stops"] >= 1
    finally:
        link.stop()
        link.stop()
        recorder.close()


def test_link_fresh_commands_hold_off_the_watchdog(channel: str) -> None:
    recorder = Recorder(channel)
    sent: list[float] = []
    link = HandLink(lambda: LpcHand(channel=channel), on_status=lambda s: None, watchdog_s=0.05)
    link.start()
    try:
        wait_for(lambda: link.connected, 5.0, "the link to connect")
        start = time.monotonic()
        while time.monotonic() - start < 0.5:  # a 100 Hz command stream, as the controller's
            link.command(HandCommand(grasp=0.3))
            sent.append(time.time())
            time.sleep(0.01)
        wait_for(lambda: len(recorder.commands()) >= len(sent), 5.0, "every command recorded")
        commands = recorder.commands()
        first_moving = min(t for t, c in commands if c.grasp > 0)
        # Every zero command after the stream began followed a gap of at least 50 ms since the
        # previous command: a loaded machine may delay the stream, never the logic.
        for t, c in commands:
            if c.grasp == 0.0 and first_moving < t < sent[-1]:
                before = [s for s in sent if s < t]
                assert t - before[-1] >= 0.05 - 0.002
    finally:
        link.stop()
        recorder.close()


@pytest.mark.parametrize("sender", ["loop", "thread"])
def test_link_on_a_loop_reads_the_simulated_hand_and_stops_it(channel: str, sender: str) -> None:
    """The bridge's way: link and simulated hand as callbacks on one asyncio loop, no thread of
    their own. Status comes in through ``poll`` after each tick; the watchdog, a timer on the
    loop, sends zero velocity no sooner than ``watchdog_s`` after the last command, and again
    every period while no command comes. The commands come from the loop, or from another
    thread (the bridge's: Zenoh's, which receives them) without moving the loop's timer."""
    recorder = Recorder(channel)
    statuses: list[HandStatus] = []
    sent: list[float] = []

    async def run() -> tuple[float, int]:
        loop = asyncio.get_running_loop()
        sim = SimulatedHand("lpc", channel=channel, aperture_mm=80.0).start(loop)
        link = HandLink(
            lambda: LpcHand(channel=channel), on_status=statuses.append, watchdog_s=0.05
        ).start(loop)
        sim.on_sent = link.poll
        try:
            while not link.connected:
                await asyncio.sleep(0.005)
            if sender == "loop":
                for _ in range(20):  # 200 ms of closing at 100 Hz
                    sent.append(time.time())  # python-can stamps the frame with time.time() too
                    assert link.command(HandCommand(grasp=0.5))
                    await asyncio.sleep(0.01)
            else:

                def stream() -> None:
                    for _ in range(20):
                        sent.append(time.time())
                        assert link.command(HandCommand(grasp=0.5))
                        time.sleep(0.01)

                await asyncio.to_thread(stream)
            last = sent[-1]
            stops = link.counters["watchdog_stops"]
            while link.counters["watchdog_stops"] < stops + 3:
                await asyncio.sleep(0.01)
            return last, int(sim.state.aperture_mm)
        finally:
            link.stop()
            sim.stop()

    try:
        last, aperture = asyncio.run(run())
        assert len(statuses) >= 10 and statuses[-1].aperture_mm < 80.0
        assert aperture < 80
        # The watchdog's three stops; stop() adds a last zero of its own after them.
        commands = recorder.commands()
        zeros = [t for t, c in commands if c.grasp == 0.0 and t > last - 0.002][:3]
        assert len(zeros) == 3
        # While the stream flowed, a zero only ever followed a 50 ms gap in it.
        for t, c in commands:
            if c.grasp == 0.0 and sent[0] < t < last:
                assert t - max(s for s in sent if s < t) >= 0.05 - 0.002
        assert zeros[0] - last >= 0.05 - 0.002  # never early
        # Repeated every period while silent: a stop frame lost on the bus is sent again.
        assert all(b - a >= 0.05 - 0.002 for a, b in itertools.pairwise(zeros))
        print(f"on a loop: zero velocity {1000 * (zeros[0] - last):.1f} ms after the last command")
    finally:
        recorder.close()


class FlakyHand(LpcHand):
    """A driver whose bus goes away after a few receives (a bus-off, an unplugged adapter)."""

    opened = 0

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        FlakyHand.opened += 1
        self._receives = 0

    def recv(self, timeout: float | None = None) -> HandStatus | None:
        self._receives += 1
        if FlakyHand.opened == 1 and self._receives > 5:
            raise OperationError("bus-off (simulated)")
        return super().recv(timeout)


def test_link_reports_bus_errors_and_reconnects(channel: str) -> None:
    attempts = {"n": 0}
    events: list[tuple[str, str]] = []
    statuses: list[HandStatus] = []

    def opener() -> LpcHand:
        attempts["n"] += 1
        if attempts["n"] <= 2:
            raise DeviceUnavailable("can0 is down (simulated)")
        return FlakyHand(channel=channel)

    FlakyHand.opened = 0
    with SimulatedHand("lpc", channel=channel):
        link = HandLink(opener, statuses.append, lambda lv, text: events.append((lv, text)))
        link.start()
        try:
            wait_for(lambda: FlakyHand.opened >= 2 and len(statuses) > 5, 10.0, "a reconnection")
        finally:
            link.stop()
    texts = [text for _, text in events]
    assert any("cannot open the hand" in t for t in texts)
    assert any("bus-off (simulated)" in t and "reconnecting" in t for t in texts)
    assert any(t == "hand connected again" for t in texts)
    assert link.counters["errors"] >= 3 and link.counters["reconnects"] >= 1


def test_link_rejects_a_bad_watchdog() -> None:
    with pytest.raises(ValueError, match="watchdog_s"):
        HandLink(lambda: LpcHand(), on_status=lambda s: None, watchdog_s=0.0)


# --------------------------------------------------------------------------- over the bus


def _closes_then_stops(states: list, command) -> None:  # type: ignore[no-untyped-def]
    """Fresh grasp commands close the hand by at least 10 mm; once they stop, the bridge's
    watchdog stops it (its aperture settles)."""
    start = states[-1].aperture_mm
    deadline = time.monotonic() + 10.0
    while states[-1].aperture_mm > start - 10.0 and time.monotonic() < deadline:
        command(0.5)
        time.sleep(0.01)
    assert states[-1].aperture_mm <= start - 10.0  # closed by at least 10 mm
    wait_for(
        lambda: len(states) > 20 and abs(states[-1].aperture_mm - states[-10].aperture_mm) < 0.01,
        5.0,
        "the hand to stop",
    )


def test_bridge_service_moves_the_hand_and_stops_it(
    rendezvous: zenoh.Session, endpoint: str
) -> None:
    states: list = []
    sub = rendezvous.declare_subscriber(
        "lpc/prosthesis/state",
        lambda s: states.append(decode("lpc/prosthesis/state", s.payload.to_bytes())),
    )
    process = spawn_service("services.prosthesis_bridge", endpoint, "--sim-hand")
    try:
        wait_for(lambda: len(states) > 10, 20.0, "status from the bridge")
        pub = rendezvous.declare_publisher("lpc/prosthesis/command")
        seq = itertools.count(1)

        def command(grasp: float) -> None:
            pub.put(
                encode(
                    ProsthesisCommand(seq=next(seq), t_ns=time.time_ns(), grasp=grasp, wrist=0.0)
                )
            )

        _closes_then_stops(states, command)
        # A stale command (200 ms old) is dropped, not executed.
        settled = states[-1].aperture_mm
        pub.put(
            encode(
                ProsthesisCommand(
                    seq=next(seq), t_ns=time.time_ns() - 200_000_000, grasp=1.0, wrist=0.0
                )
            )
        )
        n = len(states)
        wait_for(lambda: len(states) > n + 20, 5.0, "more status")
        assert states[-1].aperture_mm == pytest.approx(settled, abs=0.1)  # a 1.0 command: mm
        assert states[-1].hand == "lpc:sim"
    finally:
        process.terminate()
        process.wait(timeout=10)
        sub.undeclare()
    assert process.returncode == 0


def test_bridge_drives_a_simulated_hand_in_another_process_over_a_serial_can_bus(
    rendezvous: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    """The hand as a device apart from the set (``lpc bench footprint --devices outside``):
    ``hand_sim --ports-file`` serves it on python-can's serial bus over a pty, the bridge opens
    the pty as a python-can bus of its own, closes the hand through it and reads its status."""
    ports = tmp_path / "ports"
    hand = spawn_service("services.hand_sim", endpoint, "--ports-file", str(ports))
    bridge = None
    states: list = []
    sub = rendezvous.declare_subscriber(
        "lpc/prosthesis/state",
        lambda s: states.append(decode("lpc/prosthesis/state", s.payload.to_bytes())),
    )
    try:
        wait_for(ports.exists, 20.0, "the simulated hand's port")
        port = dict(line.split(" ", 1) for line in ports.read_text().splitlines())["hand"]
        bridge = spawn_service(
            "services.prosthesis_bridge", endpoint, "--interface", "serial", "--channel", port
        )
        wait_for(lambda: len(states) > 10, 20.0, "status from the hand over the pty")
        pub = rendezvous.declare_publisher("lpc/prosthesis/command")
        seq = itertools.count(1)
        _closes_then_stops(
            states,
            lambda grasp: pub.put(
                encode(
                    ProsthesisCommand(seq=next(seq), t_ns=time.time_ns(), grasp=grasp, wrist=0.0)
                )
            ),
        )
        assert states[-1].hand == "lpc:serial"
    finally:
        sub.undeclare()
        for process in (bridge, hand):
            if process is not None:
                process.terminate()
                process.wait(timeout=10)
    assert bridge is not None and bridge.returncode == 0 and hand.returncode == 0
