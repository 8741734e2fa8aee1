"""Camera service: depth frames on ``lpc/camera/depth`` from the simulated scene (default), a
RealSense camera or file, or an MCAP recording. Simulated and replayed frames are paced by the
injected clock; a live camera paces itself. A live camera that is missing at the start or lost
mid-stream (unplugged) is looked for again every ``--reopen-every`` seconds: the service stays
up, reports ``degraded`` and counts it, and frames resume with the next ``seq``.

A RealSense camera gets the visual preset and depth units of ``--rs-preset`` and
``--rs-depth-units`` before it streams, and ``--rs-filters`` runs librealsense's own
post-processing; what is in force goes into the health's ``detail`` (``rs_preset=...
rs_depth_units=... rs_filters=...``) so that a replay knows, and a setting the device refuses
(a recording's options are read-only) is logged, counted and skipped.

``--source sim-device`` reads the simulated camera run as a device of its own (``lpc
sim-camera``) over its Unix ``--socket``, as a live camera: the device paces the frames, a
device that is missing or goes away is looked for again like a RealSense, and bytes from it that
are not a frame are logged, counted (``malformed_frames``) and skipped.

Perception is shed before control: when the control path's health (``lpc/health/*``) reports
too many ``late_ticks`` (over 30 % in two reports in a row), the camera publishes fewer frames
(a simulated frame shed is not even rendered): it halves its rate and climbs back a tenth of
it (at least 1 Hz) a second once on time (``lpc_core.perception.shedding``), never below
``--min-rate``. Its health counts the frames shed (``shed_frames``) and the rate now allowed
(``shed_rate_hz``); the published frames keep consecutive ``seq``. ``--no-shed`` publishes
every frame."""

from __future__ import annotations

import argparse
import asyncio
import sys

from lpc_core.perception.pipeline import intrinsics_to_message
from lpc_core.perception.shedding import (
    FrameReady,
    Gate,
    RateChange,
    ShedParams,
    ShedState,
    shed_step,
)
from schemas import DepthFrame, to_wire
from services.drivers.depth import (
    DepthReading,
    EndOfStream,
    MalformedFrame,
    RealSenseSource,
    ReplaySource,
    SimDeviceSource,
    SimSource,
    SourceUnavailable,
    default_sim_socket,
    skip_missed_slots,
)
from services.drivers.depth_flags import (
    add_realsense_arguments,
    add_sensor_arguments,
    stereo_sensor,
)
from services.drivers.errors import OperationError
from services.runtime import Bus, run_service, service_parser


def _frame(seq: int, t_ns: int, reading: DepthReading, intrinsics, source: str) -> DepthFrame:
    return DepthFrame(
        seq=seq,
        t_ns=t_ns,
        intrinsics=intrinsics,
        depth=to_wire(reading.depth) if reading.wire is None else reading.wire,
        source=source,
        truth=reading.truth,
    )


def _realsense(args: argparse.Namespace, file: str | None) -> RealSenseSource:
    return RealSenseSource(
        file,
        rate=round(args.rate),
        preset=args.rs_preset,
        depth_units=args.rs_depth_units,
        filters=args.rs_filters,
    )


def _live(args: argparse.Namespace) -> RealSenseSource | SimDeviceSource:
    """The live camera the flags name: a RealSense, or the simulated camera device."""
    if args.source == "sim-device":
        return SimDeviceSource(args.socket)
    return _realsense(args, None)


class _Shedder:
    """The frame gate of ``lpc_core.perception.shedding``, fed the control path's health."""

    def __init__(self, bus: Bus, args: argparse.Namespace) -> None:
        self._bus = bus
        # Callers that build the flags themselves may leave these out: the defaults of main.
        least = min(getattr(args, "min_rate", 5.0), args.rate)
        self.state = ShedState(ShedParams(max_rate_hz=args.rate, min_rate_hz=least))
        bus.health.counters["shed_frames"] = 0
        bus.health.counters["shed_rate_hz"] = round(args.rate)

    def publish(self) -> bool:
        """Whether the frame now ready is to be published (if not, it is counted as shed)."""
        self.state, gate = shed_step(self.state, FrameReady(), self._bus.clock.now_ns())
        self._bus.health.counters["shed_frames"] = self.state.shed_frames
        self._bus.health.counters["shed_rate_hz"] = round(self.state.rate)  # climbs here too
        return gate is Gate.PUBLISH

    async def watch(self) -> None:
        async for health in self._bus.subscribe("lpc/health/*"):
            self.state, change = shed_step(self.state, health, self._bus.clock.now_ns())
            if not isinstance(change, RateChange):
                continue
            if change.previous_hz == self.state.params.max_rate_hz or not self.state.shedding:
                self._bus.log(
                    "info",
                    f"frame rate {change.previous_hz:.1f} -> {change.rate_hz:.1f} Hz: "
                    f"{change.service} late in {100 * change.late_fraction:.0f}% of its ticks",
                )


