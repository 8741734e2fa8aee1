"""``lpc bench sweep``: one row per stereo setting, and before -> after against an earlier run."""

from __future__ import annotations

import argparse
import json
import math

import pytest

from services.cli.bench import sweep


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    sweep.add_arguments(parser)
    return sweep.run(parser.parse_args(argv))


def test_sweep_rejects_an_unknown_setting_naming_the_known_ones(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert _run(["--setting", "sgbm8"]) == 2
    err = capsys.readouterr().err
    assert "unknown --setting sgbm8" in err and "sgbm7" in err and "bm11" in err


def test_every_setting_builds_its_sensor_and_the_untuned_differ_from_the_tuning() -> None:
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    sensors = {name: s.sensor() for name, s in sweep.SETTINGS.items()}
    assert sensors["p1x3p2x6"].matcher.p1 == 3 * 8 * 49
    assert sensors["p1x3p2x6"].matcher.p2 == 6 * 32 * 49
    assert sensors["sgbm7"].matcher.p1 is None  # OpenCV's usual penalties
    tuning = [s for n, s in sensors.items() if sweep.SETTINGS[n].group == "tuning"]
    untuned = [s for n, s in sensors.items() if sweep.SETTINGS[n].group == "untuned"]
    fresh = [s for n, s in sensors.items() if sweep.SETTINGS[n].group == "fresh"]
    assert len(tuning) == 8 and len(untuned) == 76 and len(fresh) == 5
    assert len(set(map(repr, sensors.values()))) == len(sensors)  # no setting twice


def test_sweep_prints_a_row_and_compares_with_an_earlier_run(
    tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    argv = ["--setting", "sgbm7", "--suite", "functional", "--object", "sphere_small",
            "--trials", "1", "--frames", "2", "--jobs", "0"]  # fmt: skip
    argv += ["--cache", str(tmp_path / "frames")]
    before = tmp_path / "before.json"
    assert _run([*argv, "--json", str(before)]) == 0
    out = capsys.readouterr().out
    assert "| SGBM 7 |" in out
    figures = json.loads(before.read_text())
    width, pct = figures["sgbm7"]["laser"]["table"]["sphere"]
    assert pct == 100.0 and 0.0 <= width < 5.0  # the 50 mm ball, within a few mm on stereo
    assert math.isnan(figures["sgbm7"]["laser"]["table"]["cuboid"][0])  # no box was asked for

    # The same frames again against a doctored earlier run: only the doctored cell moves.
    figures["sgbm7"]["laser"]["table"]["sphere"][0] = 9.9
    before.write_text(json.dumps(figures))
    assert _run([*argv, "--against", str(before)]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if "| SGBM 7 |" in line)
    assert f"| 9.9 -> {width:.1f} |" in row
    assert row.count("->") == 1


def test_summarise_counts_irregular_objects_and_per_frame_shape_accuracy() -> None:
    rows = [
        ("cylinder_upright", "cylinder", True, 2.0, 1.0),
        ("cylinder_upright", "cylinder", True, -4.0, -3.0),
        ("cylinder_upright", "cylinder", False, None, None),
        ("cuboid_lying", "cuboid", True, 1.0, 0.5),
    ]
    results = [
        {"setting": "bm7", "suite": "functional",
         "methods": {"laser": {"rows": rows, "failed": [], "objects": 0}}},
        {"setting": "bm7", "suite": "irregular",
         "methods": {"laser": {"rows": [], "failed": ["jar_cap"], "objects": 10}}},
    ]  # fmt: skip
    table = sweep.summarise(results)["bm7"]["laser"]["table"]
    assert table["cylinder"][0] == pytest.approx(3.0)
    assert table["cylinder"][1] == pytest.approx(200 / 3)
    assert table["all"] == pytest.approx([7 / 3, 75.0])
    assert table["angle"][0] == pytest.approx(1.5)
    assert table["irregular"] == [9, 10]

    # Without the functional set the shapes' table is the rotation suite's.
    rotation = [{"setting": "bm7", "suite": "rotation",
                 "methods": {"laser": {"rows": rows[:2], "failed": [], "objects": 0}}}]  # fmt: skip
    assert sweep.summarise(rotation)["bm7"]["laser"]["table"]["cylinder"] == [3.0, 100.0]
