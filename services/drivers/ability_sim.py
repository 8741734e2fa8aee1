"""A simulated PSYONIC Ability Hand on a pseudo-terminal, speaking the real protocol.

``AbilitySim()`` opens a pty pair and answers on the hand's end, in a thread: it unstuffs and
checks each host frame (``lpc_core.devices.ability``), applies it to the hand model
(``lpc_core.sim.ability_hand``) at the time its bytes arrived, and answers at once with a
stuffed reply frame in the variant the header asked for, as the hand does in its standard
UART response mode. Frames for another address are ignored; bad frames are counted and get no
reply. A driver opens ``sim.port`` as it would ``/dev/ttyUSB0``. ``close()`` hangs up.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import os
import select
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass

from lpc_core.devices import ability as ab
from lpc_core.sim.ability_hand import (
    AbilityParams,
    AbilityState,
    ability_command,
    ability_reply,
    ability_step,
)


@dataclass(frozen=True)
class Received:
    """One host frame as the hand saw it."""

    arrival_ns: int
    header: int
    values: tuple[int, ...]


class AbilitySim:
    """The hand's end of a pty; see the module docstring."""

    def __init__(
        self,
        *,
        address: int = ab.ADDRESS,
        params: AbilityParams | None = None,
        object_mm: float | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
        history: int = 1000,
    ) -> None:
        self.address = address
        self._clock = clock
        self._state = AbilityState(params=params or AbilityParams(), object_mm=object_mm)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        tty.setraw(self._master)
        # A hand's UART transmits whether or not the host reads: a reply the host's full buffer
        # cannot take is lost (counted), it never stalls the hand.
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self._parser = ab.FrameParser()
        self.received: collections.deque[Received] = collections.deque(maxlen=history)
        self.replies: collections.deque[bytes] = collections.deque(maxlen=history)
        self.errors = collections.Counter[str]()
        self.commands = 0
        self.silenced = False  # tests: stop answering (a hand that went quiet)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="ability-sim", daemon=True)
        self._thread.start()

    @property
    def state(self) -> AbilityState:
        with self._lock:
            return ability_step(self._state, self._clock())

    @property
    def object_mm(self) -> float | None:
        return self._state.object_mm

    @object_mm.setter
    def object_mm(self, value: float | None) -> None:
        with self._lock:
            self._state = dataclasses.replace(self._state, object_mm=value)

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
            arrival = self._clock()
            for event in self._parser.feed(data):
                reply = self._apply(event, arrival)
                if reply and not self.silenced:
                    try:
                        os.write(self._master, reply)
                    except BlockingIOError:
                        self.errors["replies_lost"] += 1
                    except OSError:
                        pass

    def _apply(self, event: bytes | ab.FrameError, arrival: int) -> bytes:
        if isinstance(event, ab.FrameError):
            self.errors[event.kind] += 1
            return b""
        try:
            command = ab.decode_command(event)
        except ab.FrameError as exc:
            self.errors[exc.kind] += 1
            return b""
        if command.address != self.address:
            return b""
        with self._lock:
            self._state = ability_command(self._state, command, arrival)
            reply = ab.encode_reply(ability_reply(self._state))
            self.commands += 1
            self.received.append(Received(arrival, command.header, command.values))
            self.replies.append(reply)
        return reply

    def close(self) -> None:
        """Hang up: the port disappears. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._thread.join(timeout=1.0)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> AbilitySim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
