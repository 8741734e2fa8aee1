"""``lpc bench footprint``: the whole set (``lpc up --source sim``) confined to ``--cpus`` CPUs,
as on the small computer worn with the prosthesis: per service its CPU share, resident memory,
rates, drops and capture latency, then the totals and the figures the set must keep.

The quota is the kernel's CFS bandwidth control through the cgroup interface: v2 ``cpu.max``
or v1 ``cpu.cfs_quota_us``, whichever this machine has (needs root). ``lpc up`` is started
inside a fresh cgroup, so every service and the reconstructor's workers share the quota; the
cgroup's weight is raised so that other work on the machine cannot take the quota from it, and
the cgroup is removed afterwards, also on failure. Without ``--cpus`` the set runs unconfined
(and shares the machine with whatever else runs on it).

The set is also held to ``ceil(C)`` CPUs (its affinity; the simulated devices take the other
CPUs), as the quota of a small board's core is one core's time, not a share of every core's.
Spread over this machine's two CPUs, a quota of 0.5 in 10 ms periods is one 5 ms slice of
runtime (the kernel's ``sched_cfs_bandwidth_slice_us``): the first CPU to run a thread of the
set takes all of it, and a thread woken on the other CPU waits throttled for the next period
while runtime lies unused on the first. Measured at load 20 with the recorder on: spread, the
set used 0.389 CPU of its 0.5 and the camera ran at 40 Hz; held to one CPU, 0.467 CPU and
79 Hz. ``--spread`` measures the old way.

The simulated camera is a device, as the RealSense is on the worn computer, where its own chip
makes the depth and the camera service only receives finished frames. So by default
(``--devices outside``) it runs as ``lpc sim-camera``, started before the set and stopped after
it, outside the quota, and the set reads it with ``--source sim-device``; its own CPU and memory
are printed on a line of their own, not in the set's totals. So are the simulated hand and
tactor controller, physical devices on the worn computer too: one device process
(``python -m services.hand_sim --ports-file``) serves the hand on python-can's serial bus over a
pty (this kernel has no vcan) and the tactors on another pty, and the set drives them with
``lpc up --hand-can serial:PORT --tactor-port PORT``. ``--devices inside`` measures the set as
``lpc up --source sim``, rendering in the camera service, the hand simulated in the prosthesis
bridge and the tactors in the tactor bridge, under the quota.

CPU and memory come from the processes themselves (psutil: user + system time over the
measured window, and resident set size); with ``--together`` the per-service CPU is what
each service's tasks took on the shared event loop (its health's ``cpu_ms``), and the rest of
the process (Zenoh's threads, the loop itself) is shown apart. Rates and latencies come from
each service's ``lpc/health``. Sequence gaps, the share of frames scanned and reconstructed, and
the capture -> tactor command latency end to end come from every small topic (not depth): with
the recorder on, read from its recording after the run, since a subscriber in the bench loads
what it measures (every message it takes is one more the set sends: 10-16 % of a core for the
container at 90 Hz); without it, or with ``--live-topics``, from the bench's subscribers.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import zenoh

from schemas import TOPICS
from services.children import stop
from services.cli.bench.soak import ProcessReport, Watcher, lpc_up
from services.cli.up import SERVICES
from services.mcap_log import McapLogError, free_path, read_messages
from services.runtime import zenoh_config
from services.thread_names import CONTROL_LOOP, RECORDER_WRITER

START_TIMEOUT_S = 90.0
# The CFS period. At the kernel's default of 100 ms, a set held to 0.5 CPU runs 50 ms, then is
# frozen for 50 ms: every latency gets up to 50 ms that a core of half the speed would not
# add. A 10 ms period bounds the freeze to 5 ms, nearer to a slower core.
PERIOD_US = 10_000
# The cgroup's CPU weight, in multiples of the default. A cgroup weighs as much as one task
# beside it: on a machine busy with other work, the set would get far less than its quota
# (measured here at load 20: 0.2 CPU of a 1.0 quota). Weighted up, the quota is its ceiling
# and, nearly, its floor: the figures then measure the set, not its neighbours.
WEIGHT = 100
# Frame-derived topics: their frame_seq says which camera frame they came from.
FRAME_TOPICS = ("lpc/scans", "lpc/reconstruction", "lpc/grasp/target", "lpc/aim/cue")
CAPTURE_TOPICS = (*FRAME_TOPICS, "lpc/tactors/command")
# Health counters of a service's own CPU time (in the container, where no process is its own).
OWN_CPU = ("cpu_ms", "writer_cpu_ms")
# Health counters shown in a service's drops column, as they grew over the measured window:
# late_ticks is the control path's lateness, shed_frames the frames the camera shed for it.
DROP_COUNTERS = (
    "dropped", "dropped_frames", "late_frames", "stale_commands", "late_ticks", "shed_frames",
)  # fmt: skip


class _Stamp(msgspec.Struct):
    """The header of any message, and the frame it came from when it says so."""

    seq: int
    t_ns: int
    frame_seq: int = -1


_STAMP = msgspec.msgpack.Decoder(_Stamp)


# --------------------------------------------------------------------------- cgroup


class QuotaUnavailable(Exception):
    """No cgroup CPU controller this process may use (not root, not Linux, none mounted)."""


@dataclass
class CpuQuota:
    """A fresh cgroup with a CFS quota of ``cpus`` CPUs (None: no ceiling, only the weight),
    named after this process and ``suffix``; ``close`` removes it."""

    cpus: float | None
    suffix: str = ""
    on: frozenset[int] | None = None
    path: Path = field(init=False)
    version: int = field(init=False)

    def __post_init__(self) -> None:
        self.path, self.version = _make_cgroup(f"lpc-footprint-{os.getpid()}{self.suffix}")
        # The kernel's least quota is 1 ms; -1 / "max" is none.
        quota_us = -1 if self.cpus is None else max(1000, round(self.cpus * PERIOD_US))
        try:
            if self.version == 2:
                limit = "max" if quota_us < 0 else str(quota_us)
                (self.path / "cpu.max").write_text(f"{limit} {PERIOD_US}")
                (self.path / "cpu.weight").write_text(str(100 * WEIGHT))
            else:
                (self.path / "cpu.cfs_period_us").write_text(str(PERIOD_US))
                (self.path / "cpu.cfs_quota_us").write_text(str(quota_us))
                (self.path / "cpu.shares").write_text(str(1024 * WEIGHT))
        except OSError as exc:
            self.close()
            raise QuotaUnavailable(f"cannot set the CPU quota in {self.path}: {exc}") from exc

    def enter(self) -> None:
        """Move the calling process into the cgroup (run in the child before exec)."""
        (self.path / "cgroup.procs").write_text(str(os.getpid()))
        if self.on:
            os.sched_setaffinity(0, self.on)

    def stat(self) -> dict[str, int]:
        """The cgroup's CPU accounting: throttled periods and time, as the kernel counts it."""
        out: dict[str, int] = {}
        with contextlib.suppress(OSError, ValueError):
            for line in (self.path / "cpu.stat").read_text().splitlines():
                key, value = line.split()
                out[key] = int(value)
        return out

    def close(self) -> None:
        """Kill what is left inside (only processes this bench started are there), remove."""
        procs = self.path / "cgroup.procs"
        for _ in range(50):
            try:
                pids = [int(p) for p in procs.read_text().split()]
            except OSError:
                return  # already gone
            if not pids:
                break
            for pid in pids:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            time.sleep(0.1)
        with contextlib.suppress(OSError):
            self.path.rmdir()


