"""A simulated hand on a CAN bus: the other end of the hand driver, for tests and ``lpc up``.

It opens its own python-can bus on the same channel as the driver (python-can's virtual bus
connects buses of one process; socketcan's ``vcan0``, or python-can's serial bus on a pty from
``open_pty_bus``, connects processes), listens for velocity
commands in the ``lpc`` or ``robolimb`` profile, advances ``lpc_core.sim.hand`` in real time and
sends status at 100 Hz. Like real hands it has its own fail-safe: with no command for
``hand_watchdog_s`` it stops and flags it (PSYONIC's hand leaves API mode after 300 ms).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import fcntl
import struct
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import can

from lpc_core.devices import can_protocol as cp
from lpc_core.devices.hand import HandCommand, HandStatus
from lpc_core.sim.hand import HandParams, HandState, hand_step
from services.drivers.errors import DeviceUnavailable
from services.drivers.hand import DEFAULT_CHANNEL, open_can_bus

PERIOD_S = 0.01
_STOP = HandCommand()
# Linux's pty ioctls, which Python's termios does not name: unlock the slave, get its number.
_TIOCSPTLCK = 0x40045431
_TIOCGPTN = 0x80045430


def open_pty_bus() -> tuple[can.BusABC, str]:
    """python-can's serial bus on a new pseudo-terminal's master, and the slave's path: a CAN
    link between processes (this kernel has no vcan), where the driver opens the path with
    ``--interface serial --channel /dev/pts/N``. Both ends read without waiting
    (``open_can_bus``): run the hand with ``start(loop)``. Each frame goes out in one write, so
    a reader never sees half of one."""
    try:
        bus = open_can_bus("serial", "/dev/ptmx")
    except (can.CanError, OSError) as exc:
        raise DeviceUnavailable(f"simulated hand cannot open a pty: {exc}") from exc
    try:
        fd = bus.fileno()
        fcntl.ioctl(fd, _TIOCSPTLCK, struct.pack("i", 0))
        number = struct.unpack("i", fcntl.ioctl(fd, _TIOCGPTN, b"\0" * 4))[0]
    except (can.CanError, OSError) as exc:
        bus.shutdown()
        raise DeviceUnavailable(f"simulated hand cannot open a pty: {exc}") from exc
    return bus, f"/dev/pts/{number}"


def _next_tick(tick: float, now: float) -> float:
    """When the tick after ``tick`` (due, and run at ``now``) is due: a period later, or, when
    that has passed already (a stall: this process descheduled, or throttled by a CPU quota), a
    period after ``now``, without the ticks missed meanwhile. A hand's control cycle does not replay
    the cycles it missed, and the model integrates the real time since its last step anyway: a
    burst of catch-up ticks would only send a burst of status frames at once, of which the
    bridge publishes each and the controller, which keeps the newest status, drops all but one
    (``lpc bench footprint --together --record --cpus 0.5``: ~1000 dropped in 30 s)."""
    tick += PERIOD_S
    return tick if tick > now else now + PERIOD_S


class SimulatedHand:
    """A hand model behind a CAN bus, in a thread. ``start()``/``stop()``; ``stop`` is safe twice.

    ``start(loop)`` runs it as a 100 Hz timer on an asyncio loop instead, with no thread: each
    tick takes the commands that came since the last one, as a hand's firmware takes them in its
    control cycle, then sends status and calls ``on_sent`` (a driver on the same virtual bus,
    which has no file to wait on, reads it then: ``HandLink.poll``).

    ``object_mm`` sets the width of an object between the fingers (``None``: nothing to grip);
    ``emg`` optionally supplies the socket electrodes' raw values for each status.
    """

    def __init__(
        self,
        profile: str = "lpc",
        interface: str = "virtual",
        channel: str = DEFAULT_CHANNEL,
        *,
        params: HandParams | None = None,
        aperture_mm: float = 80.0,
        wrist_deg: float = 0.0,
        object_mm: float | None = None,
        emg: Callable[[], Sequence[float]] | None = None,
        hand_watchdog_s: float = 0.3,
        bus: can.BusABC | None = None,
        **kwargs: Any,
    ) -> None:
        if profile not in ("lpc", "robolimb"):
            raise ValueError(f"profile must be 'lpc' or 'robolimb', got {profile!r}")
        if bus is not None:
            self._bus = bus
        else:
            try:
                self._bus = open_can_bus(interface, channel, receive_own_messages=False, **kwargs)
            except (can.CanError, ImportError, OSError, ValueError) as exc:
                raise DeviceUnavailable(
                    f"simulated hand cannot open {interface}:{channel}: {exc}"
                ) from exc
        self.profile = profile
        self.object_mm = object_mm
        self.emg = emg
        self.hand_watchdog_s = hand_watchdog_s
        self._state = HandState(
            params=params or HandParams(), aperture_mm=aperture_mm, wrist_deg=wrist_deg
        )
        self._command = HandCommand()
        self._digits: dict[int, tuple[int, int]] = {}  # robolimb: digit -> (action, velocity)
        self._last_command = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-hand", daemon=True)
        self._timer: asyncio.TimerHandle | None = None
        self.on_sent: Callable[[], None] | None = None
        self.commands_received = 0
        self.frames_rejected = 0
        self.status_sent = 0
        self.silenced = False  # tests: stop sending status (a hand that went quiet)

    # ------------------------------------------------------------------ control

    def start(self, loop: asyncio.AbstractEventLoop | None = None) -> SimulatedHand:
        if loop is None:
            self._thread.start()
        else:
            self._timer = loop.call_soon(self._on_timer, loop, loop.time())
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._timer is not None:
            self._timer.cancel()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        with contextlib.suppress(can.CanError, OSError):
            self._bus.shutdown()

    def __enter__(self) -> SimulatedHand:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def state(self) -> HandState:
        with self._lock:
            return self._state

    @property
    def command(self) -> HandCommand:
        with self._lock:
            return self._command

    # ------------------------------------------------------------------ loop

    def _run(self) -> None:
        next_tick = time.monotonic()
        while not self._stop.is_set():
            timeout = max(next_tick - time.monotonic(), 0.0)
            try:
                message = self._bus.recv(timeout=timeout)
            except (can.CanError, OSError):
                if self._stop.wait(0.05):
                    return
                continue
            if message is not None:
                self._receive(message)
                continue
            next_tick = _next_tick(next_tick, time.monotonic())
            self._tick()

    def _on_timer(self, loop: asyncio.AbstractEventLoop, next_tick: float) -> None:
        if self._stop.is_set():
            return
        try:
            while (message := self._bus.recv(timeout=0.0)) is not None:
                self._receive(message)
        except (can.CanError, OSError):
            pass  # the bus is gone; status cannot go out either: keep ticking, as the thread
        self._tick()
        if self.on_sent is not None:
            self.on_sent()
        next_tick = _next_tick(next_tick, loop.time())
        self._timer = loop.call_at(next_tick, self._on_timer, loop, next_tick)

    def _receive(self, message: can.Message) -> None:
        if message.is_error_frame or message.is_extended_id:
            return
        frame = cp.Frame(message.arbitration_id, bytes(message.data))
        try:
            if self.profile == "lpc":
                if frame.arbitration_id != cp.COMMAND_ID:
                    return
                command, _ = cp.decode_command(frame)
            else:
                if not 0x101 <= frame.arbitration_id <= 0x106:
                    return
                digit, action, velocity = cp.decode_robolimb_digit(frame)
                self._digits[digit] = (action, velocity)
                command = self._robolimb_command()
        except cp.FrameError:
            self.frames_rejected += 1
            return
        with self._lock:
            self._command = command
            self._last_command = time.monotonic()
            self.commands_received += 1

    def _robolimb_command(self) -> HandCommand:
        # The model has one grasp axis: the fingers' mean signed speed drives it.
        lo, hi = cp.ROBOLIMB_VELOCITY
        speeds = []
        for digit in cp.ROBOLIMB_FINGERS:
            action, velocity = self._digits.get(digit, (cp.STOP, lo))
            sign = {cp.STOP: 0.0, cp.CLOSE: 1.0, cp.OPEN: -1.0}[action]
            speeds.append(sign * (velocity - lo) / (hi - lo))
        return HandCommand(grasp=max(-1.0, min(1.0, sum(speeds) / len(speeds))))

    def _tick(self) -> None:
        now = time.monotonic()
        with self._lock:
            stale = now - self._last_command > self.hand_watchdog_s
            command = _STOP if stale else self._command
            state = self._state
            if state.object_mm != self.object_mm:  # a copy a tick costs more than the compare
                state = dataclasses.replace(state, object_mm=self.object_mm)
            state, status = hand_step(state, command, time.monotonic_ns())
            self._state = state
        if self.silenced:
            return
        if self.emg is not None:
            status = dataclasses.replace(status, emg=tuple(self.emg()))
        if stale:
            status = dataclasses.replace(status, watchdog=True)
        for frame in self._frames(status, command):
            with contextlib.suppress(can.CanError, OSError):
                self._bus.send(
                    can.Message(
                        arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=False
                    ),
                    timeout=0.005,
                )
        self.status_sent += 1

    def _frames(self, status: HandStatus, command: HandCommand) -> list[cp.Frame]:
        if self.profile == "lpc":
            return cp.encode_status(status)
        p = self._state.params
        frames = []
        for digit in (*cp.ROBOLIMB_FINGERS[::-1],):  # little .. thumb: the thumb closes a cycle
            if status.grip_force_pct > 0:
                code, current = 3, status.grip_force_pct / 100.0 * 1.2
            elif status.aperture_mm >= p.aperture_max_mm and command.grasp <= 0:
                code, current = 4, 0.0
            elif command.grasp > 0.02:
                code, current = 1, 0.2
            elif command.grasp < -0.02:
                code, current = 2, 0.2
            else:
                code, current = 0, 0.0
            frames.append(cp.encode_robolimb_feedback(digit, code, current))
        return frames
