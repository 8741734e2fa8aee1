"""``lpc reconstruct`` on depth PNGs and intrinsics written to a temporary directory."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from lpc_core.perception.intrinsics import Intrinsics
from services.cli import reconstruct

INTR = Intrinsics()


def _sphere_depth(center_m: tuple[float, float, float], radius_m: float, seed: int) -> np.ndarray:
    """A ball in front of a far wall, 0.3 mm range noise, 1 mm depth units."""
    xs, ys = INTR.pixel_rays()
    d = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    c = np.asarray(center_m)
    a = (d * d).sum(-1)
    b = d @ c
    disc = b * b - a * (c @ c - radius_m**2)
    with np.errstate(invalid="ignore"):
        z = np.where(disc >= 0, (b - np.sqrt(disc)) / a, 0.6)
    z = z + np.random.default_rng(seed).normal(0, 0.0003, z.shape)
    return np.round(z / INTR.depth_scale).astype(np.uint16)


def _write_png(path: Path, depth: np.ndarray) -> str:
    Image.fromarray(depth).save(path)
    return str(path)


def _write_intrinsics(path: Path, **overrides: object) -> str:
    data = {
        "width": INTR.width, "height": INTR.height, "fx": INTR.fx, "fy": INTR.fy,
        "ppx": INTR.ppx, "ppy": INTR.ppy, "model": "brown_conrady", "coeffs": [0, 0, 0, 0, 0],
        "depth_scale": INTR.depth_scale,
    }  # fmt: skip
    data.update(overrides)
    path.write_text(json.dumps(data))
    return str(path)


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    reconstruct.add_arguments(parser)
    return reconstruct.run(parser.parse_args(argv))


def test_reconstruct_prints_one_line_per_frame_with_window(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    intr = _write_intrinsics(tmp_path / "intr.json")
    frames = [
        _write_png(tmp_path / f"f{k}.png", _sphere_depth((0.002, -0.001, 0.215), 0.025, k))
        for k in range(10)
    ]
    assert _run(["--intrinsics", intr, *frames]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["frame"] for r in lines] == frames
    for record in lines:
        assert record["shape"] == "sphere"
        assert record["grasp_width_mm"] == pytest.approx(50.0, abs=2.0)
        assert record["wrist_angle_deg"] is None
        assert record["points"] > 40 and record["compute_ms"] > 0
    assert lines[-1]["window"]["shape"] == "sphere"
    assert lines[-1]["window"]["grasp_width_mm"] == pytest.approx(50.0, abs=1.0)
    assert lines[-1]["window"]["reconstructed"] is True
    assert lines[0]["window"]["reconstructed"] is False


def test_reconstruct_empty_frame_gives_none_with_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    intr = _write_intrinsics(tmp_path / "intr.json")
    empty = _write_png(tmp_path / "empty.png", np.zeros((INTR.height, INTR.width), np.uint16))
    assert _run(["--intrinsics", intr, empty]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["shape"] == "none" and record["grasp_width_mm"] is None
    assert "too few points" in record["reason"]


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        ("missing", "no such file"),
        ("eight_bit", "16-bit"),
        ("wrong_size", "the intrinsics say 424x240"),
        ("not_png", "not an image"),
        ("bad_intrinsics", "lacks fx"),
        ("no_intrinsics", "--intrinsics"),
    ],
)
def test_reconstruct_bad_input_is_one_clear_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], setup: str, message: str
) -> None:
    intr = _write_intrinsics(tmp_path / "intr.json")
    frame = str(tmp_path / "frame.png")
    argv = ["--intrinsics", intr, frame]
    if setup == "eight_bit":
        Image.fromarray(np.zeros((INTR.height, INTR.width), np.uint8)).save(frame)
    elif setup == "wrong_size":
        _write_png(Path(frame), np.zeros((100, 100), np.uint16))
    elif setup == "not_png":
        Path(frame).write_text("hello")
    elif setup == "bad_intrinsics":
        _write_png(Path(frame), np.zeros((INTR.height, INTR.width), np.uint16))
        data = json.loads(Path(intr).read_text())
        del data["fx"]
        Path(intr).write_text(json.dumps(data))
    elif setup == "no_intrinsics":
        argv = [frame]
    code = _run(argv)
    err = capsys.readouterr().err
    assert code != 0
    assert message in err
    assert err.startswith("lpc reconstruct: error:") and len(err.strip().splitlines()) == 1


def test_reconstruct_paper_method_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    intr = _write_intrinsics(tmp_path / "intr.json")
    frame = _write_png(tmp_path / "f.png", _sphere_depth((0.0, 0.0, 0.22), 0.03, 1))
    assert _run(["--method", "paper", "--intrinsics", intr, frame]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["shape"] == "sphere"
    assert math.isclose(record["grasp_width_mm"], 60.0, abs_tol=5.0)


def test_reconstruct_method_table_maps_laser() -> None:
    assert "laser" in reconstruct.METHODS
    depth = _sphere_depth((0.0, 0.0, 0.2), 0.02, 2)
    assert reconstruct.METHODS["laser"](depth, INTR, 0).shape == "sphere"


def test_reconstruct_reads_depth_frames_from_mcap(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from lpc_core.perception.pipeline import intrinsics_to_message
    from schemas import DepthFrame, to_wire
    from services.mcap_log import LogWriter

    path = tmp_path / "rec.mcap"
    with LogWriter(path) as log:
        for seq in range(3):
            frame = DepthFrame(
                seq=seq + 5,
                t_ns=1_000_000_000 + seq * reconstruct.FRAME_PERIOD_NS,
                intrinsics=intrinsics_to_message(INTR),
                depth=to_wire(_sphere_depth((0.0, 0.002, 0.2), 0.02, seq)),
            )
            log.write("lpc/camera/depth", frame, log_time=frame.t_ns)
    assert _run(["--mcap", str(path)]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["frame"] for r in lines] == [f"{path}:{seq}" for seq in (5, 6, 7)]
    assert all(r["shape"] == "sphere" for r in lines)
    assert lines[-1]["window"]["grasp_width_mm"] == pytest.approx(40.0, abs=2.0)


def test_reconstruct_mcap_missing_or_not_mcap(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run(["--mcap", str(tmp_path / "nope.mcap")]) != 0
    assert "cannot open" in capsys.readouterr().err
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    assert _run(["--mcap", str(junk)]) != 0
    assert "not an MCAP file" in capsys.readouterr().err
