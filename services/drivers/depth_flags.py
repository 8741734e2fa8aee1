"""The depth sources' command-line flags: the simulated sensor's and the RealSense camera's.

Shared by the camera service, the benchmarks and ``lpc up``, which checks them and passes them
on to the camera. Nothing here loads numpy: the supervisor imports it, and numpy alone is about
12 MB of a process's resident memory.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from lpc_core.sim.stereo_settings import MATCHERS, Matcher, StereoRig

if TYPE_CHECKING:
    from lpc_core.sim.stereo import StereoSensor

SENSORS = ("model", "stereo")


def add_sensor_arguments(parser: argparse.ArgumentParser) -> None:
    """The simulated camera's sensor flags: the noise model or the stereo camera and its
    matcher (shared by the camera service and the benchmarks)."""
    group = parser.add_argument_group("simulated sensor")
    group.add_argument(
        "--sensor",
        choices=SENSORS,
        default="model",
        help="model: exact depth plus D435-like noise (default); stereo: two IR images lit "
        "by a dot projector, matched by OpenCV (needs pip install 'lpc[stereo]')",
    )
    group.add_argument(
        "--matcher",
        choices=MATCHERS,
        default="sgbm",
        help="stereo matcher: sgbm (semi-global, default) or bm (plain block matching)",
    )
    default = Matcher()
    group.add_argument(
        "--block-size",
        type=int,
        default=default.block_size,
        metavar="N",
        help=f"matching window, odd (default {default.block_size}; bm needs >= 5)",
    )
    group.add_argument(
        "--uniqueness",
        type=int,
        default=default.uniqueness,
        metavar="PCT",
        help=f"margin of the best match over the second, percent (default {default.uniqueness})",
    )
    group.add_argument(
        "--texture-threshold",
        type=int,
        default=default.texture_threshold,
        metavar="N",
        help=f"bm only: least texture a window needs (default {default.texture_threshold})",
    )
    group.add_argument(
        "--dot-density",
        type=float,
        default=StereoRig().dot_density,
        metavar="D",
        help=f"projector dots per pixel² (default {StereoRig().dot_density})",
    )


def stereo_sensor(args: argparse.Namespace) -> StereoSensor | None:
    """The stereo camera the flags describe, None for the noise model; ``ValueError`` naming
    the bad setting."""
    if getattr(args, "sensor", "model") != "stereo":
        return None
    # Imported here: rendering needs numpy and OpenCV, which the noise model's processes
    # (and the supervisor, which only checks the flags) need not load.
    from lpc_core.sim.stereo import StereoSensor

    matcher = Matcher(
        kind=args.matcher,
        block_size=args.block_size,
        uniqueness=args.uniqueness,
        texture_threshold=args.texture_threshold,
    )
    return StereoSensor(rig=StereoRig(dot_density=args.dot_density), matcher=matcher)


def sensor_label(args: argparse.Namespace) -> str:
    """A short description of the simulated sensor, for reports."""
    if getattr(args, "sensor", "model") != "stereo":
        return "noise model"
    texture = f", texture {args.texture_threshold}" if args.matcher == "bm" else ""
    return (
        f"stereo, {args.matcher} block {args.block_size}, uniqueness {args.uniqueness}"
        f"{texture}, dots {args.dot_density:g}/px²"
    )


def sensor_argv(args: argparse.Namespace) -> list[str]:
    """The sensor flags again, to pass on to the camera service."""
    if getattr(args, "sensor", "model") != "stereo":
        return []
    return [
        "--sensor", "stereo", "--matcher", args.matcher,
        "--block-size", str(args.block_size), "--uniqueness", str(args.uniqueness),
        "--texture-threshold", str(args.texture_threshold),
        "--dot-density", str(args.dot_density),
    ]  # fmt: skip


RS_PRESETS = (
    "default",
    "hand",
    "high_accuracy",
    "high_density",
    "medium_density",
    "remove_ir_pattern",
)
"""librealsense's built-in D400 visual presets (``rs.rs400_visual_preset``)."""

RS_FILTERS = ("spatial", "temporal", "hole_filling")
"""librealsense's post-processing filters that ``--rs-filters`` may name."""

DEFAULT_RS_PRESET = "default"
DEFAULT_RS_DEPTH_UNITS_M = 0.001


def parse_rs_filters(text: str) -> tuple[str, ...]:
    """``"spatial,temporal"`` -> ("spatial", "temporal"); ``ValueError`` naming an unknown one."""
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    unknown = [n for n in names if n not in RS_FILTERS]
    if unknown:
        raise ValueError(
            f"unknown --rs-filters {', '.join(unknown)}; known: {', '.join(RS_FILTERS)}"
        )
    return names


def rs_filters_arg(text: str) -> tuple[str, ...]:
    """``parse_rs_filters`` for argparse, which shows an ``ArgumentTypeError``'s own words."""
    try:
        return parse_rs_filters(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def add_realsense_arguments(parser: argparse.ArgumentParser) -> None:
    """The live camera's settings (``--source realsense``): preset, depth units, filters."""
    group = parser.add_argument_group("RealSense camera (--source realsense)")
    group.add_argument(
        "--rs-preset",
        choices=RS_PRESETS,
        default=DEFAULT_RS_PRESET,
        help="visual preset set on the depth sensor before streaming (librealsense's D400 "
        f"presets; default {DEFAULT_RS_PRESET}: set explicitly, since the camera keeps what the "
        "last program set); recorded in the camera's health",
    )
    group.add_argument(
        "--rs-depth-units",
        type=float,
        default=DEFAULT_RS_DEPTH_UNITS_M,
        metavar="M",
        help=f"depth unit in metres (default {DEFAULT_RS_DEPTH_UNITS_M:g}); recorded in the "
        "camera's health and in every frame's intrinsics",
    )
    group.add_argument(
        "--rs-filters",
        type=rs_filters_arg,
        default=(),
        metavar="LIST",
        help=f"librealsense post-processing filters, comma-separated, from {', '.join(RS_FILTERS)}"
        " (applied in Intel's order: spatial and temporal on disparity, then hole filling)",
    )


def realsense_argv(args: argparse.Namespace) -> list[str]:
    """The RealSense flags again, to pass on to the camera service."""
    argv = ["--rs-preset", args.rs_preset, "--rs-depth-units", repr(args.rs_depth_units)]
    if args.rs_filters:
        argv += ["--rs-filters", ",".join(args.rs_filters)]
    return argv