def _pinned(cpus: float) -> tuple[frozenset[int] | None, frozenset[int] | None]:
    """The CPUs the set is held to for a quota of ``cpus`` (the last ``ceil(cpus)`` this
    process may use) and the rest, for the devices (None: all, where none are left)."""
    allowed = sorted(os.sched_getaffinity(0))
    need = max(1, math.ceil(cpus - 1e-9))
    if need >= len(allowed):
        return None, None
    return frozenset(allowed[-need:]), frozenset(allowed[:-need])


def _make_cgroup(name: str) -> tuple[Path, int]:
    """A new cgroup with the cpu controller: v2 if its hierarchy offers cpu, else v1's."""
    if sys.platform != "linux":
        raise QuotaUnavailable("CPU quotas need Linux cgroups")
    mounts: list[tuple[str, str, set[str]]] = []
    with contextlib.suppress(OSError):
        for line in Path("/proc/mounts").read_text().splitlines():
            _, where, kind, options, *_ = line.split()
            mounts.append((where, kind, set(options.split(","))))
    problems = []
    for where, kind, _ in mounts:
        if kind != "cgroup2":
            continue
        root = Path(where)
        try:
            if "cpu" not in (root / "cgroup.controllers").read_text().split():
                problems.append(f"{where}: cgroup v2 without the cpu controller")
                continue
            if "cpu" not in (root / "cgroup.subtree_control").read_text().split():
                (root / "cgroup.subtree_control").write_text("+cpu")
            path = root / name
            path.mkdir()
            return path, 2
        except OSError as exc:
            problems.append(f"{where}: {exc}")
    for where, kind, options in mounts:
        if kind == "cgroup" and "cpu" in options:
            path = Path(where) / name
            try:
                path.mkdir()
            except OSError as exc:
                problems.append(f"{where}: {exc}")
                continue
            return path, 1
    why = "; ".join(problems) or "no cgroup filesystem with the cpu controller is mounted"
    hint = "" if os.geteuid() == 0 else " (creating a cgroup needs root)"
    raise QuotaUnavailable(f"cannot confine the set to a CPU quota: {why}{hint}")


# --------------------------------------------------------------------------- observers


