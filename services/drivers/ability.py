"""The PSYONIC Ability Hand over pyserial, and the hand it makes with a wrist rotator on CAN.

``AbilityHand(port)`` opens the hand's serial line (460800 baud; PPP stuffing on, toggles 46
and 47), checks it answers a read-only query, and then drives the fingers in position mode:
lpc's commands are velocities of one grasp axis, so the driver integrates ``grasp`` into an
aperture set-point (``full_speed_mm_s`` at 1.0) and sends the grip's joint angles for it
(``lpc_core.devices.ability_grips``). A command's ``grip`` switches the table, keeping the
aperture. ``recv`` sends the set-point every ``period_s`` (the hand answers every frame, and
leaves API mode after 300 ms without one) and returns the next reply as a ``HandStatus``:
aperture read off the grip's lead joint, grip force from the currents. A zero command holds the
set-point where it is: that is the watchdog's stop. Without a port the hand is simulated on a
pty (``services.drivers.ability_sim``). Bad frames are counted in ``errors``, never raised.

The hand has no wrist: ``AbilityWithCanWrist`` pairs it with a wrist rotator on CAN in lpc's
layout (``services.drivers.hand``), so that one ``HandLink`` and its one watchdog drive both:
``send`` goes to both, ``recv`` returns the fingers' status with the wrist's angle, and nothing
when either side has gone quiet.
"""

from __future__ import annotations

import collections
import dataclasses
import select
import threading
import time
from typing import Any

import serial

from lpc_core.devices import ability as ab
from lpc_core.devices import ability_grips as ag
from lpc_core.devices.hand import HandCommand, HandStatus
from services.drivers.ability_sim import AbilitySim
from services.drivers.errors import (
    DeviceUnavailable,
    DriverError,
    InitialisationError,
    OperationError,
)
from services.drivers.hand import HandDriver
from services.drivers.serial_io import write_all

MIN_WRITE_TIMEOUT_S = 0.1


