"""lpc messages re-logged in Foxglove's well-known schemas, for the live bridge and the export.

Foxglove does not decode msgpack, so every bus message becomes one or more JSON messages
(message encoding ``json``, schema encoding ``jsonschema``), each a :class:`Output`:

=======================  ============================  ==========================================
lpc key                  Foxglove topic                schema
=======================  ============================  ==========================================
lpc/camera/depth         /lpc/camera/depth             foxglove.RawImage, ``16UC1``
                         /lpc/camera/calibration       foxglove.CameraCalibration
                         /tf                           foxglove.FrameTransforms (world -> camera)
lpc/scans                /lpc/scans                    foxglove.PointCloud (x, y, z, angle_deg)
                         /lpc/scans/info               lpc.ScanInfo (points per line)
lpc/reconstruction       /lpc/reconstruction/scene     foxglove.SceneUpdate: the solid, its
                                                       principal axis, the 2-D model of each scan
                                                       line drawn in its plane, a label
                         /lpc/reconstruction           lpc.Reconstruction (plottable)
lpc/aim/cue              /lpc/aim/scene                foxglove.SceneUpdate: cue arrow, tactors
                         /lpc/aim/cue                  lpc.AimCue (plottable)
lpc/log/<service>        /lpc/log                      foxglove.Log
any other key            /<key>                        lpc.<Type> (plottable)
=======================  ============================  ==========================================

Times are ``{sec, nsec}`` from the message's ``t_ns``. Geometry is in the camera frame
(``camera``: x right, y down, z forward, metres); ``/tf`` places it under ``world`` (x forward,
y left, z up) so the 3-D panel's default view is upright. Payloads are plain dicts; ``bytes``
values (image and point data) are left for the JSON encoder to write as base64, which the
schemas declare with ``contentEncoding``.

Pure: no I/O, no clock. A message that cannot be shown (wrong dtype or shape) raises
``ValueError`` naming the field; the bridge counts it and carries on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from schemas import (
    AimCue,
    DepthFrame,
    Log,
    Message,
    Reconstruction,
    ScanLines,
    from_wire,
    json_schema,
)

CAMERA_FRAME = "camera"
WORLD_FRAME = "world"
# Where fitted 2-D lines are drawn: the scan plane inside the capture volume (x, y within
# +-50 mm), and depths the D435 reports at 424x240 (it sees from about 10 cm).
CAPTURE_HALF_WIDTH_M = 0.05
DRAW_DEPTH_M = (0.10, 0.35)
# The reconstruction gives no length along the principal axis: solids are drawn this long.
SOLID_LENGTH_M = 0.10
CURVE_SEGMENTS = 64
AIM_DEPTH_M = 0.20  # the aim cue is drawn in the plane z = 20 cm, mid capture volume
TACTOR_RING_M = 0.06

LOG_LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4}
FLOAT32 = 7  # foxglove.PackedElementFieldNumericType.FLOAT32
LINE_STRIP, LINE_LOOP = 0, 1  # foxglove.LinePrimitiveLineType

SHAPE_COLORS = {
    "sphere": (0.20, 0.60, 1.00, 0.45),
    "cylinder": (0.20, 0.85, 0.35, 0.45),
    "cuboid": (1.00, 0.60, 0.15, 0.45),
}
MODEL_COLORS = {
    "line": (1.00, 0.90, 0.20, 1.0),
    "circle": (0.20, 0.90, 1.00, 1.0),
    "ellipse": (1.00, 0.35, 0.90, 1.0),
}
AXIS_COLOR = (1.0, 0.2, 0.2, 1.0)
TEXT_COLOR = (1.0, 1.0, 1.0, 1.0)
AIM_COLORS = {
    "nothing": (0.5, 0.5, 0.5, 1.0),
    "guiding": (1.0, 0.8, 0.1, 1.0),
    "on_target": (0.2, 0.9, 0.3, 1.0),
    "ready": (0.2, 0.6, 1.0, 1.0),
}


@dataclass(frozen=True)
class Output:
    """One Foxglove message: its topic, schema name (a key of ``schema_for``) and payload."""

    topic: str
    schema: str
    payload: dict[str, Any]


# --------------------------------------------------------------------------- conversion


def convert(key: str, message: Message) -> list[Output]:
    """The Foxglove messages that show one lpc message received on ``key``."""
    match message:
        case DepthFrame():
            return [
                Output(f"/{key}", "foxglove.RawImage", depth_image(message)),
                Output(
                    "/lpc/camera/calibration", "foxglove.CameraCalibration", calibration(message)
                ),
                Output("/tf", "foxglove.FrameTransforms", camera_transform(message.t_ns)),
            ]
        case ScanLines():
            return [
                Output(f"/{key}", "foxglove.PointCloud", scan_cloud(message)),
                Output(f"/{key}/info", "lpc.ScanInfo", scan_info(message)),
            ]
        case Reconstruction():
            return [
                Output(f"/{key}/scene", "foxglove.SceneUpdate", reconstruction_scene(message)),
                Output(f"/{key}", "lpc.Reconstruction", plain(message)),
            ]
        case AimCue():
            return [
                Output("/lpc/aim/scene", "foxglove.SceneUpdate", aim_scene(message)),
                Output(f"/{key}", "lpc.AimCue", plain(message)),
            ]
        case Log():
            return [Output("/lpc/log", "foxglove.Log", log_entry(message))]
        case _:
            return [Output(f"/{key}", f"lpc.{type(message).__name__}", plain(message))]


def timestamp(t_ns: int) -> dict[str, int]:
    """``{sec, nsec}`` of an int64 nanosecond time."""
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def plain(message: Message) -> dict[str, Any]:
    """A message as plottable JSON: its fields, with ``timestamp`` first."""
    fields = msgspec.to_builtins(message)
    if not isinstance(fields, dict):
        raise ValueError(f"message {type(message).__name__} is not a struct")
    return {"timestamp": timestamp(message.t_ns), **fields}


def depth_image(frame: DepthFrame) -> dict[str, Any]:
    """foxglove.RawImage ``16UC1``: the Z16 bytes as they are (little-endian, 1 unit = 1 mm)."""
    depth = frame.depth
    if depth.dtype != "<u2" or len(depth.shape) != 2:
        raise ValueError(f"depth must be uint16 (H, W), got {depth.dtype} {tuple(depth.shape)}")
    height, width = depth.shape
    if len(depth.data) != 2 * width * height:
        raise ValueError(f"depth holds {len(depth.data)} bytes, expected {2 * width * height}")
    return {
        "timestamp": timestamp(frame.t_ns),
        "frame_id": CAMERA_FRAME,
        "width": width,
        "height": height,
        "encoding": "16UC1",
        "step": 2 * width,
        "data": depth.data,
    }


def calibration(frame: DepthFrame) -> dict[str, Any]:
    """foxglove.CameraCalibration from the frame's intrinsics, so panels can project 3-D on it."""
    k = frame.intrinsics
    # librealsense's Brown-Conrady coefficients are (k1, k2, p1, p2, k3): ROS's plumb_bob order.
    coeffs = list(k.coeffs) if len(k.coeffs) == 5 else [0.0] * 5
    return {
        "timestamp": timestamp(frame.t_ns),
        "frame_id": CAMERA_FRAME,
        "width": k.width,
        "height": k.height,
        "distortion_model": "plumb_bob",
        "D": coeffs,
        "K": [k.fx, 0.0, k.ppx, 0.0, k.fy, k.ppy, 0.0, 0.0, 1.0],
        "R": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "P": [k.fx, 0.0, k.ppx, 0.0, 0.0, k.fy, k.ppy, 0.0, 0.0, 0.0, 1.0, 0.0],
    }


