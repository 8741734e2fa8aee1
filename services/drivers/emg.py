"""EMG sources behind one small interface, and the user profile's ``emg`` section.

A source's ``recv(timeout)`` returns the next ``(channels, t_ns)`` — the (flexor, extensor)
envelopes and the time they were read — or ``None`` on timeout; ``shutdown()`` may be called
twice. Sources:

- ``SerialEmg``: an amplifier sending ``lpc_core.devices.emg_protocol`` frames over a serial port
  (pyserial's ``serial_for_url``: ``/dev/ttyUSB0``, or ``loop://`` as the simulated backend);
- ``HandEmg``: the EMG channels a hand reports in its CAN status (``services.drivers.hand``).

The simulated user is not a driver: it reacts to the bus, so ``services.emg`` runs it.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import serial

from lpc_core.control.emg import EmgProfile
from lpc_core.devices.emg_protocol import FrameParser
from services.drivers.errors import DeviceUnavailable, DriverError, OperationError
from services.drivers.hand import open_hand

DEFAULT_PROFILE = Path("~/.config/lpc/profile.json")


class SerialEmg:
    """An EMG amplifier on a serial port."""

    def __init__(
        self, port: str, baudrate: int = 115200, channels: tuple[int, int] = (0, 1)
    ) -> None:
        self.channels = channels
        self.parser = FrameParser()
        self._pending: list[tuple[list[float], int]] = []
        self._closed = False
        try:
            self._serial = serial.serial_for_url(port, baudrate=baudrate, timeout=0)
        except (serial.SerialException, ValueError) as exc:
            raise DeviceUnavailable(f"cannot open EMG amplifier on {port}: {exc}") from exc

    def recv(self, timeout: float | None = None) -> tuple[list[float], int] | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._pending:
            if self._closed:
                raise OperationError("EMG amplifier is shut down")
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return None
            self._serial.timeout = 0.01 if remaining is None else min(remaining, 0.01)
            try:
                data = self._serial.read(max(1, self._serial.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise OperationError(f"EMG amplifier read failed: {exc}") from exc
            now = time.time_ns()
            for frame in self.parser.feed(data):
                if max(self.channels) >= len(frame.channels):
                    continue
                self._pending.append(([frame.channels[i] for i in self.channels], now))
        return self._pending.pop(0)

    def shutdown(self) -> None:
        if not self._closed:
            self._closed = True
            self._serial.close()


class HandEmg:
    """The EMG channels a hand's status frames carry (e.g. a Michelangelo socket, 0-856)."""

    def __init__(self, channels: tuple[int, int] = (0, 1), **hand: Any) -> None:
        self.channels = channels
        self._driver = open_hand(**hand)

    def recv(self, timeout: float | None = None) -> tuple[list[float], int] | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            remaining = None if deadline is None else max(deadline - time.monotonic(), 0.0)
            status = self._driver.recv(timeout=remaining)
            if status is None:
                return None
            if len(status.emg) > max(self.channels):
                return [status.emg[i] for i in self.channels], time.time_ns()
            if remaining == 0.0:
                return None

    def shutdown(self) -> None:
        self._driver.shutdown()


def load_emg_profile(path: str | os.PathLike[str] | None) -> EmgProfile | None:
    """The ``emg`` section of the user profile, or None when there is none.

    An explicit ``path`` that does not exist, unreadable JSON, or a bad section raises
    ``ValueError`` naming the file.
    """
    file = Path(path if path is not None else DEFAULT_PROFILE).expanduser()
    if not file.exists():
        if path is not None:
            raise ValueError(f"profile {file} does not exist")
        return None
    data = _read(file)
    section = data.get("emg")
    if section is None:
        return None
    if not isinstance(section, dict):
        raise ValueError(f"profile {file}: 'emg' must be an object")
    try:
        return EmgProfile.from_dict(section)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"profile {file}: emg: {exc}") from exc


def save_emg_profile(profile: EmgProfile, path: str | os.PathLike[str] | None) -> Path:
    """Write the ``emg`` section, keeping every other section of the file."""
    file = Path(path if path is not None else DEFAULT_PROFILE).expanduser()
    data = _read(file) if file.exists() else {}
    data["emg"] = profile.to_dict()
    file.parent.mkdir(parents=True, exist_ok=True)
    tmp = file.with_suffix(file.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    tmp.replace(file)
    return file


def _read(file: Path) -> dict[str, Any]:
    try:
        data = json.loads(file.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"profile {file} is not readable JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"profile {file} must hold a JSON object")
    return data


__all__ = ["DriverError", "HandEmg", "SerialEmg", "load_emg_profile", "save_emg_profile"]
