"""Smoke test of ``lpc bench compare``: both methods run on a few simulated frames and the
report carries real figures (no timing assertions: speed is what the command prints)."""

from __future__ import annotations

import argparse
import re

from services.cli.bench import compare as bench_compare


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    bench_compare.add_arguments(parser)
    return parser.parse_args(list(argv))


def test_bench_compare_quick_prints_both_methods_per_shape(capsys):
    assert bench_compare.run(_args("--quick", "--frames", "1", "--seed", "3")) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert "3 frames (1 per object), seed 3" in out
    for shape in ("sphere", "cylinder", "cuboid", "all"):
        for method in ("laser", "cloud"):
            row = re.search(rf"^{shape}\s+{method}\s+(\d+)\s+([\d.]+)%(.*)$", out, re.M)
            assert row, f"no {shape}/{method} row in:\n{out}"
            frames, accuracy, rest = int(row[1]), float(row[2]), row[3]
            assert frames == (3 if shape == "all" else 1)
            assert 0.0 <= accuracy <= 100.0
            cpu_ms = float(rest.split()[-1])
            assert 0.0 < cpu_ms < 10_000.0
    # The cloud method reads thousands of points, the laser method hundreds.
    points = {
        m: float(re.search(rf"^all\s+{m}\s.*?(\d+) ± \d+\s+[\d.]+$", out, re.M)[1])
        for m in ("laser", "cloud")
    }
    assert 0 < points["laser"] < points["cloud"]
    ratio = re.search(r"points per frame\s+([\d.]+)", out)
    assert ratio and 0.0 < float(ratio[1]) < 1.0
    assert re.search(r"CPU time p50\s+[\d.]+\s+laser from its scan lines", out)
    assert re.search(r"CPU time mean\s+[\d.]+\s+laser", out)
    assert "least of 3 per frame" in out
    assert "5300 ± 2100" in out and "138 vs 75 ms" in out
    assert "compare: sphere_small" in captured.err  # progress goes to stderr


def test_bench_compare_rejects_zero_frames(capsys):
    assert bench_compare.run(_args("--frames", "0")) == 2
    assert "--frames" in capsys.readouterr().err
    assert bench_compare.run(_args("--repeat", "0")) == 2
    assert "--repeat" in capsys.readouterr().err


def test_bench_compare_quick_views_cover_each_shape_once():
    views = list(bench_compare.simulated_views(bench_compare.QUICK_OBJECTS, 1, 0))
    assert sorted(v.shape for v in views) == ["cuboid", "cylinder", "sphere"]
    assert [v.seq for v in views] == [0, 1, 2]
    assert all(v.depth.dtype.name == "uint16" and v.depth.shape == (240, 424) for v in views)
