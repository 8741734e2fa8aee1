"""``lpc tactors test``: pulse each tactor in turn, to fit the sleeve and the gains to a new user.

Each tactor is pulsed at the user's weakest level (``gain_min``, if above zero) and then at the
strongest (``gain_max``), read from the ``tactors`` section of the profile file. The user should
feel both, and neither should be unpleasant; edit the profile until that holds. Without
``--port`` a simulated controller stands in (a dry run of the sequence).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from lpc_core.control.aim import tactor_placement
from lpc_core.devices.tactor_protocol import N_TACTORS, TactorOutput
from services.drivers.errors import DriverError
from services.drivers.tactors import (
    DEFAULT_PROFILE,
    TactorDriver,
    load_profile,
    open_driver,
    tactor_profile,
)

_DIRECTIONS = {0: "right", 90: "down", 180: "left", 270: "up"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    test = sub.add_parser("test", help="pulse each tactor in turn", description=__doc__)
    test.add_argument("--port", help="serial port (default: a simulated controller)")
    test.add_argument("--driver", choices=("eai", "line"), default="eai", help="protocol")
    test.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    test.add_argument(
        "--profile", metavar="FILE", help=f"user profile JSON (default {DEFAULT_PROFILE}, if any)"
    )
    test.add_argument("--on-ms", type=float, default=500.0, help="pulse length (default 500 ms)")
    test.add_argument("--off-ms", type=float, default=400.0, help="pause (default 400 ms)")
    test.add_argument("--rounds", type=int, default=1, help="times through all tactors")


def run(args: argparse.Namespace) -> int:
    try:
        section = load_profile(args.profile)
        profile = tactor_profile(section)
        angles = tactor_placement(
            section.get("arm", "right"), float(section.get("rotation_deg", 0))
        )
    except (TypeError, ValueError) as exc:
        print(f"lpc tactors: error: profile: {exc}", file=sys.stderr)
        return 2
    if args.on_ms <= 0 or args.off_ms < 0 or args.rounds < 1:
        print("lpc tactors: error: --on-ms > 0, --off-ms >= 0, --rounds >= 1", file=sys.stderr)
        return 2
    try:
        driver = open_driver(args.driver, args.port, baudrate=args.baud)
    except DriverError as exc:
        print(f"lpc tactors: error: {exc}", file=sys.stderr)
        return 1
    where = args.port or f"{driver.port} (simulated controller)"
    used = args.profile or (DEFAULT_PROFILE if section else "none (full range)")
    print(f"tactors: {args.driver} on {where}; profile {used}")
    plan = [
        (k, label, level)
        for _ in range(args.rounds)
        for k in range(N_TACTORS)
        for label, level in (("weakest", profile.gain_min[k]), ("strongest", profile.gain_max[k]))
        if level > 0
    ]
    naks = 0
    try:
        with driver:
            for k, label, level in plan:
                direction = _DIRECTIONS.get(round(math.degrees(angles[k])) % 360, "")
                print(f"tactor {k} ({direction}): {label} level {level:.2f}", flush=True)
                naks += _pulse(driver, k, level, args.on_ms / 1000, args.off_ms / 1000)
    except DriverError as exc:
        print(f"lpc tactors: error: {exc}", file=sys.stderr)
        return 1
    if naks:
        print(f"lpc tactors: the controller refused {naks} command(s)", file=sys.stderr)
        return 1
    print("tactors: done, all off")
    return 0


def _pulse(driver: TactorDriver, k: int, level: float, on_s: float, off_s: float) -> int:
    """Tactor ``k`` alone at ``level`` for ``on_s``, then all off for ``off_s``; NAKs seen."""
    driver.send(TactorOutput(tuple(level if j == k else 0.0 for j in range(N_TACTORS))), 1.0)
    time.sleep(on_s)
    driver.all_off(timeout=1.0)
    time.sleep(off_s)
    naks = 0
    while (reply := driver.recv(0.0)) is not None:
        naks += not reply.ok
    return naks
