"""Tactor bridge: ``lpc/tactors/command`` in, bytes on the tactor controller's serial line out.

All off on shutdown, on a stale cue and on serial errors; the port is reopened when it comes
back. Without ``--tactor-port`` a simulated controller on a pseudo-terminal stands in.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import sys
from concurrent.futures import ThreadPoolExecutor

from lpc_core.devices.tactor_bridge import (
    PORT_OPENED,
    TICK,
    BridgeParams,
    BridgeState,
    PortOpened,
    bridge_step,
)
from schemas import TactorCommand
from services.drivers.tactors import TactorLink, load_profile, open_driver, tactor_profile
from services.runtime import Bus, run_service, service_parser


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    params = BridgeParams(
        stale_ns=int(args.stale_ms * 1e6),
        stale_from=args.stale_from,
        min_interval_ns=int(1e9 / args.max_rate_hz),
        profile=tactor_profile(load_profile(args.profile)),
    )
    link = TactorLink(lambda: open_driver(args.driver, args.tactor_port, baudrate=args.baud))
    serial_thread = ThreadPoolExecutor(1, thread_name_prefix="tactor-serial")
    loop = asyncio.get_running_loop()
    inbox: collections.deque[TactorCommand | PortOpened] = collections.deque()
    # Awaited by the bridge's own loop below, not by a task that hands each cue over: one
    # task wake-up a cue instead of two.
    commands = bus.subscribe("lpc/tactors/command")
    state = BridgeState(params=params)
    was_up = False
    try:
        while True:
            # Opening waits for the controller's answer: off the loop, and only when down.
            if not link.up and await loop.run_in_executor(
                serial_thread, link.reopen, bus.clock.now_ns()
            ):
                bus.log("info", f"tactor port {link.driver.port} open ({args.driver})")
                inbox.appendleft(PORT_OPENED)
            # Replies, and a port that hung up while idle, are taken every pass.
            if link.up and link.poll() == "reset":
                inbox.appendleft(PORT_OPENED)
            events = [inbox.popleft() for _ in range(len(inbox))] or [TICK]
            for event in events:
                state, outputs = bridge_step(state, event, bus.clock.now_ns())
                for output in outputs:
                    # A few bytes into the port's kernel buffer: written on the loop, bounded
                    # by the driver's write timeout, saving a thread hand-off per frame.
                    if link.write(output) == "reset":  # refused: all off sent, write again
                        inbox.appendleft(PORT_OPENED)
            if was_up and not link.up:
                bus.log("warning", f"tactor port lost, retrying: {link.last_error}")
            was_up = link.up
            for name, value in link.counters.items():
                bus.health.counters[f"tactor_{name}"] = value
            if inbox:  # a refused write: another pass at once
                continue
            wake = [t for t in (state.wake_ns, None if link.up else link.retry_at_ns) if t]
            timeout = (min(wake) - bus.clock.now_ns()) / 1e9 if wake else 1.0
            # A timeout that cancels the wait loses nothing: a cue leaves the subscription's
            # queue only when it is returned.
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(max(timeout, 0.0)):
                    _, command, _ = await commands.receive()
                    inbox.append(command)
    finally:
        commands.close()
        serial_thread.shutdown(wait=True)
        link.close()  # all off, then close


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("tactor_bridge", __doc__ or "")
    parser.add_argument(
        "--driver", choices=("eai", "line", "sim"), default="eai", help="protocol (default eai)"
    )
    parser.add_argument(
        "--tactor-port", metavar="PORT", help="serial port (default: a simulated controller)"
    )
    parser.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    parser.add_argument("--profile", metavar="FILE", help="user profile JSON (gain limits)")
    parser.add_argument(
        "--stale-ms", type=float, default=100.0, help="all off when the cue is older (ms)"
    )
    parser.add_argument(
        "--stale-from",
        choices=("capture", "receipt"),
        default="capture",
        help="age a cue from its frame's capture time (default) or from its arrival",
    )
    parser.add_argument(
        "--max-rate-hz", type=float, default=200.0, help="at most this many writes a second"
    )
    args = parser.parse_args(argv)
    if not args.stale_ms > 0 or not 0 < args.max_rate_hz <= 10_000:
        parser.error("--stale-ms and --max-rate-hz must be positive")
    try:
        tactor_profile(load_profile(args.profile))
    except ValueError as exc:
        parser.error(str(exc))
    return run_service("tactor_bridge", serve, args)


if __name__ == "__main__":
    sys.exit(main())