def _report_settings(bus: Bus, source: RealSenseSource | SimDeviceSource) -> None:
    bus.health.detail = source.settings_text()
    for refused in source.unsupported:
        bus.health.counters["rs_option_unsupported"] += 1
        bus.log("warning", f"camera setting not applied, carrying on: {refused}")


async def _open_camera(
    bus: Bus, args: argparse.Namespace, why: str
) -> RealSenseSource | SimDeviceSource:
    """The live camera, looked for every ``args.reopen_every`` seconds until it is there."""
    bus.status = "degraded"
    bus.log("error", f"{why}; looking for the camera every {args.reopen_every:g} s")
    while True:
        await bus.clock.sleep_until(bus.clock.now_ns() + round(args.reopen_every * 1e9))
        try:
            source = _live(args)
        except SourceUnavailable:
            bus.health.counters["camera_reopen_failures"] += 1
            continue
        _report_settings(bus, source)
        bus.status = "ok"
        bus.log("info", "camera back")
        return source


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    live = args.source == "sim-device" or (args.source == "realsense" and not args.file)
    stereo = args.source == "sim" and getattr(args, "sensor", "model") == "stereo"
    try:
        if args.source == "sim":
            source = SimSource(seed=args.seed, sensor=stereo_sensor(args) if stereo else None)
        elif args.source == "realsense":
            source = _realsense(args, args.file)
            _report_settings(bus, source)
        elif args.source == "sim-device":
            source = _live(args)
            _report_settings(bus, source)
        else:
            source = ReplaySource(args.file)
    except SourceUnavailable as exc:
        if not live:  # a wrong file or a missing package: nothing to wait for
            bus.log("error", str(exc))
            raise
        bus.health.counters["camera_missing"] += 1
        source = await _open_camera(bus, args, str(exc))
    intrinsics = intrinsics_to_message(source.intrinsics)
    depth = bus.publisher("lpc/camera/depth")
    sensor = f" ({getattr(args, 'sensor', 'model')} sensor)" if args.source == "sim" else ""
    bus.log(
        "info",
        f"source {args.source}{sensor} {source.intrinsics.width}x{source.intrinsics.height}",
    )
    period_ns = round(1e9 / args.rate)
    start_ns = bus.clock.now_ns()
    first_recorded_ns = 0
    seq = slot = 0  # frames published; the simulated frame clock's slots
    shedder = _Shedder(bus, args)
    watch = asyncio.create_task(shedder.watch()) if getattr(args, "shed", True) else None

    def publish(reading: DepthReading, t_ns: int) -> None:
        nonlocal seq
        if args.source == "sim" or shedder.publish():  # a simulated frame was gated before
            depth.put(_frame(seq, t_ns, reading, intrinsics, args.source))
            seq += 1

    def device_frame(reading: DepthReading) -> None:
        # The device's own stamp: when the frame was complete, as a camera stamps it.
        publish(reading, bus.clock.now_ns() if reading.t_ns is None else reading.t_ns)

    try:
        while True:
            if args.source in ("realsense", "sim-device"):
                try:
                    if isinstance(source, SimDeviceSource):
                        # Published where the socket's callback parses each frame (no task
                        # woken a frame); back here only after a second with none.
                        reading = None
                        await source.deliver_async(device_frame, 1.0)
                    else:
                        reading = await asyncio.to_thread(source.read, 1.0)
                except MalformedFrame as exc:
                    bus.health.counters["malformed_frames"] += 1
                    bus.log("warning", f"{exc}; carrying on")
                    continue
                except OperationError as exc:
                    if not live:
                        raise
                    source.shutdown()
                    bus.health.counters["camera_lost"] += 1
                    source = await _open_camera(bus, args, f"camera lost: {exc}")
                    intrinsics = intrinsics_to_message(source.intrinsics)
                    continue
                if reading is None:
                    bus.health.counters["timeouts"] += 1
                    continue
                if args.file and reading.t_ns is not None:  # a file keeps its frame spacing
                    first_recorded_ns = first_recorded_ns or reading.t_ns
                    await bus.clock.sleep_until(start_ns + reading.t_ns - first_recorded_ns)
                t_ns = bus.clock.now_ns()
            else:
                if args.source == "sim":
                    start_ns, missed = skip_missed_slots(
                        start_ns, slot, period_ns, bus.clock.now_ns()
                    )
                    if missed:
                        bus.health.counters["late_frames"] += missed
                    due = start_ns + slot * period_ns
                    await bus.clock.sleep_until(due)
                    slot += 1
                    if not shedder.publish():  # shed before rendering
                        continue
                    if stereo:  # 100+ ms a frame: keep the loop (health, stop) free
                        reading = await asyncio.to_thread(
                            source.render, (due - start_ns) / 1e9, seq
                        )
                    else:
                        reading = source.render((due - start_ns) / 1e9, seq)
                else:  # keep the recording's own frame spacing
                    recorded_ns, reading = source.next_frame()
                    first_recorded_ns = first_recorded_ns or recorded_ns
                    await bus.clock.sleep_until(start_ns + recorded_ns - first_recorded_ns)
                # Stamped when the frame is complete, as a camera stamps its frames.
                t_ns = bus.clock.now_ns()
            publish(reading, t_ns)
    except EndOfStream:
        bus.log("info", f"end of {args.file} after {seq} frames")
    finally:
        source.shutdown()
        if watch is not None:
            watch.cancel()
    # Stay up (and healthy) after the end of a file: the session ends when 'lpc up' says so.
    await asyncio.Event().wait()


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("camera", __doc__ or "")
    parser.add_argument(
        "--source", choices=("sim", "sim-device", "realsense", "replay"), default="sim"
    )
    parser.add_argument("--file", help="recording for realsense (.bag/.db3) or replay (.mcap)")
    parser.add_argument(
        "--socket",
        default=default_sim_socket(),
        metavar="PATH",
        help=f"the simulated camera device's socket (--source sim-device; default "
        f"{default_sim_socket()}, where lpc sim-camera listens by default)",
    )
    parser.add_argument(
        "--rate",
        type=float,
        default=90.0,
        help="frame rate in Hz (default 90; a live camera or the sim device paces itself)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated scene")
    parser.add_argument(
        "--reopen-every",
        type=float,
        default=1.0,
        metavar="S",
        help="look for a missing or lost live camera every S seconds (default 1)",
    )
    parser.add_argument(
        "--no-shed",
        dest="shed",
        action="store_false",
        help="publish every frame even when the control path reports late ticks (default: "
        "shed frames then, down to --min-rate)",
    )
    parser.add_argument(
        "--min-rate",
        type=float,
        default=5.0,
        metavar="HZ",
        help="the least frame rate shedding goes down to (default 5 Hz; --rate if lower)",
    )
    add_sensor_arguments(parser)
    add_realsense_arguments(parser)
    args = parser.parse_args(argv)
    try:
        stereo_sensor(args)
    except ValueError as exc:
        parser.error(str(exc))
    if args.source == "replay" and not args.file:
        parser.error("--source replay needs --file FILE.mcap")
    if not 0 < args.rate <= 1000:
        parser.error("--rate must be in (0, 1000]")
    if not 0 < args.min_rate <= 1000:
        parser.error("--min-rate must be in (0, 1000]")
    if not 1e-6 <= args.rs_depth_units <= 0.01:
        parser.error("--rs-depth-units must be in [1e-6, 0.01] m")
    if not 0.01 <= args.reopen_every <= 60:
        parser.error("--reopen-every must be in [0.01, 60] s")
    return run_service("camera", serve, args)


if __name__ == "__main__":
    sys.exit(main())
