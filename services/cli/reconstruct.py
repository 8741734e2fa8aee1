"""``lpc reconstruct``: shape, grasp width and wrist angle of depth frames, one JSON line each.

    lpc reconstruct --intrinsics INTR.json FRAME.png [FRAME.png ...]
    lpc reconstruct --mcap RECORDING.mcap

PNG frames are 16-bit single-channel depth images in units of the intrinsics' ``depth_scale``
metres; the intrinsics JSON uses pyrealsense2's names (width, height, fx, fy, ppx, ppy, model,
coeffs, depth_scale). ``--mcap`` reads the ``lpc/camera/depth`` messages of a recording, each
carrying its own intrinsics. The frames form one sequence: the 10-frame window runs across
them, and each line carries the window's state after that frame.

``METHODS`` maps a ``--method`` name to a function (depth, intrinsics, seed) -> Reconstruction.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.reconstruction import Reconstruction
from lpc_core.perception.window import WindowResult, WindowState, window_step

FRAME_PERIOD_NS = 11_111_111  # PNG frames carry no time: take them as 90 fps
DEPTH_TOPIC = "lpc/camera/depth"

Method = Callable[[np.ndarray, Intrinsics, int], Reconstruction]


def _laser(depth: np.ndarray, intrinsics: Intrinsics, seed: int) -> Reconstruction:
    from lpc_core.perception.laser import reconstruct_laser
    from lpc_core.perception.scans import cut_scan_lines

    return reconstruct_laser(cut_scan_lines(depth, intrinsics), seed=seed)


def _paper(depth: np.ndarray, intrinsics: Intrinsics, seed: int) -> Reconstruction:
    from lpc_core.perception.laser import LaserParams, reconstruct_laser
    from lpc_core.perception.scans import cut_scan_lines

    return reconstruct_laser(cut_scan_lines(depth, intrinsics), LaserParams(variant="paper"), seed)


def _cloud(depth: np.ndarray, intrinsics: Intrinsics, seed: int) -> Reconstruction:
    from lpc_core.perception.cloud import reconstruct_cloud

    return reconstruct_cloud(depth, intrinsics, seed=seed)


METHODS: dict[str, Method] = {
    "laser": _laser,  # the four-line method with lpc's 3-D solids (lpc_core.perception.laser)
    "paper": _paper,  # the four-line method as the paper describes it
    "cloud": _cloud,  # the full-point-cloud benchmark (lpc_core.perception.cloud)
}


class InputError(Exception):
    """A frame or an intrinsics file that cannot be used; the message says which and why."""


@dataclass(frozen=True)
class Frame:
    name: str
    seq: int
    t_ns: int
    depth: np.ndarray
    intrinsics: Intrinsics


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("frames", nargs="*", metavar="FRAME.png", help="16-bit depth PNG frames")
    parser.add_argument(
        "--intrinsics", metavar="INTR.json", help="depth intrinsics (pyrealsense2 names)"
    )
    parser.add_argument(
        "--method", choices=sorted(METHODS), default="laser", help="reconstruction method"
    )
    parser.add_argument(
        "--mcap", metavar="FILE", help=f"read the frames from a recording's {DEPTH_TOPIC} topic"
    )


def read_intrinsics(path: str) -> Intrinsics:
    """Intrinsics from a JSON file with pyrealsense2's field names."""
    try:
        data = json.loads(Path(path).read_text())
    except OSError as exc:
        raise InputError(f"cannot read intrinsics {path}: {exc.strerror or exc}") from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"intrinsics {path} is not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise InputError(f"intrinsics {path} must hold a JSON object")
    missing = [k for k in ("width", "height", "fx", "fy", "ppx", "ppy") if k not in data]
    if missing:
        raise InputError(f"intrinsics {path} lacks {', '.join(missing)}")
    try:
        return Intrinsics(
            width=int(data["width"]),
            height=int(data["height"]),
            fx=float(data["fx"]),
            fy=float(data["fy"]),
            ppx=float(data["ppx"]),
            ppy=float(data["ppy"]),
            model=str(data.get("model", "brown_conrady")),
            coeffs=tuple(float(c) for c in data.get("coeffs", (0.0,) * 5)),
            depth_scale=float(data.get("depth_scale", 0.001)),
        )
    except (TypeError, ValueError) as exc:
        raise InputError(f"intrinsics {path}: {exc}") from exc


