"""The errors every driver raises, one short hierarchy (after python-can's ``can/exceptions.py``).

A vendor exception (``serial.SerialException``, ``can.CanError``, ``OSError``) is re-raised as one
of these with ``from``, so a service catches ``DriverError`` and counts it, and the cause stays in
the traceback. A timeout on ``recv`` is not an error: it returns ``None``.

    DriverError
     +-- DeviceUnavailable
     +-- InitialisationError
     +-- OperationError
     +-- DriverTimeout
"""

from __future__ import annotations


class DriverError(Exception):
    """Base class of every driver error. ``code`` is a vendor error code when there is one.

    Example: ``except DriverError as exc: bus.health.counters["driver_errors"] += 1``.
    """

    def __init__(self, message: str = "", code: int | None = None) -> None:
        super().__init__(message)
        self.code = code

    def __str__(self) -> str:
        text = super().__str__()
        return f"{text} [code {self.code}]" if self.code is not None else text


class DeviceUnavailable(DriverError):
    """The device is not there, or cannot be opened.

    Examples: the serial port does not exist (USB adapter unplugged), permission denied on
    ``/dev/ttyUSB0``, the CAN interface ``can0`` is down or missing, a backend name is unknown.
    """


class InitialisationError(DriverError):
    """The device opened but did not come up as expected.

    Examples: no reply to the firmware-version query, the board answers with the wrong
    protocol, setting the bit rate failed.
    """


class OperationError(DriverError):
    """The device failed while in use.

    Examples: a write to the serial port fails with EIO because the adapter was unplugged, the
    controller answers NAK, the CAN controller goes bus-off.
    """


class DriverTimeout(DriverError):
    """A blocking operation other than ``recv`` ran out of time.

    Examples: a write does not drain within its timeout (flow control stuck), a reply that a
    handshake needs never arrives.
    """
