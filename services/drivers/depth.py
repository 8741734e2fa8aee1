"""Depth sources behind one small interface: the simulated scene, a RealSense camera (live or a
recorded .bag/.db3 file), and the depth topic of an MCAP recording.

A source's ``read(timeout)`` returns the next ``DepthReading`` or ``None`` on timeout; at the end
of a file it raises ``EndOfStream``. ``shutdown()`` may be called twice.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lpc_core.intrinsics import Intrinsics
from schemas import ObjectTruth
from services.drivers.errors import DeviceUnavailable


class EndOfStream(Exception):
    """The source has no more frames (end of a recording)."""


class SourceUnavailable(DeviceUnavailable):
    """The source cannot be opened: missing package, missing device, unreadable file."""


@dataclass(frozen=True)
class DepthReading:
    depth: np.ndarray
    truth: ObjectTruth | None = None
    t_ns: int | None = None  # the source's own capture time, when it has one


class SimSource:
    """The built-in simulated scene (``lpc_core.simcam``): a pure function of time and seed."""

    name = "sim"
    paced = True  # the service's clock paces it

    def __init__(self, seed: int = 0) -> None:
        from lpc_core.simcam import SimCamera

        self._camera = SimCamera(seed=seed)
        self.intrinsics: Intrinsics = self._camera.intrinsics

    def render(self, t_s: float, seq: int) -> DepthReading:
        depth, truth = self._camera.frame(t_s, seq)
        return DepthReading(depth=depth, truth=truth)

    def shutdown(self) -> None:
        pass


class RealSenseSource:
    """pyrealsense2: a live camera, or a recorded file played back as fast as it is read."""

    name = "realsense"
    paced = False  # the device (or the file's timestamps) paces it

    def __init__(self, file: str | None = None, rate: int = 90) -> None:
        try:
            import pyrealsense2 as rs  # type: ignore[import-not-found]
        except ImportError as exc:
            raise SourceUnavailable(
                "pyrealsense2 is not installed: pip install 'lpc[realsense]' "
                "(and Debian's libusb-1.0-0)"
            ) from exc
        self._rs = rs
        self._pipeline = rs.pipeline()
        config = rs.config()
        if file:
            if not Path(file).is_file():
                raise SourceUnavailable(f"no such RealSense recording: {file}")
            config.enable_device_from_file(file, repeat_playback=False)
        else:
            config.enable_stream(rs.stream.depth, 424, 240, rs.format.z16, rate)
        try:
            profile = self._pipeline.start(config)
        except RuntimeError as exc:
            raise SourceUnavailable(f"cannot start the RealSense pipeline: {exc}") from exc
        if file:
            profile.get_device().as_playback().set_real_time(False)
        stream = profile.get_stream(rs.stream.depth).as_video_stream_profile()
        i = stream.get_intrinsics()
        scale = profile.get_device().first_depth_sensor().get_depth_scale()
        self.intrinsics = Intrinsics(
            width=i.width,
            height=i.height,
            fx=i.fx,
            fy=i.fy,
            ppx=i.ppx,
            ppy=i.ppy,
            model=str(i.model).split(".")[-1],
            coeffs=tuple(i.coeffs),
            depth_scale=scale,
        )
        self._file = file
        self._stopped = False

    def read(self, timeout: float) -> DepthReading | None:
        ok, frames = self._pipeline.try_wait_for_frames(int(timeout * 1000))
        if not ok:
            if self._file:
                raise EndOfStream(self._file)
            return None
        depth = frames.get_depth_frame()
        return DepthReading(depth=np.asanyarray(depth.get_data()).copy())

    def shutdown(self) -> None:
        if not self._stopped:
            self._stopped = True
            self._pipeline.stop()


class ReplaySource:
    """The ``lpc/camera/depth`` topic of an MCAP recording, with its recorded capture times."""

    name = "replay"
    paced = True

    def __init__(self, file: str) -> None:
        from services.mcap_log import read_messages

        if not Path(file).is_file():
            raise SourceUnavailable(f"no such recording: {file}")
        self._file = file
        self._messages: Iterator = (m for m in read_messages(file, topics=["lpc/camera/depth"]))
        first = next(self._messages, None)
        if first is None:
            raise SourceUnavailable(f"{file} holds no lpc/camera/depth messages")
        self._pending = first
        from lpc_core.pipeline import intrinsics_from_message

        self.intrinsics = intrinsics_from_message(first.message.intrinsics)

    def next_frame(self) -> tuple[int, DepthReading]:
        """The next frame and its recorded capture time; ``EndOfStream`` at the end."""
        from lpc_core.pipeline import depth_image

        item = self._pending if self._pending is not None else next(self._messages, None)
        self._pending = None
        if item is None:
            raise EndOfStream(self._file)
        frame = item.message
        return frame.t_ns, DepthReading(depth=depth_image(frame), truth=frame.truth)

    def shutdown(self) -> None:
        self._messages = iter(())
