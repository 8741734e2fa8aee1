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
import dataclasses
import threading
import time
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
from services.drivers.pty_device import PtyDevice


@dataclass(frozen=True)
class Received:
    """One host frame as the hand saw it."""

    arrival_ns: int
    header: int
    values: tuple[int, ...]


class AbilitySim(PtyDevice):
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
        # A hand's UART transmits whether or not the host reads: a reply the host's full buffer
        # cannot take is lost (counted), it never stalls the hand.
        self._open_pty("ability-sim", drop_unread=True)
        self._parser = ab.FrameParser()
        self.received: collections.deque[Received] = collections.deque(maxlen=history)
        self.replies: collections.deque[bytes] = collections.deque(maxlen=history)
        self.errors = collections.Counter[str]()
        self.commands = 0
        self.silenced = False  # tests: stop answering (a hand that went quiet)
        self._lock = threading.Lock()
        self._start()

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

    def _received(self, data: bytes, arrival_ns: int) -> None:
        for event in self._parser.feed(data):
            reply = self._apply(event, arrival_ns)
            if reply and not self.silenced and not self._send(reply):
                self.errors["replies_lost"] += 1

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
