"""lpc messages to Foxglove's well-known schemas: payloads decode back to the data sent."""

from __future__ import annotations

import base64
import json
import math
import re
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest

from lpc_core import foxglove_convert as fc
from schemas import (
    TOPICS,
    AimCue,
    CameraIntrinsics,
    ControllerState,
    DepthFrame,
    EmgSample,
    GraspTarget,
    Health,
    LineModel,
    Log,
    ObjectTruth,
    ProsthesisCommand,
    ProsthesisState,
    Reconstruction,
    ScanLine,
    ScanLines,
    TactorCommand,
    to_wire,
)

T_NS = 1_700_000_000_123_456_789
INTRINSICS = CameraIntrinsics(width=424, height=240, fx=213.0, fy=213.0, ppx=212.0, ppy=120.0)


def depth_frame(seed: int = 0) -> DepthFrame:
    rng = np.random.default_rng(seed)
    depth = rng.integers(0, 400, size=(240, 424), dtype=np.uint16)
    return DepthFrame(seq=seed, t_ns=T_NS, intrinsics=INTRINSICS, depth=to_wire(depth))


def scan_lines(seed: int = 0) -> ScanLines:
    rng = np.random.default_rng(seed)
    lines = []
    for angle in (0.0, 45.0, 90.0, 135.0):
        s = np.sort(rng.uniform(-0.05, 0.05, size=30 + int(angle) // 5))
        phi = math.radians(angle)
        z = 0.2 + 0.01 * rng.standard_normal(s.size)
        points = np.column_stack([s * math.cos(phi), s * math.sin(phi), z]).astype(np.float32)
        lines.append(ScanLine(angle_deg=angle, points=to_wire(points)))
    return ScanLines(seq=seed, t_ns=T_NS, frame_seq=seed, lines=lines, capture_points=500)


def reconstruction(
    shape: str = "cylinder", axis: tuple[float, ...] = (0.6, 0.8, 0.0)
) -> Reconstruction:
    return Reconstruction(
        seq=3,
        t_ns=T_NS,
        frame_seq=3,
        shape=shape,  # type: ignore[arg-type]
        grasp_width_mm=40.0,
        wrist_angle_deg=53.13,
        center_m=[0.0, 0.0, 0.22],
        axis=list(axis),
        lines=[
            LineModel(angle_deg=0.0, model="circle", params=[0.0, 0.22, 0.02]),
            LineModel(angle_deg=45.0, model="ellipse", params=[0.0, 0.22, 0.03, 0.02, 0.3]),
            LineModel(angle_deg=90.0, model="line", params=[0.0, 0.2, 0.98, 0.2]),
            LineModel(angle_deg=135.0, model="none"),
        ],
        truth=ObjectTruth(name="can", shape="cylinder", grasp_width_mm=40.0),
    )


def one_of_each() -> dict[str, Any]:
    """A message of every registered topic, keyed by a concrete key."""
    return {
        "lpc/camera/depth": depth_frame(),
        "lpc/scans": scan_lines(),
        "lpc/reconstruction": reconstruction(),
        "lpc/grasp/target": GraspTarget(
            seq=1, t_ns=T_NS, frame_seq=1, shape="sphere", grasp_width_mm=50.0, reconstructed=True
        ),
        "lpc/aim/cue": AimCue(
            seq=1,
            t_ns=T_NS,
            frame_seq=1,
            state="guiding",
            rho=0.5,
            theta_deg=90.0,
            amplitudes=[0.0, 0.5, 0.0, 0.0],
        ),
        "lpc/tactors/command": TactorCommand(seq=1, t_ns=T_NS, amplitudes=[0.0, 0.5, 0.0, 0.0]),
        "lpc/emg": EmgSample(seq=1, t_ns=T_NS, channels=[0.1, 0.7]),
        "lpc/controller/state": ControllerState(seq=1, t_ns=T_NS, state="aiming", event="trigger"),
        "lpc/prosthesis/command": ProsthesisCommand(seq=1, t_ns=T_NS, grasp=0.5, wrist=-0.25),
        "lpc/prosthesis/state": ProsthesisState(
            seq=1, t_ns=T_NS, wrist_angle_deg=10.0, aperture_mm=80.0
        ),
        "lpc/health/scans": Health(seq=1, t_ns=T_NS, service="scans", pid=1, counters={"a": 1}),
        "lpc/log/scans": Log(seq=1, t_ns=T_NS, service="scans", level="warning", text="hi"),
    }


def rotate(q: dict[str, float], v: np.ndarray) -> np.ndarray:
    u = np.array([q["x"], q["y"], q["z"]])
    w = q["w"]
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def check_against_schema(
    value: Any, schema: dict[str, Any], path: str = "", nullable: bool = False
) -> None:
    """The payload uses only declared fields, each of its declared JSON type (or null, in lpc's
    own messages, where ``T | None`` fields were simplified to ``T``)."""
    if value is None and nullable:
        return
    kind = schema.get("type")
    if kind == "object":
        assert isinstance(value, dict), path
        properties = schema.get("properties")
        if properties is not None:
            extra = set(value) - set(properties)
            assert not extra, f"{path}: fields {extra} not in schema {schema.get('title')}"
            for k, v in value.items():
                check_against_schema(v, properties[k], f"{path}.{k}", nullable)
    elif kind == "array":
        assert isinstance(value, list), path
        for i, item in enumerate(value):
            check_against_schema(item, schema["items"], f"{path}[{i}]", nullable)
    elif kind == "string":
        expected = bytes if schema.get("contentEncoding") == "base64" else str
        assert isinstance(value, expected), f"{path}: {type(value)}"
    elif kind == "integer":
        assert isinstance(value, int) and not isinstance(value, bool), path
    elif kind == "number":
        assert isinstance(value, int | float) and not isinstance(value, bool), path
    elif kind == "boolean":
        assert isinstance(value, bool), path


def test_timestamp_splits_seconds_and_nanoseconds() -> None:
    assert fc.timestamp(T_NS) == {"sec": 1_700_000_000, "nsec": 123_456_789}
    assert fc.timestamp(0) == {"sec": 0, "nsec": 0}


def test_convert_depth_is_raw_image_16uc1_with_the_same_pixels() -> None:
    frame = depth_frame(seed=4)
    outputs = {o.topic: o for o in fc.convert("lpc/camera/depth", frame)}
    image = outputs["/lpc/camera/depth"]
    assert image.schema == "foxglove.RawImage"
    p = image.payload
    assert (p["width"], p["height"], p["encoding"], p["step"]) == (424, 240, "16UC1", 848)
    assert p["timestamp"] == {"sec": 1_700_000_000, "nsec": 123_456_789}
    pixels = np.frombuffer(p["data"], "<u2").reshape(240, 424)
    np.testing.assert_array_equal(pixels, np.frombuffer(frame.depth.data, "<u2").reshape(240, 424))
    calibration = outputs["/lpc/camera/calibration"].payload
    assert calibration["K"] == [213.0, 0.0, 212.0, 0.0, 213.0, 120.0, 0.0, 0.0, 1.0]
    assert calibration["frame_id"] == p["frame_id"] == "camera"


def test_convert_depth_rejects_wrong_dtype_naming_depth() -> None:
    frame = msgspec.structs.replace(depth_frame(), depth=to_wire(np.zeros((240, 424), np.float32)))
    with pytest.raises(ValueError, match="depth"):
        fc.convert("lpc/camera/depth", frame)


def test_camera_transform_points_the_optical_axis_forward_and_y_down() -> None:
    (transform,) = fc.camera_transform(T_NS)["transforms"]
    q = transform["rotation"]
    assert (transform["parent_frame_id"], transform["child_frame_id"]) == ("world", "camera")
    np.testing.assert_allclose(rotate(q, np.array([0.0, 0.0, 1.0])), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(rotate(q, np.array([0.0, 1.0, 0.0])), [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(rotate(q, np.array([1.0, 0.0, 0.0])), [0, -1, 0], atol=1e-12)


def test_quaternion_from_matrix_round_trips_random_rotations() -> None:
    rng = np.random.default_rng(7)
    for _ in range(200):
        q, r = np.linalg.qr(rng.standard_normal((3, 3)))
        rotation = q * np.sign(np.diag(r))
        if np.linalg.det(rotation) < 0:
            rotation[:, 0] *= -1
        quat = fc.quaternion_from_matrix(rotation)
        for column in range(3):
            np.testing.assert_allclose(
                rotate(quat, np.eye(3)[column]), rotation[:, column], atol=1e-9
            )


def test_convert_scans_point_cloud_holds_every_point_and_its_line() -> None:
    scans = scan_lines(seed=2)
    outputs = {o.topic: o for o in fc.convert("lpc/scans", scans)}
    cloud = outputs["/lpc/scans"].payload
    assert outputs["/lpc/scans"].schema == "foxglove.PointCloud"
    assert cloud["point_stride"] == 16
    assert [f["name"] for f in cloud["fields"]] == ["x", "y", "z", "angle_deg"]
    data = np.frombuffer(cloud["data"], "<f4").reshape(-1, 4)
    expected = np.concatenate(
        [np.frombuffer(line.points.data, "<f4").reshape(-1, 3) for line in scans.lines]
    )
    np.testing.assert_array_equal(data[:, :3], expected)
    counts = [line.points.shape[0] for line in scans.lines]
    assert outputs["/lpc/scans/info"].payload["points_per_line"] == counts
    np.testing.assert_array_equal(data[:, 3], np.repeat([0.0, 45.0, 90.0, 135.0], counts))


@pytest.mark.parametrize("angle_deg", [0.0, 45.0, 90.0, 135.0])
def test_model_curve_circle_lies_in_its_scan_plane_at_radius(angle_deg: float) -> None:
    points, closed = fc.model_curve("circle", [0.01, 0.22, 0.02], angle_deg)
    phi = math.radians(angle_deg)
    normal = np.array([-math.sin(phi), math.cos(phi), 0.0])
    s = points[:, 0] * math.cos(phi) + points[:, 1] * math.sin(phi)
    assert closed
    np.testing.assert_allclose(points @ normal, 0.0, atol=1e-15)
    np.testing.assert_allclose(np.hypot(s - 0.01, points[:, 2] - 0.22), 0.02, atol=1e-12)


def test_model_curve_ellipse_satisfies_its_equation() -> None:
    cs, cz, a, b, theta = 0.005, 0.21, 0.03, 0.02, 0.4
    points, closed = fc.model_curve("ellipse", [cs, cz, a, b, theta], 45.0)
    s = (points[:, 0] + points[:, 1]) / math.sqrt(2.0)
    ds, dz = s - cs, points[:, 2] - cz
    u = ds * math.cos(theta) + dz * math.sin(theta)
    v = -ds * math.sin(theta) + dz * math.cos(theta)
    assert closed
    np.testing.assert_allclose((u / a) ** 2 + (v / b) ** 2, 1.0, atol=1e-12)


def test_model_curve_line_is_cut_to_the_capture_volume() -> None:
    direction = np.array([0.98, 0.2]) / np.hypot(0.98, 0.2)
    points, closed = fc.model_curve("line", [0.0, 0.2, *direction], 0.0)
    assert not closed and points.shape == (2, 3)
    np.testing.assert_allclose(np.abs(points[:, 0]), fc.CAPTURE_HALF_WIDTH_M, atol=1e-12)
    np.testing.assert_allclose(points[:, 2], 0.2 + points[:, 0] * 0.2 / 0.98, atol=1e-12)
    # Along the 45-degree line the volume's corner is farther out: |s| up to 50 mm * sqrt(2).
    diagonal, _ = fc.model_curve("line", [0.0, 0.2, 1.0, 0.0], 45.0)
    np.testing.assert_allclose(np.abs(diagonal[:, :2]), fc.CAPTURE_HALF_WIDTH_M, atol=1e-12)


def test_model_curve_draws_nothing_for_missing_or_outside_models() -> None:
    assert fc.model_curve("none", [], 0.0) is None
    assert fc.model_curve("circle", [0.0, 0.2], 0.0) is None
    assert fc.model_curve("line", [0.0, 0.9, 1.0, 0.0], 0.0) is None  # z = 0.9 m: outside


def test_reconstruction_scene_cylinder_runs_along_the_principal_axis() -> None:
    axis = np.array([0.6, 0.8, 0.0])
    update = fc.reconstruction_scene(reconstruction("cylinder", tuple(axis)))
    solid, models = update["entities"]
    (cylinder,) = solid["cylinders"]
    np.testing.assert_allclose(
        rotate(cylinder["pose"]["orientation"], np.array([0.0, 0.0, 1.0])), axis, atol=1e-12
    )
    assert cylinder["size"]["x"] == cylinder["size"]["y"] == pytest.approx(0.040)
    (arrow,) = solid["arrows"]
    np.testing.assert_allclose(
        rotate(arrow["pose"]["orientation"], np.array([1.0, 0.0, 0.0])), axis, atol=1e-12
    )
    assert "cylinder 40.0 mm" in solid["texts"][0]["text"]
    assert "truth cylinder 40.0 mm" in solid["texts"][0]["text"]
    # Circle, ellipse and line drawn; the line with no model is skipped.
    assert [line["type"] for line in models["lines"]] == [fc.LINE_LOOP, fc.LINE_LOOP, fc.LINE_STRIP]


def test_reconstruction_scene_sphere_and_cuboid_sizes() -> None:
    solid = fc.reconstruction_scene(reconstruction("sphere"))["entities"][0]
    (sphere,) = solid["spheres"]
    assert sphere["size"] == {
        "x": pytest.approx(0.04),
        "y": pytest.approx(0.04),
        "z": pytest.approx(0.04),
    }
    assert sphere["pose"]["position"] == {"x": 0.0, "y": 0.0, "z": 0.22}
    solid = fc.reconstruction_scene(reconstruction("cuboid", (1.0, 0.0, 0.0)))["entities"][0]
    (cube,) = solid["cubes"]
    # The pierced face is at z = 0.22; the box lies behind it, half its depth farther away.
    assert cube["pose"]["position"]["z"] == pytest.approx(0.24)
    np.testing.assert_allclose(
        rotate(cube["pose"]["orientation"], np.array([1.0, 0.0, 0.0])), [1, 0, 0], atol=1e-12
    )


def test_reconstruction_scene_none_clears_the_solid_and_says_why() -> None:
    rec = Reconstruction(seq=1, t_ns=T_NS, frame_seq=1, shape="none", reason="too few points")
    solid, models = fc.reconstruction_scene(rec)["entities"]
    assert not (solid["spheres"] or solid["cylinders"] or solid["cubes"] or solid["arrows"])
    assert solid["texts"][0]["text"] == "no object: too few points"
    assert models["lines"] == []


def test_aim_scene_arrow_points_toward_the_target_as_far_as_the_hull() -> None:
    cue = one_of_each()["lpc/aim/cue"]
    (aim,) = fc.aim_scene(cue)["entities"]
    (arrow,) = aim["arrows"]
    np.testing.assert_allclose(
        rotate(arrow["pose"]["orientation"], np.array([1.0, 0.0, 0.0])), [0, 1, 0], atol=1e-12
    )
    assert arrow["shaft_length"] + arrow["head_length"] == pytest.approx(0.025)
    sizes = [s["size"]["x"] for s in aim["spheres"]]
    assert sizes[1] > sizes[0] == sizes[2] == sizes[3]


@pytest.mark.parametrize("theta_deg", [0.0, 90.0, 180.0, 270.0, 200.0])
def test_aim_scene_arrow_direction_follows_theta_all_round(theta_deg: float) -> None:
    cue = msgspec.structs.replace(one_of_each()["lpc/aim/cue"], theta_deg=theta_deg)
    (arrow,) = fc.aim_scene(cue)["entities"][0]["arrows"]
    theta = math.radians(theta_deg)
    np.testing.assert_allclose(
        rotate(arrow["pose"]["orientation"], np.array([1.0, 0.0, 0.0])),
        [math.cos(theta), math.sin(theta), 0.0],
        atol=1e-12,
    )


def test_log_entry_maps_levels() -> None:
    (out,) = fc.convert("lpc/log/scans", one_of_each()["lpc/log/scans"])
    assert (out.topic, out.schema) == ("/lpc/log", "foxglove.Log")
    assert out.payload["level"] == 3 and out.payload["name"] == "scans"
    assert out.payload["message"] == "hi"


def test_convert_plain_messages_keep_fields_for_plots() -> None:
    (emg,) = fc.convert("lpc/emg", one_of_each()["lpc/emg"])
    assert (emg.topic, emg.schema) == ("/lpc/emg", "lpc.EmgSample")
    assert emg.payload["channels"] == [0.1, 0.7]
    assert emg.payload["timestamp"] == fc.timestamp(T_NS)
    (state,) = fc.convert("lpc/controller/state", one_of_each()["lpc/controller/state"])
    assert state.payload["state"] == "aiming"


def test_convert_every_topic_fits_its_schema() -> None:
    messages = one_of_each()
    assert {type(m) for m in messages.values()} == {t.type for t in TOPICS}
    for key, message in messages.items():
        for out in fc.convert(key, message):
            schema = fc.schema_for(out.schema, type(message))
            assert schema["title"] == out.schema
            check_against_schema(out.payload, schema, out.topic, out.schema.startswith("lpc."))
            # JSON as Foxglove reads it: bytes as base64 strings.
            decoded = msgspec.json.decode(msgspec.json.encode(out.payload))
            if "data" in out.payload:
                assert base64.b64decode(decoded["data"]) == out.payload["data"]


def test_schema_for_lpc_types_has_one_type_per_field() -> None:
    def walk(node: dict[str, Any], path: str) -> None:
        assert "$ref" not in node and "anyOf" not in node, path
        assert isinstance(node.get("type"), str), f"{path}: {node}"
        for k, v in node.get("properties", {}).items():
            walk(v, f"{path}.{k}")
        if "items" in node:
            walk(node["items"], f"{path}[]")

    for topic in TOPICS:
        walk(fc.schema_for(f"lpc.{topic.type.__name__}", topic.type), topic.type.__name__)
    with pytest.raises(ValueError, match=r"lpc\.Unknown"):
        fc.schema_for("lpc.Unknown")


ENUMS = {
    ("foxglove.LinePrimitive", "type"): "LinePrimitiveLineType",
    ("foxglove.PackedElementField", "type"): "PackedElementFieldNumericType",
    ("foxglove.Log", "level"): "LogLevel",
    ("foxglove.SceneEntityDeletion", "type"): "SceneEntityDeletionType",
}


def to_sdk(value: Any, schema: dict[str, Any], messages: Any) -> Any:
    """Build the SDK's own message from a payload: every field name must exist in Foxglove's
    schema for the SDK to accept it."""
    title = schema.get("title", "")
    if schema.get("type") == "array":
        return [to_sdk(v, schema["items"], messages) for v in value]
    if title in ("time", "duration"):
        return getattr(messages, "Timestamp" if title == "time" else "Duration")(**value)
    if title.startswith("foxglove."):
        cls = getattr(messages, title.removeprefix("foxglove."))
        kwargs = {}
        for k, v in value.items():
            enum = ENUMS.get((title, k))
            if enum is not None:
                enum_cls = getattr(messages, enum)
                members = [getattr(enum_cls, n) for n in dir(enum_cls) if n[:1].isupper()]
                kwargs[k] = next(m for m in members if m.value == v)
            else:
                kwargs[k] = to_sdk(v, schema["properties"][k], messages)
        return cls(**kwargs)
    return value


def test_convert_payloads_build_the_sdk_messages_of_the_same_name() -> None:
    messages = pytest.importorskip("foxglove.messages")
    seen = set()
    for key, message in one_of_each().items():
        for out in fc.convert(key, message):
            if not out.schema.startswith("foxglove."):
                continue
            sdk = to_sdk(out.payload, fc.schema_for(out.schema), messages)
            assert sdk.get_schema().name == out.schema
            assert sdk.encode()
            seen.add(out.schema)
    assert seen == set(name for name in fc.FOXGLOVE_SCHEMAS if name.startswith("foxglove."))


LAYOUT = Path(__file__).resolve().parents[1] / "deploy" / "foxglove-layout.json"


def test_layout_uses_only_topics_and_fields_the_conversion_produces() -> None:
    produced = {
        out.topic: fc.schema_for(out.schema, type(message))
        for key, message in one_of_each().items()
        for out in fc.convert(key, message)
    }
    layout = json.loads(LAYOUT.read_text())
    references: list[str] = []

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                if k.startswith("/"):
                    references.append(k)
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)
        elif isinstance(node, str) and node.startswith("/"):
            references.append(node)

    walk(layout)
    assert len(references) > 10
    for reference in references:
        topic, _, path = reference.partition(".")
        assert topic in produced, reference
        field = re.match(r"[A-Za-z_]\w*", path)
        if field:
            assert field.group(0) in produced[topic]["properties"], reference
