"""Simulated hand service: the simulated hand on a CAN bus of its own process, for buses that
connect processes (socketcan ``vcan0``: ``ip link add dev vcan0 type vcan``). With python-can's
in-process virtual bus, run ``prosthesis_bridge --sim-hand`` instead. The object between the
fingers is the one the controller pre-shaped for (``lpc/controller/state``).

``--ports-file FILE``: where no vcan exists, the hand speaks python-can's serial bus on a
pseudo-terminal of its own (``prosthesis_bridge --interface serial --channel /dev/pts/N``), and
``--tactors eai|line`` adds the simulated tactor controller on another; their ports go to FILE
(``hand PORT`` and ``tactors PORT`` lines) once open. ``lpc bench footprint`` runs them so, as
devices outside the measured set, as the hand and the tactor driver are on the worn computer."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from services.drivers.errors import DriverError
from services.drivers.hand import BACKENDS
from services.drivers.hand_sim import SimulatedHand, open_pty_bus
from services.drivers.tactor_sim import TactorSim
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
    tactors = None
    try:
        if args.ports_file:
            can_bus, port = open_pty_bus()
            sim = SimulatedHand(args.profile, object_mm=args.object_mm, bus=can_bus)
            ports = [f"hand {port}"]
            if args.tactors:
                tactors = TactorSim(args.tactors)
                ports.append(f"tactors {tactors.port}")
            _write_ports(Path(args.ports_file), ports)
        else:
            sim = SimulatedHand(
                args.profile, args.interface, args.channel, object_mm=args.object_mm
            )
    except DriverError as exc:
        bus.log("error", str(exc))
        raise
    # The pty's bus never waits (open_pty_bus): the hand ticks on this loop's timer.
    sim.start(asyncio.get_running_loop() if args.ports_file else None)
    try:
        await follow_grasps(bus, sim, args.object_mm)
    finally:
        await asyncio.to_thread(sim.stop)
        if tactors is not None:
            tactors.close()


def _write_ports(path: Path, ports: list[str]) -> None:
    # Whole or not at all: the reader waits for the file to exist.
    part = path.with_name(path.name + ".part")
    part.write_text("".join(f"{line}\n" for line in ports))
    part.rename(path)


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("hand_sim", __doc__ or "")
    parser.add_argument("--profile", choices=sorted(BACKENDS), default="lpc")
    parser.add_argument("--interface", default="socketcan", help="python-can interface")
    parser.add_argument("--channel", default="vcan0", help="CAN channel")
    parser.add_argument("--object-mm", type=float, default=60.0, help="default object width")
    parser.add_argument(
        "--ports-file",
        metavar="FILE",
        help="the hand on a pty (python-can's serial bus) instead; its port written to FILE",
    )
    parser.add_argument(
        "--tactors",
        choices=("eai", "line"),
        help="with --ports-file: the simulated tactor controller too, on a pty of its own",
    )
    args = parser.parse_args(argv)
    if args.tactors and not args.ports_file:
        parser.error("--tactors is for --ports-file")
    return run_service("hand_sim", serve, args)


if __name__ == "__main__":
    sys.exit(main())
