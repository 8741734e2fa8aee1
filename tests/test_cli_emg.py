"""``lpc emg calibrate`` with the simulated user: no hardware, a profile written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lpc_core.sim.emg_sim import MuscleParams
from services.cli import main


def test_emg_calibrate_sim_writes_the_emg_section_and_keeps_the_rest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    profile = tmp_path / "profile.json"
    profile.write_text(json.dumps({"tactors": {"arm": "left"}}))
    assert main(["emg", "calibrate", "--profile", str(profile), "--user", "sim"]) == 0
    data = json.loads(profile.read_text())
    assert data["tactors"] == {"arm": "left"}
    emg = data["emg"]
    params = MuscleParams()
    # The simulated person's rest and maximal contraction, recovered within 10 % (fatigue
    # during a 3 s maximal hold lowers the plateau a little).
    assert emg["rest"] == pytest.approx(list(params.rest), rel=0.1)
    assert emg["maximal"] == pytest.approx(list(params.maximal), rel=0.1)
    assert emg["user"] == "sim" and emg["unit"] == "V"
    out = capsys.readouterr().out
    assert "flexor" in out and f"written: {profile}" in out


def test_emg_calibrate_dry_run_writes_nothing(tmp_path: Path) -> None:
    profile = tmp_path / "new" / "profile.json"
    assert main(["emg", "calibrate", "--profile", str(profile), "--dry-run"]) == 0
    assert not profile.exists()


def test_emg_calibrate_rejects_bad_durations_and_profiles(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["emg", "calibrate", "--rest-s", "0.1", "--profile", str(tmp_path / "p")]) == 2
    assert "--rest-s" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["emg", "calibrate", "--profile", str(bad)]) == 2
    assert "not readable JSON" in capsys.readouterr().err


def test_emg_calibrate_unavailable_serial_port(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(
        [
            "emg",
            "calibrate",
            "--source",
            "serial",
            "--port",
            "/dev/no-such-port",
            "--profile",
            str(tmp_path / "p.json"),
        ]
    )
    assert code == 2 and "/dev/no-such-port" in capsys.readouterr().err
