"""``lpc bench pool`` runs both ways on a few jobs and prints their figures and ratio."""

from __future__ import annotations

import argparse
import re

import pytest

from services.cli.bench import pool as bench_pool


def test_bench_pool_prints_both_ways_and_a_ratio(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    bench_pool.add_arguments(parser)
    args = parser.parse_args(["--jobs", "5", "--rounds", "1", "--interval-ms", "1"])
    assert bench_pool.run(args) == 0
    out = capsys.readouterr().out
    assert "5 jobs of 8000 B each way" in out
    for way in ("pipes (PipePool)", "ProcessPoolExecutor"):
        row = re.search(rf"^{re.escape(way)}\s+([\d.]+) ms\s+([\d.]+) ms\s+([\d.]+) ms$", out, re.M)
        assert row is not None, out
        cpu, p50, p99 = map(float, row.groups())
        assert cpu > 0 and 0 < p50 <= p99
    assert re.search(r"pipes / executor = \d+\.\d\d$", out, re.M)


def test_bench_pool_rejects_bad_counts() -> None:
    parser = argparse.ArgumentParser()
    bench_pool.add_arguments(parser)
    with pytest.raises(SystemExit, match="--jobs, --rounds and --bytes must be >= 1"):
        bench_pool.run(parser.parse_args(["--jobs", "0"]))
