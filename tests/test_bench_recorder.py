"""``lpc bench recorder``: the write figure compares the zstd levels it is asked for."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from services.cli.bench import recorder as bench


def test_bench_write_prints_one_row_per_zstd_level(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bench.bench_write(bench._frames(2), 12, tmp_path, [3, -5])
    rows = {
        m.group(1): float(m.group(2))
        for m in re.finditer(
            r"^\s+(none|lz4|zstd -?\d+)\s+[\d.]+\s+[\d.]+\s+([\d.]+)", capsys.readouterr().out, re.M
        )
    }
    assert set(rows) == {"none", "lz4", "zstd 3", "zstd -5"}
    assert rows["none"] == pytest.approx(1.0, abs=0.01)
    # Depth compresses; zstd's level 3 more than its fast level -5.
    assert rows["zstd 3"] > rows["zstd -5"] > 1.0


def test_bench_zstd_levels_flag_rejects_bad_lists() -> None:
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    assert parser.parse_args(["--zstd-levels=1,-3"]).zstd_levels == [1, -3]
    for bad in ("1,x", "30", "-8"):
        with pytest.raises(SystemExit):
            parser.parse_args([f"--zstd-levels={bad}"])