# Camera axes (x right, y down, z forward) in the world frame (x forward, y left, z up).
_CAMERA_IN_WORLD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def camera_transform(t_ns: int) -> dict[str, Any]:
    """foxglove.FrameTransforms: ``world`` -> ``camera``, a pure rotation."""
    return {
        "transforms": [
            {
                "timestamp": timestamp(t_ns),
                "parent_frame_id": WORLD_FRAME,
                "child_frame_id": CAMERA_FRAME,
                "translation": _vec((0.0, 0.0, 0.0)),
                "rotation": quaternion_from_matrix(_CAMERA_IN_WORLD),
            }
        ]
    }


def scan_cloud(scans: ScanLines) -> dict[str, Any]:
    """foxglove.PointCloud of the four scan lines, float32 x, y, z and the line's angle."""
    blocks = []
    for i, line in enumerate(scans.lines):
        points = from_wire(line.points)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"lines[{i}].points must be (N, 3), got {points.shape}")
        block = np.empty((points.shape[0], 4), np.float32)
        block[:, :3] = points
        block[:, 3] = line.angle_deg
        blocks.append(block)
    cloud = np.concatenate(blocks) if blocks else np.empty((0, 4), np.float32)
    return {
        "timestamp": timestamp(scans.t_ns),
        "frame_id": CAMERA_FRAME,
        "pose": _pose((0.0, 0.0, 0.0)),
        "point_stride": 16,
        "fields": [
            {"name": name, "offset": 4 * i, "type": FLOAT32}
            for i, name in enumerate(("x", "y", "z", "angle_deg"))
        ],
        "data": cloud.astype("<f4", copy=False).tobytes(),
    }


