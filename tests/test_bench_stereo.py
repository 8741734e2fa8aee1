"""``lpc bench stereo`` runs end to end on one frame per scene and prints its figures."""

from __future__ import annotations

import argparse

import pytest

pytest.importorskip("cv2", reason="the stereo camera needs OpenCV: pip install 'lpc[stereo]'")

from services.cli.bench import stereo as bench_stereo


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    bench_stereo.add_arguments(parser)
    return bench_stereo.run(parser.parse_args(argv))


def test_bench_stereo_prints_artifacts_and_cost(capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(["--matcher", "bm", "--block-size", "7", "--frames", "1"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("bm        7"))
    valid, bias, rms, stairs, fat, fat90, holes, grazing = (float(x) for x in row.split()[2:])
    assert 0.85 <= valid <= 1.0 and abs(bias) < 0.2 and 0.02 < rms < 0.2 and 0 <= stairs <= 1
    assert 0.0 <= fat <= fat90 <= 5.0 and holes >= 0.5 and grazing <= 0.2
    assert "frames/s (the camera asks 90)" in out


def test_bench_stereo_skips_a_block_the_matcher_refuses(capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(["--matcher", "bm", "--block-size", "3", "--frames", "1"]) == 0
    assert "skipped: block_size for bm must be in [5, 255]" in capsys.readouterr().out
    assert _run(["--frames", "0"]) == 2
