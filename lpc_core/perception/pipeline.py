"""Message-level step functions: decoded message in, messages out, no I/O and no clock.

Services call these live; ``lpc replay`` calls the same functions in-process on a recording.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from lpc_core.perception.intrinsics import Intrinsics
from lpc_core.perception.scans import ScanLines as CoreScanLines
from lpc_core.perception.scans import ScanParams, cut_scan_lines
from schemas import (
    CameraIntrinsics,
    DepthFrame,
    ScanLine,
    ScanLines,
    from_wire,
    to_wire_rows,
)


def intrinsics_from_message(message: CameraIntrinsics) -> Intrinsics:
    return Intrinsics(
        width=message.width,
        height=message.height,
        fx=message.fx,
        fy=message.fy,
        ppx=message.ppx,
        ppy=message.ppy,
        model=message.model,
        coeffs=tuple(message.coeffs),
        depth_scale=message.depth_scale,
    )


def intrinsics_to_message(intrinsics: Intrinsics) -> CameraIntrinsics:
    return CameraIntrinsics(
        width=intrinsics.width,
        height=intrinsics.height,
        fx=intrinsics.fx,
        fy=intrinsics.fy,
        ppx=intrinsics.ppx,
        ppy=intrinsics.ppy,
        model=intrinsics.model,
        coeffs=list(intrinsics.coeffs),
        depth_scale=intrinsics.depth_scale,
    )


def depth_image(frame: DepthFrame) -> np.ndarray:
    """The frame's depth as a (height, width) uint16 array; ``ValueError`` if it does not fit."""
    depth = from_wire(frame.depth)
    expected = (frame.intrinsics.height, frame.intrinsics.width)
    if depth.dtype != np.uint16 or depth.shape != expected:
        raise ValueError(
            f"depth is {depth.dtype} {depth.shape}, expected uint16 {expected} from the intrinsics"
        )
    return depth


@dataclass
class ScansState:
    """The scans service's state: its parameters and the intrinsics it last saw."""

    params: ScanParams = field(default_factory=ScanParams)
    seq: int = 0
    # The intrinsics message last seen and its Intrinsics: a camera sends the same ones with
    # every frame, and building (validating) them cost as much as a tenth of the cut's numpy.
    intrinsics: tuple[CameraIntrinsics, Intrinsics] | None = None


def _past_ends(lines: CoreScanLines) -> list[list[float] | None]:
    if lines.past_ends_m is None:
        return [None] * len(lines.points)
    return lines.past_ends_m.tolist()


def _far_past(lines: CoreScanLines) -> list[list[float] | None]:
    if lines.far_past_m is None:
        return [None] * len(lines.points)
    return lines.far_past_m.reshape(len(lines.points), 6).tolist()


def _edge_past(lines: CoreScanLines) -> list[list[float] | None]:
    if lines.edge_past_m is None:
        return [None] * len(lines.points)
    return lines.edge_past_m.reshape(len(lines.points), 6).tolist()


def scans_step(state: ScansState, frame: DepthFrame, now_ns: int) -> tuple[ScansState, ScanLines]:
    """Cut the four scan lines of one depth frame. ``t_ns`` stays the frame's capture time."""
    del now_ns  # capture time, not processing time, travels with the scans
    depth = depth_image(frame)
    seen = state.intrinsics
    if seen is None or seen[0] != frame.intrinsics:
        # Equal messages give equal Intrinsics (and a bad one raises here, never cached).
        seen = state.intrinsics = (frame.intrinsics, intrinsics_from_message(frame.intrinsics))
    lines = cut_scan_lines(depth, seen[1], state.params)
    state.seq += 1
    # Every line's points cast to float32 and packed in one go (the same values and bytes as
    # a cast and a to_wire per line): seven of numpy's calls fewer a frame.
    wire = to_wire_rows(
        np.concatenate(lines.points, dtype=np.float32, casting="same_kind"),
        [0, *itertools.accumulate(len(points) for points in lines.points)],
    )
    message = ScanLines(
        seq=state.seq,
        t_ns=frame.t_ns,
        frame_seq=frame.seq,
        lines=[
            ScanLine(
                angle_deg=angle,
                points=points,
                past_ends_m=past,
                far_past_m=far,
                edge_past_m=edge,
            )
            # The angles in degrees in one call (the same ufunc loop as four scalar calls).
            for angle, points, past, far, edge in zip(
                np.degrees(lines.angles_rad).tolist(),
                wire,
                _past_ends(lines),
                _far_past(lines),
                _edge_past(lines),
                strict=True,
            )
        ],
        capture_points=lines.capture_count,
        truth=frame.truth,
    )
    return state, message
