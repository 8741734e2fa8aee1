"""Raw EMG sources: amplifiers that stream the signal itself (200 Hz to 2 kHz), not envelopes.

Same small interface as ``services.drivers.emg``: ``recv(timeout)`` returns ``(samples, t_ns)``
— a chunk of shape (N, 2), the (flexor, extensor) channels, and the time its last sample
arrived — or ``None`` on timeout; ``shutdown()`` may be called twice. ``rate_hz`` is the
nominal sampling rate, ``description`` says what was opened. ``services.emg`` turns the chunks
into 100 Hz envelopes with ``lpc_core.devices.emg_envelope``.

- ``LslEmg``: a Lab Streaming Layer outlet (pylsl; its wheels bring liblsl), found by name or
  type within a timeout. The inlet recovers by itself when the outlet disappears and comes
  back (same source id, or same name and type): meanwhile ``recv`` returns ``None``.
- ``BrainFlowEmg``: any board BrainFlow drives, by name (``cyton``, ``ganglion``,
  ``synthetic``, ``cyton_daisy``, ...) or number; the channels are indices into the board's EMG
  channels (its EXG channels when it lists none). BrainFlow reports EXG data in microvolts.
  ``config`` is sent to the board before it streams (BrainFlow's ``config_board``).

Both packages are optional extras (``pip install 'lpc[lsl]'``, ``'lpc[brainflow]'``); a missing
one raises ``DeviceUnavailable`` saying which to install.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any

import numpy as np

from lpc_core.devices.emg_envelope import MIN_RATE_HZ
from services.drivers.errors import DeviceUnavailable, InitialisationError, OperationError

LSL_SCOPES = ("machine", "link", "site", "organization", "global")
_lsl_configured: str | None = None


def import_pylsl(scope: str | None) -> Any:
    """pylsl, configured once per process: ``scope`` confines discovery (``machine``: this
    computer only, over loopback) and quietens liblsl's info lines; None keeps liblsl's own
    configuration (``lsl_api.cfg``, default scope ``site``)."""
    global _lsl_configured
    try:
        import pylsl
    except (ImportError, OSError, RuntimeError) as exc:
        raise DeviceUnavailable(f"LSL needs pylsl: pip install 'lpc[lsl]' ({exc})") from exc
    if scope is not None and _lsl_configured is None:
        if scope not in LSL_SCOPES:
            raise DeviceUnavailable(f"LSL scope must be one of {', '.join(LSL_SCOPES)}")
        # liblsl reads its configuration once, before its first call: set it before anything.
        pylsl.set_config_content(lsl_config(scope))
        _lsl_configured = scope
    elif scope is not None and scope != _lsl_configured:
        raise DeviceUnavailable(f"LSL already configured with scope {_lsl_configured}")
    return pylsl


def lsl_config(scope: str) -> str:
    """liblsl's configuration (``lsl_api.cfg`` syntax) for a discovery scope; ``machine``
    sends discovery to 127.0.0.1 only and disables IPv6."""
    ipv6 = "disable" if scope == "machine" else "allow"
    return f"[multicast]\nResolveScope = {scope}\n[ports]\nIPv6 = {ipv6}\n[log]\nlevel = -2\n"


class LslEmg:
    """Two channels of an LSL stream."""

    def __init__(
        self,
        channels: tuple[int, int] = (0, 1),
        *,
        name: str | None = None,
        stream_type: str = "EMG",
        timeout: float = 5.0,
        scope: str | None = None,
        reresolve_s: float = 5.0,
    ) -> None:
        pylsl = import_pylsl(scope)
        self.reresolve_s = reresolve_s
        self.channels = channels
        self._closed = False
        prop, value = ("name", name) if name else ("type", stream_type)
        try:
            found = pylsl.resolve_byprop(prop, value, minimum=1, timeout=timeout)
        except (RuntimeError, ValueError) as exc:
            raise DeviceUnavailable(f"LSL resolve failed: {exc}") from exc
        if not found:
            raise DeviceUnavailable(
                f"no LSL stream with {prop} {value!r} within {timeout:g} s: is the amplifier "
                "streaming, on this network (and the same LSL scope)?"
            )
        info = found[0]
        if info.channel_format() == pylsl.cf_string:
            raise InitialisationError(f"LSL stream {info.name()!r} carries strings, not samples")
        count = info.channel_count()
        if max(channels) >= count:
            raise InitialisationError(
                f"LSL stream {info.name()!r} has {count} channels; channels {channels} asked"
            )
        self.rate_hz = float(info.nominal_srate())
        if self.rate_hz < MIN_RATE_HZ:
            raise InitialisationError(
                f"LSL stream {info.name()!r} runs at {self.rate_hz:g} Hz: raw EMG needs a regular "
                f"rate of at least {MIN_RATE_HZ:g} Hz"
            )
        self.description = (
            f"LSL stream {info.name()!r} (type {info.type()!r}, {count} channels, "
            f"{self.rate_hz:g} Hz, source id {info.source_id()!r})"
        )
        try:
            self._inlet = pylsl.StreamInlet(info, max_buflen=2, recover=True)
            self._inlet.open_stream(timeout=timeout)
        except RuntimeError as exc:  # pylsl's TimeoutError and the rest derive from it
            raise InitialisationError(f"cannot open {self.description}: {exc}") from exc
        self._index = list(channels)
        self._last_sample = time.monotonic()

    def recv(self, timeout: float | None = None) -> tuple[np.ndarray, int] | None:
        if self._closed:
            raise OperationError("LSL inlet is shut down")
        try:
            samples, stamps = self._inlet.pull_chunk(timeout=timeout or 0.0)
        except RuntimeError as exc:  # pylsl's LostError and internal errors
            raise OperationError(f"LSL stream lost: {exc}") from exc
        if not stamps:
            if time.monotonic() - self._last_sample > self.reresolve_s:
                # liblsl recovers only a stream with the same identity (source id, or name,
                # type, rate and channels); an amplifier app restarted otherwise needs a new
                # resolve, which the caller does by opening the source again.
                raise OperationError(f"no samples for {self.reresolve_s:g} s: resolving again")
            return None
        self._last_sample = time.monotonic()
        return np.asarray(samples, dtype=float)[:, self._index], time.time_ns()

    def shutdown(self) -> None:
        if not self._closed:
            self._closed = True
            self._inlet.close_stream()


def brainflow_board_id(board: str) -> int:
    """BrainFlow's board id for a name (``cyton``, ``CYTON_BOARD``, ``synthetic``) or number."""
    from brainflow.board_shim import BoardIds

    if board.lstrip("-").isdigit():
        return int(board)
    key = board.strip().upper().replace("-", "_")
    for name in (key, key + "_BOARD"):
        if name in BoardIds.__members__:
            return int(BoardIds[name].value)
    known = ", ".join(n.removesuffix("_BOARD").lower() for n in list(BoardIds.__members__)[3:12])
    raise DeviceUnavailable(f"BrainFlow knows no board {board!r} (e.g. {known}, ...)")


