"""``lpc export --foxglove``: a recording re-logged in Foxglove's schemas, read back schema by
schema."""

from __future__ import annotations

import argparse
import base64
import json
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from mcap.reader import make_reader

from lpc_core import foxglove_convert as fc
from schemas import to_wire
from services.cli import export
from services.mcap_log import LogWriter
from tests.test_foxglove_convert import T_NS, depth_frame, one_of_each

FRAMES = 12
PERIOD_NS = 11_111_111  # 90 Hz


def record(path: Path, frames: int = FRAMES) -> dict[str, list[Any]]:
    """A recording: every topic once per frame, one bad depth frame, one unreadable payload."""
    sent: dict[str, list[Any]] = {}
    with LogWriter(path, chunk_bytes=256 * 1024) as writer:
        for i in range(frames):
            t = T_NS + i * PERIOD_NS
            for key, message in one_of_each().items():
                if key == "lpc/camera/depth":
                    message = depth_frame(seed=i)
                message = msgspec.structs.replace(message, seq=i, t_ns=t)
                writer.write(key, message, log_time=t + 1000)
                sent.setdefault(key, []).append(message)
        bad = msgspec.structs.replace(
            depth_frame(), depth=to_wire(np.zeros((240, 424), np.float32))
        )
        writer.write("lpc/camera/depth", bad, log_time=T_NS + frames * PERIOD_NS)
        writer.write_received("lpc/emg", b"\xc1 not msgpack", T_NS + frames * PERIOD_NS)
    return sent


def run_export(*argv: str) -> int:
    parser = argparse.ArgumentParser()
    export.add_arguments(parser)
    return export.run(parser.parse_args(list(argv)))


def read_back(path: Path) -> dict[str, list[tuple[Any, Any, dict[str, Any]]]]:
    """topic -> [(schema, message record, decoded JSON)] in log-time order."""
    by_topic: dict[str, list[tuple[Any, Any, dict[str, Any]]]] = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            assert channel.message_encoding == "json"
            assert schema is not None and schema.encoding == "jsonschema"
            by_topic.setdefault(channel.topic, []).append(
                (schema, message, json.loads(message.data))
            )
    return by_topic


