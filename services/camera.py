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
are not a frame are logged, counted (``malformed_frames``) and skipped."""

from __future__ import annotations

import argparse
import asyncio
import sys

from lpc_core.perception.pipeline import intrinsics_to_message
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
    add_realsense_arguments,
    add_sensor_arguments,
    default_sim_socket,
    skip_missed_slots,
    stereo_sensor,
)
from services.drivers.errors import OperationError
from services.runtime import Bus, run_service, service_parser


def _frame(seq: int, t_ns: int, reading: DepthReading, intrinsics, source: str) -> DepthFrame:
    return DepthFrame(
        seq=seq,
        t_ns=t_ns,
        intrinsics=intrinsics,
        depth=to_wire(reading.depth),
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
    seq = 0
    try:
        while True:
            if args.source in ("realsense", "sim-device"):
                try:
                    if isinstance(source, SimDeviceSource):
                        reading = await source.read_async(1.0)
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
                # The device's own stamp: when the frame was complete, as a camera stamps it.
                device_stamp = args.source == "sim-device" and reading.t_ns is not None
                t_ns = reading.t_ns if device_stamp else bus.clock.now_ns()
            else:
                if args.source == "sim":
                    start_ns, missed = skip_missed_slots(
                        start_ns, seq, period_ns, bus.clock.now_ns()
                    )
                    if missed:
                        bus.health.counters["late_frames"] += missed
                    due = start_ns + seq * period_ns
                    await bus.clock.sleep_until(due)
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
            depth.put(_frame(seq, t_ns, reading, intrinsics, args.source))
            seq += 1
    except EndOfStream:
        bus.log("info", f"end of {args.file} after {seq} frames")
    finally:
        source.shutdown()
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
    if not 1e-6 <= args.rs_depth_units <= 0.01:
        parser.error("--rs-depth-units must be in [1e-6, 0.01] m")
    if not 0.01 <= args.reopen_every <= 60:
        parser.error("--reopen-every must be in [0.01, 60] s")
    return run_service("camera", serve, args)


if __name__ == "__main__":
    sys.exit(main())
