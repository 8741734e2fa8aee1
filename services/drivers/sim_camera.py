"""The simulated depth camera as a device of its own (``lpc sim-camera``): it renders the
built-in scene exactly as the camera service's ``SimSource`` does in-process (frame ``seq`` at
``seq / rate`` seconds of the scene, the same seed, so the same depth and truth), paces itself
at its rate as a camera does, and hands each finished frame to the one reader connected to its
Unix socket (``lpc_core.devices.depth_link``; ``SimDeviceSource`` reads it).

On the worn computer the RealSense's own chip makes the depth and the camera service only
receives finished frames; run apart, the simulator's rendering stays out of the set's CPU the
same way. A reader that connects gets the hello (intrinsics), then frames; one that goes away
or stops reading for ``SEND_TIMEOUT_S`` is dropped and the device waits for the next. The
scene goes on from the next frame across readers, and stands still while no one reads.

A socket rather than shared memory: reading a frame costs the camera about 0.47 ms of CPU here,
of which parsing and copying its 203 KB are 0.05 ms; the rest is the wake-up, which a shared
buffer would need as well (its notification).
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import stat
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from lpc_core.devices.depth_link import DeviceFrame, DeviceHello, encode
from lpc_core.perception.pipeline import intrinsics_to_message
from schemas import to_wire
from services.drivers.depth import SimSource, SourceUnavailable, skip_missed_slots

SEND_TIMEOUT_S = 2.0  # a reader this long behind is taken for gone
_POLL_S = 0.1  # longest wait before the stop flag is looked at again


@dataclass
class DeviceStats:
    connections: int = 0
    frames: int = 0
    late_frames: int = 0  # slots skipped because rendering fell behind
    unread_frames: int = 0  # slots skipped because the reader had not taken the last frame


def listen(path: str | Path) -> socket.socket:
    """A Unix stream socket listening at ``path``; a stale socket left there is replaced, any
    other file is not touched (``SourceUnavailable``)."""
    path = Path(path)
    with contextlib.suppress(FileNotFoundError):
        if not stat.S_ISSOCK(path.lstat().st_mode):
            raise SourceUnavailable(f"{path} exists and is not a socket; choose another --socket")
    # Bound and listening under another name first, then renamed into place: a reader that
    # finds the path can connect (between bind and listen it would be refused).
    staging = path.with_name(f".{path.name}.{os.getpid()}")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        staging.unlink(missing_ok=True)
        server.bind(str(staging))
        server.listen(1)
        staging.rename(path)
    except OSError as exc:
        server.close()
        staging.unlink(missing_ok=True)
        raise SourceUnavailable(f"cannot listen at {path}: {exc}") from exc
    server.settimeout(_POLL_S)
    return server


class SimCameraDevice:
    """Serves ``source``'s frames at ``rate`` Hz on ``path`` until ``stop`` is set."""

    def __init__(self, path: str | Path, source: SimSource, rate: float, detail: str = "") -> None:
        self.path = Path(path)
        self.source = source
        self.period_ns = round(1e9 / rate)
        self.hello = encode(
            DeviceHello(
                intrinsics=intrinsics_to_message(source.intrinsics), rate_hz=rate, detail=detail
            )
        )
        self.stats = DeviceStats()
        self.seq = 0
        self._server = listen(self.path)

    def serve(self, stop: threading.Event, log=print) -> None:
        try:
            while not stop.is_set():
                try:
                    conn, _ = self._server.accept()
                except TimeoutError:
                    continue
                self.stats.connections += 1
                log(f"reader connected; streaming from frame {self.seq}")
                with conn:
                    why = self._stream(conn, stop)
                log(f"reader gone ({why}) after frame {self.seq - 1}")
        finally:
            self.close()

    def _stream(self, conn: socket.socket, stop: threading.Event) -> str:
        conn.settimeout(SEND_TIMEOUT_S)
        try:
            conn.sendall(self.hello)
            # The frame due now is the next seq: the scene resumes where the last reader left.
            start_ns = time.time_ns() - self.seq * self.period_ns
            while not stop.is_set():
                start_ns, missed = skip_missed_slots(
                    start_ns, self.seq, self.period_ns, time.time_ns()
                )
                self.stats.late_frames += missed
                due = start_ns + self.seq * self.period_ns
                while (wait_ns := due - time.time_ns()) > 0:
                    if stop.wait(min(wait_ns / 1e9, _POLL_S)):
                        return "stopped"
                # A camera does not wait for its host: while the last frame is still unread
                # (a Unix socket is writable again once 3/4 of its send buffer, about one
                # frame, is free), this slot is dropped, so the reader always gets a fresh frame.
                if not select.select([], [conn], [], 0)[1]:
                    self.stats.unread_frames += 1
                    start_ns += self.period_ns
                    continue
                # The same scene time as SimSource in the camera service: seq periods in.
                reading = self.source.render(self.seq * self.period_ns / 1e9, self.seq)
                frame = DeviceFrame(
                    seq=self.seq, t_ns=time.time_ns(), depth=to_wire(reading.depth),
                    truth=reading.truth,
                )  # fmt: skip
                conn.sendall(encode(frame))
                self.seq += 1
                self.stats.frames += 1
        except TimeoutError:
            return f"not reading for {SEND_TIMEOUT_S:g} s"
        except OSError as exc:  # BrokenPipe, ConnectionReset: the reader closed
            return exc.strerror or type(exc).__name__
        return "stopped"

    def close(self) -> None:
        self._server.close()
        with contextlib.suppress(OSError):
            if stat.S_ISSOCK(self.path.lstat().st_mode):
                self.path.unlink()
        self.source.shutdown()


def stderr_log(text: str) -> None:
    print(f"lpc sim-camera: {text}", file=sys.stderr, flush=True)
