"""A simulated tactor controller on a pseudo-terminal.

``TactorSim()`` opens a pty pair (``os.openpty``) and answers on the controller's end, in a
thread, like the EAI controller (``protocol="eai"``) or a DIY board (``protocol="line"``): it
parses frames, keeps the tactors' state, ACKs or NAKs, and records every command with the
time its bytes arrived. A driver opens ``sim.port`` (``/dev/pts/N``) as it would a real
serial port, so tests, ``lpc up`` without hardware and ``lpc bench latency`` exercise the real
byte path. ``close()`` hangs the line up, as unplugging the adapter would.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from lpc_core.devices import tactor_protocol as tp
from lpc_core.devices.tactor_protocol import N_TACTORS, Command, EaiCommand, FrameError, NakCode
from services.drivers.pty_device import PtyDevice

# Data length each EAI command must carry (firmware version and all off carry none).
_EAI_LENGTHS = {
    Command.ALL_OFF: 0,
    Command.ON_TIME: 2,
    Command.SINE_FREQUENCY_1: 2,
    Command.SINE_FREQUENCY_2: 2,
    Command.SIGNAL_SOURCE: 1,
    Command.GAIN: 1,
    Command.FIRMWARE_VERSION: 0,
    Command.SET_TACTORS: 1,
}


@dataclass(frozen=True)
class SimEvent:
    """One command as the controller saw it, and the tactor state right after it.

    ``levels`` are the tactors' drive levels 0..1 (EAI: gain / 3 on the active mask).
    """

    arrival_ns: int
    command: int | str
    ok: bool
    mask: int
    levels: tuple[float, ...]


class TactorSim(PtyDevice):
    """The controller end of a pty; see the module docstring."""

    def __init__(
        self,
        protocol: str = "eai",
        *,
        clock: Callable[[], int] = time.time_ns,
        firmware: bytes = b"\x01\x00",
        history: int = 100_000,
    ) -> None:
        if protocol not in ("eai", "line"):
            raise ValueError(f"protocol must be 'eai' or 'line', got {protocol!r}")
        self.protocol = protocol
        self.firmware = firmware
        self._clock = clock
        self._open_pty("tactor-sim")
        self._parser: tp.EaiParser | tp.LineParser = (
            tp.EaiParser("controller") if protocol == "eai" else tp.LineParser("controller")
        )
        self.mask = 0
        self.gain = 0
        self.frequency_hz = 0
        self.source = 0
        self.duties: tuple[int, ...] = (0,) * N_TACTORS
        self.nak_next = 0  # tests: answer the next N frames with NAK (invalid data)
        self.events: collections.deque[SimEvent] = collections.deque(maxlen=history)
        self.bytes_received = 0
        self._cond = threading.Condition()
        self._start()

    # ------------------------------------------------------------------ observation

    @property
    def levels(self) -> tuple[float, ...]:
        if self.protocol == "line":
            return tuple(d / 255 for d in self.duties)
        return tuple(self.gain / 3 if self.mask >> k & 1 else 0.0 for k in range(N_TACTORS))

    def wait_for(self, predicate: Callable[[TactorSim], bool], timeout: float) -> bool:
        """Wait until ``predicate(self)`` holds, re-checked after each command; ``False`` on
        timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: predicate(self), timeout)

    # ------------------------------------------------------------------ controller

    def _received(self, data: bytes, arrival_ns: int) -> None:
        with self._cond:
            self.bytes_received += len(data)
            for event in self._parser.feed(data):
                self._send(self._apply(event, arrival_ns))
            self._cond.notify_all()

    def _record(self, arrival: int, command: int | str, ok: bool) -> None:
        self.events.append(SimEvent(arrival, command, ok, self.mask, self.levels))

    def _apply(self, event: EaiCommand | FrameError | tp.Reply | bytes, arrival: int) -> bytes:
        if isinstance(event, bytes):
            return self._apply_line(event, arrival)
        if isinstance(event, FrameError):
            self._record(arrival, "frame error", False)
            return tp.nak_frame(event.code)
        assert isinstance(event, EaiCommand)
        command, data = event.command, event.data
        if command not in _EAI_LENGTHS:
            self._record(arrival, command, False)
            return tp.nak_frame(NakCode.INVALID_COMMAND)
        if len(data) != _EAI_LENGTHS[Command(command)] or self.nak_next > 0:
            self.nak_next = max(0, self.nak_next - 1)
            self._record(arrival, command, False)
            return tp.nak_frame(NakCode.INVALID_DATA)
        extra = b""
        if command == Command.ALL_OFF:
            self.mask = 0
        elif command == Command.SET_TACTORS:
            self.mask = data[0] & ((1 << N_TACTORS) - 1)
        elif command == Command.GAIN:
            self.gain = data[0] >> 6
        elif command == Command.SINE_FREQUENCY_1:
            self.frequency_hz = int.from_bytes(data, "little")
        elif command == Command.SIGNAL_SOURCE:
            self.source = data[0] & 0x0F
        elif command == Command.FIRMWARE_VERSION:
            extra = self.firmware
        self._record(arrival, command, True)
        return tp.ack_frame(command, extra)

    def _apply_line(self, line: bytes, arrival: int) -> bytes:
        parsed = tp.parse_line_command(line)
        if isinstance(parsed, str) or self.nak_next > 0:
            self.nak_next = max(0, self.nak_next - 1)
            self._record(arrival, line.decode("ascii", "replace"), False)
            return f"ERR {parsed if isinstance(parsed, str) else 'refused'}\n".encode()
        self.duties = parsed
        self.mask = sum(1 << k for k, d in enumerate(parsed) if d > 0)
        self._record(arrival, "T", True)
        return b"OK\n"
