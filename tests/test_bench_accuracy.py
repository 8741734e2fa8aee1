"""``lpc bench accuracy`` runs end to end on a few frames and prints the paper beside ours."""

from __future__ import annotations

import argparse
import os

import numpy as np
import pytest

from services.cli.bench import accuracy as bench_accuracy


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    bench_accuracy.add_arguments(parser)
    return bench_accuracy.run(parser.parse_args(argv))


def test_bench_accuracy_one_object_prints_table(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--suite", "functional", "--object", "sphere_small", "--trials", "1", "--frames", "3"]
    assert _run(argv) == 0
    captured = capsys.readouterr()
    assert "sphere" in captured.out and "96.5" in captured.out  # the paper's figure beside
    assert "CPU per frame" in captured.out
    assert "functional: 3/3 frames" in captured.err


def test_bench_accuracy_rejects_zero_frames(capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(["--frames", "0"]) == 2
    assert "--frames" in capsys.readouterr().err


def test_bench_accuracy_runs_frames_through_librealsense_filters(
    capsys: pytest.CaptureFixture[str],
) -> None:
    pytest.importorskip("pyrealsense2", reason="needs pip install 'lpc[realsense]'")
    argv = ["--suite", "functional", "--object", "sphere_small", "--trials", "1", "--frames", "2"]
    assert (
        _run([*argv, "--method", "laser", "--method", "cloud", "--rs-filters", "hole_filling"]) == 0
    )
    out = capsys.readouterr().out
    assert "librealsense filters: hole_filling" in out
    assert "[method laser]" in out and "[method cloud]" in out
    assert "98.0" in out  # the paper's full-cloud figure for spheres beside the cloud method's


def test_a_cached_frame_is_written_beside_another_writers_temporary_file(tmp_path) -> None:
    """Two sweeps rendering the same frame at once each write a temporary file and rename it
    onto the frame: with one name for both, the second rename found its file gone (a sweep
    crashed on ``os.replace``). Another process's temporary files, still there, do not stop
    this one's frames from being written and read back."""
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from services.cli import _laser_views as lv

    def frames() -> list:
        return list(lv.views("functional", 1, 2, 0, names=["sphere_small"],
                             sensor=StereoSensor(), cache=tmp_path))  # fmt: skip

    first = frames()
    keys = [p.stem for p in tmp_path.glob("*.npy")]
    assert len(keys) == 2
    for key in keys:
        (tmp_path / f"{key}.npy").unlink()
        # Where a writer of the same frame in another process has its temporary file.
        (tmp_path / f"{key}.{key[:8]}.tmp.npy").mkdir()
        (tmp_path / f"{key}.{os.getpid() + 1}.tmp.npy").mkdir()
    again = frames()
    assert sorted(p.stem for p in tmp_path.glob("*.npy") if p.is_file()) == sorted(keys)
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)


def test_bench_accuracy_rejects_an_unknown_filter(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        _run(["--rs-filters", "decimation"])
    assert "unknown --rs-filters decimation" in capsys.readouterr().err


def test_bench_accuracy_reads_stereo_frames_back_from_its_cache(tmp_path, monkeypatch) -> None:
    pytest.importorskip("cv2", reason="needs pip install 'lpc[stereo]'")
    from lpc_core.sim.stereo import StereoSensor
    from services.cli import _laser_views as lv

    sensor = StereoSensor()
    first = list(lv.views("functional", 1, 2, 0, names=["sphere_small"], sensor=sensor,
                          cache=tmp_path))  # fmt: skip
    assert len(list(tmp_path.glob("*.npy"))) == 2
    rendered = []
    real = StereoSensor.render_depth
    monkeypatch.setattr(
        StereoSensor, "render_depth", lambda self, *a: rendered.append(1) or real(self, *a)
    )
    again = list(lv.views("functional", 1, 2, 0, names=["sphere_small"], sensor=sensor,
                          cache=tmp_path))  # fmt: skip
    assert not rendered  # both frames came from the cache, equal to the rendered ones
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)
    # Another seed is another frame, never the cached one.
    other = next(lv.views("functional", 1, 1, 1, names=["sphere_small"], sensor=sensor,
                          cache=tmp_path))  # fmt: skip
    assert rendered and not np.array_equal(other.depth, first[0].depth)