def read_depth_png(path: str, intrinsics: Intrinsics) -> np.ndarray:
    """A 16-bit single-channel PNG as a (height, width) uint16 array."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            mode, size = image.mode, image.size
            if mode not in ("I;16", "I;16B", "I;16L", "I"):
                raise InputError(f"{path} is a {mode} image, expected a 16-bit depth PNG")
            depth = np.array(image)
    except FileNotFoundError as exc:
        raise InputError(f"{path}: no such file") from exc
    except UnidentifiedImageError as exc:
        raise InputError(f"{path} is not an image Pillow can read") from exc
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc}") from exc
    if mode == "I" and (depth.min() < 0 or depth.max() > np.iinfo(np.uint16).max):
        raise InputError(f"{path} holds values outside 0-65535")
    expected = (intrinsics.width, intrinsics.height)
    if size != expected:
        raise InputError(
            f"{path} is {size[0]}x{size[1]}, the intrinsics say {expected[0]}x{expected[1]}"
        )
    return depth.astype(np.uint16, copy=False)


def png_frames(paths: list[str], intrinsics: Intrinsics) -> Iterator[Frame]:
    for seq, path in enumerate(paths):
        yield Frame(path, seq, seq * FRAME_PERIOD_NS, read_depth_png(path, intrinsics), intrinsics)


def mcap_frames(path: str, intrinsics: Intrinsics | None) -> Iterator[Frame]:
    from lpc_core.perception.pipeline import depth_image, intrinsics_from_message
    from services.mcap_log import McapLog, McapLogError

    try:
        log = McapLog(path)
    except McapLogError as exc:
        raise InputError(str(exc)) from exc
    found = 0
    with log:
        for logged in log.messages([DEPTH_TOPIC], decode=True):
            frame = logged.message
            if frame is None:
                print(f"lpc reconstruct: skipped a depth message: {logged.error}", file=sys.stderr)
                continue
            try:
                depth = depth_image(frame)
                own = intrinsics_from_message(frame.intrinsics)
            except ValueError as exc:
                print(f"lpc reconstruct: skipped frame {frame.seq}: {exc}", file=sys.stderr)
                continue
            found += 1
            yield Frame(f"{path}:{frame.seq}", frame.seq, frame.t_ns, depth, intrinsics or own)
        if log.cut is not None:
            print(f"lpc reconstruct: {path} is cut short: {log.cut.reason}", file=sys.stderr)
    if found == 0:
        raise InputError(f"{path} holds no usable {DEPTH_TOPIC} messages")


def _round(value: float | None, digits: int) -> float | None:
    return None if value is None or not math.isfinite(value) else round(value, digits)


def frame_record(
    frame: Frame, result: Reconstruction, compute_ms: float, window: WindowResult
) -> dict[str, object]:
    """The JSON object printed for one frame."""
    record: dict[str, object] = {
        "frame": frame.name,
        "shape": result.shape,
        "grasp_width_mm": _round(result.grasp_width_mm, 2),
        "wrist_angle_deg": _round(result.wrist_angle_deg, 2),
        "points": result.points,
        "compute_ms": round(compute_ms, 3),
        "window": {
            "shape": window.shape,
            "grasp_width_mm": _round(window.grasp_width_mm, 2),
            "wrist_angle_deg": _round(window.wrist_angle_deg, 2),
            "reconstructed": window.reconstructed,
        },
    }
    if result.reason:
        record["reason"] = result.reason
    return record


def _warm_up(method: Method) -> None:
    """Run the method once on a synthetic frame, untimed: the first frame's ``compute_ms`` is
    then the method's, not the imports' and first calls' (recordings/depth.mcap: the first frame
    102 ms, the next 2.4 ms; warmed, 5.8 ms on a loaded machine), as the service's workers do
    before they take frames."""
    from lpc_core.perception.pipeline import depth_image, intrinsics_from_message
    from lpc_core.perception.reconstructor import warmup_frame

    frame = warmup_frame()
    method(depth_image(frame), intrinsics_from_message(frame.intrinsics), 0)


def run(args: argparse.Namespace) -> int:
    def fail(message: str) -> int:
        print(f"lpc reconstruct: error: {message}", file=sys.stderr)
        return 2

    if args.mcap and args.frames:
        return fail("give PNG frames or --mcap, not both")
    if not args.mcap and not args.frames:
        return fail("no frames: give FRAME.png files, or --mcap FILE")
    if args.frames and not args.intrinsics:
        return fail("PNG frames need --intrinsics INTR.json")
    method = METHODS[args.method]
    state = WindowState()
    _warm_up(method)
    try:
        intrinsics = read_intrinsics(args.intrinsics) if args.intrinsics else None
        if args.mcap:
            frames = mcap_frames(args.mcap, intrinsics)
        else:
            assert intrinsics is not None
            frames = png_frames(args.frames, intrinsics)
        for frame in frames:
            start = time.perf_counter()
            try:
                result = method(frame.depth, frame.intrinsics, frame.seq)
            except ValueError as exc:
                raise InputError(f"{frame.name}: {exc}") from exc
            compute_ms = 1000.0 * (time.perf_counter() - start)
            state, window = window_step(state, result, frame.seq, frame.t_ns)
            print(json.dumps(frame_record(frame, result, compute_ms, window)), flush=True)
    except InputError as exc:
        return fail(str(exc))
    except BrokenPipeError:
        return 0
    return 0
