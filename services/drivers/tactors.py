"""Tactor drivers: one interface, three backends chosen by name (python-can's shape).

- ``eai``: the EAI tactor controller's serial framing (``tactor_protocol``), 115200 baud.
- ``line``: the documented line protocol for DIY boards (``T a0 a1 a2 a3`` / ``OK``).
- ``sim``: a simulated controller on a pseudo-terminal (``services.drivers.tactor_sim``),
  driven through the real ``eai`` (or ``line``) backend; the default when no port is given.

The constructor opens the port and checks the other end answers (firmware version for EAI,
an ``OK`` to an all-off line for DIY boards). ``send(output, timeout)`` writes one
``TactorOutput``; ``recv(timeout)`` returns the next ``Reply`` or ``None`` on timeout;
``shutdown()`` switches everything off and closes, and may be called twice. Every blocking
call takes a timeout. Errors are ``services.drivers.errors`` classes, raised ``from`` pyserial's.

``TactorLink`` wraps a driver for a service: it drops the driver on an error (after a
best-effort all-off) and reopens it when the port comes back.

User profile (``--profile FILE``, JSON; other sections of the file are ignored)::

    {"tactors": {"gain_min": [0.2, 0.2, 0.25, 0.2], "gain_max": [0.9, 1.0, 1.0, 0.8],
                 "arm": "right", "rotation_deg": 0.0}}
"""

from __future__ import annotations

import collections
import json
import os
import select
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import serial

from lpc_core.devices import tactor_protocol as tp
from lpc_core.devices.tactor_bridge import TactorProfile
from lpc_core.devices.tactor_protocol import OFF, Reply, TactorOutput
from services.drivers.errors import (
    DeviceUnavailable,
    DriverError,
    InitialisationError,
    OperationError,
)
from services.drivers.serial_io import write_all
from services.drivers.tactor_sim import TactorSim

DEFAULT_PROFILE = Path("~/.config/lpc/profile.json")
BAUDRATE = 115200


