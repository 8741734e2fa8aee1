"""Prosthesis bridge: ``lpc/prosthesis/command`` to the hand over CAN, the hand's status to
``lpc/prosthesis/state``. A watchdog sends zero velocity when no fresh command has come for
40 ms (default), so that the hand is stopped within 50 ms of the last command even with
scheduling jitter; a command older than that when it arrives is dropped and counted. Bus errors are
logged and counted, and the bridge reopens the bus with backoff. ``--sim-hand`` runs the
simulated hand on the same bus (required with python-can's in-process virtual bus); a
simulated hand in a process of its own speaks python-can's serial bus on a pty
(``hand_sim --ports-file``; ``--interface serial --channel /dev/pts/N`` here).

``--hand ability`` drives a PSYONIC Ability Hand on ``--hand-port`` (pyserial, 460800 baud; a
simulated one on a pseudo-terminal without a port) in the command's grip, with the wrist
rotator still on CAN in lpc's layout: one watchdog stops both (zero velocity on the wrist, the
fingers held where they are). Bad frames from the hand are counted in health."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
from collections.abc import Callable

import zenoh

from lpc_core.devices.hand import HandCommand, HandStatus
from schemas import BadMessage, ProsthesisCommand, ProsthesisState, topic_for_key
from services.drivers.hand import BACKENDS, DEFAULT_CHANNEL, HandLink, open_hand
from services.drivers.hand_sim import SimulatedHand
from services.hand_sim import follow_grasps
from services.runtime import Bus, run_service, service_parser

COMMAND = "lpc/prosthesis/command"


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    loop = asyncio.get_running_loop()
    states = bus.publisher("lpc/prosthesis/state")
    watchdog_ns = int(args.watchdog_ms * 1e6)
    seq = 0

    def publish(status: HandStatus) -> None:
        nonlocal seq
        seq += 1
        states.put(
            ProsthesisState(
                seq=seq,
                t_ns=bus.clock.now_ns(),
                wrist_angle_deg=status.wrist_angle_deg,
                aperture_mm=status.aperture_mm,
                grip_force_pct=status.grip_force_pct,
                emg=list(status.emg),
                hand=name,
                grip=status.grip,  # type: ignore[arg-type]
            )
        )
        if seq % 100 == 0:
            report()

    def report() -> None:
        # A copy: Zenoh's thread that forwards the commands may add a counter meanwhile.
        for key, count in list(link.counters.items()):  # totals: assign, do not add
            bus.health.counters[key] = count

    # A hand on CAN whose status this loop can wait for (socketcan's or the serial bus's file,
    # or the simulated hand on this loop, which says when it has sent) runs on the loop: no
    # thread wakes every cycle for the link, its watchdog or the simulated hand. Other buses
    # keep the link's thread. The serial bus must: its reads never wait (open_can_bus).
    on_loop = getattr(args, "hand", "can") == "can" and (
        args.sim_hand or args.interface in ("socketcan", "serial")
    )
    sim = fingers = None
    if args.sim_hand:
        sim = SimulatedHand(args.profile, args.interface, args.channel, object_mm=args.object_mm)
        sim.start(loop if on_loop else None)
    hand_port = getattr(args, "hand_port", None)  # callers that build the args may omit both
    if getattr(args, "hand", "can") == "ability":
        # Imported only for this hand: its protocol needs numpy, which a bridge for a hand on
        # CAN need not load (about 12 MB of the process's memory).
        from services.drivers.ability import open_ability
        from services.drivers.ability_sim import AbilitySim

        # The fingers on serial, the wrist on CAN: one driver, one link, one watchdog.
        if hand_port is None:
            fingers = AbilitySim(object_mm=args.object_mm)
        port = hand_port or fingers.port  # type: ignore[union-attr]
        wrist = f"{args.profile}:{'sim' if args.sim_hand else args.interface}"
        name = f"ability:{'sim' if fingers else port}+{wrist}"
        opener: Callable[[], object] = lambda: open_ability(  # noqa: E731
            port, interface=args.interface, channel=args.channel
        )
    else:
        name = f"{args.profile}:{'sim' if args.sim_hand else args.interface}"
        opener = lambda: open_hand(  # noqa: E731
            args.profile, interface=args.interface, channel=args.channel
        )

    link = HandLink(
        opener,  # type: ignore[arg-type]
        on_status=publish if on_loop else lambda status: loop.call_soon_threadsafe(publish, status),
        # Also from the worker thread that opens the hand.
        on_event=lambda level, text: loop.call_soon_threadsafe(bus.log, level, text),
        watchdog_s=args.watchdog_ms / 1000.0,
    ).start(loop if on_loop else None)
    if sim is not None and on_loop:
        sim.on_sent = link.poll
    # Simulation only: the object between the fingers is the one pre-shaped for.
    held = fingers if fingers is not None else sim
    follow = asyncio.create_task(follow_grasps(bus, held, args.object_mm)) if held else None

    def forward(command: ProsthesisCommand, received_ns: int) -> None:
        if received_ns - command.t_ns > watchdog_ns:
            bus.health.counters["stale_commands"] += 1
            return
        link.command(HandCommand(grasp=command.grasp, wrist=command.wrist, grip=command.grip))

    commands = None
    try:
        if bus.router is not None and bus.router.covers(COMMAND):
            # In a process with other services (a container) the controller's commands may
            # come from this process, which Zenoh does not hand back: the bus's subscription.
            async for command in bus.subscribe(COMMAND):
                forward(command, bus.clock.now_ns())
        else:
            commands = bus.session.declare_subscriber(COMMAND, _on_command(bus, forward))
            await loop.create_future()  # until the service is stopped
    finally:
        if commands is not None:
            commands.undeclare()
        if follow is not None:
            follow.cancel()
        link.stop()
        if sim is not None:
            sim.stop()
        if fingers is not None:
            fingers.close()
        report()


def _on_command(
    bus: Bus, forward: Callable[[ProsthesisCommand, int], None]
) -> Callable[[zenoh.Sample], None]:
    """Zenoh's callback for the commands: each goes to the hand from Zenoh's thread that
    received it, with no wake-up of the loop. Through the bus's subscription each command woke
    the loop (about a fifth of the bridge's CPU at 100 Hz, py-spy); the link takes commands
    from any thread and its watchdog still stops the hand ``--watchdog-ms`` after the last."""
    topic = topic_for_key(COMMAND)
    stream = bus.health.received[COMMAND]

    def on_sample(sample: zenoh.Sample) -> None:
        received_ns = bus.clock.now_ns()
        stream.count += 1
        stream.stamps.append(received_ns)
        try:
            command = topic.decode(sample.payload.to_bytes(), COMMAND)
        except BadMessage as exc:
            stream.rejected += 1
            with contextlib.suppress(RuntimeError):  # the loop may be closed at shutdown
                bus.loop.call_soon_threadsafe(bus.reject, COMMAND, str(exc))
            return
        forward(command, received_ns)

    return on_sample


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("prosthesis_bridge", __doc__ or "")
    parser.add_argument(
        "--hand",
        choices=("can", "ability"),
        default="can",
        help="can: the whole hand on CAN (--profile); ability: a PSYONIC Ability Hand on "
        "--hand-port (simulated on a pty without one), its wrist rotator on CAN",
    )
    parser.add_argument(
        "--hand-port", metavar="PORT", help="the Ability Hand's serial port (e.g. /dev/ttyUSB0)"
    )
    parser.add_argument(
        "--profile", choices=sorted(BACKENDS), default="lpc", help="CAN frame layout"
    )
    parser.add_argument(
        "--interface", default="virtual", help="python-can interface (virtual, socketcan, ...)"
    )
    parser.add_argument("--channel", default=DEFAULT_CHANNEL, help="CAN channel (e.g. can0)")
    parser.add_argument(
        "--watchdog-ms",
        type=float,
        default=40.0,
        help="zero velocity when no fresh command came for this long (default 40 ms)",
    )
    parser.add_argument("--sim-hand", action="store_true", help="run the simulated hand too")
    parser.add_argument(
        "--object-mm", type=float, default=60.0, help="simulated object width (default 60 mm)"
    )
    args = parser.parse_args(argv)
    if not 5 <= args.watchdog_ms <= 1000:
        parser.error("--watchdog-ms must be in [5, 1000]")
    if args.hand_port is not None and args.hand != "ability":
        parser.error("--hand-port is for --hand ability")
    if args.hand == "ability" and args.profile != "lpc":
        parser.error("--hand ability keeps its wrist on CAN in lpc's layout: --profile lpc")
    if args.hand == "ability" and args.interface == "serial":
        # That link runs on a thread of its own, which a serial bus that never waits would spin.
        parser.error("--interface serial is for --hand can")
    if args.interface == "virtual" and not args.sim_hand:
        print(
            "[prosthesis_bridge] warning: virtual bus without --sim-hand: no hand", file=sys.stderr
        )
    return run_service("prosthesis_bridge", serve, args)


if __name__ == "__main__":
    sys.exit(main())
