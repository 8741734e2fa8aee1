"""lpc bench soak: the memory slope fit, and a short smoke run of two services (the figures
themselves come from a long run of the command, not from tests)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from services.cli.bench.soak import memory_slope
from tests.conftest import free_port

ROOT = Path(__file__).resolve().parent.parent


def test_memory_slope_recovers_a_linear_leak() -> None:
    rng = np.random.default_rng(7)
    t_s = np.arange(0, 1800, 10.0)
    rss = 100.0 + 0.5 * t_s / 60.0 + rng.normal(0, 0.2, t_s.size)
    slope = memory_slope(list(t_s), list(rss))
    assert slope is not None and abs(slope - 0.5) < 0.01
    assert memory_slope([0.0, 1.0], [1.0, 2.0]) is None


def test_soak_smoke_reports_every_process(tmp_path: Path) -> None:
    out = tmp_path / "soak.json"
    result = subprocess.run(
        [
            sys.executable, "-m", "services.cli.bench.soak", "--minutes", "0.08",
            "--sample-every", "0.5", "--warmup", "1", "--port", str(free_port()),
            "--services", "camera", "scans", "--json", str(out),
        ],
        cwd=ROOT, capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads(out.read_text())
    assert set(report["processes"]) == {"camera", "scans"}
    for p in report["processes"].values():
        assert p["samples"] >= 3 and p["restarts"] == 0
        assert p["rss_mb"]["last"] > 10
        assert p["rss_slope_mb_per_min"] is not None
    assert report["topics"]["lpc/camera/depth"]["seen"] > 0
    assert "slope MB/min" in result.stdout
