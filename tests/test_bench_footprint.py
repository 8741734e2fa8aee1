"""lpc bench footprint: a short smoke run that reports every service, and leaves no cgroup
behind (the figures themselves come from runs of the command, not from tests)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from schemas import AimCue, EmgSample
from services.cli.bench.footprint import Captures, CpuQuota, QuotaUnavailable, _read_recording
from services.cli.bench.soak import Watcher
from services.mcap_log import LogWriter
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


def test_footprint_recording_gives_rates_gaps_and_capture_latencies(tmp_path: Path) -> None:
    # With the recorder on, the bench reads the small topics back from the set's recording
    # instead of subscribing to them: a message counts when it reached the recorder inside the
    # window, and its capture latency is that arrival less its capture time.
    path = tmp_path / "set.mcap"
    t0 = 10_000_000_000
    with LogWriter(path) as log:
        for seq in range(20):
            t = t0 + seq * 10_000_000
            if seq % 2 == 0:  # frames captured every 20 ms, each cue out 3 ms later
                cue = AimCue(seq=seq // 2, t_ns=t, frame_seq=seq // 2, state="guiding")
                log.write("lpc/aim/cue", cue, t + 3_000_000)
            if seq != 12:  # EMG sample 12 lost on the way: a gap of one
                emg = EmgSample(seq=seq, t_ns=t, channels=[0.1, 0.2])
                log.write("lpc/emg", emg, t + 1_000_000)
    watcher, captures = Watcher(), Captures()
    # The window: arrivals from the 5th EMG sample (seq 4) to the 15th (seq 14).
    captures.t_from_ns = t0 + 4 * 10_000_000
    captures.t_to_ns = t0 + 14 * 10_000_000 + 1_000_000
    _read_recording(path, watcher, captures)
    assert watcher.seen["lpc/emg"] == 10  # seq 4..14 without 12
    assert watcher.lost["lpc/emg"] == 1
    assert watcher.seen["lpc/aim/cue"] == 5  # frames 2..6 (captured 40..120 ms, out +3 ms)
    # Capture latencies: frames captured inside the window, whenever they arrived.
    assert captures.frames["lpc/aim/cue"] == {2, 3, 4, 5, 6, 7}
    assert captures.latencies_ms["lpc/aim/cue"] == pytest.approx([3.0] * 6)
    assert "lpc/emg" not in captures.latencies_ms  # not a capture-derived topic


def test_footprint_unreadable_recording_leaves_the_counts_empty(tmp_path: Path) -> None:
    path = tmp_path / "broken.mcap"
    path.write_bytes(b"not an mcap file")
    watcher, captures = Watcher(), Captures()
    _read_recording(path, watcher, captures)
    assert not watcher.seen and not captures.latencies_ms
