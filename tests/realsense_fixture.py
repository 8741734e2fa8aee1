"""Write a short RealSense recording of synthetic depth frames, with no camera attached.

pyrealsense2's ``software_device`` stands in for the camera: one depth sensor with one Z16 video
stream, the depth units option set (a depth sensor without it has no depth scale), and a
``recorder`` that writes what the sensor produces. pyrealsense2 2.59 writes ROS 2 ``.db3`` and
refuses any other extension; earlier versions write ROS 1 ``.bag``.

    python -m tests.realsense_fixture out.db3 --frames 90

writes 90 frames of the simulated scene (``lpc_core.sim.simcam``) at 90 fps, readable with
``lpc camera --source realsense --file out.db3`` or ``RealSenseSource("out.db3")``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lpc_core.perception.intrinsics import D435_424X240, Intrinsics
from lpc_core.sim.simcam import SimCamera
from services.drivers.depth import feed_depth_frame, software_depth_sensor


def recording_suffix() -> str:
    """The file extension this pyrealsense2's recorder writes (``.db3`` from 2.59 on)."""
    import pyrealsense2 as rs

    major, minor = (int(part) for part in rs.__version__.split(".")[:2])
    return ".db3" if (major, minor) >= (2, 59) else ".bag"


def simulated_frames(
    count: int, intrinsics: Intrinsics = D435_424X240, fps: float = 90.0, seed: int = 0
) -> list[np.ndarray]:
    """``count`` depth images of the simulated scene, one every ``1/fps`` seconds."""
    camera = SimCamera(seed=seed, intrinsics=intrinsics)
    return [camera.frame(seq / fps, seq)[0] for seq in range(count)]


def plane_frames(
    count: int, intrinsics: Intrinsics = D435_424X240, seed: int = 0
) -> list[np.ndarray]:
    """``count`` depth images of a tilted plane 200 mm away, moving 1 mm closer per frame,
    with seeded holes (0) and saturated pixels (65535): cheap, and every value is checkable."""
    u = np.arange(intrinsics.width) - intrinsics.ppx
    v = np.arange(intrinsics.height)[:, None] - intrinsics.ppy
    frames = []
    for seq in range(count):
        rng = np.random.default_rng([seed, seq])
        z_m = 0.200 - 0.001 * seq + 0.0002 * u + 0.0001 * v
        depth = np.round(z_m / intrinsics.depth_scale).astype(np.uint16)
        depth[rng.random(depth.shape) < 0.02] = 0
        depth[rng.random(depth.shape) < 0.001] = 65535
        frames.append(depth)
    return frames


def write_recording(
    path: str | Path,
    frames: Sequence[np.ndarray],
    intrinsics: Intrinsics = D435_424X240,
    fps: int = 90,
) -> Path:
    """Record ``frames`` (uint16, ``(height, width)`` of ``intrinsics``) as a depth stream at
    ``fps``; frame ``i`` has frame number ``i`` and timestamp ``i * 1000 / fps`` ms."""
    import pyrealsense2 as rs

    shape = (intrinsics.height, intrinsics.width)
    for i, frame in enumerate(frames):
        if frame.dtype != np.uint16 or frame.shape != shape:
            raise ValueError(f"frames[{i}] is {frame.dtype} {frame.shape}, expected uint16 {shape}")
    path = Path(path)
    device, sensor, profile = software_depth_sensor(rs, intrinsics, fps)

    recorder = rs.recorder(str(path), device)
    sensor.open(profile)
    sensor.start(lambda frame: None)  # the recorder sees every frame; nobody else needs them
    for i, depth in enumerate(frames):
        feed_depth_frame(rs, sensor, profile, intrinsics, depth, i, fps)
    sensor.stop()
    sensor.close()
    del recorder  # the file is complete once the recorder is destroyed
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("path", help=f"output file ({recording_suffix()} for this pyrealsense2)")
    parser.add_argument("--frames", type=int, default=10, help="number of frames (default 10)")
    parser.add_argument("--fps", type=int, default=90, help="frame rate (default 90)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated scene")
    args = parser.parse_args(argv)
    frames = simulated_frames(args.frames, fps=args.fps, seed=args.seed)
    path = write_recording(args.path, frames, fps=args.fps)
    print(f"wrote {len(frames)} frames to {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