@dataclass
class Captures:
    """Per capture-derived topic: frame sequence numbers and capture -> arrival latencies."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    t_from_ns: int = 0
    t_to_ns: int = 2**63 - 1
    frames: dict[str, set[int]] = field(default_factory=lambda: defaultdict(set))
    latencies_ms: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    frame_times: dict[int, int] = field(default_factory=dict)

    def on_sample(self, sample: zenoh.Sample) -> None:
        self.add(str(sample.key_expr), sample.payload.to_bytes(), time.time_ns())

    def add(self, key: str, payload: bytes, received: int) -> None:
        """One message on ``key`` that arrived at ``received`` (ns), live or recorded."""
        try:
            stamp = _STAMP.decode(payload)
        except (msgspec.DecodeError, ValueError):
            return
        if not self.t_from_ns <= stamp.t_ns <= self.t_to_ns:
            return
        with self.lock:
            self.latencies_ms[key].append((received - stamp.t_ns) / 1e6)
            if stamp.frame_seq >= 0:
                self.frames[key].add(stamp.frame_seq)
                self.frame_times.setdefault(stamp.frame_seq, stamp.t_ns)


# Zenoh's own threads (its runtimes: receive, transmit, network, accept, application).
_ZENOH_THREADS = re.compile(r"(rx|tx|net|acc|app)-\d+")


def _thread_group(name: str, tid: int, pid: int) -> str:
    """Which part of the container a thread is, by its kernel name (``services.thread_names``)."""
    if tid == pid:
        return "main loop"
    if name == CONTROL_LOOP:
        return "control loop"
    if name == RECORDER_WRITER:
        return "recorder writer"
    if _ZENOH_THREADS.fullmatch(name):
        return "Zenoh"
    return "other"  # Zenoh's callbacks into Python, drivers' threads


def thread_times(pid: int, proc: Path = Path("/proc")) -> dict[int, tuple[str, float]]:
    """CPU seconds (user + system) and kernel name of each live thread of ``pid``."""
    ticks = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    times: dict[int, tuple[str, float]] = {}
    for tid, _, name, fields in _tasks(pid, proc):
        with contextlib.suppress(ValueError, IndexError):
            times[tid] = (name, (int(fields[11]) + int(fields[12])) / ticks)
    return times


def _tasks(pid: int, proc: Path) -> Iterator[tuple[int, Path, str, list[str]]]:
    """Each live thread of ``pid``: its id, /proc directory, kernel name and the fields of its
    ``stat`` after the name; a thread that ended meanwhile is skipped."""
    with contextlib.suppress(OSError):
        for task in (proc / str(pid) / "task").iterdir():
            with contextlib.suppress(OSError, ValueError):
                stat = (task / "stat").read_text()
                # The name sits in parentheses and may hold spaces: fields follow the last ')'.
                close = stat.rindex(")")
                name = stat[stat.index("(") + 1 : close]
                yield int(task.name), task, name, stat[close + 2 :].split()


def thread_shares(
    pid: int, start: dict[int, tuple[str, float]], end: dict[int, tuple[str, float]]
) -> dict[str, float]:
    """CPU seconds per part of the process (``_thread_group``) between two ``thread_times``."""
    shares: dict[str, float] = defaultdict(float)
    for tid, (name, cpu) in end.items():
        shares[_thread_group(name, tid, pid)] += cpu - start.get(tid, (name, 0.0))[1]
    return dict(shares)


def thread_wakeups(pid: int, proc: Path = Path("/proc")) -> dict[int, tuple[str, int]]:
    """Voluntary context switches (the times it slept and was woken) and kernel name of each
    live thread of ``pid``. On a virtual machine each wake-up costs tens of µs of CPU whatever
    the thread then does, so a 100 Hz path is as dear as the hand-overs it makes per message."""
    counts: dict[int, tuple[str, int]] = {}
    for tid, task, name, _ in _tasks(pid, proc):
        with contextlib.suppress(OSError, ValueError, IndexError):
            for line in (task / "status").read_text().splitlines():
                if line.startswith("voluntary_ctxt_switches:"):
                    counts[tid] = (name, int(line.split()[1]))
    return counts


def wakeup_counts(
    pid: int,
    start: dict[int, tuple[str, int]],
    end: dict[int, tuple[str, int]],
    *,
    by_thread: bool,
) -> dict[str, int]:
    """Wake-ups between two ``thread_wakeups`` of one process: per part of the container
    (``_thread_group``) with ``by_thread``, else all of the process's threads as ``"all"``."""
    counts: dict[str, int] = defaultdict(int)
    for tid, (name, n) in end.items():
        group = _thread_group(name, tid, pid) if by_thread else "all"
        counts[group] += n - start.get(tid, (name, 0))[1]
    return dict(counts)


@dataclass
class Proc:
    """One process of the set, named after its service (workers after their parent's)."""

    name: str
    cpu_start: float
    cpu_last: float
    rss: list[int] = field(default_factory=list)
    # Its threads' voluntary context switches at the window's start and at the latest sample.
    wakeups_start: dict[int, tuple[str, int]] = field(default_factory=dict)
    wakeups_last: dict[int, tuple[str, int]] = field(default_factory=dict)


def _process_name(proc: Any, names: dict[int, str]) -> str:
    try:
        cmdline = proc.cmdline()
    except Exception:  # psutil.Error, and a process gone between listing and asking
        return "?"
    module = cmdline[cmdline.index("-m") + 1] if "-m" in cmdline else None
    if module is not None and module != "services.pipe_pool":
        for name, spec in SERVICES.items():
            if spec.module == module:
                return name
        if module == "services.cli":
            return "supervisor"
        return module.rsplit(".", 1)[-1]
    with contextlib.suppress(Exception):
        return names.get(proc.ppid(), "?") + " workers"
    return "?"


