"""Hand drivers over python-can, one per frame profile, and the bridge's watchdog loop.

A driver opens a python-can bus (``interface="virtual"`` by default: no hardware needed;
``"socketcan"`` with ``channel="can0"`` or ``"vcan0"`` on Linux), sends velocity commands and
receives status. Profiles (``BACKENDS``):

- ``"lpc"``: lpc's own layout (``lpc_core.devices.can_protocol``), velocity for grasp and wrist,
  status with wrist angle, aperture, grip force and EMG;
- ``"robolimb"``: the Touch Bionics RoboLimb's digit commands; it has no wrist and reports only
  each digit's status and current, so the driver estimates the aperture from the commanded
  velocities and the stall reports, and the grip force from the finger currents.

``HandLink`` is the one place where timing lives: it receives status, sends zero velocity when
no fresh command has arrived for ``watchdog_s`` (50 ms), reports bus errors and reopens the
driver after a failure, with backoff; in a thread of its own, or as callbacks on an asyncio loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import queue
import threading
import time
from collections.abc import Callable
from typing import Any, ClassVar

import can
import can.interfaces.virtual

from lpc_core.devices import can_protocol as cp
from lpc_core.devices.hand import HandCommand, HandStatus
from services.drivers.errors import (
    DeviceUnavailable,
    DriverError,
    DriverTimeout,
    InitialisationError,
    OperationError,
)

DEFAULT_CHANNEL = "lpc-hand"
DEFAULT_BITRATE = 1_000_000


class VirtualBus(can.interfaces.virtual.VirtualBus):
    """python-can's in-process virtual bus (its channels: a python-can ``virtual`` bus of the
    same channel, as tests open, sees the same frames) without the cost the simulated hand
    does not need: python-can deep-copies a frame for each receiver and reads through the
    generic receive loop; this bus hands over the sent message itself (the driver and the
    simulated hand build one per send and never touch it again; every receiver gets the same
    stamps it would on a copy), and a read without waiting is one queue pop. py-spy on the
    bridge: the deep copies alone were 5 % of its main thread's samples."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        if not self.preserve_timestamps:
            msg.timestamp = time.time()
        msg.channel = self.channel_id
        msg.is_rx = True
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            try:
                bus_queue.put(msg, block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if timeout != 0 or self._filters:
            return super().recv(timeout)
        self._check_if_open()
        if not self.queue.queue:  # empty (a frame put meanwhile is read next time): no raise
            return None
        try:
            return self.queue.get_nowait()
        except queue.Empty:
            return None


def open_can_bus(interface: str, channel: str, **kwargs: Any) -> can.BusABC:
    """A python-can bus; the virtual one is ``VirtualBus``. python-can's serial bus (a CAN
    link over a serial line, e.g. to ``hand_sim --ports-file``) ignores ``recv``'s timeout and waits
    the port's: it gets a port that never waits, for readers that wait on its file instead
    (``HandLink.start(loop)``)."""
    if interface == "virtual":
        return VirtualBus(channel=channel, **kwargs)
    if interface == "serial":
        kwargs.setdefault("timeout", 0.0)
    return can.Bus(interface=interface, channel=channel, **kwargs)


def serial_port_url(path: str) -> str:
    """The pyserial URL a driver's python-can serial bus opens for a terminal it reads
    without waiting (a serial device, a pty's slave): on POSIX pyserial's ``VTIMESerial``
    (``alt://PATH?class=VTIMESerial``, pyserial's own handler), which reads with one ``read``
    where its default port selects first. python-can reads a frame in six reads (start, stamp,
    length, id, data, end): twelve system calls a frame, six with it; each releases the GIL,
    which the bridge's loop then waits to take back behind the thread that forwards the
    commands. With no timeout (VMIN and VTIME 0) both return what the line holds at once. Not
    for a pty's master (``open_pty_bus``), whose reads no VMIN/VTIME governs: they would wait.
    A URL, or a platform without it, is left as it is."""
    import serial  # python-can's serial bus imports it anyway; a virtual bus need not

    if "://" in path or not hasattr(serial, "VTIMESerial"):
        return path
    return f"alt://{path}?class=VTIMESerial"


class HandDriver:
    """Base class: opening, sending frames, receiving with timeout and filtering, shutdown.

    A profile overrides ``_encode`` (command -> frames) and ``_decode`` (one frame -> a status
    or ``None`` while a cycle is incomplete), and declares the identifiers it receives,
    ``_ids``. The filtering is done here rather than in the CAN controller so that error
    frames still reach ``recv``, which counts them.
    """

    profile: ClassVar[str] = ""
    _ids: ClassVar[frozenset[int]] = frozenset()

    def __init__(
        self,
        interface: str = "virtual",
        channel: str = DEFAULT_CHANNEL,
        bitrate: int = DEFAULT_BITRATE,
        **kwargs: Any,
    ) -> None:
        self.interface = interface
        self.channel = channel
        self.error_frames = 0
        self.last_error = ""
        self._closed = False
        config = {"bitrate": bitrate} if interface not in ("virtual", "socketcan") else {}
        if interface == "serial" and "timeout" not in kwargs:  # read without waiting
            channel = serial_port_url(channel)
        try:
            self._bus = open_can_bus(
                interface, channel, receive_own_messages=False, **config, **kwargs
            )
        except (can.CanInterfaceNotImplementedError, ImportError) as exc:
            raise DeviceUnavailable(f"CAN interface {interface!r} is not available: {exc}") from exc
        except can.CanInitializationError as exc:
            raise InitialisationError(f"cannot open {interface}:{self.channel}: {exc}") from exc
        except (OSError, ValueError) as exc:
            raise DeviceUnavailable(f"cannot open {interface}:{self.channel}: {exc}") from exc

    # ------------------------------------------------------------------ interface

    def send(self, command: HandCommand, timeout: float | None = 0.01) -> None:
        """Send one velocity command (one or more frames)."""
        for frame in self._encode(command):
            self.send_frame(frame, timeout)

    def send_frame(self, frame: cp.Frame, timeout: float | None = 0.01) -> None:
        if self._closed:
            raise OperationError("driver is shut down")
        message = can.Message(
            arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=False
        )
        try:
            self._bus.send(message, timeout=timeout)
        except can.CanTimeoutError as exc:
            raise DriverTimeout(f"send of {frame.arbitration_id:#x} timed out: {exc}") from exc
        except (can.CanError, OSError) as exc:
            raise OperationError(f"send of {frame.arbitration_id:#x} failed: {exc}") from exc

    def recv(self, timeout: float | None = None) -> HandStatus | None:
        """The next complete status, or ``None`` when ``timeout`` passes first."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            remaining = None if deadline is None else max(deadline - time.monotonic(), 0.0)
            if self._closed:
                raise OperationError("driver is shut down")
            try:
                message = self._bus.recv(timeout=remaining)
            except (can.CanError, OSError) as exc:
                raise OperationError(f"receive failed: {exc}") from exc
            if message is None:
                return None
            if message.is_error_frame:
                self.error_frames += 1
                self.last_error = f"error frame id {message.arbitration_id:#x}"
                continue
            if (
                message.is_extended_id
                or message.is_remote_frame
                or message.arbitration_id not in self._ids
            ):
                continue
            try:
                status = self._decode(cp.Frame(message.arbitration_id, bytes(message.data)))
            except (cp.FrameError, ValueError) as exc:
                self.last_error = str(exc)
                continue
            if status is not None:
                return status
            # A poll (timeout 0, the loop's reader) reads on through the frames the bus holds
            # (a cycle's EMG frames, then its status): returning here after the first one
            # ran the loop's reader again for the rest, a second pass a cycle.
            if timeout != 0 and deadline is not None and time.monotonic() >= deadline:
                return None

    def fileno(self) -> int | None:
        """The bus's file descriptor to wait on (socketcan), or ``None`` (the virtual bus)."""
        try:
            fd = self._bus.fileno()
        except (NotImplementedError, AttributeError, OSError):
            return None
        return fd if fd >= 0 else None

    @property
    def state(self) -> str:
        """python-can's bus state: ACTIVE, PASSIVE or ERROR (bus-off), where known."""
        try:
            return self._bus.state.name
        except (NotImplementedError, AttributeError):
            return "UNKNOWN"

    def shutdown(self) -> None:
        if not self._closed:
            self._closed = True
            with contextlib.suppress(can.CanError, OSError):
                self._bus.shutdown()

    def __enter__(self) -> HandDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    # ------------------------------------------------------------------ profile

    def _encode(self, command: HandCommand) -> list[cp.Frame]:
        raise NotImplementedError

    def _decode(self, frame: cp.Frame) -> HandStatus | None:
        raise NotImplementedError


class LpcHand(HandDriver):
    """lpc's layout: one COMMAND frame; STATUS (preceded by its EMG frames) per cycle."""

    profile = "lpc"
    _ids = frozenset({cp.STATUS_ID, *cp.EMG_IDS})

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._counter = 0
        self._emg: dict[int, tuple[int, ...]] = {}

    def _encode(self, command: HandCommand) -> list[cp.Frame]:
        self._counter = (self._counter + 1) & 0xFF
        return [cp.encode_command(command, self._counter)]

    def _decode(self, frame: cp.Frame) -> HandStatus | None:
        if frame.arbitration_id in cp.EMG_IDS:
            first, values = cp.decode_emg(frame)
            self._emg[first] = values
            return None
        if frame.arbitration_id != cp.STATUS_ID:
            return None
        status = cp.decode_status(frame)
        if self._emg:
            emg = tuple(float(v) for k in sorted(self._emg) for v in self._emg[k])
            self._emg = {}
            status = dataclasses.replace(status, emg=emg)
        return status


class RoboLimbHand(HandDriver):
    """The Touch Bionics RoboLimb: five digit commands per grasp command, no wrist."""

    profile = "robolimb"
    _ids = frozenset(cp.ROBOLIMB_FEEDBACK_BASE + d for d in range(1, 7))
    full_speed_mm_s = 120.0  # aperture speed at velocity 297 (to be measured on a real hand)
    aperture_range_mm = (0.0, 110.0)
    full_current_a = 1.2  # finger current counted as 100 % grip

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.wrist_ignored = 0
        self._aperture = self.aperture_range_mm[1]
        self._speed = 0.0
        self._since = time.monotonic()
        self._status: dict[int, int] = {}
        self._current: dict[int, float] = {}
        self._counter = 0

    def _advance(self) -> None:
        now = time.monotonic()
        lo, hi = self.aperture_range_mm
        closed_stall = any(s == 3 for s in self._status.values())
        if not (closed_stall and self._speed > 0):
            self._aperture -= self._speed * self.full_speed_mm_s * (now - self._since)
        self._aperture = min(max(self._aperture, lo), hi)
        self._since = now

    def _encode(self, command: HandCommand) -> list[cp.Frame]:
        if command.wrist != 0.0:
            self.wrist_ignored += 1
        self._advance()
        self._speed = command.grasp if abs(command.grasp) >= 0.02 else 0.0
        return cp.encode_robolimb_grasp(command)

    def _decode(self, frame: cp.Frame) -> HandStatus | None:
        digit, status, current = cp.decode_robolimb_feedback(frame)
        self._status[digit], self._current[digit] = status, current
        if digit != 1:  # the thumb's report closes a cycle
            return None
        self._advance()
        fingers = [self._status.get(d, 0) for d in cp.ROBOLIMB_FINGERS]
        if all(s == 4 for s in fingers):
            self._aperture = self.aperture_range_mm[1]  # stalled open: fully open
        currents = [self._current.get(d, 0.0) for d in cp.ROBOLIMB_FINGERS]
        force = 0.0
        if any(s == 3 for s in fingers):
            force = min(100.0, 100.0 * max(currents) / self.full_current_a)
        self._counter = (self._counter + 1) & 0xFF
        return HandStatus(
            wrist_angle_deg=0.0,
            aperture_mm=self._aperture,
            grip_force_pct=force,
            moving=any(s in (1, 2) for s in fingers),
            counter=self._counter,
        )


BACKENDS: dict[str, type[HandDriver]] = {"lpc": LpcHand, "robolimb": RoboLimbHand}


def open_hand(profile: str = "lpc", **kwargs: Any) -> HandDriver:
    """A driver for ``profile`` (see ``BACKENDS``); ``DeviceUnavailable`` for an unknown one."""
    try:
        cls = BACKENDS[profile]
    except KeyError:
        raise DeviceUnavailable(
            f"unknown hand profile {profile!r}; known: {', '.join(BACKENDS)}"
        ) from None
    return cls(**kwargs)


# --------------------------------------------------------------------------- the link


class HandLink:
    """A driver kept alive: status in, commands out, watchdog, reconnection.

    ``start()`` runs it in a thread of its own; ``start(loop)`` runs it as callbacks on an
    asyncio loop that already wakes for the commands, with no thread: the watchdog is a timer
    on that loop, status is read when the bus's file is readable (socketcan) or when
    ``poll()`` is called (the virtual bus: by the simulated hand on the same loop, after it
    sends), and only opening the driver goes to a worker thread. ``command()`` may be called
    from any thread, and sends at once. On a loop, a command from the loop's thread moves the
    watchdog's timer to its new deadline; one from another thread (Zenoh's, which receives it)
    leaves the timer be: the next status read (``poll``) moves it, or the timer, when it fires,
    finds the fresh command and moves itself; no wake-up of the loop per command. When the
    newest command is older than ``watchdog_s`` the link sends zero velocity, again every
    ``watchdog_s`` while no fresh command comes. A driver error is reported
    (``on_event(level, text)``), the driver is shut down and reopened after a backoff that
    doubles up to ``max_backoff_s``.
    """

    def __init__(
        self,
        open_driver: Callable[[], HandDriver],
        on_status: Callable[[HandStatus], None],
        on_event: Callable[[str, str], None] = lambda level, text: None,
        *,
        watchdog_s: float = 0.05,
        max_backoff_s: float = 2.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not watchdog_s > 0:
            raise ValueError(f"watchdog_s must be positive, got {watchdog_s}")
        self._open = open_driver
        self._on_status = on_status
        self._on_event = on_event
        self.watchdog_s = watchdog_s
        self.max_backoff_s = max_backoff_s
        self._clock = clock
        self._lock = threading.Lock()
        self._driver: HandDriver | None = None
        self._last_command = -float("inf")
        self._last_zero = -float("inf")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hand-link", daemon=True)
        # On a loop: the task that (re)connects, the watchdog's timer, the file read from.
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: int | None = None
        self._connecting: asyncio.Task[None] | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._armed_after = -float("inf")  # the newest command when the timer was set
        self._reader: int | None = None
        self.counters: dict[str, int] = {
            "commands": 0,
            "watchdog_stops": 0,
            "status": 0,
            "errors": 0,
            "reconnects": 0,
        }

    def start(self, loop: asyncio.AbstractEventLoop | None = None) -> HandLink:
        if loop is None:
            self._thread.start()
        else:
            self._loop = loop
            self._loop_thread = threading.get_ident()  # start(loop) is called on the loop
            self._connecting = loop.create_task(self._reconnect(first=True))
        return self

    def command(self, command: HandCommand) -> bool:
        """Send a fresh command now; False when the hand is not connected (it is counted)."""
        with self._lock:
            self._last_command = self._clock()
            driver = self._driver
            if driver is None:
                self.counters["dropped_disconnected"] = (
                    self.counters.get("dropped_disconnected", 0) + 1
                )
                return False
            try:
                driver.send(command, timeout=0.005)
            except DriverError as exc:
                self._fail(exc)
                return False
            self.counters["commands"] += 1
        if self._loop is not None and threading.get_ident() == self._loop_thread:
            self._arm()
        return True

    @property
    def connected(self) -> bool:
        return self._driver is not None

    def stop(self) -> None:
        """Send a last zero command, stop the thread (or the loop's callbacks), shut the driver
        down. Safe twice."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        if self._connecting is not None:
            self._connecting.cancel()
        if self._timer is not None:
            self._timer.cancel()
        with self._lock:
            self._unwatch()
            if self._driver is not None:
                with contextlib.suppress(DriverError):
                    self._driver.send(HandCommand(), timeout=0.01)
                self._driver.shutdown()
                self._driver = None

    def _fail(self, exc: DriverError) -> None:
        # Called with the lock held.
        self.counters["errors"] += 1
        self._on_event("error", f"hand bus error: {type(exc).__name__}: {exc}; reconnecting")
        off_loop = self._loop is not None and threading.get_ident() != self._loop_thread
        if not off_loop:
            self._unwatch()
        if self._driver is not None:
            self._driver.shutdown()
        self._driver = None
        if off_loop:  # a command sent from another thread failed: the loop's part on the loop
            with contextlib.suppress(RuntimeError):  # the loop may be closed
                self._loop.call_soon_threadsafe(self._restart)  # type: ignore[union-attr]
        elif self._loop is not None and not self._stop.is_set():
            self._connecting = self._loop.create_task(self._reconnect(first=False))

    def _restart(self) -> None:
        # On the loop, after a failure on another thread: stop reading the old driver's file
        # (unless a new one is read already), reconnect.
        with self._lock:
            if self._driver is not None or self._stop.is_set():
                return
            self._unwatch()
        self._connecting = self._loop.create_task(  # type: ignore[union-attr]
            self._reconnect(first=False)
        )

    def _connect(self) -> bool:
        try:
            driver = self._open()
        except DriverError as exc:
            self.counters["errors"] += 1
            self._on_event("warning", f"cannot open the hand: {exc}")
            return False
        with self._lock:
            if self._stop.is_set():  # stopped while opening: nobody would shut it down
                driver.shutdown()
                return False
            self._driver = driver
        return True

    # ------------------------------------------------------------------ on a loop

    async def _reconnect(self, first: bool) -> None:
        backoff = 0.05
        while True:
            if not first:
                self.counters["reconnects"] += 1
            # Opening may wait on the device (a serial hand's answer): not on the loop.
            if await asyncio.to_thread(self._connect):
                break
            await asyncio.sleep(backoff)
            backoff = min(backoff * 2, self.max_backoff_s)
        self._on_event("info", "hand connected" + ("" if first else " again"))
        driver = self._driver
        fd = driver.fileno() if driver is not None and hasattr(driver, "fileno") else None
        if fd is not None:
            self._reader = fd
            self._loop.add_reader(fd, self.poll)  # type: ignore[union-attr]
        self._on_watchdog()  # a fresh connection starts from a stopped hand

    def poll(self) -> None:
        """On a loop: take every status the bus holds now, without waiting."""
        driver = self._driver
        if driver is None:
            return
        while True:
            try:
                status = driver.recv(timeout=0.0)
            except DriverError as exc:
                with self._lock:
                    if self._driver is driver:
                        self._fail(exc)
                return
            if status is None:
                break
            self._received(driver, status)
        if self._timer is not None and self._last_command > self._armed_after:
            # Commands came from another thread since the timer was set: move it now, while
            # the loop is awake for the status, rather than wake it when the old deadline
            # passes (25 times a second at 100 Hz of commands and a 40 ms watchdog).
            self._arm()

    def _arm(self) -> None:
        # One timer, moved to the new deadline by each command: a stream of fresh commands
        # never wakes the loop for the watchdog.
        if self._timer is not None:
            self._timer.cancel()
        self._armed_after = self._last_command
        due = max(self._last_command, self._last_zero) + self.watchdog_s
        self._timer = self._loop.call_later(  # type: ignore[union-attr]
            max(due - self._clock(), 0.0), self._on_watchdog
        )

    def _on_watchdog(self) -> None:
        self._timer = None
        self._watchdog()
        if self._driver is not None:
            self._arm()

    def _unwatch(self) -> None:
        if self._reader is not None and self._loop is not None:
            with contextlib.suppress(RuntimeError, ValueError):  # the loop may be closed
                self._loop.remove_reader(self._reader)
        self._reader = None

    # ------------------------------------------------------------------ in a thread

    def _received(self, driver: HandDriver, status: HandStatus) -> None:
        self.counters["status"] += 1
        health = getattr(driver, "health", None)
        if health is not None:  # a driver that counts bad frames of its own
            self.counters.update(health())
        self._on_status(status)

    def _run(self) -> None:
        backoff = 0.05
        first = True
        while not self._stop.is_set():
            if self._driver is None:
                if not first:
                    self.counters["reconnects"] += 1
                if not self._connect():
                    self._stop.wait(backoff)
                    backoff = min(backoff * 2, self.max_backoff_s)
                    continue
                self._on_event("info", "hand connected" + ("" if first else " again"))
                first, backoff = False, 0.05
                self._watchdog()  # a fresh connection starts from a stopped hand
            driver = self._driver
            if driver is None:
                continue
            now = self._clock()
            due = max(self._last_command, self._last_zero) + self.watchdog_s
            try:
                status = driver.recv(timeout=min(max(due - now, 0.0), 0.01))
            except DriverError as exc:
                with self._lock:
                    if self._driver is driver:
                        self._fail(exc)
                continue
            if status is not None:
                self._received(driver, status)
            self._watchdog()

    def _watchdog(self) -> None:
        with self._lock:
            driver = self._driver
            now = self._clock()
            if driver is None or now - self._last_command < self.watchdog_s:
                return
            if now - self._last_zero < self.watchdog_s:
                return
            try:
                driver.send(HandCommand(), timeout=0.005)
            except DriverError as exc:
                self._fail(exc)
                return
            self._last_zero = now
            self.counters["watchdog_stops"] += 1
