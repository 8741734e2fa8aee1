"""``lpc bench soak --minutes N``: the whole service set at 90 Hz for N minutes, with per-process
rates, drops, latency percentiles and resident memory over time, and each process's memory
slope (MB/min, least-squares line after a warm-up).

It runs ``lpc up`` as a subprocess (the same machinery a user runs), listens to every
service's ``lpc/health/*`` report and samples it every ``--sample-every`` seconds. It also
counts sequence gaps on every topic it sees (``lost``): a gap on a sensor topic is a frame its
publisher skipped or the bus dropped; on a command topic it is a loss.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import zenoh

from schemas import BadMessage, Health, decode
from services.children import stop
from services.runtime import zenoh_config

START_TIMEOUT_S = 90.0


class _Seq(msgspec.Struct):
    """Just the sequence number of any message (the rest of the payload is skipped)."""

    seq: int


_SEQ = msgspec.msgpack.Decoder(_Seq)


@dataclass
class Sample:
    t_s: float
    pid: int
    rss_mb: float
    rates_hz: dict[str, float]
    latency_ms: dict[str, float]
    counters: dict[str, int]


@dataclass
class ProcessReport:
    service: str
    samples: list[Sample] = field(default_factory=list)
    pids: list[int] = field(default_factory=list)

    def summary(self, warmup_s: float) -> dict[str, Any]:
        s = self.samples
        if not s:
            return {"service": self.service, "samples": 0}
        last = s[-1]
        steady = [x for x in s if x.t_s >= warmup_s] or s
        rates: dict[str, float] = defaultdict(float)
        for x in steady:
            for key, hz in x.rates_hz.items():
                rates[key] += hz / len(steady)
        p99s = [x.latency_ms["p99"] for x in steady if "p99" in x.latency_ms]
        p50s = [x.latency_ms["p50"] for x in steady if "p50" in x.latency_ms]
        return {
            "service": self.service,
            "samples": len(s),
            "restarts": len(self.pids) - 1,
            "rates_hz": {k: round(v, 2) for k, v in rates.items()},
            "latency_ms": {
                "p50_median": round(float(np.median(p50s)), 3) if p50s else None,
                "p99_median": round(float(np.median(p99s)), 3) if p99s else None,
                "p99_max": round(max(p99s), 3) if p99s else None,
            },
            "received": last.counters.get("received", 0),
            "published": last.counters.get("published", 0),
            "dropped": last.counters.get("dropped", 0),
            "rejected": last.counters.get("rejected", 0),
            "rss_mb": {
                "first": round(s[0].rss_mb, 1),
                "last": round(last.rss_mb, 1),
                "max": round(max(x.rss_mb for x in s), 1),
            },
            "rss_slope_mb_per_min": memory_slope(
                [x.t_s for x in steady], [x.rss_mb for x in steady]
            ),
        }


def memory_slope(t_s: list[float], rss_mb: list[float]) -> float | None:
    """Least-squares slope of resident memory, MB per minute; None with fewer than 3 samples."""
    if len(t_s) < 3 or max(t_s) - min(t_s) <= 0:
        return None
    slope, _ = np.polyfit(np.asarray(t_s) / 60.0, np.asarray(rss_mb), 1)
    return round(float(slope), 4)


class Watcher:
    """Health samples and sequence gaps, gathered on Zenoh's threads behind one lock."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.latest: dict[str, Health] = {}
        self.last_seq: dict[str, int] = {}
        self.seen: dict[str, int] = defaultdict(int)
        self.lost: dict[str, int] = defaultdict(int)
        self.undecodable = 0

    def on_health(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            health = decode(key, sample.payload.to_bytes())
        except (BadMessage, KeyError, ValueError):
            with self.lock:
                self.undecodable += 1
            return
        with self.lock:
            self.latest[health.service] = health

    def on_message(self, sample: zenoh.Sample) -> None:
        self.count(str(sample.key_expr), sample.payload.to_bytes())

    def count(self, key: str, payload: bytes) -> None:
        """One message on ``key``, seen live or read back from a recording."""
        if key.startswith(("lpc/health/", "lpc/log/")):
            return  # per-service counters restart with the service
        try:
            seq = _SEQ.decode(payload).seq
        except (msgspec.DecodeError, ValueError):
            with self.lock:
                self.undecodable += 1
            return
        with self.lock:
            self.seen[key] += 1
            previous = self.last_seq.get(key)
            if previous is not None and seq > previous + 1:
                self.lost[key] += seq - previous - 1
            self.last_seq[key] = seq  # a restart (seq going back) starts afresh

    def sample_into(self, reports: dict[str, ProcessReport], t_s: float) -> None:
        """Append each service's latest health to its report, noting a new pid (a restart)."""
        with self.lock:
            latest = dict(self.latest)
        for name, h in latest.items():
            report = reports.setdefault(name, ProcessReport(name))
            if not report.pids or report.pids[-1] != h.pid:
                report.pids.append(h.pid)
            report.samples.append(
                Sample(
                    t_s=round(t_s, 3),
                    pid=h.pid,
                    rss_mb=h.rss_bytes / 2**20,
                    rates_hz=dict(h.rates_hz),
                    latency_ms=dict(h.latency_ms),
                    counters=dict(h.counters),
                )
            )


@contextlib.contextmanager
def lpc_up(
    argv: list[str], preexec_fn: Callable[[], None] | None = None
) -> Iterator[tuple[subprocess.Popen[str], threading.Event, list[str]]]:
    """``lpc up`` (``argv``) in a session of its own: its stderr lines gathered in ``log``,
    ``started`` set once its services are up. On leaving it gets SIGINT, as a person's ^C,
    and is killed if it has not stopped 30 s later."""
    up = subprocess.Popen(
        argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        text=True, start_new_session=True, preexec_fn=preexec_fn,
    )  # fmt: skip
    started = threading.Event()
    log: list[str] = []

    def read_stderr() -> None:
        for line in up.stderr or []:
            log.append(line.rstrip())
            if "services up" in line:
                started.set()

    threading.Thread(target=read_stderr, daemon=True).start()
    try:
        yield up, started, log
    finally:
        stop(up, signal.SIGINT, grace_s=30)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--minutes", type=float, default=30.0, help="soak duration (default 30 minutes)"
    )
    parser.add_argument(
        "--sample-every", type=float, default=10.0, metavar="S", help="sampling period (s)"
    )
    parser.add_argument("--rate", type=float, default=90.0, help="camera rate (default 90 Hz)")
    parser.add_argument("--port", type=int, default=7457, help="rendezvous port (loopback)")
    parser.add_argument("--services", nargs="+", metavar="NAME", help="passed to lpc up")
    parser.add_argument("--record", metavar="PATH", help="record the session (lpc up --record)")
    parser.add_argument(
        "--warmup", type=float, default=None, metavar="S",
        help="seconds left out of rates and slopes (default: 20%% of the run, at most 60 s)",
    )  # fmt: skip
    parser.add_argument("--json", metavar="FILE", help="write the full report (with series)")