class Sampler:
    """CPU times and RSS of every process under ``lpc up``, sampled once a second."""

    def __init__(self, root_pid: int) -> None:
        import psutil

        self._psutil = psutil
        self.root = psutil.Process(root_pid)
        self.procs: dict[int, Proc] = {}
        self.names: dict[int, str] = {}
        self.totals: list[int] = []
        # The container's threads at the window's start and at the latest sample.
        self.threads_start: dict[int, tuple[str, float]] = {}
        self.threads_last: dict[int, tuple[str, float]] = {}
        self.container_pid: int | None = None

    def sample(self) -> None:
        psutil = self._psutil
        try:
            tree = [self.root, *self.root.children(recursive=True)]
        except psutil.Error:
            return
        total = 0
        for proc in tree:
            try:
                with proc.oneshot():
                    times = proc.cpu_times()
                    rss = proc.memory_info().rss
            except psutil.Error:
                continue
            cpu = times.user + times.system
            if proc.pid not in self.procs:
                self.names[proc.pid] = _process_name(proc, self.names)
                self.procs[proc.pid] = Proc(self.names[proc.pid], cpu, cpu)
            entry = self.procs[proc.pid]
            entry.cpu_last = cpu
            entry.wakeups_last = thread_wakeups(proc.pid)
            if entry.name == "container":
                if proc.pid != self.container_pid:  # a restarted container starts afresh
                    self.container_pid, self.threads_start = proc.pid, {}
                self.threads_last = thread_times(proc.pid)
            entry.rss.append(rss)
            total += rss
        self.totals.append(total)

    def restart_window(self) -> None:
        for entry in self.procs.values():
            entry.cpu_start = entry.cpu_last
            entry.wakeups_start = entry.wakeups_last
            entry.rss.clear()
        self.totals.clear()
        self.threads_start = self.threads_last

    def memory_detail(self) -> dict[str, int]:
        """USS and PSS of the whole set now (shared library pages counted once)."""
        psutil = self._psutil
        uss = pss = 0
        with contextlib.suppress(psutil.Error):
            for proc in [self.root, *self.root.children(recursive=True)]:
                with contextlib.suppress(psutil.Error):
                    full = proc.memory_full_info()
                    uss += full.uss
                    pss += getattr(full, "pss", 0)
        return {"uss": uss, "pss": pss}


# --------------------------------------------------------------------------- command


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--cpus",
        type=float,
        metavar="C",
        help="confine the whole set to C CPUs (a cgroup CPU quota; default: no quota)",
    )
    parser.add_argument(
        "--spread",
        action="store_true",
        help="with --cpus, let the set's threads run on every CPU under the quota (default: "
        "held to ceil(C) CPUs, the simulated devices on the others)",
    )
    parser.add_argument(
        "--seconds", type=float, default=30.0, metavar="S", help="measured seconds (default 30)"
    )
    parser.add_argument(
        "--warmup", type=float, default=5.0, metavar="S",
        help="seconds after every service is up that are left out (default 5)",
    )  # fmt: skip
    parser.add_argument(
        "--together", action="store_true", help="run the set as lpc up --together (one process)"
    )
    parser.add_argument(
        "--record", action="store_true", help="with the recorder on (to a temporary file)"
    )
    parser.add_argument(
        "--keep",
        metavar="PATH",
        help="with the recorder on, to PATH (kept): per-frame stage times for lpc info",
    )
    parser.add_argument(
        "--devices",
        choices=("outside", "inside"),
        default="outside",
        help="outside (default): the simulated camera (lpc sim-camera), hand and tactors "
        "(services.hand_sim --ports-file) run as devices apart from the set and its quota, as "
        "the RealSense, the hand and the tactor driver are; inside: the set simulates them "
        "(lpc up --source sim), under the quota",
    )
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument("--port", type=int, default=7467, help="rendezvous port (loopback)")
    parser.add_argument("--rate", type=float, default=90.0, help="camera rate (default 90 Hz)")
    parser.add_argument(
        "--live-topics",
        action="store_true",
        help="with the recorder on, still listen to every small topic over Zenoh for the topic "
        "rates, gaps and capture latencies (as without it), instead of reading them from the "
        "recording afterwards; the set then sends each of those messages to the bench too",
    )


def _validate(args: argparse.Namespace) -> str | None:
    if args.cpus is not None and not 0.1 <= args.cpus <= (os.cpu_count() or 1):
        return f"--cpus must be in [0.1, {os.cpu_count() or 1}] (this machine's CPUs)"
    if not 1 <= args.seconds <= 3600:
        return "--seconds must be in [1, 3600]"
    if not 0 <= args.warmup <= 600:
        return "--warmup must be in [0, 600]"
    if not 1 <= args.port <= 65535:
        return "--port must be a TCP port number"
    if not 0 < args.rate <= 1000:
        return "--rate must be in (0, 1000] Hz"
    return None


