"""``lpc tactors test`` against a simulated controller on a pty."""

from __future__ import annotations

import argparse
import json

import pytest

from services.cli import tactors
from services.drivers.tactor_sim import TactorSim
from tests.conftest import wait_for


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    tactors.add_arguments(parser)
    return parser.parse_args(["test", "--on-ms", "20", "--off-ms", "0", *argv])


@pytest.mark.parametrize("protocol", ["eai", "line"])
def test_tactors_test_pulses_each_tactor_in_turn(protocol: str, tmp_path, capsys) -> None:
    profile = tmp_path / "profile.json"
    gains = {"gain_min": [0, 0.3, 0, 0], "gain_max": [1.0, 0.9, 0.6, 0.3], "arm": "left"}
    profile.write_text(json.dumps({"tactors": gains}))
    with TactorSim(protocol) as sim:
        code = tactors.run(
            parse("--port", sim.port, "--driver", protocol, "--profile", str(profile))
        )
        # The simulator reads the pty on its own thread: wait for the final all-off to land.
        wait_for(lambda: sim.mask == 0, 5.0, "all tactors off")
        lit = [e.mask for e in sim.events if e.mask]
        levels = [max(e.levels) for e in sim.events if e.mask]
    out = capsys.readouterr().out
    assert code == 0
    # Tactor 1 twice (weakest 0.3, then strongest 0.9), the others once at their strongest.
    assert lit == [0b0001, 0b0010, 0b0010, 0b0100, 0b1000]
    assert "tactor 3 (down): strongest level 0.30" in out  # left arm: tactor 3 means down
    if protocol == "line":
        assert levels == pytest.approx([1.0, 0.3, 0.9, 0.6, 0.3], abs=1 / 255)
    else:  # one gain for all: levels quantised to thirds
        assert levels == pytest.approx([1.0, 1 / 3, 1.0, 2 / 3, 1 / 3])


def test_tactors_test_without_port_or_profile_uses_a_simulator(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.config/lpc/profile.json
    assert tactors.run(parse()) == 0
    assert "simulated controller" in capsys.readouterr().out


def test_tactors_test_missing_port_fails_cleanly(capsys) -> None:
    assert tactors.run(parse("--port", "/nonexistent/ttyUSB7")) == 1
    assert "cannot open tactor port" in capsys.readouterr().err