class AbilityHand:
    """The fingers of an Ability Hand on a serial port (or a simulated one: ``port=None``)."""

    profile = "ability"

    def __init__(
        self,
        port: str | None = None,
        *,
        baudrate: int = ab.BAUDRATE,
        address: int = ab.ADDRESS,
        reply_variant: int = 2,  # variant 3: positions, currents, rotor speeds (39 bytes)
        period_s: float = 0.01,
        full_speed_mm_s: float = 120.0,
        timeout: float = 1.0,
        object_mm: float | None = None,
    ) -> None:
        if reply_variant not in (0, 2):
            raise ValueError("reply_variant must be 0 or 2: the grip force needs the currents")
        self.sim = AbilitySim(address=address, object_mm=object_mm) if port is None else None
        self.port = port if port is not None else self.sim.port  # type: ignore[union-attr]
        self.address = address
        self.reply_variant = reply_variant
        self.period_s = period_s
        self.full_speed_mm_s = full_speed_mm_s
        self.errors = collections.Counter[str]()
        self.grip = "power"
        self._parser = ab.FrameParser()
        self._closed = False
        self._speed = 0.0
        self._advanced = time.monotonic()
        self._due = time.monotonic()
        self._setpoint_lock = threading.Lock()
        self._replies: collections.deque[ab.Reply] = collections.deque(maxlen=64)
        self._counter = 0
        try:
            self._serial = serial.Serial(self.port, baudrate=baudrate, timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._close_sim()
            raise DeviceUnavailable(f"cannot open the Ability Hand on {self.port}: {exc}") from exc
        try:
            self._write(ab.read_only_frame(reply_variant, address), timeout)
            reply = self._reply(timeout)
            if reply is None:
                raise InitialisationError(
                    f"no reply to a read-only query on {self.port} within {timeout} s; is the "
                    "hand on, in UART mode at 460800 baud, with PPP stuffing (toggles 46, 47)?"
                )
        except BaseException:
            self._closed = True
            self._serial.close()
            self._close_sim()
            raise
        # Start from where the hand is, in the grip its pose is nearest to (after a reconnection
        # the hand may still be in another grip than power).
        self.grip, aperture, _ = ag.classify(reply.positions_deg)
        lo, hi = ag.posture(self.grip).range_mm
        self.aperture_sp = min(max(aperture, lo), hi)

    # ------------------------------------------------------------------ interface

    def send(self, command: HandCommand, timeout: float | None = 0.01) -> None:
        """Take a velocity (and grip) command. The set-point goes out with the next frame of
        the ``period_s`` stream (one reply each: the status stays at 100 Hz), at once when the
        command stops the fingers or changes the grip."""
        if self._closed:
            raise OperationError(f"Ability Hand port {self.port} is shut down")
        with self._setpoint_lock:
            self._advance()
            urgent = command.grasp == 0.0 and self._speed != 0.0
            if command.grip is not None and command.grip != self.grip:
                self.grip, urgent = command.grip, True
                lo, hi = ag.posture(self.grip).range_mm
                self.aperture_sp = min(max(self.aperture_sp, lo), hi)
            self._speed = command.grasp
            if urgent:
                self._send_setpoint(timeout)

    def recv(self, timeout: float | None = None) -> HandStatus | None:
        """The next reply as a status, or ``None`` after ``timeout``. Meanwhile the set-point
        goes out every ``period_s`` on a fixed schedule, without waiting for the replies: a
        caller woken late catches up, and the status keeps its rate on average."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if self._replies:
                return self._status(self._replies.popleft())
            now = time.monotonic()
            if now >= self._due:
                with self._setpoint_lock:  # send() may come from another thread
                    self._advance()
                    self._send_setpoint(0.01)
                self._due += self.period_s
                if now - self._due > 0.25:  # far behind (a stalled machine): resynchronise
                    self._due = now + self.period_s
            wait = self._due - time.monotonic()
            if deadline is not None:
                wait = min(wait, deadline - time.monotonic())
            self._read(max(wait, 0.0))
            if not self._replies and deadline is not None and time.monotonic() >= deadline:
                return None

    def health(self) -> dict[str, int]:
        return {f"bad_frames_{kind}": n for kind, n in self.errors.items()}

    def shutdown(self) -> None:
        """Close the port (the hand holds its pose and leaves API mode). Safe twice."""
        if self._closed:
            return
        self._closed = True
        try:
            self._serial.close()
        finally:
            self._close_sim()

    def __enter__(self) -> AbilityHand:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    # ------------------------------------------------------------------ set-point

    def _advance(self) -> None:
        now = time.monotonic()
        dt = min(now - self._advanced, 0.1)  # a stalled caller does not fling the hand
        self._advanced = now
        lo, hi = ag.posture(self.grip).range_mm
        self.aperture_sp -= self._speed * self.full_speed_mm_s * dt
        self.aperture_sp = min(max(self.aperture_sp, lo), hi)

    def _send_setpoint(self, timeout: float | None) -> None:
        positions = ag.positions_for(self.grip, self.aperture_sp)
        self._write(ab.position_frame(positions, self.reply_variant, self.address), timeout)

    def _status(self, reply: ab.Reply) -> HandStatus:
        positions = reply.positions_deg
        currents = reply.currents_a
        force = 0.0 if currents is None else ag.grip_force_pct(self.grip, currents)
        self._counter = (self._counter + 1) & 0xFF
        moving = bool(abs(self._speed) > 0.02)
        if reply.rotor_velocity is not None:
            moving = bool(abs(reply.rotor_velocity_rad_s).max() > 50.0)
        return HandStatus(
            wrist_angle_deg=0.0,
            aperture_mm=ag.aperture_of(self.grip, positions),
            grip_force_pct=force,
            moving=moving,
            counter=self._counter,
            grip=self.grip,
        )

    # ------------------------------------------------------------------ bytes

    def _write(self, data: bytes, timeout: float | None) -> None:
        """Write all of ``data``, waiting at least ``MIN_WRITE_TIMEOUT_S`` for a full port (a
        frame is 0.4 ms of line at 460800 baud)."""
        if self._closed:
            raise OperationError(f"Ability Hand port {self.port} is shut down")
        wait = None if timeout is None else max(timeout, MIN_WRITE_TIMEOUT_S)
        write_all(self._serial, data, wait, name=self.port)

    def _read(self, timeout: float) -> None:
        """Wait up to ``timeout`` for bytes; queue the good replies, count the bad frames."""
        if self._closed:
            raise OperationError(f"Ability Hand port {self.port} is shut down")
        try:
            ready, _, _ = select.select([self._serial.fileno()], [], [], timeout)
            data = self._serial.read(max(1, self._serial.in_waiting)) if ready else b""
        except (serial.SerialException, OSError, ValueError, TypeError) as exc:
            # TypeError, ValueError: the port was closed by another thread meanwhile.
            raise OperationError(f"read from {self.port} failed: {exc}") from exc
        for event in self._parser.feed(data):
            if isinstance(event, ab.FrameError):
                self.errors[event.kind] += 1
                continue
            try:
                self._replies.append(ab.decode_reply(event))
            except ab.FrameError as exc:
                self.errors[exc.kind] += 1

    def _reply(self, timeout: float) -> ab.Reply | None:
        """The next good reply within ``timeout``."""
        deadline = time.monotonic() + timeout
        while not self._replies:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            self._read(remaining)
        return self._replies.popleft()

    def _close_sim(self) -> None:
        if self.sim is not None:
            self.sim.close()


class AbilityWithCanWrist:
    """The Ability Hand's fingers and a wrist rotator on CAN, as one driver for ``HandLink``."""

    profile = "ability"

    def __init__(
        self, fingers: AbilityHand, wrist: HandDriver, *, wrist_stale_s: float = 0.1
    ) -> None:
        self.fingers = fingers
        self.wrist = wrist
        self.wrist_stale_s = wrist_stale_s
        self.wrist_silent = 0
        self._wrist: HandStatus | None = None
        self._wrist_at = -float("inf")

    def send(self, command: HandCommand, timeout: float | None = 0.01) -> None:
        self.fingers.send(command, timeout)
        self.wrist.send(HandCommand(wrist=command.wrist), timeout)

    def recv(self, timeout: float | None = None) -> HandStatus | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            remaining = None if deadline is None else max(deadline - time.monotonic(), 0.0)
            status = self.fingers.recv(remaining)
            while (wrist := self.wrist.recv(0.0)) is not None:
                self._wrist, self._wrist_at = wrist, time.monotonic()
            if status is not None:
                if self._wrist is None or time.monotonic() - self._wrist_at > self.wrist_stale_s:
                    self.wrist_silent += 1  # half a hand is no status: the controller stops
                else:
                    return dataclasses.replace(
                        status,
                        wrist_angle_deg=self._wrist.wrist_angle_deg,
                        moving=status.moving or self._wrist.moving,
                        fault=status.fault or self._wrist.fault,
                    )
            if deadline is not None and time.monotonic() >= deadline:
                return None

    def health(self) -> dict[str, int]:
        return {
            **self.fingers.health(),
            "wrist_error_frames": self.wrist.error_frames,
            "wrist_silent": self.wrist_silent,
        }

    def shutdown(self) -> None:
        """Both sides; safe twice."""
        try:
            self.fingers.shutdown()
        finally:
            self.wrist.shutdown()

    def __enter__(self) -> AbilityWithCanWrist:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


def open_ability(
    port: str | None = None,
    *,
    interface: str = "virtual",
    channel: str = "lpc-hand",
    object_mm: float | None = None,
    **kwargs: Any,
) -> AbilityWithCanWrist:
    """The Ability Hand on ``port`` (simulated without one) with lpc's wrist on CAN."""
    from services.drivers.hand import LpcHand

    fingers = AbilityHand(port, object_mm=object_mm, **kwargs)
    try:
        wrist = LpcHand(interface=interface, channel=channel)
    except DriverError:
        fingers.shutdown()
        raise
    return AbilityWithCanWrist(fingers, wrist)
