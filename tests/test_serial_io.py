"""write_all on a real pseudo-terminal pair: all bytes out, a full port times out, a closed
port is an OperationError."""

from __future__ import annotations

import os
import pty
import time

import pytest
import serial

from services.drivers.errors import DriverTimeout, OperationError
from services.drivers.serial_io import write_all


@pytest.fixture
def port() -> tuple[serial.Serial, int]:
    controller, device = pty.openpty()
    tty = serial.Serial(os.ttyname(device), timeout=0)
    os.close(device)
    yield tty, controller
    tty.close()
    os.close(controller)


def read_exactly(fd: int, n: int) -> bytes:
    got = b""
    while len(got) < n:
        got += os.read(fd, n - len(got))
    return got


def test_every_byte_arrives_in_order(port: tuple[serial.Serial, int]) -> None:
    tty, controller = port
    data = bytes(range(256)) * 4
    write_all(tty, data, 1.0, name="pty")
    assert read_exactly(controller, len(data)) == data


def test_a_port_nobody_reads_times_out_when_full(port: tuple[serial.Serial, int]) -> None:
    tty, controller = port
    chunk = b"x" * 4096
    written, started = 0, time.monotonic()
    with pytest.raises(DriverTimeout, match=r"write to pty blocked for 0\.05 s"):
        while time.monotonic() - started < 10.0:  # the pty's buffer is a few KB to 64 KB
            write_all(tty, chunk, 0.05, name="pty")
            written += len(chunk)
    assert written > 0
    # What was written before the buffer filled is all there.
    assert len(os.read(controller, 1 << 20)) >= min(written, 1)


def test_a_closed_port_is_an_operation_error(port: tuple[serial.Serial, int]) -> None:
    tty, _ = port
    tty.close()
    with pytest.raises(OperationError, match="write to pty failed"):
        write_all(tty, b"abc", 0.1, name="pty")
