"""``lpc bench speed`` runs end to end on a few frames and prints every stage."""

from __future__ import annotations

import argparse

import pytest

from services.cli.bench import speed as bench_speed


def test_bench_speed_quick_prints_stages_and_profile(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    bench_speed.add_arguments(parser)
    assert bench_speed.run(parser.parse_args(["--quick", "--top", "3"])) == 0
    out = capsys.readouterr().out
    for stage in ("scan cut", "fit ellipse", "decision", "total from scan lines", "cProfile"):
        assert stage in out
