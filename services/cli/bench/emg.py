"""``lpc bench emg``: the rate of ``lpc/emg`` from a raw EMG source, and an outage of it.

The real EMG service runs as its own process on a private loopback bus, reading either a
simulated LSL amplifier (a real pylsl outlet in another process, 2 kHz by default, discovery
confined to this machine) or BrainFlow's synthetic board (250 Hz). The bench counts the
envelopes on ``lpc/emg`` for ``--seconds`` after a warm-up and prints their rate by arrival
time and by sample time, against 100 Hz.

``--envelope`` measures the envelope filter alone instead, on raw EMG with a known envelope
(``lpc_core.sim.raw_emg``: a sine or Gaussian-noise carrier, mains hum five times the EMG) at
200 Hz to 2 kHz fed in irregular chunks: its delay and its error.

With ``--outage S`` (LSL only) the controller and the prosthesis bridge (simulated hand) run
too, and the outlet is closed for S seconds, then reopened: the bench prints when the EMG
service reported degraded and resumed, when the controller stopped (its stale-EMG rule) and
what it commanded the hand meanwhile.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import threading
import time
import uuid

import numpy as np
import zenoh

from schemas import decode
from services.runtime import zenoh_config


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source", choices=("lsl", "brainflow"), default="lsl")
    parser.add_argument("--rate", type=float, default=2000.0, help="LSL outlet rate, Hz (2000)")
    parser.add_argument("--seconds", type=float, default=60.0, help="measured seconds (60)")
    parser.add_argument("--warmup", type=float, default=3.0, help="unmeasured seconds first (3)")
    parser.add_argument(
        "--outage", type=float, metavar="S", help="then close the LSL outlet for S seconds"
    )
    parser.add_argument("--port", type=int, default=7461, help="loopback port of the bus (7461)")
    parser.add_argument(
        "--envelope", action="store_true", help="only the envelope filter's delay and error"
    )


class _Listener:
    """Arrival times (monotonic ns) and messages of a few keys."""

    def __init__(self, session: zenoh.Session, keys: tuple[str, ...]) -> None:
        self.lock = threading.Lock()
        self.got: dict[str, list[tuple[int, object]]] = {k: [] for k in keys}
        self._subs = [session.declare_subscriber(k, self._on) for k in keys]

    def _on(self, sample: zenoh.Sample) -> None:
        now = time.monotonic_ns()
        key = str(sample.key_expr)
        try:
            message = decode(key, sample.payload.to_bytes())
        except (ValueError, KeyError):
            return
        with self.lock:
            self.got[key].append((now, message))

    def snapshot(self, key: str) -> list[tuple[int, object]]:
        with self.lock:
            return list(self.got[key])


def _spawn(endpoint: str, module: str, *argv: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", module, "--connect", endpoint, "--quiet", *argv],
        stdin=subprocess.DEVNULL,
    )


def run(args: argparse.Namespace) -> int:
    if args.envelope:
        return _envelope_figures()
    if args.outage is not None and args.source != "lsl":
        print("lpc bench emg: error: --outage needs --source lsl", file=sys.stderr)
        return 2
    if not (args.seconds > 0 and args.warmup >= 0 and 200 <= args.rate <= 20000):
        print("lpc bench emg: error: bad --seconds, --warmup or --rate", file=sys.stderr)
        return 2
    endpoint = f"tcp/127.0.0.1:{args.port}"
    keys = ("lpc/emg", "lpc/log/emg", "lpc/controller/state", "lpc/prosthesis/command")
    children: list[subprocess.Popen[bytes]] = []
    outlet = None
    with zenoh.open(zenoh_config(connect=[], listen=[endpoint])) as session:
        listen = _Listener(session, keys)
        try:
            if args.source == "lsl":
                name = f"lpc-bench-{uuid.uuid4().hex[:6]}"
                sim = [sys.executable, "-m", "services.drivers.emg_lsl_sim", "--name", name]
                sim += ["--rate", str(args.rate), "--duration", "100000", "--scope", "machine"]
                outlet = subprocess.Popen(
                    [*sim, "--pause", str(args.outage or 2.0)],
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,
                )
                emg = ["--source", "lsl", "--lsl-stream", name, "--lsl-scope", "machine"]
                emg += ["--lsl-timeout", "30"]
            else:
                emg = ["--source", "brainflow", "--board", "synthetic"]
            children.append(_spawn(endpoint, "services.emg", *emg))
            if args.outage is not None:
                children.append(_spawn(endpoint, "services.prosthesis_bridge", "--sim-hand"))
                children.append(
                    _spawn(endpoint, "services.controller", "--sim-user", "--camera-fixed")
                )
            return _measure(args, listen, outlet)
        finally:
            for child in [*children, outlet]:
                if child is not None and child.poll() is None:
                    child.send_signal(signal.SIGINT)
            for child in [*children, outlet]:
                if child is not None:
                    try:
                        child.wait(timeout=10)
                    except subprocess.TimeoutExpired:
                        child.kill()


def _measure(
    args: argparse.Namespace, listen: _Listener, outlet: subprocess.Popen[bytes] | None
) -> int:
    deadline = time.monotonic() + 90.0
    while not listen.snapshot("lpc/emg"):
        if time.monotonic() > deadline:
            print("lpc bench emg: error: no lpc/emg within 90 s", file=sys.stderr)
            return 1
        time.sleep(0.1)
    time.sleep(args.warmup)
    start = time.monotonic_ns()
    time.sleep(args.seconds)
    end = time.monotonic_ns()
    window = [(t, m) for t, m in listen.snapshot("lpc/emg") if start <= t < end]
    arrivals = np.array([t for t, _ in window], dtype=np.int64)
    stamps = np.array([m.t_ns for _, m in window], dtype=np.int64)  # type: ignore[attr-defined]
    by_arrival = (len(arrivals) - 1) / ((arrivals[-1] - arrivals[0]) / 1e9)
    by_stamp = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1e9)
    gaps = np.diff(arrivals) / 1e6
    source = f"LSL outlet at {args.rate:g} Hz" if args.source == "lsl" else "BrainFlow synthetic"
    print(f"lpc/emg from {source}, {args.seconds:g} s after {args.warmup:g} s warm-up:")
    print(f"  samples {len(window)} (expected {args.seconds * 100:.0f})")
    print(f"  rate by arrival {by_arrival:.3f} Hz ({(by_arrival / 100 - 1) * 100:+.2f} %)")
    print(f"  rate by sample time {by_stamp:.3f} Hz ({(by_stamp / 100 - 1) * 100:+.2f} %)")
    print(
        f"  arrival gaps p50 {np.percentile(gaps, 50):.1f} ms, p99 {np.percentile(gaps, 99):.1f} "
        f"ms, max {gaps.max():.1f} ms"
    )
    ok = abs(by_arrival / 100 - 1) <= 0.01 and abs(by_stamp / 100 - 1) <= 0.01
    print(f"  within 100 Hz +/- 1 %: {'yes' if ok else 'NO'}")
    if args.outage is not None and outlet is not None:
        _outage(args, listen, outlet)
    return 0


def _outage(args: argparse.Namespace, listen: _Listener, outlet: subprocess.Popen[bytes]) -> None:
    cut_ns = time.monotonic_ns()
    outlet.send_signal(signal.SIGUSR1)
    deadline = time.monotonic() + args.outage + 30.0
    resumed = None
    while time.monotonic() < deadline and resumed is None:
        time.sleep(0.1)
        logs = [(t, m) for t, m in listen.snapshot("lpc/log/emg") if t > cut_ns]
        resumed = next((t for t, m in logs if "resumed" in m.text), None)  # type: ignore[attr-defined]
    time.sleep(1.0)

    def ms(t_ns: int) -> str:
        return f"{(t_ns - cut_ns) / 1e6:7.0f} ms"

    # The outage is the longest silence of lpc/emg after the cut.
    arrivals = np.array([t for t, _ in listen.snapshot("lpc/emg") if t > cut_ns - 10**9])
    gap = int(np.argmax(np.diff(arrivals)))
    last_before, first_after = int(arrivals[gap]), int(arrivals[gap + 1])
    logs = [(t, m.text) for t, m in listen.snapshot("lpc/log/emg") if t > cut_ns]  # type: ignore[attr-defined]
    states = [(t, m) for t, m in listen.snapshot("lpc/controller/state") if t > cut_ns]
    commands = listen.snapshot("lpc/prosthesis/command")
    print(f"outage: the LSL outlet closed for {args.outage:g} s (times from closing it):")
    print(f"  last lpc/emg before          {ms(last_before)}")
    for t, text in logs:
        print(f"  emg log                      {ms(t)}  {text}")
    for t, m in states:
        if m.event:  # type: ignore[attr-defined]
            print(f"  controller {m.previous:>9} -> {m.state:<9} {ms(t)}  {m.reason}")  # type: ignore[attr-defined]
    print(f"  first lpc/emg after          {ms(first_after)}")
    during = [m for t, m in commands if last_before + 50_000_000 <= t < first_after]
    moving = [m for m in during if m.grasp != 0.0 or m.wrist != 0.0]  # type: ignore[attr-defined]
    print(
        f"  hand commands while EMG was silent (from 50 ms after the last sample): "
        f"{len(during)}, non-zero velocity: {len(moving)}"
    )


def _envelope_figures() -> int:
    from lpc_core.devices.emg_envelope import EnvelopeParams
    from lpc_core.sim.raw_emg import envelope_error, raw_emg, run_chunked

    t0_ns = 1_700_000_000_000_000_000
    print("envelope filter on raw EMG with a known envelope (mains 50 Hz, 5x the EMG):")
    print("  carrier  rate Hz  delay ms  error at delay  error at zero lag")
    for carrier, seconds, seed in (("sine", 12.0, 0), ("noise", 30.0, 3)):
        for rate in (200.0, 250.0, 512.0, 1000.0, 2000.0):
            emg = raw_emg(rate, seconds, carrier, 50.0, seed=seed)
            t_ns, values = run_chunked(EnvelopeParams(rate_hz=rate), emg.raw, t0_ns)
            e = envelope_error(emg, t_ns, values, t0_ns)
            print(
                f"  {carrier:<7}  {rate:7.0f}  {e.delay_ms:8.0f}  {e.error * 100:12.1f} %"
                f"  {e.error_at_zero * 100:15.1f} %"
            )
    return 0
