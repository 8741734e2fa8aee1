"""The device's end of a pseudo-terminal, shared by the simulated serial devices.

A simulator opens a raw pty pair (a serial line, not a terminal: no echo, no CR/LF mapping),
hands every read to its ``_received(data, arrival_ns)`` on a thread of its own, and answers
with ``_send``. A driver opens ``port`` (``/dev/pts/N``) as it would ``/dev/ttyUSB0``;
``close()`` hangs the line up, as unplugging the adapter would.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import tty
from collections.abc import Callable
from typing import Self


class PtyDevice:
    """Subclasses call ``_open_pty`` first, set up their state, then ``_start``."""

    port: str
    _clock: Callable[[], int]

    def _open_pty(self, thread_name: str, *, drop_unread: bool = False) -> None:
        """``drop_unread``: writes never block, as a UART transmits whether or not the host
        reads; ``_send`` then reports a reply the host's full buffer could not take."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        tty.setraw(self._master)
        if drop_unread:
            os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)

    def _start(self) -> None:
        self._thread.start()

    def _received(self, data: bytes, arrival_ns: int) -> None:
        raise NotImplementedError

    def _send(self, reply: bytes) -> bool:
        """Write ``reply`` to the host; ``False`` when it was lost to a full buffer."""
        try:
            os.write(self._master, reply)
        except BlockingIOError:
            return False
        except OSError:  # hung up under us
            pass
        return True

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(self._master, 4096)
            except BlockingIOError:
                continue
            except OSError:  # closed under us
                return
            self._received(data, self._clock())

    def close(self) -> None:
        """Hang up: the port disappears and writes to it fail. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._thread.join(timeout=1.0)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
