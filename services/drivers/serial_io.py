"""Writing to a serial port opened by pyserial, for the drivers that speak to one.

pyserial's own write timeout is not used: it checks the clock after a write that succeeded,
so a thread descheduled past the timeout on a loaded machine fails a write whose bytes are
already in the kernel's buffer (seen on the tactor and Ability Hand ports under CI load).
"""

from __future__ import annotations

import os
import select

import serial

from services.drivers.errors import DriverTimeout, OperationError


def write_all(port: serial.Serial, data: bytes, timeout: float | None, *, name: str) -> None:
    """Write all of ``data``; ``DriverTimeout`` only when the port stays unwritable for
    ``timeout`` seconds (None: wait as long as it takes), ``OperationError`` when it fails.

    pyserial opens its ports non-blocking, so a full buffer shows as ``BlockingIOError``.
    """
    view = memoryview(data)
    try:
        fd = port.fileno()
        while view:
            try:
                view = view[os.write(fd, view) :]
                continue
            except BlockingIOError:
                pass
            _, ready, _ = select.select([], [fd], [], timeout)
            if not ready:
                raise DriverTimeout(f"write to {name} blocked for {timeout} s")
    except (serial.SerialException, OSError, TypeError, ValueError) as exc:
        # TypeError, ValueError: the port was closed by another thread meanwhile.
        raise OperationError(f"write to {name} failed: {exc}") from exc
