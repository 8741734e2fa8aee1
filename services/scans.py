"""Scans service: depth frames in on ``lpc/camera/depth``, four scan lines out on ``lpc/scans``."""

from __future__ import annotations

import argparse
import sys

from lpc_core.perception.pipeline import ScansState, scans_step
from lpc_core.perception.scans import ScanParams
from services.runtime import Bus, service_main, service_parser


def parser() -> argparse.ArgumentParser:
    """The service's flags (a replay parses the recorded ones with it)."""
    parser = service_parser("scans", __doc__ or "")
    parser.add_argument(
        "--band-mm", type=float, default=0.5, help="half-width of a scan line (default 0.5 mm)"
    )
    return parser


def initial_state(args: argparse.Namespace) -> ScansState:
    """The step function's state at start, from the flags; ``ValueError`` if they are bad."""
    if not 0 < args.band_mm <= 10:
        raise ValueError("--band-mm must be in (0, 10]")
    return ScansState(params=ScanParams(band_m=args.band_mm / 1000.0))


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    state = initial_state(args)
    scans = bus.publisher("lpc/scans")
    async for frame in bus.subscribe("lpc/camera/depth"):
        try:
            state, out = scans_step(state, frame, bus.clock.now_ns())
        except ValueError as exc:
            bus.reject("lpc/camera/depth", str(exc))
            continue
        scans.put(out)


def main(argv: list[str] | None = None) -> int:
    return service_main("scans", parser(), initial_state, serve, argv)


if __name__ == "__main__":
    sys.exit(main())