def scan_info(scans: ScanLines) -> dict[str, Any]:
    """lpc.ScanInfo: how many points each scan line kept, for plots."""
    return {
        "timestamp": timestamp(scans.t_ns),
        "seq": scans.seq,
        "frame_seq": scans.frame_seq,
        "capture_points": scans.capture_points,
        "angles_deg": [line.angle_deg for line in scans.lines],
        "points_per_line": [
            int(line.points.shape[0]) if line.points.shape else 0 for line in scans.lines
        ],
    }


def reconstruction_scene(rec: Reconstruction) -> dict[str, Any]:
    """foxglove.SceneUpdate: entity ``solid`` (shape, axis, label) and ``models`` (2-D fits).

    Fixed entity ids, so each update replaces the last; an empty entity clears it.
    """
    stamp = timestamp(rec.t_ns)
    solid = _entity("solid", stamp)
    width = None if rec.grasp_width_mm is None else rec.grasp_width_mm / 1000.0
    center = None if rec.center_m is None else np.asarray(rec.center_m, float)
    axis = _unit_or_none(rec.axis)
    color = _color(SHAPE_COLORS.get(rec.shape, TEXT_COLOR))
    if center is not None and width is not None and width > 0:
        if rec.shape == "sphere":
            solid["spheres"].append(
                {"pose": _pose(center), "size": _vec((width, width, width)), "color": color}
            )
        elif rec.shape == "cylinder" and axis is not None:
            solid["cylinders"].append(
                {
                    "pose": _pose(center, _rotation_to(np.array([0.0, 0.0, 1.0]), axis)),
                    "size": _vec((width, width, SOLID_LENGTH_M)),
                    "bottom_scale": 1.0,
                    "top_scale": 1.0,
                    "color": color,
                }
            )
        elif rec.shape == "cuboid" and axis is not None:
            # center_m is the pierced face's centre: push the box back by half its depth.
            ray = center / (np.linalg.norm(center) or 1.0)
            rotation = _frame_from_axis(axis, ray)
            solid["cubes"].append(
                {
                    "pose": _pose(
                        center + rotation[:, 2] * width / 2, quaternion_from_matrix(rotation)
                    ),
                    "size": _vec((SOLID_LENGTH_M, width, width)),
                    "color": color,
                }
            )
    if center is not None and axis is not None:
        solid["arrows"].append(
            _arrow(center - axis * SOLID_LENGTH_M * 0.6, axis, 1.2 * SOLID_LENGTH_M, AXIS_COLOR)
        )
    solid["texts"].append(
        {
            "pose": _pose(center if center is not None else (0.0, 0.0, DRAW_DEPTH_M[0])),
            "billboard": True,
            "font_size": 14.0,
            "scale_invariant": True,
            "color": _color(TEXT_COLOR),
            "text": _label(rec),
        }
    )
    models = _entity("models", stamp)
    for line in rec.lines:
        curve = model_curve(line.model, line.params, line.angle_deg)
        if curve is None:
            continue
        points, closed = curve
        models["lines"].append(
            {
                "type": LINE_LOOP if closed else LINE_STRIP,
                "pose": _pose((0.0, 0.0, 0.0)),
                "thickness": 2.0,
                "scale_invariant": True,
                "points": [_vec(p) for p in points],
                "color": _color(MODEL_COLORS[line.model]),
                "colors": [],
                "indices": [],
            }
        )
    return {"deletions": [], "entities": [solid, models]}


