"""``lpc emg calibrate``: record the rest baseline and the maximal contraction of each channel
and write them, with the decision thresholds, to the ``emg`` section of the user profile.

The person relaxes, contracts the wrist flexors as hard as they can, relaxes, then the
extensors. Sources: ``sim`` (the simulated user follows the prompts; no hardware, no waiting),
``serial`` (the amplifier), ``can`` (the hand's status), ``bus`` (``lpc/emg`` of a running
``lpc up``).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lpc_core.control.emg import EmgProfile, calibrate
from lpc_core.sim.emg_sim import RATE_HZ, MuscleParams, MuscleState, simulate_emg
from services.drivers.emg import (
    DEFAULT_PROFILE,
    HandEmg,
    SerialEmg,
    load_emg_profile,
    save_emg_profile,
)
from services.drivers.errors import DriverError

PHASES = (
    ("rest", "relax both forearm muscles", None),
    ("flexor", "flex the wrist (close) as hard as you can, and hold", 0),
    ("pause", "relax", None),
    ("extensor", "extend the wrist (open) as hard as you can, and hold", 1),
)

Recorder = Callable[[float], np.ndarray]  # seconds -> (N, 2) samples


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="emg_command", metavar="ACTION", required=True)
    p = sub.add_parser("calibrate", help="record rest and maximal contraction into the profile")
    p.add_argument("--source", choices=("sim", "serial", "can", "bus"), default="sim")
    p.add_argument("--port", default="/dev/ttyUSB0", help="serial port (or a pyserial URL)")
    p.add_argument("--interface", default="socketcan", help="python-can interface (can)")
    p.add_argument("--can", default="can0", help="CAN channel (can)")
    p.add_argument("--channels", type=int, nargs=2, default=[0, 1], metavar=("FLEXOR", "EXTENSOR"))
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="bus endpoint (bus)")
    p.add_argument("--config", metavar="FILE", help="Zenoh config file (bus)")
    p.add_argument("--rest-s", type=float, default=3.0, help="rest recording (s)")
    p.add_argument("--contract-s", type=float, default=3.0, help="each contraction (s)")
    p.add_argument(
        "--profile", metavar="FILE", help=f"profile to update (default {DEFAULT_PROFILE})"
    )
    p.add_argument("--user", default="", help="name stored in the profile")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated user")
    p.add_argument("--dry-run", action="store_true", help="print the result, write nothing")


def run(args: argparse.Namespace) -> int:
    if not (0.5 <= args.rest_s <= 60 and 0.5 <= args.contract_s <= 60):
        print(
            "lpc emg calibrate: error: --rest-s and --contract-s must be in [0.5, 60]",
            file=sys.stderr,
        )
        return 2
    try:
        exists = args.profile is None or Path(args.profile).expanduser().exists()
        base = (load_emg_profile(args.profile) if exists else None) or EmgProfile()
        record, close = _recorder(args)
    except (ValueError, DriverError) as exc:
        print(f"lpc emg calibrate: error: {exc}", file=sys.stderr)
        return 2
    recordings: dict[str, np.ndarray] = {}
    try:
        for name, prompt, _ in PHASES:
            seconds = args.rest_s if name == "rest" else 1.5 if name == "pause" else args.contract_s
            print(f"{name:>9}: {prompt} ({seconds:g} s)", flush=True)
            recordings[name] = record(seconds)
    except DriverError as exc:
        print(f"lpc emg calibrate: error: {exc}", file=sys.stderr)
        return 1
    finally:
        close()
    try:
        profile = calibrate(
            recordings["rest"], [recordings["flexor"], recordings["extensor"]], base=base
        )
    except ValueError as exc:
        print(f"lpc emg calibrate: error: {exc}; nothing written", file=sys.stderr)
        return 1
    profile = EmgProfile.from_dict(
        {
            **profile.to_dict(),
            "user": args.user or base.user,
            "unit": "raw" if args.source == "can" else "V",
        }
    )
    counts = {k: len(v) for k, v in recordings.items()}
    print(
        f"samples {counts}\n"
        f"rest     flexor {profile.rest[0]:.4g}  extensor {profile.rest[1]:.4g}\n"
        f"maximal  flexor {profile.maximal[0]:.4g}  extensor {profile.maximal[1]:.4g}\n"
        f"thresholds off {profile.off:g}  on {profile.on:g}  upper {profile.upper:g}  "
        f"co-contraction {profile.co_contraction:g}  quick {profile.quick_ms:g} ms"
    )
    if args.dry_run:
        print("dry run: profile not written")
        return 0
    path = save_emg_profile(profile, args.profile)
    print(f"written: {path} (emg section)")
    return 0


def _recorder(args: argparse.Namespace) -> tuple[Recorder, Callable[[], None]]:
    channels = tuple(args.channels)
    if args.source == "sim":
        return _sim_recorder(args.seed), lambda: None
    if args.source == "bus":
        return _bus_recorder(args)
    source: SerialEmg | HandEmg
    if args.source == "serial":
        source = SerialEmg(args.port, channels=channels)  # type: ignore[arg-type]
    else:
        source = HandEmg(channels, profile="lpc", interface=args.interface, channel=args.can)  # type: ignore[arg-type]

    def record(seconds: float) -> np.ndarray:
        samples, end = [], time.monotonic() + seconds
        while time.monotonic() < end:
            got = source.recv(timeout=0.05)
            if got is not None:
                samples.append(got[0])
        return np.asarray(samples, dtype=float).reshape(-1, 2)

    return record, source.shutdown


def _sim_recorder(seed: int) -> Recorder:
    """The simulated person follows the prompts: a reaction time, a ramp, a hold at full effort."""
    params, state, seq = MuscleParams(), [MuscleState()], [0]
    phase = iter(PHASES)

    def record(seconds: float) -> np.ndarray:
        _, _, channel = next(phase)
        n = round(seconds * RATE_HZ)
        drive = np.zeros((n, 2))
        if channel is not None:
            t = np.arange(n) / RATE_HZ
            drive[:, channel] = np.clip((t - 0.4) / 0.3, 0.0, 1.0)  # react in 0.4 s, rise 0.3 s
        state[0], out = simulate_emg(state[0], drive, params, seed, seq[0])
        seq[0] += n
        return out

    return record


def _bus_recorder(args: argparse.Namespace) -> tuple[Recorder, Callable[[], None]]:
    from schemas import decode
    from services.cli._bus import open_session

    session = open_session(args)
    lock, samples = threading.Lock(), []

    def on_sample(sample) -> None:  # type: ignore[no-untyped-def]
        try:
            message = decode("lpc/emg", sample.payload.to_bytes())
        except ValueError:
            return
        with lock:
            samples.append(message.channels[:2])

    sub = session.declare_subscriber("lpc/emg", on_sample)

    def record(seconds: float) -> np.ndarray:
        with lock:
            samples.clear()
        time.sleep(seconds)  # the person is recorded for this long, by the bus's own clock
        with lock:
            got = list(samples)
        if not got:
            raise DriverError("no samples on lpc/emg: is 'lpc up' running with an EMG source?")
        return np.asarray(got, dtype=float)

    def close() -> None:
        sub.undeclare()
        session.close()

    return record, close
