"""lpc bench footprint: a short smoke run that reports every service, and leaves no cgroup
behind (the figures themselves come from runs of the command, not from tests)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from services.cli.bench.footprint import CpuQuota, QuotaUnavailable
from tests.conftest import free_port

ROOT = Path(__file__).resolve().parent.parent


def _quota_or_skip() -> CpuQuota:
    try:
        return CpuQuota(0.5)
    except QuotaUnavailable as exc:
        pytest.skip(f"no cgroup CPU quota here: {exc}")


def test_footprint_device_cgroup_has_a_weight_and_no_quota() -> None:
    _quota_or_skip().close()
    group = CpuQuota(None, "-devices")
    try:
        assert group.path.name.endswith("-devices")
        if group.version == 2:
            assert (group.path / "cpu.max").read_text().split() == ["max", "10000"]
        else:
            assert (group.path / "cpu.cfs_quota_us").read_text().strip() == "-1"
    finally:
        group.close()
    assert not group.path.exists()


def test_footprint_quota_is_written_and_removed() -> None:
    quota = _quota_or_skip()
    try:
        if quota.version == 2:
            assert (quota.path / "cpu.max").read_text().split() == ["5000", "10000"]
        else:
            assert (quota.path / "cpu.cfs_quota_us").read_text().strip() == "5000"
            assert (quota.path / "cpu.cfs_period_us").read_text().strip() == "10000"
    finally:
        quota.close()
    assert not quota.path.exists()


def test_footprint_smoke_together_under_a_quota() -> None:
    _quota_or_skip().close()
    bench = subprocess.Popen(
        [
            sys.executable, "-m", "services.cli", "bench", "footprint", "--cpus", "1.0",
            "--seconds", "2", "--warmup", "1", "--together", "--record", "--json",
            "--port", str(free_port()),
        ],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        stdin=subprocess.DEVNULL,
    )  # fmt: skip
    stdout, stderr = bench.communicate(timeout=240)
    assert bench.returncode == 0, stdout[-3000:] + stderr[-3000:]
    # The bench's cgroups (the set's, the device's) are named after its pid, and gone once it
    # has exited.
    for pattern in (f"lpc-footprint-{bench.pid}*", f"*/lpc-footprint-{bench.pid}*"):  # v2, v1
        assert not list(Path("/sys/fs/cgroup").glob(pattern))
    report = json.loads(stdout)
    assert report["mode"] == "together" and report["cgroup"] in ("v1", "v2")
    # By default the simulated camera is a device outside the set, measured on its own.
    assert report["devices"] == "outside"
    assert report["outside_set"]["sim-camera"]["rss_mb"] > 10
    services = report["services"]
    for name in ("camera", "scans", "reconstructor", "aim", "controller", "recorder"):
        assert services[name]["cpu_from"] == "event loop", name
    assert services["prosthesis_bridge"]["cpu_from"] == "process"
    assert services["container"]["rss_mb"] > 10
    assert report["totals"]["processes"] >= 3  # supervisor, container, bridge (+ workers)
    assert report["topics"]["lpc/emg"]["rate_hz"] > 0
    assert report["frames"]["frames"] > 0