def model_curve(
    model: str, params: list[float] | tuple[float, ...], angle_deg: float
) -> tuple[np.ndarray, bool] | None:
    """A fitted 2-D model as 3-D points ``(M, 3)`` in its scan plane, and whether it is closed.

    ``params`` are ``lpc_core.perception.fit``'s, in the plane's coordinates ``(s, z)`` with
    ``s = x cos(phi) + y sin(phi)``: line ``(s0, z0, ds, dz)``, circle ``(cs, cz, r)``, ellipse
    ``(cs, cz, a, b, theta)``. A line is cut to the capture volume; ``None`` when there is
    nothing to draw (no model, wrong parameter count, a line that misses the volume).
    """
    phi = math.radians(angle_deg)
    direction = np.array([math.cos(phi), math.sin(phi)])
    p = [float(v) for v in params]
    t = np.linspace(0.0, 2.0 * math.pi, CURVE_SEGMENTS, endpoint=False)
    if model == "line" and len(p) == 4:
        s_max = CAPTURE_HALF_WIDTH_M / max(abs(direction[0]), abs(direction[1]))
        span = _clip_line((p[0], p[1]), (p[2], p[3]), (-s_max, s_max), DRAW_DEPTH_M)
        if span is None:
            return None
        ts = np.array(span)
        s, z = p[0] + ts * p[2], p[1] + ts * p[3]
        closed = False
    elif model == "circle" and len(p) == 3:
        s, z = p[0] + p[2] * np.cos(t), p[1] + p[2] * np.sin(t)
        closed = True
    elif model == "ellipse" and len(p) == 5:
        cs, cz, a, b, theta = p
        u, v = a * np.cos(t), b * np.sin(t)
        s = cs + u * math.cos(theta) - v * math.sin(theta)
        z = cz + u * math.sin(theta) + v * math.cos(theta)
        closed = True
    else:
        return None
    points = np.column_stack([s * direction[0], s * direction[1], z])
    if not np.isfinite(points).all():
        return None
    return points, closed


def aim_scene(cue: AimCue) -> dict[str, Any]:
    """foxglove.SceneUpdate ``aim``: an arrow from the optical axis toward the target, as long as
    the distance to the hull (``rho`` x 50 mm), and the four tactors sized by amplitude."""
    stamp = timestamp(cue.t_ns)
    aim = _entity("aim", stamp)
    color = AIM_COLORS.get(cue.state, TEXT_COLOR)
    origin = np.array([0.0, 0.0, AIM_DEPTH_M])
    theta = math.radians(cue.theta_deg)
    if cue.state == "guiding" and cue.rho > 0:
        direction = np.array([math.cos(theta), math.sin(theta), 0.0])
        aim["arrows"].append(_arrow(origin, direction, cue.rho * CAPTURE_HALF_WIDTH_M, color))
    else:
        aim["spheres"].append(
            {"pose": _pose(origin), "size": _vec((0.008, 0.008, 0.008)), "color": _color(color)}
        )
    for i, amplitude in enumerate(cue.amplitudes):
        # Tactors at 0, 90, 180, 270 degrees in the image plane (x right, y down).
        angle = math.radians(90.0 * i)
        position = origin + TACTOR_RING_M * np.array([math.cos(angle), math.sin(angle), 0.0])
        size = 0.004 + 0.012 * float(amplitude)
        aim["spheres"].append(
            {
                "pose": _pose(position),
                "size": _vec((size, size, size)),
                "color": _color((1.0, 0.3 + 0.7 * (1.0 - amplitude), 0.2, 0.4 + 0.6 * amplitude)),
            }
        )
    return {"deletions": [], "entities": [aim]}


def log_entry(log: Log) -> dict[str, Any]:
    """foxglove.Log from an lpc log line."""
    return {
        "timestamp": timestamp(log.t_ns),
        "level": LOG_LEVELS.get(log.level, 0),
        "message": log.text,
        "name": log.service,
        "file": "",
        "line": 0,
    }


