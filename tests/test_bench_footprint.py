"""lpc bench footprint: a short smoke run that reports every service, and leaves no cgroup
behind (the figures themselves come from runs of the command, not from tests)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from schemas import AimCue, EmgSample
from services.cli.bench import footprint
from services.cli.bench.footprint import (
    Captures,
    CpuQuota,
    QuotaUnavailable,
    _read_recording,
    thread_shares,
    thread_times,
    thread_wakeups,
    wakeup_counts,
)
from services.cli.bench.soak import Watcher
from services.mcap_log import LogWriter
from services.thread_names import CONTROL_LOOP, name_native_thread
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


def test_footprint_holds_the_set_to_whole_cpus_and_the_devices_to_the_rest() -> None:
    allowed = sorted(os.sched_getaffinity(0))
    own, rest = footprint._pinned(0.5)
    if len(allowed) < 2:
        assert (own, rest) == (None, None)  # nothing left for the devices: no pinning
        return
    assert own == {allowed[-1]} and rest == set(allowed[:-1])
    assert footprint._pinned(1.0)[0] == {allowed[-1]}
    # As many CPUs as the quota needs, whole: 1.5 CPUs are two.
    assert footprint._pinned(len(allowed)) == (None, None)
    if len(allowed) > 2:
        assert len(footprint._pinned(1.5)[0]) == 2


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
    # Held to one whole CPU for a quota of 1.0 where the machine has another for the devices.
    pinned = footprint._pinned(1.0)[0]
    assert report["on_cpus"] == (sorted(pinned) if pinned else None)
    # By default the simulated camera is a device outside the set, measured on its own.
    assert report["devices"] == "outside"
    assert report["outside_set"]["sim-camera"]["rss_mb"] > 10
    # So are the simulated hand and tactor controller (one device process, the hand on a
    # python-can serial bus over a pty): not a service of the set.
    assert report["outside_set"]["sim-hand+tactors"]["rss_mb"] > 10
    assert "hand_sim" not in report["services"]
    assert report["topics"]["lpc/prosthesis/state"]["rate_hz"] > 50
    services = report["services"]
    for name in ("camera", "scans", "reconstructor", "aim", "controller", "recorder"):
        assert services[name]["cpu_from"] == "event loop", name
    assert services["prosthesis_bridge"]["cpu_from"] == "process"
    assert services["container"]["rss_mb"] > 10
    assert report["totals"]["processes"] >= 3  # supervisor, container, bridge (+ workers)
    assert report["topics"]["lpc/emg"]["rate_hz"] > 0  # read back from the recording
    # The container's CPU by thread: its loops and the recorder's writer by their names.
    threads = report["container_threads"]
    assert {"main loop", "control loop", "recorder writer", "Zenoh"} <= threads.keys()
    assert threads["main loop"] > 0 and threads["control loop"] > 0
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


def _fake_task(proc: Path, pid: int, tid: int, name: str, utime: int, stime: int) -> None:
    task = proc / str(pid) / "task" / str(tid)
    task.mkdir(parents=True, exist_ok=True)
    # /proc/PID/task/TID/stat: utime and stime are the 14th and 15th fields, in clock ticks.
    rest = ["S", "1", "1", "1", "0", "-1", "0", "0", "0", "0", "0", str(utime), str(stime)]
    (task / "stat").write_text(f"{tid} ({name}) " + " ".join(rest + ["0"] * 30) + "\n")


def test_footprint_thread_shares_split_the_container_by_thread(tmp_path: Path) -> None:
    ticks = os.sysconf("SC_CLK_TCK")
    pid = 100
    threads = [
        (100, "python", 3 * ticks, ticks),  # the main loop: the process's own thread
        (101, CONTROL_LOOP, ticks, 0),
        (102, "mcap-writer", ticks, 0),
        (103, "tx-0", 0, ticks),
        (104, "rx-1", ticks, 0),
        (105, "python", ticks, 0),  # a Zenoh callback thread
        (106, "a (b) c", ticks, 0),  # a name with spaces and parentheses
    ]
    for tid, name, utime, stime in threads:
        _fake_task(tmp_path, pid, tid, name, utime, stime)
    start = thread_times(pid, tmp_path)
    assert start[106] == ("a (b) c", 1.0)
    assert start[100] == ("python", 4.0)
    _fake_task(tmp_path, pid, 100, "python", 5 * ticks, 2 * ticks)  # +3 s
    _fake_task(tmp_path, pid, 101, CONTROL_LOOP, 2 * ticks, 0)  # +1 s
    _fake_task(tmp_path, pid, 103, "tx-0", 0, 3 * ticks)  # +2 s
    _fake_task(tmp_path, pid, 107, "acc-0", ticks, 0)  # new since the start: all of it
    shares = thread_shares(pid, start, thread_times(pid, tmp_path))
    assert shares == {
        "main loop": 3.0,
        "control loop": 1.0,
        "recorder writer": 0.0,
        "Zenoh": 3.0,
        "other": 0.0,
    }


def _fake_wakeups(proc: Path, pid: int, tid: int, name: str, voluntary: int) -> None:
    _fake_task(proc, pid, tid, name, 0, 0)
    (proc / str(pid) / "task" / str(tid) / "status").write_text(
        f"Name:\t{name}\nvoluntary_ctxt_switches:\t{voluntary}\nnonvoluntary_ctxt_switches:\t7\n"
    )


def test_footprint_counts_wake_ups_per_part_of_the_container(tmp_path: Path) -> None:
    pid = 100
    for tid, name, voluntary in [
        (100, "python", 50),  # the main loop
        (101, CONTROL_LOOP, 1000),
        (103, "tx-0", 400),
        (104, "rx-1", 300),
        (105, "python", 20),  # zenoh-python's callback thread
    ]:
        _fake_wakeups(tmp_path, pid, tid, name, voluntary)
    start = thread_wakeups(pid, tmp_path)
    assert start[101] == (CONTROL_LOOP, 1000)
    _fake_wakeups(tmp_path, pid, 101, CONTROL_LOOP, 3000)  # 200 a second over 10 s
    _fake_wakeups(tmp_path, pid, 103, "tx-0", 1400)
    _fake_wakeups(tmp_path, pid, 105, "python", 1020)
    _fake_wakeups(tmp_path, pid, 106, "rx-0", 90)  # new since the start: all of it
    end = thread_wakeups(pid, tmp_path)
    assert wakeup_counts(pid, start, end, by_thread=True) == {
        "main loop": 0,
        "control loop": 2000,
        "Zenoh": 1090,
        "other": 1000,
    }
    assert wakeup_counts(pid, start, end, by_thread=False) == {"all": 4090}


def test_footprint_sees_the_name_a_thread_gives_itself() -> None:
    seen: list[str] = []

    def run() -> None:
        if name_native_thread(CONTROL_LOOP):
            seen.append(thread_times(os.getpid())[threading.get_native_id()][0])

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    if sys.platform.startswith("linux"):
        assert seen == [CONTROL_LOOP]
