"""Depth sources behind one small interface: the simulated scene, a RealSense camera (live or a
recorded .db3/.bag file), and the depth topic of an MCAP recording.

A source's ``read(timeout)`` returns the next ``DepthReading`` or ``None`` on timeout; at the end
of a file it raises ``EndOfStream``. ``shutdown()`` may be called twice.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import os
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lpc_core.devices.depth_link import DeviceFrame, DeviceHello, LinkParser, Rejected
from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.sim.stereo import StereoSensor
from schemas import NDArray, ObjectTruth, from_wire
from services.drivers.depth_flags import RS_PRESETS, parse_rs_filters
from services.drivers.errors import DeviceUnavailable, OperationError


class EndOfStream(Exception):
    """The source has no more frames (end of a recording)."""


class SourceUnavailable(DeviceUnavailable):
    """The source cannot be opened: missing package, missing device, unreadable file."""


class MalformedFrame(Exception):
    """The device sent something that is not a frame; it was skipped and the source reads on."""


@dataclass(frozen=True)
class DepthReading:
    depth: np.ndarray
    truth: ObjectTruth | None = None
    t_ns: int | None = None  # the source's own capture time, when it has one
    # ``depth`` as it came over a wire (the simulated device's frames), which the published
    # frame reuses instead of packing the array again (a 600 KB copy at 90 Hz).
    wire: NDArray | None = None


def skip_missed_slots(start_ns: int, seq: int, period_ns: int, now_ns: int) -> tuple[int, int]:
    """A frame clock (frame ``seq`` due at ``start_ns + seq * period_ns``) that has fallen more
    than a period behind skips the slots it missed, as a live camera does: the new
    ``start_ns`` and how many slots were skipped."""
    late_ns = now_ns - (start_ns + seq * period_ns)
    if late_ns <= period_ns:
        return start_ns, 0
    missed = late_ns // period_ns
    return start_ns + missed * period_ns, int(missed)


class SimSource:
    """The built-in simulated scene (``lpc_core.sim.simcam``): a pure function of time and seed,
    seen through the noise model or, given ``sensor``, the simulated stereo camera."""

    name = "sim"
    paced = True  # the service's clock paces it

    def __init__(self, seed: int = 0, sensor: StereoSensor | None = None) -> None:
        from lpc_core.sim.simcam import SimCamera

        if sensor is not None:
            try:
                import cv2  # type: ignore[import-not-found]  # noqa: F401
            except ModuleNotFoundError as exc:
                raise SourceUnavailable(
                    "the stereo sensor needs OpenCV: pip install 'lpc[stereo]'"
                ) from exc
        self._camera = SimCamera(seed=seed, sensor=sensor)
        self.intrinsics: Intrinsics = self._camera.intrinsics

    def render(self, t_s: float, seq: int) -> DepthReading:
        depth, truth = self._camera.frame(t_s, seq)
        return DepthReading(depth=depth, truth=truth)

    def shutdown(self) -> None:
        pass


def _import_pyrealsense2():
    """pyrealsense2, or ``SourceUnavailable`` saying what to install."""
    try:
        import pyrealsense2 as rs  # type: ignore[import-not-found]
    except ModuleNotFoundError as exc:
        if exc.name not in (None, "pyrealsense2"):
            raise SourceUnavailable(f"pyrealsense2 failed to import: {exc}") from exc
        raise SourceUnavailable(
            "pyrealsense2 is not installed: pip install 'lpc[realsense]' "
            "(it also needs Debian's libusb-1.0-0)"
        ) from exc
    except ImportError as exc:  # the wheel is there but a shared library is not
        raise SourceUnavailable(
            f"pyrealsense2 is installed but does not load ({exc}); "
            "on Debian/Ubuntu: apt-get install libusb-1.0-0"
        ) from exc
    return rs


def _f32(value: float) -> float:
    """A float32 from librealsense as the decimal it was written as (0.001, not 0.0010000000475).

    Intrinsics and depth units are float32 on the device and in recordings; the shortest decimal
    that rounds to the same float32 is the value that was set, and compares equal to it.
    """
    return float(str(np.float32(value)))


def filter_chain(rs, names: tuple[str, ...]) -> list:
    """pyrealsense2 filter objects for ``names``, in the order Intel's post-processing guide
    gives: depth to disparity, spatial, temporal, back to depth, hole filling."""
    chain = []
    on_disparity = [n for n in ("spatial", "temporal") if n in names]
    if on_disparity:
        chain.append(rs.disparity_transform(True))
        for name in on_disparity:
            chain.append(rs.spatial_filter() if name == "spatial" else rs.temporal_filter())
        chain.append(rs.disparity_transform(False))
    if "hole_filling" in names:
        chain.append(rs.hole_filling_filter())
    return chain


def software_depth_sensor(rs: Any, intrinsics: Intrinsics, fps: int) -> tuple[Any, Any, Any]:
    """A pyrealsense2 ``software_device`` with one depth sensor streaming z16 images of
    ``intrinsics`` at ``fps``, its depth units ``intrinsics.depth_scale``: ``(device, sensor,
    profile)``. Images fed to it (``feed_depth_frame``) come out as librealsense frames."""
    device = rs.software_device()
    sensor = device.add_sensor("Depth")
    ri = rs.intrinsics()
    ri.width, ri.height = intrinsics.width, intrinsics.height
    ri.fx, ri.fy, ri.ppx, ri.ppy = intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy
    ri.model = getattr(rs.distortion, intrinsics.model)
    ri.coeffs = list(intrinsics.coeffs)
    stream = rs.video_stream()
    stream.type, stream.index, stream.uid = rs.stream.depth, 0, 0
    stream.width, stream.height, stream.fps = intrinsics.width, intrinsics.height, fps
    stream.bpp, stream.fmt, stream.intrinsics = 2, rs.format.z16, ri
    profile = sensor.add_video_stream(stream, True).as_video_stream_profile()
    sensor.add_read_only_option(rs.option.depth_units, intrinsics.depth_scale)
    return device, sensor, profile


def feed_depth_frame(
    rs: Any,
    sensor: Any,
    profile: Any,
    intrinsics: Intrinsics,
    depth: np.ndarray,
    number: int,
    fps: int,
) -> None:
    """Hand one uint16 depth image to a ``software_depth_sensor`` as frame ``number``, stamped
    ``number * 1000 / fps`` ms on the hardware clock."""
    pixels = np.ascontiguousarray(depth, dtype=np.uint16)  # alive until the sensor has it
    frame = rs.software_video_frame()
    frame.pixels = pixels
    frame.bpp, frame.stride = 2, intrinsics.width * 2
    frame.timestamp = number * 1000.0 / fps
    frame.domain = rs.timestamp_domain.hardware_clock
    frame.frame_number = number
    frame.depth_units = intrinsics.depth_scale
    frame.profile = profile
    sensor.on_video_frame(frame)


class SoftwareFilters:
    """librealsense's post-processing filters run on depth images from anywhere (the simulated
    camera, a bench): each image is fed to a pyrealsense2 ``software_device`` depth sensor with
    ``intrinsics`` and its depth units, and the frame it yields goes through ``filter_chain``.

    The temporal filter keeps a history: ``reset()`` starts a new sequence. ``SourceUnavailable``
    if pyrealsense2 is missing.
    """

    def __init__(self, intrinsics: Intrinsics, names: tuple[str, ...], fps: int = 90) -> None:
        parse_rs_filters(",".join(names))
        rs = _import_pyrealsense2()
        self._rs = rs
        self._names = names
        self._intrinsics = intrinsics
        self._fps = fps
        device, sensor, self._profile = software_depth_sensor(rs, intrinsics, fps)
        self._syncer = rs.syncer()
        sensor.open(self._profile)
        sensor.start(self._syncer)
        self._device, self._sensor = device, sensor
        self._count = 0
        self.reset()

    def reset(self) -> None:
        self._chain = filter_chain(self._rs, self._names)

    def process(self, depth: np.ndarray) -> np.ndarray:
        """The filtered copy of one uint16 depth image (``(height, width)`` of the intrinsics)."""
        feed_depth_frame(
            self._rs, self._sensor, self._profile, self._intrinsics, depth, self._count, self._fps
        )
        self._count += 1
        out = self._syncer.wait_for_frames(5000).get_depth_frame()
        for stage in self._chain:
            out = stage.process(out)
        return np.asanyarray(out.get_data()).copy()

    def close(self) -> None:
        with contextlib.suppress(RuntimeError):
            self._sensor.stop()
            self._sensor.close()


class RealSenseSource:
    """pyrealsense2: a live camera, or a recorded file played back as fast as it is read.

    A recording is ROS 2 ``.db3`` (written by pyrealsense2 2.59 on) or ROS 1 ``.bag`` (earlier
    versions); 2.59 reads both. Only the depth stream is used, and it must be Z16. The
    intrinsics come from the depth stream's profile, the depth scale from the depth sensor
    (both are stored in a recording). Each reading's ``t_ns`` is the frame's own timestamp:
    the recorded device clock for a file, librealsense's host-synchronised global time for a
    live camera.

    A file plays back in non-real-time mode: playback waits for the reader, so no frame is
    dropped however slowly ``read`` is called, and ``read`` raises ``EndOfStream`` once the
    last frame has been read.

    Before streaming, the depth sensor gets the visual ``preset`` and the ``depth_units``
    (None leaves either as it is); a setting the device does not take (a recording's are
    read-only) is reported in ``unsupported`` and the source carries on. ``settings`` says
    what is in force, for the camera's health. ``filters`` (names from ``RS_FILTERS``) run
    librealsense's own post-processing on every depth frame.
    """

    name = "realsense"
    paced = False  # the device (or the reader, for a file) paces it

    _SLICE_S = 0.05  # longest single wait, so shutdown() from another thread is never held long

    def __init__(
        self,
        file: str | Path | None = None,
        rate: int = 90,
        width: int = 424,
        height: int = 240,
        *,
        preset: str | None = None,
        depth_units: float | None = None,
        filters: tuple[str, ...] = (),
    ) -> None:
        if preset is not None and preset not in RS_PRESETS:
            raise ValueError(f"preset must be one of {RS_PRESETS}, got {preset!r}")
        if depth_units is not None and not 1e-6 <= depth_units <= 0.01:
            raise ValueError(f"depth_units must be in [1e-6, 0.01] m, got {depth_units}")
        parse_rs_filters(",".join(filters))
        self._file = str(file) if file else None
        if self._file and not Path(self._file).is_file():
            raise SourceUnavailable(f"no such RealSense recording: {self._file}")
        rs = _import_pyrealsense2()
        self._stopped = False
        self._ended = threading.Event()
        self._played = False
        self._pipeline = rs.pipeline()
        config = rs.config()
        if self._file:
            config.enable_device_from_file(self._file, repeat_playback=False)
            config.enable_stream(rs.stream.depth, rs.format.z16, 0)
            what = f"RealSense recording {self._file}"
        else:
            # Checked first: with no camera, pipeline.start() waits 15 s before it gives up.
            if len(rs.context().query_devices()) == 0:
                raise SourceUnavailable(
                    "no RealSense camera found: is it plugged in (USB 3), and when not root, "
                    "are librealsense's udev rules installed?"
                )
            config.enable_stream(rs.stream.depth, width, height, rs.format.z16, rate)
            what = f"a RealSense camera for depth {width}x{height} Z16 at {rate} fps"
        self.unsupported: list[str] = []
        try:
            # The pipeline starts the device that resolve() returns: set it up before it starts
            # (set after start, real-time playback has already dropped frames, and a live
            # sensor may refuse new depth units while it streams).
            device = config.resolve(rs.pipeline_wrapper(self._pipeline)).get_device()
            if self._file:
                playback = device.as_playback()
                playback.set_real_time(False)
                playback.set_status_changed_callback(self._on_status)
                self._playback = playback  # the callback lives as long as this handle
            self._apply_options(rs, device, preset, depth_units)
            profile = self._pipeline.start(config)
        except RuntimeError as exc:
            raise SourceUnavailable(f"cannot open {what}: {exc}") from exc
        try:
            stream = profile.get_stream(rs.stream.depth).as_video_stream_profile()
            i = stream.get_intrinsics()
            scale = profile.get_device().first_depth_sensor().get_depth_scale()
        except RuntimeError as exc:
            self.shutdown()
            raise SourceUnavailable(f"{what} has no depth sensor with depth units: {exc}") from exc
        self.intrinsics = Intrinsics(
            width=i.width,
            height=i.height,
            fx=_f32(i.fx),
            fy=_f32(i.fy),
            ppx=_f32(i.ppx),
            ppy=_f32(i.ppy),
            model=str(i.model).split(".")[-1],
            coeffs=tuple(_f32(c) for c in i.coeffs),
            depth_scale=_f32(scale),
        )
        self.fps: int = stream.fps()
        self._filters = filter_chain(rs, filters)
        self.settings: dict[str, str] = {
            "rs_preset": self._preset_in_force(rs, profile.get_device(), preset),
            "rs_depth_units": f"{self.intrinsics.depth_scale:g}",
            "rs_filters": ",".join(filters) or "none",
        }

    def _apply_options(self, rs, device, preset: str | None, depth_units: float | None) -> None:
        """Set the preset, then the depth units, on the depth sensor; note what it refuses."""
        try:
            sensor = device.first_depth_sensor()
        except RuntimeError as exc:
            self.unsupported.append(f"no depth sensor to set options on ({exc})")
            return
        wanted = []
        if preset is not None:
            wanted.append(("visual_preset", rs.option.visual_preset, preset))
        if depth_units is not None:
            wanted.append(("depth_units", rs.option.depth_units, depth_units))
        for name, option, value in wanted:
            number = (
                float(int(getattr(rs.rs400_visual_preset, value)))
                if name == "visual_preset"
                else float(value)
            )
            if not sensor.supports(option):
                self.unsupported.append(f"{name} {value}: the device has no such option")
                continue
            if sensor.is_option_read_only(option):
                self.unsupported.append(f"{name} {value}: read-only on this device")
                continue
            try:
                sensor.set_option(option, number)
            except RuntimeError as exc:
                self.unsupported.append(f"{name} {value}: {exc}")

    @staticmethod
    def _preset_in_force(rs, device, preset: str | None) -> str:
        """The preset the sensor reports, else what was asked and could not be set."""
        try:
            sensor = device.first_depth_sensor()
            if sensor.supports(rs.option.visual_preset):
                value = int(sensor.get_option(rs.option.visual_preset))
                return str(rs.rs400_visual_preset(value)).rsplit(".", 1)[-1]
        except (RuntimeError, ValueError):
            pass
        return f"{preset} (not set)" if preset is not None else "unknown"

    def settings_text(self) -> str:
        """``key=value`` pairs of ``settings``, then what the device refused."""
        text = " ".join(f"{k}={v}" for k, v in self.settings.items())
        if self.unsupported:
            text += "; not applied: " + "; ".join(self.unsupported)
        return text

    def _on_status(self, status: object) -> None:
        # Runs on librealsense's reading thread. A playback reports "stopped" before it starts
        # as well, so the end is a stop after play. The stop comes after the last frame has
        # been handed to the pipeline's queue (the playback flushes its sensors first).
        name = str(status).rsplit(".", 1)[-1]
        if name == "playing":
            self._played = True
        elif name == "stopped" and self._played:
            self._ended.set()

    def read(self, timeout: float) -> DepthReading | None:
        """The next depth frame, ``None`` after ``timeout`` seconds, ``EndOfStream`` at the end
        of a file; ``OperationError`` if the pipeline fails (or was shut down)."""
        deadline = time.monotonic() + max(timeout, 0.0)
        while True:
            # Read before waiting: once the stop is seen, every frame is already queued.
            ended = self._ended.is_set()
            wait_s = min(self._SLICE_S, max(deadline - time.monotonic(), 0.0))
            try:
                ok, frames = self._pipeline.try_wait_for_frames(max(1, round(wait_s * 1000)))
                if ok:
                    depth = frames.get_depth_frame()
                    t_ns = round(depth.get_timestamp() * 1e6)
                    for stage in self._filters:
                        depth = stage.process(depth)
                    # Copy: the frame's buffer goes back to librealsense's pool.
                    return DepthReading(depth=np.asanyarray(depth.get_data()).copy(), t_ns=t_ns)
            except RuntimeError as exc:
                raise OperationError(f"RealSense read failed: {exc}") from exc
            if ended:
                raise EndOfStream(self._file)
            if time.monotonic() >= deadline:
                return None

    def shutdown(self) -> None:
        if not self._stopped:
            self._stopped = True
            # A pipeline that failed while starting has nothing to stop.
            with contextlib.suppress(RuntimeError):
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
        from lpc_core.perception.pipeline import intrinsics_from_message

        self.intrinsics = intrinsics_from_message(first.message.intrinsics)

    def next_frame(self) -> tuple[int, DepthReading]:
        """The next frame and its recorded capture time; ``EndOfStream`` at the end."""
        from lpc_core.perception.pipeline import depth_image

        item = self._pending if self._pending is not None else next(self._messages, None)
        self._pending = None
        if item is None:
            raise EndOfStream(self._file)
        frame = item.message
        return frame.t_ns, DepthReading(depth=depth_image(frame), truth=frame.truth)

    def shutdown(self) -> None:
        self._messages = iter(())


def default_sim_socket() -> str:
    """Where ``lpc sim-camera`` listens and ``--source sim-device`` looks by default (per user)."""
    base = os.environ.get("XDG_RUNTIME_DIR") or "/tmp"
    return str(Path(base) / f"lpc-sim-camera-{os.getuid()}.sock")


class SimDeviceSource:
    """The simulated camera run as a device of its own (``lpc sim-camera``), read over its Unix
    socket like a live camera: it paces itself, and each reading carries the device's capture
    time and the scene's truth.

    ``SourceUnavailable`` when no device answers at ``path`` (or it sends no hello within
    ``timeout``); ``read`` raises ``OperationError`` once the device has gone away, and
    ``MalformedFrame`` for bytes that are not a frame of the announced size (skipped: the next
    ``read`` goes on with the frame after them).
    """

    name = "sim-device"
    paced = False

    _RECV_BYTES = 1 << 18

    def __init__(self, path: str | Path, timeout: float = 2.0) -> None:
        self._path = str(path)
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._parser = LinkParser()
        self._ready: collections.deque = collections.deque()
        self._closed = False
        self._failure = ""  # why the socket failed, when it did (read_async)
        self._reader: _DeviceReader | None = None
        self.unsupported: list[str] = []
        try:
            self._sock.connect(self._path)
            hello = self._next_message(timeout)
        except (OSError, OperationError) as exc:
            self._sock.close()
            raise SourceUnavailable(
                f"no simulated camera at {self._path} ({exc}); start one: "
                f"lpc sim-camera --socket {self._path}"
            ) from exc
        if not isinstance(hello, DeviceHello):
            self._sock.close()
            raise SourceUnavailable(f"the device at {self._path} did not say hello first")
        from lpc_core.perception.pipeline import intrinsics_from_message

        self.intrinsics = intrinsics_from_message(hello.intrinsics)
        self.rate_hz = hello.rate_hz
        self._detail = hello.detail
        shape = (self.intrinsics.height, self.intrinsics.width)
        self._shape = shape
        # Anything longer than a frame of this size is not one of this device's frames.
        self._parser.max_body = shape[0] * shape[1] * 2 + 65536

    def settings_text(self) -> str:
        return f"device={self._path} rate_hz={self.rate_hz:g}" + (
            f" {self._detail}" if self._detail else ""
        )

    def _next_message(self, timeout: float) -> DeviceHello | DeviceFrame | Rejected | None:
        """The next parsed item, ``None`` after ``timeout`` s, ``OperationError`` at the end."""
        deadline = time.monotonic() + max(timeout, 0.0)
        while not self._ready:
            self._check_open()
            self._sock.settimeout(max(deadline - time.monotonic(), 1e-3))
            try:
                data = self._sock.recv(self._RECV_BYTES)
            except TimeoutError:
                return None
            except OSError as exc:
                raise OperationError(f"reading the simulated camera failed: {exc}") from exc
            self._feed(data)
        return self._ready.popleft()

    def _check_open(self) -> None:
        if self._failure:
            raise OperationError(f"reading the simulated camera failed: {self._failure}")
        if self._closed:
            raise OperationError(f"the simulated camera at {self._path} went away")

    def _feed(self, data: bytes | memoryview, *, handed_over: bool = False) -> bool:
        """Parse a piece; whether a message views it (``LinkParser.feed``)."""
        if data:
            self._ready.extend(self._parser.feed(data, handed_over=handed_over))
            return self._parser.viewing
        self._closed = True  # what is left is a truncated record, then the end
        rest = self._parser.flush()
        if rest is not None:
            self._ready.append(rest)
        return False

    def read(self, timeout: float) -> DepthReading | None:
        """The next frame, ``None`` after ``timeout`` seconds."""
        item = self._next_message(timeout)
        return None if item is None else self._reading(item)

    async def read_async(self, timeout: float) -> DepthReading | None:
        """``read`` on the running event loop: woken by the socket, with no thread between
        (measured: 0.47 ms of CPU a frame against 1.4 ms through ``asyncio.to_thread``).

        The first call hands the socket to the loop for good (``_DeviceReader``; ``read`` is
        not to be called after it): the socket stays registered and is read into one reused
        buffer, instead of a new 200 KB bytes, a ``recv`` that found nothing yet and a reader
        added and removed for every frame (``loop.sock_recv``: 0.52-0.55 ms of CPU a frame,
        against 0.42-0.49 ms, three runs each, alternating, at 90 Hz)."""
        reader = await self._started_reader()
        if not self._ready:
            deadline = reader.loop.time() + timeout
            while not self._ready:
                self._check_open()
                if not await reader.wait(deadline):
                    return None
        return self._reading(self._ready.popleft())

    async def deliver_async(self, on_frame: Callable[[DepthReading], None], timeout: float) -> None:
        """``read_async`` for a reader that only publishes each frame: every frame is handed to
        ``on_frame`` where the socket's reader callback parses it, with no task woken between
        its arrival and ``on_frame`` (a loop pass and a task step fewer a frame). Returns once
        ``timeout`` seconds pass with no frame; raises what ``read_async`` raises
        (``MalformedFrame``, ``OperationError``) and what ``on_frame`` raised, in the calling
        task, after the frames before it. Frames parsed while no call runs wait for the next."""
        reader = await self._started_reader()
        reader.deliver_to(on_frame, timeout)
        try:
            deadline = reader.loop.time() + timeout
            while True:
                reader.deliver_ready()
                reader.raise_error()
                if self._ready:  # not a frame: a rejected record or a second hello
                    self._reading(self._ready.popleft())
                self._check_open()
                if not await reader.wait(max(deadline, reader.frame_deadline)):
                    return
        finally:
            reader.deliver_to(None, timeout)

    async def _started_reader(self) -> _DeviceReader:
        if self._reader is None:
            self._check_open()
            self._reader = _DeviceReader(self)
            await self._reader.connect(self._sock)
        return self._reader

    def _reading(self, item: DeviceHello | DeviceFrame | Rejected) -> DepthReading:
        match item:
            case Rejected(nbytes=nbytes, reason=reason):
                raise MalformedFrame(f"skipped {nbytes} bytes from the device: {reason}")
            case DeviceHello():
                raise MalformedFrame("a second hello from the device, skipped")
        try:
            depth = from_wire(item.depth)
        except ValueError as exc:
            raise MalformedFrame(f"frame {item.seq} skipped: {exc}") from exc
        if depth.dtype != np.uint16 or depth.shape != self._shape:
            raise MalformedFrame(
                f"frame {item.seq} skipped: depth is {depth.dtype} {depth.shape}, "
                f"expected uint16 {self._shape} from the hello"
            )
        return DepthReading(depth=depth, truth=item.truth, t_ns=item.t_ns, wire=item.depth)

    def shutdown(self) -> None:
        if self._reader is not None:
            self._reader.close()
        # shutdown() before close(): it wakes a read blocked in another thread.
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()


class _DeviceReader(asyncio.BufferedProtocol):
    """The simulated device's socket on the event loop: each piece that arrives is received
    into one reused buffer and fed to the source's parser, whose frames ``read_async`` takes.

    A frame is received while the camera waits for it; when none waits (the camera is busy
    with the last one), reading pauses at the first finished frame, so the device sees the
    socket full and drops its next slot as it did before: the camera always gets a fresh
    frame, never a queue of old ones.

    A frame that arrived whole in one piece is decoded where it lies, its depth a view of the
    buffer, which then goes with the frame: the next piece is received into a new one (an
    uninitialised numpy buffer, 0.5 us; keeping the buffer and copying each frame out of it
    was a 200 KB copy, 6 us a frame). The frame stays intact however long it is kept. The new
    buffer is cheap because the heap keeps freed ones (``services.heap.keep_freed_memory``,
    which every service's process calls): otherwise each would be fresh pages, 64 faults.
    """

    def __init__(self, source: SimDeviceSource) -> None:
        self._source = source
        self._buffer = self._new_buffer()
        self._transport: asyncio.Transport | None = None
        self._waiter: asyncio.Future[bool] | None = None
        self._paused = False
        self.loop = asyncio.get_running_loop()
        # One timer for the waits' deadlines, moved on only when it fires: each frame's wait
        # ends long before its deadline, and an ``asyncio.timeout`` for each (a timer armed
        # and cancelled, the running loop and task looked up) cost about 15 us of CPU a frame
        # here. When the timer fires before the current wait's deadline, it is set again for
        # that deadline, so a stalled device still ends a wait at its own deadline.
        self._timer: asyncio.TimerHandle | None = None
        self._deadline = 0.0
        # ``SimDeviceSource.deliver_async``'s receiver of frames, their timeout, and what a
        # delivery raised (for the task to raise), with the deadline the last frame set.
        self._on_frame: Callable[[DepthReading], None] | None = None
        self._timeout = 0.0
        self._error: Exception | None = None
        self.frame_deadline = 0.0

    async def connect(self, sock: socket.socket) -> None:
        await self.loop.create_unix_connection(lambda: self, sock=sock)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self._transport = transport

    async def wait(self, deadline: float) -> bool:
        """Until a message is parsed or the socket ends or fails (``True``), or the loop's
        clock reaches ``deadline`` (``False``)."""
        if self._paused and self._transport is not None:
            self._paused = False
            self._transport.resume_reading()
        self._deadline = deadline
        if self._timer is None or self._timer.when() > deadline:
            self._arm(deadline)
        self._waiter = self.loop.create_future()
        try:
            return await self._waiter
        finally:
            self._waiter = None

    def _arm(self, when: float) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self.loop.call_at(when, self._on_timer)

    def _on_timer(self) -> None:
        when = self._timer.when() if self._timer is not None else 0.0
        self._timer = None
        if self._waiter is None or self._waiter.done():
            return  # the next wait sets it again
        if when >= self._deadline:  # set for this wait's deadline, which has come
            self._waiter.set_result(False)
        else:
            self._arm(self._deadline)

    def deliver_to(self, on_frame: Callable[[DepthReading], None] | None, timeout: float) -> None:
        self._on_frame, self._timeout = on_frame, timeout

    def deliver_ready(self) -> None:
        """Hand the frames at the head of the source's queue to the receiver, if one is set,
        until something that is not a frame, or a delivery that raised (kept for the task)."""
        on_frame, ready = self._on_frame, self._source._ready
        while on_frame is not None and ready and self._error is None:
            if not isinstance(ready[0], DeviceFrame):
                return
            try:
                on_frame(self._source._reading(ready.popleft()))
            except Exception as exc:  # raised in the task: here it would close the transport
                self._error = exc
                return
            # A frame ends the wait for one: the task's timer is moved on when it fires.
            self._deadline = self.frame_deadline = self.loop.time() + self._timeout

    def raise_error(self) -> None:
        error, self._error = self._error, None
        if error is not None:
            raise error

    def _wake(self) -> None:
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(True)

    def _new_buffer(self) -> memoryview:
        return memoryview(np.empty(self._source._RECV_BYTES, dtype=np.uint8))

    def get_buffer(self, sizehint: int) -> memoryview:
        return self._buffer

    def buffer_updated(self, nbytes: int) -> None:
        if self._source._feed(self._buffer[:nbytes], handed_over=True):
            self._buffer = self._new_buffer()
        if self._on_frame is not None:
            self.deliver_ready()
        if self._source._ready or self._error is not None:
            waiting = self._waiter is not None and not self._waiter.done()
            if not waiting and self._transport is not None and not self._paused:
                self._paused = True
                self._transport.pause_reading()
            self._wake()

    def eof_received(self) -> bool:
        self._source._feed(b"")
        self._wake()
        return False  # the transport closes itself

    def connection_lost(self, exc: Exception | None) -> None:
        if exc is not None and not self._source._closed:
            self._source._failure = str(exc) or type(exc).__name__
        self._source._closed = True
        self._wake()

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._transport is not None:
            self._transport.abort()
