"""Simulated hand service: the simulated hand on a CAN bus of its own process, for buses that
connect processes (socketcan ``vcan0``: ``ip link add dev vcan0 type vcan``). With python-can's
in-process virtual bus, run ``prosthesis_bridge --sim-hand`` instead. The object between the
fingers is the one the controller pre-shaped for (``lpc/controller/state``)."""

from __future__ import annotations

import argparse
import asyncio
import sys
from typing import TYPE_CHECKING

from services.drivers.errors import DriverError
from services.drivers.hand import BACKENDS
from services.drivers.hand_sim import SimulatedHand
from services.runtime import Bus, run_service, service_parser

if TYPE_CHECKING:
    from services.drivers.ability_sim import AbilitySim


async def follow_grasps(
    bus: Bus, sim: SimulatedHand | AbilitySim, default_mm: float | None
) -> None:
    """Simulation only: the object the hand closes on is the one it was pre-shaped for."""
    async for state in bus.subscribe("lpc/controller/state"):
        if state.state == "preshaping" and state.target_width_mm is not None:
            sim.object_mm = state.target_width_mm
        elif state.state == "idle" and state.previous == "direct":
            sim.object_mm = default_mm


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    try:
        sim = SimulatedHand(args.profile, args.interface, args.channel, object_mm=args.object_mm)
    except DriverError as exc:
        bus.log("error", str(exc))
        raise
    sim.start()
    try:
        await follow_grasps(bus, sim, args.object_mm)
    finally:
        await asyncio.to_thread(sim.stop)


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("hand_sim", __doc__ or "")
    parser.add_argument("--profile", choices=sorted(BACKENDS), default="lpc")
    parser.add_argument("--interface", default="socketcan", help="python-can interface")
    parser.add_argument("--channel", default="vcan0", help="CAN channel")
    parser.add_argument("--object-mm", type=float, default=60.0, help="default object width")
    args = parser.parse_args(argv)
    return run_service("hand_sim", serve, args)


if __name__ == "__main__":
    sys.exit(main())