class TactorDriver:
    """The interface; a backend supplies ``_parser``, ``_encode`` and ``_initialise``."""

    protocol: ClassVar[str] = ""

    def __init__(self, port: str, *, baudrate: int = BAUDRATE, timeout: float = 1.0) -> None:
        self.port = port
        self.errors = collections.Counter[str]()
        self._replies: collections.deque[Reply] = collections.deque()
        self._closed = False
        try:
            self._serial = serial.Serial(port, baudrate=baudrate, timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceUnavailable(f"cannot open tactor port {port}: {exc}") from exc
        try:
            self._serial.reset_input_buffer()
            self._initialise(timeout)
        except BaseException:
            self._closed = True
            self._serial.close()
            raise

    # ------------------------------------------------------------------ backend hooks

    _parser: tp.EaiParser | tp.LineParser

    def _initialise(self, timeout: float) -> None:
        raise NotImplementedError

    def _encode(self, output: TactorOutput) -> bytes:
        raise NotImplementedError

    # ------------------------------------------------------------------ interface

    def send(self, output: TactorOutput, timeout: float | None = 1.0) -> None:
        """Write ``output``; ``DriverTimeout`` if it cannot be written within ``timeout``."""
        self._write(self._encode(output), timeout)

    def all_off(self, timeout: float | None = 1.0) -> None:
        self.send(OFF, timeout)

    def recv(self, timeout: float | None = 0.0) -> Reply | None:
        """The next reply from the controller, or ``None`` after ``timeout`` seconds
        (``None``: wait for ever)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._replies:
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            self._feed(self._read(remaining))
            if not self._replies and remaining is not None and remaining <= 0.0:
                return None
        return self._replies.popleft()

    def shutdown(self) -> None:
        """All off (best effort), then close. Safe to call twice."""
        if self._closed:
            return
        try:
            self.all_off(timeout=0.2)
        except DriverError:
            pass
        finally:
            self._closed = True
            self._serial.close()

    def __enter__(self) -> TactorDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    # ------------------------------------------------------------------ bytes

    def _write(self, data: bytes, timeout: float | None) -> None:
        if self._closed:
            raise OperationError(f"tactor port {self.port} is shut down")
        write_all(self._serial, data, timeout, name=self.port)

    def _read(self, timeout: float | None) -> bytes:
        if self._closed:
            raise OperationError(f"tactor port {self.port} is shut down")
        try:
            ready, _, _ = select.select([self._serial.fileno()], [], [], timeout)
            if not ready:
                return b""
            return self._serial.read(max(1, self._serial.in_waiting))
        except (serial.SerialException, OSError) as exc:
            raise OperationError(f"read from {self.port} failed: {exc}") from exc

    def _feed(self, data: bytes) -> None:
        for event in self._parser.feed(data):
            if isinstance(event, Reply):
                self._replies.append(event)
            else:
                self.errors["garbled replies"] += 1

    def _await_reply(self, timeout: float, accept: Callable[[Reply], bool]) -> Reply | None:
        deadline = time.monotonic() + timeout
        while (remaining := deadline - time.monotonic()) > 0:
            reply = self.recv(remaining)
            if reply is not None and accept(reply):
                return reply
        return None


class EaiDriver(TactorDriver):
    """The EAI controller. Per-tactor levels become a mask and one gain (see the protocol)."""

    protocol = "eai"

    def __init__(self, port: str, *, mask_ratio: float = 0.5, **kwargs: Any) -> None:
        self._parser = tp.EaiParser("host")
        self._mask_ratio = mask_ratio
        self._current: tp.EaiSettings | None = None
        self.firmware = b""
        super().__init__(port, **kwargs)

    def _initialise(self, timeout: float) -> None:
        self._write(tp.firmware_version(), timeout)
        reply = self._await_reply(timeout, lambda r: r.command == tp.Command.FIRMWARE_VERSION)
        if reply is None:
            raise InitialisationError(
                f"no answer to the firmware-version query on {self.port} within {timeout} s; "
                "is an EAI controller attached and powered?"
            )
        self.firmware = reply.data
        self._write(b"".join(tp.eai_initialisation()), timeout)

    def _encode(self, output: TactorOutput) -> bytes:
        target = tp.eai_settings(output, self._mask_ratio)
        frames = tp.eai_update(target, self._current)
        if target is not None:
            self._current = target
        elif self._current is not None:
            self._current = tp.EaiSettings(self._current.gain, 0, self._current.frequency_hz)
        return b"".join(frames)


class LineDriver(TactorDriver):
    """A DIY board speaking the line protocol: four PWM duties per line, ``OK`` back."""

    protocol = "line"

    def __init__(self, port: str, **kwargs: Any) -> None:
        self._parser = tp.LineParser("host")
        super().__init__(port, **kwargs)

    def _initialise(self, timeout: float) -> None:
        self._write(tp.line_command(OFF), timeout)
        reply = self._await_reply(timeout, lambda r: True)
        if reply is None or not reply.ok:
            why = "no answer" if reply is None else f"ERR {reply.text}"
            raise InitialisationError(
                f"{why} to 'T 0 0 0 0' on {self.port} within {timeout} s; "
                "does the board speak the line protocol?"
            )

    def _encode(self, output: TactorOutput) -> bytes:
        return tp.line_command(output)


class _OnSimulator:
    """Mixin: start a ``TactorSim`` speaking ``sim_protocol`` and drive it through the real
    backend; ``sim`` is the controller, for inspection. Shutdown also hangs the sim up."""

    sim_protocol: ClassVar[str]
    sim: TactorSim
    # The last commands, for a look at what the tactors did: the simulator's default (100k,
    # for benches) grew the tactor bridge by 0.46 MB a minute in a 30-minute soak, and would
    # have for about an hour before it was full.
    SIM_HISTORY: ClassVar[int] = 1000

    def __init__(self, port: str | None = None, **kwargs: Any) -> None:
        del port  # the simulator makes its own
        self.sim = TactorSim(self.sim_protocol, history=self.SIM_HISTORY)
        try:
            super().__init__(self.sim.port, **kwargs)  # type: ignore[call-arg]
        except BaseException:
            self.sim.close()
            raise

    def shutdown(self) -> None:
        try:
            super().shutdown()  # type: ignore[misc]
        finally:
            self.sim.close()


class SimDriver(_OnSimulator, EaiDriver):
    """The ``sim`` backend: a simulated EAI controller on a pty."""

    sim_protocol = "eai"


class SimLineDriver(_OnSimulator, LineDriver):
    """A simulated DIY board on a pty (``line`` without a port)."""

    sim_protocol = "line"


BACKENDS: dict[str, Callable[..., TactorDriver]] = {
    "eai": EaiDriver,
    "line": LineDriver,
    "sim": SimDriver,
}


def open_driver(name: str, port: str | None = None, **kwargs: Any) -> TactorDriver:
    """Open the backend called ``name``. Without a port, ``eai`` and ``line`` get a simulated
    controller speaking their protocol."""
    if name not in BACKENDS:
        raise DeviceUnavailable(f"unknown tactor driver {name!r}; known: {', '.join(BACKENDS)}")
    if name == "sim" or port is None:
        return SimLineDriver(**kwargs) if name == "line" else SimDriver(**kwargs)
    return BACKENDS[name](port, **kwargs)


class TactorLink:
    """A driver that comes back. ``write`` never raises: on a serial error it tries all off,
    drops the driver and counts; on a NAK it sends all off and asks for a rewrite;
    ``reopen(now_ns)`` tries again at most every ``retry_ns``."""

    def __init__(self, factory: Callable[[], TactorDriver], retry_ns: int = 500_000_000) -> None:
        self._factory = factory
        self.retry_ns = retry_ns
        self.driver: TactorDriver | None = None
        self.retry_at_ns = 0
        self.counters = collections.Counter[str]()
        self.last_error = ""

    @property
    def up(self) -> bool:
        return self.driver is not None

    def reopen(self, now_ns: int) -> bool:
        """Open the driver if it is down and a retry is due; ``True`` when it just opened."""
        if self.driver is not None or now_ns < self.retry_at_ns:
            return False
        try:
            self.driver = self._factory()
        except DriverError as exc:
            self.retry_at_ns = now_ns + self.retry_ns
            self.counters["open_failures"] += 1
            self.last_error = str(exc)
            return False
        self.counters["opened"] += 1
        return True

    def write(self, output: TactorOutput, timeout: float = 0.05) -> str:
        """Write ``output``: ``"ok"``; ``"reset"`` when the controller refused an earlier
        command (it was sent all off, and what it holds is unknown: write again); ``"down"``
        when the port failed or is closed."""
        if self.driver is None:
            self.counters["dropped_writes"] += 1
            return "down"
        try:
            self.driver.send(output, timeout)
            self.counters["writes"] += 1
            return self._replies(timeout)
        except DriverError as exc:
            return self._lost(exc)

    def poll(self, timeout: float = 0.05) -> str:
        """Take the controller's pending replies, as ``write`` does after a command: a port
        that hung up while nothing was written is noticed here (``"down"``)."""
        if self.driver is None:
            return "down"
        try:
            return self._replies(timeout)
        except DriverError as exc:
            return self._lost(exc)

    def _replies(self, timeout: float) -> str:
        assert self.driver is not None
        refused = False
        while (reply := self.driver.recv(0.0)) is not None:
            self.counters["acks" if reply.ok else "naks"] += 1
            refused |= not reply.ok
        if refused:
            self.last_error = "the controller refused a command"
            self.driver.all_off(timeout)
            return "reset"
        return "ok"

    def _lost(self, exc: DriverError) -> str:
        self.counters["errors"] += 1
        self.last_error = str(exc)
        self.close()
        return "down"

    def close(self) -> None:
        if self.driver is not None:
            driver, self.driver = self.driver, None
            driver.shutdown()  # best-effort all off, then close


def load_profile(path: str | os.PathLike[str] | None) -> dict[str, Any]:
    """The ``tactors`` section of a user profile; ``{}`` when the default file is absent.

    An explicit ``path`` that does not exist, or a file that is not valid JSON, raises
    ``ValueError`` naming it.
    """
    explicit = path is not None
    file = Path(path).expanduser() if explicit else DEFAULT_PROFILE.expanduser()
    if not file.exists():
        if explicit:
            raise ValueError(f"profile {file} does not exist")
        return {}
    try:
        data = json.loads(file.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"profile {file} is not readable JSON: {exc}") from exc
    section = data.get("tactors", {}) if isinstance(data, dict) else None
    if not isinstance(section, dict):
        raise ValueError(f"profile {file}: 'tactors' must be an object")
    return section


def tactor_profile(section: dict[str, Any]) -> TactorProfile:
    """Gain limits from a profile section (``ValueError`` names a bad field)."""
    limits = {}
    for name in ("gain_min", "gain_max"):
        if name in section:
            try:
                limits[name] = tuple(float(x) for x in section[name])
            except (TypeError, ValueError) as exc:
                raise ValueError(f"profile field tactors.{name} must be a list of numbers") from exc
    return TactorProfile(**limits)