def _validate(args: argparse.Namespace) -> str | None:
    if not 0 < args.minutes <= 24 * 60:
        return "--minutes must be in (0, 1440]"
    if not 0.5 <= args.sample_every <= 600:
        return "--sample-every must be in [0.5, 600] seconds"
    if not 0 < args.rate <= 1000:
        return "--rate must be in (0, 1000] Hz"
    if not 1 <= args.port <= 65535:
        return "--port must be a TCP port number"
    if args.warmup is not None and not 0 <= args.warmup < args.minutes * 60:
        return "--warmup must be in [0, the run's length)"
    return None


def run(args: argparse.Namespace) -> int:
    problem = _validate(args)
    if problem:
        print(f"lpc bench soak: error: {problem}", file=sys.stderr)
        return 2
    duration_s = args.minutes * 60.0
    warmup_s = args.warmup if args.warmup is not None else min(60.0, 0.2 * duration_s)
    argv = [
        sys.executable, "-m", "services.cli", "up", "--duration", f"{duration_s:g}",
        "--port", str(args.port), "--rate", f"{args.rate:g}", "--status-every", "3600",
    ]  # fmt: skip
    if args.services:
        argv += ["--services", *args.services]
    if args.record:
        argv += ["--record", args.record]
    print(f"lpc bench soak: {args.minutes:g} min at {args.rate:g} Hz: {' '.join(argv[2:])}")
    with lpc_up(argv) as (up, started, log):
        try:
            report = _soak(args, up, started, log, duration_s)
        except KeyboardInterrupt:
            report = None
    if report is None:
        print("lpc bench soak: error: lpc up did not start:\n" + "\n".join(log[-20:]))
        return 1
    watcher, processes = report
    result = _result(args, watcher, processes, warmup_s, up.returncode, log)
    _print(result)
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
        print(f"report: {args.json}")
    return 0 if up.returncode == 0 else 1