@pytest.fixture
def exported(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[Path, dict, str]:
    source, target = tmp_path / "in.mcap", tmp_path / "out.mcap"
    sent = record(source)
    assert run_export("--foxglove", str(source), str(target)) == 0
    return target, sent, capsys.readouterr().err


def test_export_writes_every_topic_with_its_schema(exported: tuple[Path, dict, str]) -> None:
    target, _, _ = exported
    topics = read_back(target)
    expected = {out.topic: out.schema for k, m in one_of_each().items() for out in fc.convert(k, m)}
    assert {t: rows[0][0].name for t, rows in topics.items()} == expected
    for topic, rows in topics.items():
        schema = json.loads(rows[0][0].data)
        assert schema["title"] == expected[topic]
        assert set(rows[0][2]) <= set(schema["properties"]), topic
    # Every good message of every key is there, once per frame.
    assert all(len(rows) == FRAMES for rows in topics.values())


def test_export_depth_is_raw_image_with_the_recorded_pixels(
    exported: tuple[Path, dict, str],
) -> None:
    target, sent, _ = exported
    rows = read_back(target)["/lpc/camera/depth"]
    for (schema, record_, image), frame in zip(rows, sent["lpc/camera/depth"], strict=True):
        assert schema.name == "foxglove.RawImage" and image["encoding"] == "16UC1"
        assert base64.b64decode(image["data"]) == frame.depth.data
        assert image["timestamp"] == fc.timestamp(frame.t_ns)
        assert (record_.publish_time, record_.log_time, record_.sequence) == (
            frame.t_ns,
            frame.t_ns + 1000,
            frame.seq,
        )


def test_export_scans_point_cloud_and_calibration(exported: tuple[Path, dict, str]) -> None:
    target, sent, _ = exported
    topics = read_back(target)
    schema, _, cloud = topics["/lpc/scans"][0]
    assert schema.name == "foxglove.PointCloud"
    points = np.frombuffer(base64.b64decode(cloud["data"]), "<f4").reshape(-1, 4)
    first = sent["lpc/scans"][0].lines[0]
    np.testing.assert_array_equal(
        points[: first.points.shape[0], :3], np.frombuffer(first.points.data, "<f4").reshape(-1, 3)
    )
    schema, _, calibration = topics["/lpc/camera/calibration"][0]
    assert schema.name == "foxglove.CameraCalibration"
    assert (calibration["width"], calibration["height"]) == (424, 240)
    schema, _, tf = topics["/tf"][0]
    assert schema.name == "foxglove.FrameTransforms"
    assert tf["transforms"][0]["child_frame_id"] == "camera"


def test_export_reconstruction_scene_and_log(exported: tuple[Path, dict, str]) -> None:
    target, _, _ = exported
    topics = read_back(target)
    schema, _, scene = topics["/lpc/reconstruction/scene"][-1]
    assert schema.name == "foxglove.SceneUpdate"
    solid, models = scene["entities"]
    assert len(solid["cylinders"]) == 1 and len(solid["arrows"]) == 1
    assert len(models["lines"]) == 3
    schema, _, aim = topics["/lpc/aim/scene"][-1]
    assert schema.name == "foxglove.SceneUpdate" and len(aim["entities"][0]["arrows"]) == 1
    schema, _, log = topics["/lpc/log"][0]
    assert schema.name == "foxglove.Log" and log["level"] == 3 and log["name"] == "scans"


def test_export_plain_topics_are_plottable_json(exported: tuple[Path, dict, str]) -> None:
    target, sent, _ = exported
    topics = read_back(target)
    for topic, name, field in [
        ("/lpc/emg", "lpc.EmgSample", "channels"),
        ("/lpc/aim/cue", "lpc.AimCue", "amplitudes"),
        ("/lpc/tactors/command", "lpc.TactorCommand", "amplitudes"),
        ("/lpc/controller/state", "lpc.ControllerState", "state"),
        ("/lpc/prosthesis/command", "lpc.ProsthesisCommand", "grasp"),
        ("/lpc/prosthesis/state", "lpc.ProsthesisState", "aperture_mm"),
        ("/lpc/grasp/target", "lpc.GraspTarget", "grasp_width_mm"),
        ("/lpc/reconstruction", "lpc.Reconstruction", "grasp_width_mm"),
        ("/lpc/health/scans", "lpc.Health", "counters"),
    ]:
        schema, _, message = topics[topic][0]
        key = topic.removeprefix("/")
        assert schema.name == name, topic
        assert message[field] == msgspec.to_builtins(sent[key][0])[field], topic
        assert message["timestamp"] == fc.timestamp(sent[key][0].t_ns)


def test_export_counts_what_it_cannot_show(exported: tuple[Path, dict, str]) -> None:
    _, _, err = exported
    assert "skipped 1 message(s) on lpc/camera/depth: depth must be uint16" in err
    assert "skipped 1 message(s) on lpc/_rejected/lpc/emg" in err
    assert "skipped 2" in err


def test_export_is_byte_identical_for_identical_input(tmp_path: Path) -> None:
    source = tmp_path / "in.mcap"
    record(source, frames=3)
    for name in ("a.mcap", "b.mcap"):
        assert run_export("--foxglove", str(source), str(tmp_path / name)) == 0
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    assert not list(tmp_path.glob("*.partial"))


def test_export_reads_a_recording_cut_short(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source, cut, target = tmp_path / "in.mcap", tmp_path / "cut.mcap", tmp_path / "out.mcap"
    record(source, frames=40)
    data = source.read_bytes()
    cut.write_bytes(data[: len(data) * 6 // 10])
    assert run_export("--foxglove", "--progress", str(cut), str(target)) == 0
    err = capsys.readouterr().err
    assert "cut short" in err
    depth = read_back(target)["/lpc/camera/depth"]
    assert 0 < len(depth) < 40
    # No summary in a cut file: the bar counts messages without a total.
    assert " messages " in err


def test_export_progress_bar_reaches_the_total(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = tmp_path / "in.mcap"
    record(source, frames=2)
    assert run_export("--foxglove", "--progress", str(source), str(tmp_path / "o.mcap")) == 0
    total = 2 * len(one_of_each()) + 2
    assert f"100.0% {total}/{total}" in capsys.readouterr().err


def test_export_refuses_bad_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = tmp_path / "in.mcap"
    record(source, frames=1)
    assert run_export(str(source), str(tmp_path / "o.mcap")) == 2
    assert "--foxglove" in capsys.readouterr().err
    assert run_export("--foxglove", str(source), str(source)) == 2
    assert "same file" in capsys.readouterr().err
    assert run_export("--foxglove", str(tmp_path / "missing.mcap"), str(tmp_path / "o.mcap")) == 2
    assert "cannot open" in capsys.readouterr().err
    (tmp_path / "junk.mcap").write_bytes(b"not mcap")
    assert run_export("--foxglove", str(tmp_path / "junk.mcap"), str(tmp_path / "o.mcap")) == 2
    assert not (tmp_path / "o.mcap").exists()
