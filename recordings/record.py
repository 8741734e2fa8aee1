"""Re-record the replay sessions from one live run of the simulated system.

    .venv/bin/python recordings/record.py            # live run + every session (about 2 min)
    .venv/bin/python recordings/record.py --from-live LIVE.mcap   # sessions from a live file

Steps (each one an ``lpc`` command, printed as it runs):

1. ``lpc up --source sim --seed 0 --duration 32 --record LIVE.mcap`` on a private port; the
   reconstructor runs beside it if ``lpc up`` does not start it itself.
2. Each session is cut from the live file and normalised by ``lpc replay --out``: the file
   keeps the recorded inputs and the outputs of the pipeline's step functions (gated by
   the frames the live services handled, delivered at their recorded times), so that
   ``lpc replay SESSION --check`` reproduces it exactly.
3. ``faults.mcap`` is the grasp part of the live run with faults put in before the
   normalisation: a third of the scans dropped for two seconds, and 400 ms without EMG.

To accept an intended change of an algorithm, regenerate the outputs from the same inputs:

    for f in recordings/*.mcap; do .venv/bin/lpc replay "$f" --out "$f"; done
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from services.mcap_log import LogWriter, McapLog  # noqa: E402

LPC = [sys.executable, "-m", "services.cli"]
LIVE_SECONDS = 32
# name -> (extra `lpc replay` flags, what it holds)
SESSIONS: dict[str, tuple[list[str], str]] = {
    "depth": (
        ["--from", "3.0", "--until", "3.8"],
        "0.8 s with the depth frames: the scans step and everything after it",
    ),
    "shapes": (
        ["--without", "lpc/camera/depth", "--until", "14.5"],
        "a sphere, a cylinder and a cuboid (the first three stops), from the recorded scans",
    ),
    "grasp": (
        ["--without", "lpc/camera/depth"],
        "the whole run from the recorded scans: aiming, ready, pre-shape, direct control",
    ),
}
FAULTS = {
    "drop_scans": (10.0, 12.0, 3),  # from s, to s, keep one in ... dropped: every 3rd
    "emg_gap": (16.0, 16.4),  # no EMG sample between these times (s)
}


def run(cmd: list[str]) -> None:
    shown = ["lpc", *cmd[len(LPC) :]] if cmd[: len(LPC)] == LPC else cmd
    print("+ " + " ".join(shown), flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def record_live(path: Path) -> None:
    from services.cli.up import SERVICES

    port = free_port()
    up = subprocess.Popen(
        [*LPC, "up", "--source", "sim", "--seed", "0", "--duration", str(LIVE_SECONDS),
         "--port", str(port), "--record", str(path), "--status-every", "5"],
        cwd=ROOT,
    )
    beside = None
    if "reconstructor" not in SERVICES:
        # Wait for the rendezvous to listen, then join it.
        deadline = time.monotonic() + 60
        while up.poll() is None and time.monotonic() < deadline:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.05)
        beside = subprocess.Popen(
            [sys.executable, "-m", "services.reconstructor", "--connect",
             f"tcp/127.0.0.1:{port}", "--quiet"],
            cwd=ROOT,
        )
    code = up.wait()
    if beside is not None:
        beside.terminate()
        beside.wait(timeout=10)
    if code != 0:
        raise SystemExit(f"lpc up exited with {code}")
    check_single_instances(path)


def check_single_instances(path: Path) -> None:
    """Every service must have run once: another service set on the same bus (an orphan of
    an earlier run, say) would double the messages."""
    pids: dict[str, set[int]] = defaultdict(set)
    with McapLog(path) as log:
        for m in log.messages(ordered=False, decode=True):
            if m.key.startswith("lpc/health/") and m.message is not None:
                pids[m.message.service].add(m.message.pid)
    doubled = {name: sorted(p) for name, p in pids.items() if len(p) > 1}
    if doubled:
        raise SystemExit(f"{path}: services ran more than once (pids {doubled}); record again")


def put_faults(live: Path, out: Path) -> None:
    """A copy of ``live`` with scans dropped and an EMG gap, as a faulty session would have."""
    with McapLog(live) as log, LogWriter(out) as writer:
        start = None
        dropped = 0
        for m in log.messages():
            start = m.log_time if start is None else start
            t = (m.log_time - start) / 1e9
            lo, hi, every = FAULTS["drop_scans"]
            if m.key == "lpc/scans" and lo <= t < hi:
                dropped += 1
                if dropped % every == 0:
                    continue
            lo, hi = FAULTS["emg_gap"]
            if m.key == "lpc/emg" and lo <= t < hi:
                continue
            writer.write_raw(m.key, m.payload, log_time=m.log_time,
                             publish_time=m.publish_time, sequence=m.sequence)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--from-live", metavar="LIVE.mcap", help="skip the live run")
    parser.add_argument("--keep-live", metavar="PATH", help="keep the live recording here")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="lpc-record-") as tmp:
        live = Path(args.from_live) if args.from_live else Path(args.keep_live or
                                                                Path(tmp) / "live.mcap")
        if not args.from_live:
            record_live(live)
        for name, (flags, _) in SESSIONS.items():
            run([*LPC, "replay", str(live), *flags, "--out", str(HERE / f"{name}.mcap")])
        faulty = Path(tmp) / "faulty.mcap"
        put_faults(live, faulty)
        run([*LPC, "replay", str(faulty), "--without", "lpc/camera/depth", "--from", "8",
             "--until", "20", "--out", str(HERE / "faults.mcap")])
    for path in sorted(HERE.glob("*.mcap")):
        size = os.path.getsize(path) / 1e6
        print(f"{path.name}: {size:.2f} MB" + ("  (over 5 MB!)" if size > 5 else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
