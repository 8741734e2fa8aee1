"""EMG service: two channels (flexor, extensor) at 100 Hz on ``lpc/emg``, from a serial
amplifier, the hand's CAN status, or a simulated user who watches ``lpc/controller/state``,
``lpc/prosthesis/state`` and ``lpc/aim/cue`` and answers as a person would."""

from __future__ import annotations

import argparse
import asyncio
import sys
import threading

from lpc_core.sim.emg_sim import PERIOD_NS, Tick, UserParams, UserState, user_step
from schemas import EmgSample
from services.drivers.emg import HandEmg, SerialEmg
from services.drivers.errors import DriverError
from services.runtime import Bus, run_service, service_parser


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    if args.source == "sim":
        await _simulated_user(bus, args)
    else:
        await _device(bus, args)


async def _simulated_user(bus: Bus, args: argparse.Namespace) -> None:
    out = bus.publisher("lpc/emg")
    user = UserState(seed=args.seed, user=UserParams(exercise_wrist=not args.no_wrist))

    async def watch(key: str) -> None:
        nonlocal user
        async for message in bus.subscribe(key):
            user, _ = user_step(user, message, bus.clock.now_ns())

    watchers = [
        asyncio.create_task(watch(k))
        for k in ("lpc/controller/state", "lpc/prosthesis/state", "lpc/aim/cue")
    ]
    try:
        t_ns = bus.clock.now_ns()
        while True:
            t_ns += PERIOD_NS
            await bus.clock.sleep_until(t_ns)
            user, samples = user_step(user, Tick(t_ns), t_ns)
            for sample in samples:
                out.put(sample)
            behind = bus.clock.now_ns() - t_ns
            if behind > 20 * PERIOD_NS:  # stalled for 200 ms: skip ahead, do not burst
                bus.health.counters["skipped_samples"] += behind // PERIOD_NS
                t_ns = bus.clock.now_ns()
    finally:
        for task in watchers:
            task.cancel()


async def _device(bus: Bus, args: argparse.Namespace) -> None:
    loop = asyncio.get_running_loop()
    out = bus.publisher("lpc/emg")
    stop = threading.Event()
    seq = 0

    def publish(channels: list[float], t_ns: int) -> None:
        nonlocal seq
        seq += 1
        out.put(
            EmgSample(seq=seq, t_ns=t_ns, channels=channels, unit=args.unit, source=args.source)
        )

    def read() -> None:  # the driver's thread: blocking reads, handed to the loop
        source = None
        while not stop.is_set():
            try:
                if source is None:
                    source = _open(args)
                    loop.call_soon_threadsafe(bus.log, "info", f"{args.source} EMG source open")
                got = source.recv(timeout=0.1)
            except DriverError as exc:
                loop.call_soon_threadsafe(bus.log, "error", f"EMG source: {exc}; reopening")
                if source is not None:
                    source.shutdown()
                source = None
                stop.wait(1.0)
                continue
            if got is not None:
                loop.call_soon_threadsafe(publish, *got)
        if source is not None:
            source.shutdown()

    thread = threading.Thread(target=read, name="emg-source", daemon=True)
    thread.start()
    try:
        await asyncio.Event().wait()
    finally:
        stop.set()
        await asyncio.to_thread(thread.join, 2.0)


def _open(args: argparse.Namespace) -> SerialEmg | HandEmg:
    if args.source == "serial":
        return SerialEmg(args.port, args.baudrate, tuple(args.channels))
    return HandEmg(tuple(args.channels), profile="lpc", interface=args.interface, channel=args.can)


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("emg", __doc__ or "")
    parser.add_argument("--source", choices=("sim", "serial", "can"), default="sim")
    parser.add_argument("--port", default="/dev/ttyUSB0", help="serial port (or a pyserial URL)")
    parser.add_argument("--baudrate", type=int, default=115200)
    parser.add_argument("--interface", default="socketcan", help="python-can interface for can")
    parser.add_argument("--can", default="can0", help="CAN channel for --source can")
    parser.add_argument(
        "--channels", type=int, nargs=2, default=[0, 1], metavar=("FLEXOR", "EXTENSOR")
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated user")
    parser.add_argument("--no-wrist", action="store_true", help="sim user: skip the rotation")
    args = parser.parse_args(argv)
    if min(args.channels) < 0:
        parser.error("--channels must be non-negative indices")
    args.unit = {"sim": "V", "serial": "V", "can": "raw"}[args.source]
    return run_service("emg", serve, args)


if __name__ == "__main__":
    sys.exit(main())