def _soak(
    args: argparse.Namespace,
    up: subprocess.Popen[str],
    started: threading.Event,
    log: list[str],
    duration_s: float,
) -> tuple[Watcher, dict[str, ProcessReport]] | None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while not started.wait(0.1):
        if up.poll() is not None or time.monotonic() > deadline:
            return None
    t0 = time.monotonic()
    watcher = Watcher()
    processes: dict[str, ProcessReport] = {}
    conf = zenoh_config(connect=[f"tcp/127.0.0.1:{args.port}"])
    with zenoh.open(conf) as session:
        session.declare_subscriber("lpc/health/*", watcher.on_health)
        session.declare_subscriber("lpc/**", watcher.on_message)
        next_sample = t0 + args.sample_every
        while up.poll() is None and time.monotonic() - t0 < duration_s + 5.0:
            time.sleep(max(0.0, min(next_sample - time.monotonic(), 0.5)))
            now = time.monotonic()
            if now < next_sample:
                continue
            next_sample += args.sample_every
            watcher.sample_into(processes, now - t0)
            elapsed = now - t0
            total = sum(p.samples[-1].rss_mb for p in processes.values() if p.samples)
            print(
                f"t = {elapsed:7.1f} s  processes {len(processes)}  rss total {total:7.1f} MB  "
                f"lost {sum(watcher.lost.values())}",
                flush=True,
            )
    return watcher, processes


def _result(
    args: argparse.Namespace,
    watcher: Watcher,
    processes: dict[str, ProcessReport],
    warmup_s: float,
    up_exit: int | None,
    log: list[str],
) -> dict[str, Any]:
    return {
        "minutes": args.minutes,
        "rate_hz": args.rate,
        "warmup_s": warmup_s,
        "lpc_up_exit": up_exit,
        "restarts_logged": [ln for ln in log if "restart" in ln],
        "processes": {n: p.summary(warmup_s) for n, p in sorted(processes.items())},
        "topics": {
            k: {"seen": watcher.seen[k], "lost": watcher.lost.get(k, 0)}
            for k in sorted(watcher.seen)
        },
        "lost_total": sum(watcher.lost.values()),
        "series": {n: [asdict(s) for s in p.samples] for n, p in sorted(processes.items())},
    }


def _print(result: dict[str, Any]) -> None:
    print(
        f"\n{'process':<18}{'rate Hz':>9}{'p50 ms':>9}{'p99 ms':>9}{'drop':>7}{'rej':>6}"
        f"{'rss MB first/last/max':>24}{'slope MB/min':>14}{'restarts':>9}"
    )
    for name, p in result["processes"].items():
        if not p.get("samples"):
            print(f"{name:<18} (no samples)")
            continue
        rate = max(p["rates_hz"].values(), default=0.0)
        lat = p["latency_ms"]
        rss = p["rss_mb"]
        slope = p["rss_slope_mb_per_min"]
        memory = f"{rss['first']:.0f} / {rss['last']:.0f} / {rss['max']:.0f}"
        print(
            f"{name:<18}{rate:>9.1f}{_fmt(lat['p50_median']):>9}{_fmt(lat['p99_median']):>9}"
            f"{p['dropped']:>7}{p['rejected']:>6}"
            f"{memory:>24}"
            f"{_fmt(slope, 3):>14}{p['restarts']:>9}"
        )
    print("\ntopic                          seen     lost (sequence gaps)")
    for key, t in result["topics"].items():
        print(f"{key:<28}{t['seen']:>8}{t['lost']:>9}")
    print(f"lost in total: {result['lost_total']}; lpc up exit: {result['lpc_up_exit']}")


def _fmt(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


if __name__ == "__main__":
    _parser = argparse.ArgumentParser(prog="lpc bench soak", description=__doc__)
    add_arguments(_parser)
    sys.exit(run(_parser.parse_args()))
