"""``lpc trials``: a tiny real run end to end, and the report and figure from known outcomes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from lpc_core.trials import TrialOutcome
from services.cli import build_parser
from services.cli import replay as replay_cli
from services.cli import trials as cli
from services.mcap_log import read_messages


def test_trials_command_runs_records_and_reports(tmp_path: Path, capsys) -> None:
    """One user, one block, one object, a 10 Hz camera: every output is written."""
    args = build_parser("trials").parse_args(
        ["trials", "--users", "1", "--blocks", "1", "--objects", "1", "--workers", "1",
         "--camera-hz", "10", "--seed", "3", "--out", str(tmp_path)]
    )  # fmt: skip
    assert cli.run(args) == 0
    out = capsys.readouterr()
    condition = tmp_path / "laser-feedback-on"
    lines = (condition / "trials.jsonl").read_text().splitlines()
    assert len(lines) == 1
    trial = json.loads(lines[0])
    assert trial["completed"] and trial["object"] == "sphere_large"
    summary = json.loads((condition / "summary.json").read_text())
    assert summary["meta"]["condition"] == "laser-feedback-on"
    assert summary["per_block"][0]["tat_median_s"] == pytest.approx(trial["tat_s"], abs=0.01)
    recording = condition / "mcap" / "u00_b0_t00.mcap"
    keys = {m.key for m in read_messages(recording)}
    assert {"lpc/scans", "lpc/grasp/target", "lpc/emg", "lpc/controller/state"} <= keys
    assert (tmp_path / "tat_per_block.png").stat().st_size > 10_000
    assert "laser-feedback-on" in out.out and "16.7" in out.out  # the paper's figure
    assert "[   1/1] user  0 block 1" in out.err  # progress
    # The recording is what the step functions do: a replay with the user's calibration
    # reproduces every output.
    profile = condition / "mcap" / "profile-u00.json"
    replay = build_parser("replay").parse_args(
        ["replay", "--check", "--profile", str(profile), str(recording)]
    )
    assert replay_cli.run(replay) == 0
    assert "check: no differences" in capsys.readouterr().out


def synthetic(users: int, blocks: int, base: float, gain: float, seed: int) -> list[TrialOutcome]:
    rng = np.random.default_rng(seed)
    out = []
    for u in range(users):
        for b in range(blocks):
            for i in range(10):
                tat = base - gain * b + rng.normal(0, 0.8) + 0.3 * u
                out.append(
                    TrialOutcome(
                        user=u, block=b, index=i, object="x", shape="sphere", completed=True,
                        tat_s=float(tat), attempts=1, take_overs=1, reconstructed=i != 0,
                        target_shape="sphere", failures=("slipped",) if i == 9 and u == 0 else (),
                    )
                )  # fmt: skip
    return out


def write(tmp: Path, name: str, method: str, feedback: bool, outcomes: list[TrialOutcome]) -> None:
    d = tmp / name
    d.mkdir(parents=True)
    (d / "trials.jsonl").write_text(
        "\n".join(json.dumps(cli.dataclasses.asdict(o)) for o in outcomes) + "\n"
    )
    meta = {"condition": name, "method": method, "feedback": feedback}
    (d / "summary.json").write_text(json.dumps({"meta": meta}))


def test_compare_reports_both_conditions_with_the_paper_s_statistics(tmp_path: Path, capsys):
    write(tmp_path, "laser-feedback-on", "laser", True, synthetic(10, 5, 16.0, 1.0, 1))
    write(tmp_path, "cloud-feedback-off", "cloud", False, synthetic(10, 5, 10.0, 0.4, 2))
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    assert cli.run(parser.parse_args(["--compare", str(tmp_path)])) == 0
    text = capsys.readouterr().out
    laser = next(line for line in text.splitlines() if line.startswith("laser-feedback-on"))
    assert "16." in laser and "**" in laser  # block 1 about 16 s; Friedman p <= 0.01
    assert "laser-feedback-on - cloud-feedback-off (n=10)" in text
    pairs = next(line for line in text.splitlines() if "(n=10)" in line)
    assert pairs.count("**") == 5  # every block differs
    assert "paper: prototype - benchmark +6.3 s in block 1" in text
    assert "slipped 5" in text and "90%" in text  # failures (one per block); recon ok 9 of 10
    assert (tmp_path / "tat_per_block.png").exists()


def test_find_conditions_reads_a_condition_directory_or_its_parent(tmp_path: Path) -> None:
    write(tmp_path, "cloud-feedback-off", "cloud", False, synthetic(2, 1, 9.0, 0.0, 3))
    by_parent = cli.find_conditions([tmp_path])
    by_itself = cli.find_conditions([tmp_path / "cloud-feedback-off"])
    assert [c.name for c in by_parent] == [c.name for c in by_itself] == ["cloud-feedback-off"]
    assert by_parent[0].medians().shape == (2, 1)
