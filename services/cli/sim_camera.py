"""``lpc sim-camera``: the simulated depth camera as a device of its own.

It renders the built-in scene as ``lpc up --source sim`` does in-process (the same frames and
truth for the same ``--seed``, ``--rate`` and sensor flags), paces itself at ``--rate`` and hands
each finished frame to the camera service over a Unix socket: ``lpc up --source sim-device
[PATH]``. Run apart, the rendering is not part of the service set's CPU, as the RealSense's own
chip is not on the worn computer. Stops on Ctrl-C or SIGTERM and removes its socket.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from services.drivers.depth import (
    SimSource,
    SourceUnavailable,
    default_sim_socket,
)
from services.drivers.depth_flags import add_sensor_arguments, sensor_label, stereo_sensor
from services.drivers.sim_camera import SimCameraDevice, stderr_log


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--socket",
        default=default_sim_socket(),
        metavar="PATH",
        help=f"Unix socket to listen on (default {default_sim_socket()})",
    )
    parser.add_argument("--rate", type=float, default=90.0, help="frame rate in Hz (default 90)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated scene")
    add_sensor_arguments(parser)


def run(args: argparse.Namespace) -> int:
    if not 0 < args.rate <= 1000:
        print("lpc sim-camera: error: --rate must be in (0, 1000] Hz", file=sys.stderr)
        return 2
    try:
        sensor = stereo_sensor(args)
        source = SimSource(seed=args.seed, sensor=sensor)
    except (ValueError, SourceUnavailable) as exc:
        print(f"lpc sim-camera: error: {exc}", file=sys.stderr)
        return 2
    detail = f"seed={args.seed} sensor={sensor_label(args).replace(' ', '_')}"
    try:
        device = SimCameraDevice(args.socket, source, args.rate, detail)
    except SourceUnavailable as exc:
        print(f"lpc sim-camera: error: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    stderr_log(
        f"{source.intrinsics.width}x{source.intrinsics.height} at {args.rate:g} Hz, "
        f"seed {args.seed}, {sensor_label(args)}, on {args.socket}"
    )
    device.serve(stop, stderr_log)
    s = device.stats
    stderr_log(
        f"stopped: {s.frames} frames to {s.connections} reader(s); skipped {s.late_frames} "
        f"slots rendering late, {s.unread_frames} with the last frame unread"
    )
    return 0