def run(args: argparse.Namespace) -> int:
    problem = _validate(args)
    if problem:
        print(f"lpc bench footprint: error: {problem}", file=sys.stderr)
        return 2
    try:
        import psutil  # noqa: F401
    except ImportError:
        print("lpc bench footprint: error: needs psutil: pip install 'lpc[bench]'", file=sys.stderr)
        return 2
    quota = devices = None
    if args.cpus is not None:
        try:
            own, rest = _pinned(args.cpus) if not getattr(args, "spread", False) else (None, None)
            quota = CpuQuota(args.cpus, on=own)
            # The device stands for hardware: out of the quota, and as heavily weighted as the
            # set, so that neighbours on this machine do not slow the camera the set reads.
            if args.devices == "outside":
                devices = CpuQuota(None, "-devices", on=rest)
        except QuotaUnavailable as exc:
            if quota is not None:
                quota.close()
            print(f"lpc bench footprint: error: {exc}", file=sys.stderr)
            return 2
    try:
        with tempfile.TemporaryDirectory(prefix="lpc-footprint-") as tmp:
            result = _measure(args, quota, Path(tmp), devices)
    finally:
        if quota is not None:
            quota.close()
        if devices is not None:
            devices.close()
    if result is None:
        return 1
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        _print(result)
    return 0 if result["lpc_up_exit"] == 0 else 1


def _measure(
    args: argparse.Namespace, quota: CpuQuota | None, tmp: Path, devices: CpuQuota | None = None
) -> dict | None:
    if getattr(args, "devices", "outside") == "inside":
        return _measure_set(args, quota, tmp, ["sim"], {})
    path = tmp / "camera.sock"
    with (
        _sim_camera(args, path, devices) as camera,
        _sim_hand(args, tmp / "ports", devices) as (hand, ports),
    ):
        if camera is None or hand is None:
            which = "lpc sim-camera" if camera is None else "services.hand_sim"
            print(f"lpc bench footprint: error: {which} did not start", file=sys.stderr)
            return None
        source = ["sim-device", str(path), "--hand-can", f"serial:{ports['hand']}"]
        source += ["--tactor-port", ports["tactors"]]
        return _measure_set(
            args, quota, tmp, source, {"sim-camera": camera, "sim-hand+tactors": hand}
        )