# --------------------------------------------------------------------------- geometry helpers


def quaternion_from_matrix(rotation: np.ndarray) -> dict[str, float]:
    """``{x, y, z, w}`` of a proper rotation matrix (Shepperd's method, stable for any angle)."""
    r = np.asarray(rotation, float)
    trace = float(np.trace(r))
    diagonal = np.diag(r)
    i = int(np.argmax(diagonal))
    if trace >= diagonal[i]:
        w = math.sqrt(1.0 + trace) / 2.0
        x, y, z = (
            (r[2, 1] - r[1, 2]) / (4 * w),
            (r[0, 2] - r[2, 0]) / (4 * w),
            (r[1, 0] - r[0, 1]) / (4 * w),
        )
    else:
        j, k = (i + 1) % 3, (i + 2) % 3
        q = np.empty(3)
        q[i] = math.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k]) / 2.0
        q[j] = (r[j, i] + r[i, j]) / (4 * q[i])
        q[k] = (r[k, i] + r[i, k]) / (4 * q[i])
        w = (r[k, j] - r[j, k]) / (4 * q[i])
        x, y, z = q
    return {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}


def _rotation_to(source: np.ndarray, target: np.ndarray) -> dict[str, float]:
    """The shortest rotation taking unit ``source`` onto unit ``target``, as a quaternion."""
    cross = np.cross(source, target)
    w = 1.0 + float(source @ target)
    if w < 1e-9:  # opposite: half a turn about any axis orthogonal to source
        other = np.array([1.0, 0.0, 0.0]) if abs(source[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        cross, w = np.cross(source, other), 0.0
    q = np.array([*cross, w])
    q /= np.linalg.norm(q)
    return {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}


def _frame_from_axis(axis: np.ndarray, toward: np.ndarray) -> np.ndarray:
    """Rotation whose x is ``axis`` and whose z is ``toward`` made orthogonal to it."""
    z = toward - axis * float(axis @ toward)
    if np.linalg.norm(z) < 1e-9:
        z = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    z = z / np.linalg.norm(z)
    return np.column_stack([axis, np.cross(z, axis), z])


def _unit_or_none(vector: list[float] | None) -> np.ndarray | None:
    if vector is None or len(vector) != 3:
        return None
    v = np.asarray(vector, float)
    norm = float(np.linalg.norm(v))
    return v / norm if norm > 1e-12 else None


def _clip_line(
    origin: tuple[float, float],
    direction: tuple[float, float],
    s_range: tuple[float, float],
    z_range: tuple[float, float],
) -> tuple[float, float] | None:
    """Parameter interval of ``origin + t * direction`` inside the box (Liang-Barsky)."""
    lo, hi = -math.inf, math.inf
    for p0, d, (a, b) in ((origin[0], direction[0], s_range), (origin[1], direction[1], z_range)):
        if abs(d) < 1e-12:
            if not a <= p0 <= b:
                return None
            continue
        t0, t1 = sorted(((a - p0) / d, (b - p0) / d))
        lo, hi = max(lo, t0), min(hi, t1)
    if not lo < hi or math.isinf(lo) or math.isinf(hi):
        return None
    return lo, hi


def _arrow(tail: np.ndarray, direction: np.ndarray, length: float, color: tuple) -> dict:
    head = min(0.3 * length, 0.015)
    return {
        "pose": _pose(tail, _rotation_to(np.array([1.0, 0.0, 0.0]), direction)),
        "shaft_length": max(length - head, 0.0),
        "shaft_diameter": 0.002,
        "head_length": head,
        "head_diameter": 0.006,
        "color": _color(color),
    }


def _entity(entity_id: str, stamp: dict[str, int]) -> dict[str, Any]:
    return {
        "timestamp": stamp,
        "frame_id": CAMERA_FRAME,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [],
        "arrows": [],
        "cubes": [],
        "spheres": [],
        "cylinders": [],
        "lines": [],
        "triangles": [],
        "texts": [],
        "models": [],
    }


def _label(rec: Reconstruction) -> str:
    if rec.shape == "none":
        return f"no object: {rec.reason}" if rec.reason else "no object"
    text = rec.shape
    if rec.grasp_width_mm is not None:
        text += f" {rec.grasp_width_mm:.1f} mm"
    if rec.wrist_angle_deg is not None:
        text += f" {rec.wrist_angle_deg:+.1f} deg"
    if rec.truth is not None:
        text += f" (truth {rec.truth.shape} {rec.truth.grasp_width_mm:.1f} mm)"
    return text


def _vec(v: Any) -> dict[str, float]:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def _pose(position: Any, orientation: dict[str, float] | None = None) -> dict[str, Any]:
    return {
        "position": _vec(position),
        "orientation": orientation or {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
    }


def _color(rgba: tuple[float, ...]) -> dict[str, float]:
    return {"r": rgba[0], "g": rgba[1], "b": rgba[2], "a": rgba[3]}


# --------------------------------------------------------------------------- JSON schemas
# Written for the fields above, in Foxglove's JSON conventions: time and duration {sec, nsec},
# enums as integers, bytes as base64 strings. Foxglove picks the renderer by schema name.


def _obj(title: str, **properties: dict[str, Any]) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": properties}


def _arr(items: dict[str, Any]) -> dict[str, Any]:
    return {"type": "array", "items": items}


_NUM: dict[str, Any] = {"type": "number"}
_INT: dict[str, Any] = {"type": "integer"}
_STR: dict[str, Any] = {"type": "string"}
_BOOL: dict[str, Any] = {"type": "boolean"}
_BYTES: dict[str, Any] = {"type": "string", "contentEncoding": "base64"}
_TIME = _obj("time", sec=_INT, nsec=_INT)
_DURATION = _obj("duration", sec=_INT, nsec=_INT)
_VEC3 = _obj("foxglove.Vector3", x=_NUM, y=_NUM, z=_NUM)
_POINT3 = _obj("foxglove.Point3", x=_NUM, y=_NUM, z=_NUM)
_QUAT = _obj("foxglove.Quaternion", x=_NUM, y=_NUM, z=_NUM, w=_NUM)
_POSE = _obj("foxglove.Pose", position=_VEC3, orientation=_QUAT)
_COLOR = _obj("foxglove.Color", r=_NUM, g=_NUM, b=_NUM, a=_NUM)
_ENTITY = _obj(
    "foxglove.SceneEntity",
    timestamp=_TIME,
    frame_id=_STR,
    id=_STR,
    lifetime=_DURATION,
    frame_locked=_BOOL,
    metadata=_arr(_obj("foxglove.KeyValuePair", key=_STR, value=_STR)),
    arrows=_arr(
        _obj(
            "foxglove.ArrowPrimitive",
            pose=_POSE,
            shaft_length=_NUM,
            shaft_diameter=_NUM,
            head_length=_NUM,
            head_diameter=_NUM,
            color=_COLOR,
        )
    ),
    cubes=_arr(_obj("foxglove.CubePrimitive", pose=_POSE, size=_VEC3, color=_COLOR)),
    spheres=_arr(_obj("foxglove.SpherePrimitive", pose=_POSE, size=_VEC3, color=_COLOR)),
    cylinders=_arr(
        _obj(
            "foxglove.CylinderPrimitive",
            pose=_POSE,
            size=_VEC3,
            bottom_scale=_NUM,
            top_scale=_NUM,
            color=_COLOR,
        )
    ),
    lines=_arr(
        _obj(
            "foxglove.LinePrimitive",
            type=_INT,
            pose=_POSE,
            thickness=_NUM,
            scale_invariant=_BOOL,
            points=_arr(_POINT3),
            color=_COLOR,
            colors=_arr(_COLOR),
            indices=_arr(_INT),
        )
    ),
    triangles=_arr(
        _obj(
            "foxglove.TriangleListPrimitive",
            pose=_POSE,
            points=_arr(_POINT3),
            color=_COLOR,
            colors=_arr(_COLOR),
            indices=_arr(_INT),
        )
    ),
    texts=_arr(
        _obj(
            "foxglove.TextPrimitive",
            pose=_POSE,
            billboard=_BOOL,
            font_size=_NUM,
            scale_invariant=_BOOL,
            color=_COLOR,
            text=_STR,
        )
    ),
    models=_arr(
        _obj(
            "foxglove.ModelPrimitive",
            pose=_POSE,
            scale=_VEC3,
            color=_COLOR,
            override_color=_BOOL,
            url=_STR,
            media_type=_STR,
            data=_BYTES,
        )
    ),
)

FOXGLOVE_SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.RawImage": _obj(
        "foxglove.RawImage",
        timestamp=_TIME,
        frame_id=_STR,
        width=_INT,
        height=_INT,
        encoding=_STR,
        step=_INT,
        data=_BYTES,
    ),
    "foxglove.CameraCalibration": _obj(
        "foxglove.CameraCalibration",
        timestamp=_TIME,
        frame_id=_STR,
        width=_INT,
        height=_INT,
        distortion_model=_STR,
        D=_arr(_NUM),
        K=_arr(_NUM),
        R=_arr(_NUM),
        P=_arr(_NUM),
    ),
    "foxglove.FrameTransforms": _obj(
        "foxglove.FrameTransforms",
        transforms=_arr(
            _obj(
                "foxglove.FrameTransform",
                timestamp=_TIME,
                parent_frame_id=_STR,
                child_frame_id=_STR,
                translation=_VEC3,
                rotation=_QUAT,
            )
        ),
    ),
    "foxglove.PointCloud": _obj(
        "foxglove.PointCloud",
        timestamp=_TIME,
        frame_id=_STR,
        pose=_POSE,
        point_stride=_INT,
        fields=_arr(_obj("foxglove.PackedElementField", name=_STR, offset=_INT, type=_INT)),
        data=_BYTES,
    ),
    "foxglove.SceneUpdate": _obj(
        "foxglove.SceneUpdate",
        deletions=_arr(_obj("foxglove.SceneEntityDeletion", timestamp=_TIME, type=_INT, id=_STR)),
        entities=_arr(_ENTITY),
    ),
    "foxglove.Log": _obj(
        "foxglove.Log",
        timestamp=_TIME,
        level=_INT,
        message=_STR,
        name=_STR,
        file=_STR,
        line=_INT,
    ),
    "lpc.ScanInfo": _obj(
        "lpc.ScanInfo",
        timestamp=_TIME,
        seq=_INT,
        frame_seq=_INT,
        capture_points=_INT,
        angles_deg=_arr(_NUM),
        points_per_line=_arr(_INT),
    ),
}


def schema_for(name: str, message_type: type[Message] | None = None) -> dict[str, Any]:
    """The JSON schema of an output schema name; ``lpc.<Type>`` ones need ``message_type``.

    lpc schemas come from the message's own msgspec schema, simplified to what Foxglove's
    JSON-schema reader takes: references inlined, one type per field (``T | None`` -> ``T``),
    and the ``timestamp`` added by :func:`plain`.
    """
    fixed = FOXGLOVE_SCHEMAS.get(name)
    if fixed is not None:
        return fixed
    if message_type is None or name != f"lpc.{message_type.__name__}":
        raise ValueError(f"schema {name!r} needs its message type")
    full = json_schema(message_type)
    defs = full.get("$defs", {})
    schema = _simplify(full, defs)
    schema["title"] = name
    schema["properties"] = {"timestamp": _TIME, **schema.get("properties", {})}
    return schema


def _simplify(node: dict[str, Any], defs: dict[str, Any]) -> dict[str, Any]:
    ref = node.get("$ref")
    if ref is not None:
        return _simplify(defs[ref.rsplit("/", 1)[-1]], defs)
    options = node.get("anyOf")
    if options is not None:
        kept = [o for o in options if o.get("type") != "null"]
        return _simplify(kept[0], defs) if len(kept) == 1 else {}
    if "enum" in node:
        return {"type": "string" if all(isinstance(v, str) for v in node["enum"]) else "number"}
    kind = node.get("type")
    if kind == "object":
        properties = node.get("properties")
        if properties is None:  # a dict field: keys are data, not schema
            return {"type": "object"}
        return {
            "type": "object",
            "properties": {k: _simplify(v, defs) for k, v in properties.items()},
        }
    if kind == "array":
        return _arr(_simplify(node.get("items", {}), defs))
    if isinstance(kind, str):
        return {"type": kind}
    return {}