class BrainFlowEmg:
    """Two EMG channels of a BrainFlow board."""

    def __init__(
        self,
        channels: tuple[int, int] = (0, 1),
        *,
        board: str = "synthetic",
        serial_port: str = "",
        config: str = "",
    ) -> None:
        try:
            from brainflow.board_shim import BoardShim, BrainFlowError, BrainFlowInputParams
        except (ImportError, OSError) as exc:
            raise DeviceUnavailable(
                f"BrainFlow needs brainflow: pip install 'lpc[brainflow]' ({exc})"
            ) from exc
        self._error = BrainFlowError
        self._closed = True
        board_id = brainflow_board_id(board)
        BoardShim.disable_board_logger()
        try:
            emg = list(BoardShim.get_emg_channels(board_id))
        except BrainFlowError:
            emg = []
        try:
            rows = emg or list(BoardShim.get_exg_channels(board_id))
            self.rate_hz = float(BoardShim.get_sampling_rate(board_id))
        except BrainFlowError as exc:
            raise DeviceUnavailable(f"BrainFlow board {board!r}: {exc}") from exc
        if max(channels) >= len(rows):
            raise InitialisationError(
                f"BrainFlow board {board!r} has {len(rows)} EMG channels; channels {channels} asked"
            )
        if self.rate_hz < MIN_RATE_HZ:
            raise InitialisationError(
                f"BrainFlow board {board!r} samples at {self.rate_hz:g} Hz: raw EMG needs at "
                f"least {MIN_RATE_HZ:g} Hz"
            )
        self._rows = [rows[i] for i in channels]
        params = BrainFlowInputParams()
        params.serial_port = serial_port
        self._board = BoardShim(board_id, params)
        try:
            self._board.prepare_session()
            if config:  # the board's own settings command, e.g. a Cyton's channel setting
                self._board.config_board(config)
            self._board.start_stream()
        except BrainFlowError as exc:
            self._release()
            where = f" on {serial_port}" if serial_port else ""
            raise DeviceUnavailable(
                f"cannot start BrainFlow board {board!r}{where}: {exc}"
            ) from exc
        self._closed = False
        self.description = (
            f"BrainFlow board {board!r} (id {board_id}, {self.rate_hz:g} Hz, rows {self._rows})"
        )

    def recv(self, timeout: float | None = None) -> tuple[np.ndarray, int] | None:
        if self._closed:
            raise OperationError("BrainFlow board is shut down")
        deadline = time.monotonic() + (timeout or 0.0)
        try:
            # BrainFlow has no blocking read: poll its ring buffer at 200 Hz until the timeout.
            while self._board.get_board_data_count() == 0:
                if time.monotonic() >= deadline:
                    return None
                time.sleep(0.005)
            data = self._board.get_board_data()
        except self._error as exc:
            raise OperationError(f"BrainFlow read failed: {exc}") from exc
        return data[self._rows].T.astype(float), time.time_ns()

    def shutdown(self) -> None:
        if not self._closed:
            self._closed = True
            self._release()

    def _release(self) -> None:
        for step in (self._board.stop_stream, self._board.release_session):
            with contextlib.suppress(self._error):  # not streaming or not prepared: nothing to undo
                step()