@contextlib.contextmanager
def _device(
    argv: list[str], ready: Path, group: CpuQuota | None
) -> Iterator[subprocess.Popen[bytes] | None]:
    """A simulated device (``python -m`` ``argv``) in cgroup ``group`` (not the set's), until
    the set has stopped; None if it has not made ``ready`` (its socket or ports file) in time."""
    device = subprocess.Popen(
        [sys.executable, "-m", *argv],
        stdin=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
        preexec_fn=group.enter if group else None,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while not ready.exists():
            if device.poll() is not None or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        yield device if ready.exists() else None
    finally:
        stop(device)


def _sim_camera(
    args: argparse.Namespace, path: Path, group: CpuQuota | None
) -> contextlib.AbstractContextManager[subprocess.Popen[bytes] | None]:
    """``lpc sim-camera`` on ``path``, in cgroup ``group``."""
    argv = ["services.cli", "sim-camera", "--socket", str(path), "--rate", f"{args.rate:g}"]
    return _device(argv, path, group)


@contextlib.contextmanager
def _sim_hand(
    args: argparse.Namespace, path: Path, group: CpuQuota | None
) -> Iterator[tuple[subprocess.Popen[bytes] | None, dict[str, str]]]:
    """The simulated hand and tactor controller on ptys, in a device process in cgroup
    ``group``: the process and its ports (from ``path``, ``hand PORT`` and ``tactors PORT``
    lines), or None if it does not start. It joins the set's bus (``--port``) to follow the
    pre-shape as the bridge's simulated hand does; Zenoh keeps trying until ``lpc up``
    listens."""
    argv = ["services.hand_sim", "--ports-file", str(path), "--tactors", "eai", "--quiet",
            "--connect", f"tcp/127.0.0.1:{args.port}"]  # fmt: skip
    with _device(argv, path, group) as device:
        if device is None:
            yield None, {}
            return
        yield device, dict(line.split(" ", 1) for line in path.read_text().splitlines())


def _measure_set(
    args: argparse.Namespace,
    quota: CpuQuota | None,
    tmp: Path,
    source: list[str],
    devices: dict[str, subprocess.Popen[bytes]],
) -> dict | None:
    total_s = args.warmup + args.seconds
    argv = [
        sys.executable, "-m", "services.cli", "up", "--source", *source,
        "--duration", f"{total_s + 30:g}", "--port", str(args.port),
        "--rate", f"{args.rate:g}", "--status-every", "3600",
    ]  # fmt: skip
    if args.together:
        argv.append("--together")
    recording = None
    if args.record or getattr(args, "keep", None):
        argv += ["--record", args.keep or str(tmp / "footprint.mcap")]
        # Where the recorder will write (it does not overwrite a kept file: free_path).
        recording = free_path(Path(args.keep)) if args.keep else tmp / "footprint.mcap"
    live = recording is None or getattr(args, "live_topics", False)
    where = f"a quota of {args.cpus:g} CPU (cgroup v{quota.version})" if quota else "no quota"
    if quota and quota.on:
        where += f" on CPU {', '.join(map(str, sorted(quota.on)))}"
    note = f"lpc bench footprint: {args.seconds:g} s after {args.warmup:g} s, {where}:"
    print(note, " ".join(argv[2:]), file=sys.stderr, flush=True)
    with lpc_up(argv, quota.enter if quota else None) as (up, started, log):
        try:
            observed = _observe(args, up, started, quota, devices, live)
        except KeyboardInterrupt:
            observed = None
    if observed is None:
        print("lpc bench footprint: error: lpc up did not start:\n" + "\n".join(log[-20:]))
        return None
    if not live:
        assert recording is not None
        _read_recording(recording, observed[0], observed[1])
    return _result(args, quota, *observed, up.returncode, log)


def _observe(
    args: argparse.Namespace,
    up: subprocess.Popen[str],
    started: threading.Event,
    quota: CpuQuota | None,
    devices: dict[str, subprocess.Popen[bytes]] | None = None,
    live: bool = True,
) -> tuple[Watcher, Captures, Sampler, dict[str, ProcessReport], dict, float] | None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while not started.wait(0.1):
        if up.poll() is not None or time.monotonic() > deadline:
            return None
    watcher, captures, sampler = Watcher(), Captures(), Sampler(up.pid)
    # The devices are no children of lpc up: sampled on their own, out of the set's figures.
    outside = {name: Sampler(device.pid) for name, device in (devices or {}).items()}
    services: dict[str, ProcessReport] = {}
    keys = [t.key for t in TOPICS if t.key != "lpc/camera/depth" and "*" not in t.key]
    conf = zenoh_config(connect=[f"tcp/127.0.0.1:{args.port}"])
    with zenoh.open(conf) as session:
        session.declare_subscriber("lpc/health/*", watcher.on_health)
        # Every subscriber here is one more destination for each message the set publishes: a
        # put to a remote subscriber costs the publisher more, and each message wakes Zenoh's
        # transmit thread. Listening to the small topics cost the container 10-16 % of a core
        # at 90 Hz (see _read_recording); with the recorder on, they are read from its file.
        for key in keys if live else ():
            session.declare_subscriber(key, watcher.on_message)
        for key in CAPTURE_TOPICS if live else ():
            session.declare_subscriber(key, captures.on_sample)
        t0 = time.monotonic()
        window_start = t0 + args.warmup
        captures.t_from_ns = time.time_ns() + round(args.warmup * 1e9)
        captures.t_to_ns = captures.t_from_ns + round(args.seconds * 1e9)
        stat_start: dict[str, int] = {}
        in_window = False
        next_sample = t0
        while up.poll() is None:
            now = time.monotonic()
            if now >= window_start + args.seconds:
                break
            if not in_window and now >= window_start:
                in_window = True
                sampler.restart_window()
                for device in outside.values():
                    device.restart_window()
                stat_start = quota.stat() if quota else {}
                with watcher.lock:
                    watcher.lost.clear()
                    watcher.seen.clear()
            sampler.sample()
            for device in outside.values():
                device.sample()
            if in_window:
                watcher.sample_into(services, now - window_start)
            next_sample += 1.0
            time.sleep(max(0.0, next_sample - time.monotonic()))
        elapsed = time.monotonic() - window_start
        if not live:  # the recording holds what arrived after the window too
            captures.t_to_ns = captures.t_from_ns + round(elapsed * 1e9)
        time.sleep(0.3)  # the last frames of the window arrive
        memory = sampler.memory_detail()
        stat_end = quota.stat() if quota else {}
    throttle = {k: stat_end[k] - stat_start.get(k, 0) for k in stat_end}
    extra = {"memory": memory, "cgroup": throttle, "devices": outside}
    return watcher, captures, sampler, services, extra, elapsed


def _read_recording(path: Path, watcher: Watcher, captures: Captures) -> None:
    """The topic counts, sequence gaps and capture latencies of the measured window, from the
    set's own recording instead of a subscriber in the bench.

    A subscriber in the bench made the set send it every small message: alternating runs of
    the set at 90 Hz (recorder on, no quota, load 6-8), with and without a process holding the
    bench's subscriptions, gave the container 46.1 / 43.0 % of a core without and 56.4 / 59.4 %
    with it (its loop threads and Zenoh's transmit thread; context switches doubled). The
    recorder sees every message anyway. A message's arrival is its ``log_time``: when it reached
    the recorder (in the container, when its publisher handed it over), where the bench's
    subscriber saw it a hop later. Messages count when they arrived inside the window, as the
    bench's subscriber counted them; capture latencies of the frames captured inside it."""
    keys = [t.key for t in TOPICS if t.key != "lpc/camera/depth" and "*" not in t.key]
    capture = set(CAPTURE_TOPICS)
    try:
        for message in read_messages(path, keys, decode=False):
            if captures.t_from_ns <= message.log_time <= captures.t_to_ns:
                watcher.count(message.key, message.payload)
            if message.key in capture:
                captures.add(message.key, message.payload, message.log_time)
    except McapLogError as exc:
        print(f"lpc bench footprint: warning: cannot read the recording: {exc}", file=sys.stderr)


def _percentiles(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"p50": None, "p99": None, "n": 0}
    p50, p99 = np.percentile(values, [50, 99])
    return {"p50": round(float(p50), 2), "p99": round(float(p99), 2), "n": len(values)}


def _result(
    args: argparse.Namespace,
    quota: CpuQuota | None,
    watcher: Watcher,
    captures: Captures,
    sampler: Sampler,
    services: dict[str, ProcessReport],
    extra: dict,
    elapsed: float,
    up_exit: int | None,
    log: list[str],
) -> dict[str, Any]:
    window = max(elapsed, 1e-9)
    # Processes, by name (a restarted service's processes add up).
    cpu: dict[str, float] = defaultdict(float)
    rss_max: dict[str, int] = defaultdict(int)
    rss_last: dict[str, int] = defaultdict(int)
    for entry in sampler.procs.values():
        cpu[entry.name] += entry.cpu_last - entry.cpu_start
        if entry.rss:
            rss_max[entry.name] += max(entry.rss)
            rss_last[entry.name] += entry.rss[-1]
    # Wake-ups a second by process name, and the container's by part (its loops, Zenoh's).
    wakeups: dict[str, float] = defaultdict(float)
    for pid, entry in sampler.procs.items():
        container = entry.name == "container"
        counts = wakeup_counts(pid, entry.wakeups_start, entry.wakeups_last, by_thread=container)
        wakeups[entry.name] += sum(counts.values()) / window
        if container and pid == sampler.container_pid:
            for group, n in counts.items():
                wakeups[f"container {group}"] += n / window
    summaries = {n: r.summary(0.0) for n, r in services.items()}
    # A service's CPU on the container's loop, and on a thread of its own where it has one (the
    # recorder's writer).
    loop_cpu = {
        n: sum(r.samples[-1].counters.get(k, 0) - r.samples[0].counters.get(k, 0) for k in OWN_CPU)
        / 1000.0
        for n, r in services.items()
        if r.samples and "cpu_ms" in r.samples[-1].counters
    }
    rows: dict[str, dict[str, Any]] = {}
    # The simulated hand device joins the bus (it follows the pre-shape): its health is no
    # service's of the set.
    for name in sorted((set(cpu) | set(summaries)) - {"hand_sim"}, key=_order):
        s = summaries.get(name, {})
        counters = services[name].samples[-1].counters if name in services else {}
        first = services[name].samples[0].counters if name in services else {}
        drops = {
            k: counters[k] - first.get(k, 0)
            for k in DROP_COUNTERS
            if counters.get(k, 0) - first.get(k, 0)
        }
        own_cpu = cpu.get(name, loop_cpu.get(name, 0.0))
        rows[name] = {
            "cpu": round(own_cpu / window, 4),
            "cpu_from": "process" if name in cpu else ("event loop" if name in loop_cpu else "-"),
            "rss_mb": round(rss_max[name] / 2**20, 1) if name in rss_max else None,
            "rates_hz": s.get("rates_hz", {}),
            "latency_ms": s.get("latency_ms", {}),
            "drops": drops,
            "restarts": s.get("restarts", 0),
        }
    with captures.lock:
        frames = {k: set(v) for k, v in captures.frames.items()}
        latencies = {k: _percentiles(v) for k, v in captures.latencies_ms.items()}
        frame_times = dict(captures.frame_times)
    seen = set().union(*frames.values()) if frames else set()
    span = (max(seen) - min(seen) + 1) if seen else 0
    camera_hz = None
    if len(seen) >= 2:
        lo, hi = min(seen), max(seen)
        camera_hz = round((hi - lo) / ((frame_times[hi] - frame_times[lo]) / 1e9 or 1e-9), 2)
    coverage = {
        k: round(100.0 * len(frames.get(k, ())) / span, 2) if span else None for k in FRAME_TOPICS
    }
    with watcher.lock:
        topics = {
            k: {"rate_hz": round(watcher.seen[k] / window, 2), "lost": watcher.lost.get(k, 0)}
            for k in sorted(watcher.seen)
        }
    total_cpu = sum(cpu.values())
    threads: dict[str, float] = {}
    unattributed = None
    if sampler.container_pid is not None and sampler.threads_last:
        shares = thread_shares(sampler.container_pid, sampler.threads_start, sampler.threads_last)
        order = ("main loop", "control loop", "recorder writer", "Zenoh", "other")
        threads = {k: round(shares[k] / window, 4) for k in order if k in shares}
        # What the loops and the writer spent outside every service's own time: the loops'
        # passes, hand-overs from Zenoh's threads, health, the timing itself.
        # (The container's own health reports the whole process's CPU: not a service's.)
        on_loops = sum(shares.get(k, 0.0) for k in order[:3])
        own = sum(v for n, v in loop_cpu.items() if n != "container")
        unattributed = round((on_loops - own) / window, 4)
    outside: dict[str, dict[str, float]] = {}
    device: Sampler
    for name, device in extra.get("devices", {}).items():
        outside[name] = {
            "cpu": round(sum(e.cpu_last - e.cpu_start for e in device.procs.values()) / window, 4),
            "rss_mb": round(max(device.totals, default=0) / 2**20, 1),
        }
    return {
        "mode": "together" if args.together else "processes",
        "devices": "outside" if outside else "inside",
        "outside_set": outside,
        "cpus": args.cpus,
        "cgroup": f"v{quota.version}" if quota else None,
        "on_cpus": sorted(quota.on) if quota and quota.on else None,
        "record": args.record or bool(getattr(args, "keep", None)),
        "seconds": round(elapsed, 2),
        "services": rows,
        "totals": {
            "cpu": round(total_cpu / window, 4),
            "rss_mb_max": round(max(sampler.totals, default=0) / 2**20, 1),
            "rss_mb_last": round((sampler.totals or [0])[-1] / 2**20, 1),
            "pss_mb": round(extra["memory"]["pss"] / 2**20, 1),
            "uss_mb": round(extra["memory"]["uss"] / 2**20, 1),
            "processes": len({p for p, e in sampler.procs.items() if e.rss}),
            "throttled": extra["cgroup"],
        },
        "container_threads": threads,
        "wakeups_per_s": {k: round(v, 1) for k, v in sorted(wakeups.items())},
        "container_loops_unattributed": unattributed,
        "frames": {
            "camera_hz": camera_hz,
            "frames": span,
            "shed": rows.get("camera", {}).get("drops", {}).get("shed_frames", 0),
            "coverage_pct": coverage,
        },
        "capture_latency_ms": latencies,
        "topics": topics,
        "lpc_up_exit": up_exit,
        "restarts_logged": [ln for ln in log if "restart" in ln],
    }


def _order(name: str) -> tuple[int, str]:
    order = ["supervisor", "together", *SERVICES]
    base = name.removesuffix(" workers")
    return (order.index(base) if base in order else len(order), name)


def _print(r: dict[str, Any]) -> None:
    quota = f"quota {r['cpus']:g} CPU (cgroup {r['cgroup']})" if r["cpus"] else "no quota"
    if r.get("on_cpus"):
        quota += f" on CPU {', '.join(map(str, r['on_cpus']))}"
    devices = (
        "simulated camera, hand and tactors outside the set (devices, not counted)"
        if r["devices"] == "outside"
        else "simulated camera, hand and tactors inside the set"
    )
    print(
        f"lpc bench footprint: {r['mode']}, {quota}, recorder {'on' if r['record'] else 'off'}, "
        f"{devices}, {r['seconds']:g} s measured"
    )
    print(
        f"\n{'service':<22}{'cpu %':>7}{'rss MB':>8}{'rate Hz':>9}{'p50 ms':>8}{'p99 ms':>8}  drops"
    )
    for name, row in r["services"].items():
        rate = max(row["rates_hz"].values(), default=0.0)
        lat = row["latency_ms"]
        rss = "-" if row["rss_mb"] is None else f"{row['rss_mb']:.0f}"
        drops = ", ".join(f"{k} {v}" for k, v in row["drops"].items()) or "-"
        if row["restarts"]:
            drops += f"; restarts {row['restarts']}"
        print(
            f"{name:<22}{100 * row['cpu']:>7.1f}{rss:>8}{rate:>9.1f}"
            f"{_fmt(lat.get('p50_median')):>8}{_fmt(lat.get('p99_median')):>8}  {drops}"
        )
    t = r["totals"]
    throttled = t["throttled"]
    print(
        f"{'total':<22}{100 * t['cpu']:>7.1f}{t['rss_mb_max']:>8.0f}"
        f"   ({t['processes']} processes; rss last {t['rss_mb_last']:.0f} MB, "
        f"pss {t['pss_mb']:.0f} MB, uss {t['uss_mb']:.0f} MB)"
    )
    for name, device in r["outside_set"].items():
        print(
            f"{name + ' (device)':<22}{100 * device['cpu']:>7.1f}{device['rss_mb']:>8.0f}"
            "   outside the set and its quota, not in the total"
        )
    if r.get("container_threads"):
        parts = ", ".join(f"{k} {100 * v:.1f}" for k, v in r["container_threads"].items())
        print(
            f"container by thread (% of a core): {parts}; on the loops and the writer but in "
            f"no service's own time: {100 * r['container_loops_unattributed']:.1f}"
        )
    if r.get("wakeups_per_s"):
        parts = ", ".join(f"{k} {v:.0f}" for k, v in r["wakeups_per_s"].items())
        print(f"wake-ups a second (voluntary context switches): {parts}")
    if throttled:
        periods = throttled.get("nr_periods", 0)
        share = throttled.get("nr_throttled", 0) / periods if periods else 0.0
        print(f"throttled in {100 * share:.0f}% of the {periods} quota periods")
    f = r["frames"]
    cov = ", ".join(f"{k.removeprefix('lpc/')} {_fmt(v)}%" for k, v in f["coverage_pct"].items())
    shed = f" ({f['shed']} more shed at the camera)" if f.get("shed") else ""
    print(f"\ncamera {_fmt(f['camera_hz'])} Hz over {f['frames']} frames{shed}; of them: {cov}")
    print(f"\n{'capture ->':<24}{'n':>7}{'p50 ms':>9}{'p99 ms':>9}")
    for key, lat in r["capture_latency_ms"].items():
        print(f"{key:<24}{lat['n']:>7}{_fmt(lat['p50']):>9}{_fmt(lat['p99']):>9}")
    print(f"\n{'topic':<26}{'Hz':>8}{'lost':>7}")
    for key, t in r["topics"].items():
        print(f"{key:<26}{t['rate_hz']:>8.1f}{t['lost']:>7}")
    print(f"lpc up exit: {r['lpc_up_exit']}")


def _fmt(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


if __name__ == "__main__":
    _parser = argparse.ArgumentParser(prog="lpc bench footprint", description=__doc__)
    add_arguments(_parser)
    sys.exit(run(_parser.parse_args()))
