"""EMG service: two channels (flexor, extensor) at 100 Hz on ``lpc/emg``, from a serial
amplifier, the hand's CAN status, a raw stream over LSL or through BrainFlow (filtered to
envelopes by ``lpc_core.devices.emg_envelope``), or a simulated user who watches
``lpc/controller/state``, ``lpc/prosthesis/state`` and ``lpc/aim/cue`` and answers as a person
would. A raw stream silent for ``--outage-ms`` makes the service ``degraded`` (counted in
``emg_outages``); publishing stops, so the controller's stale-EMG rule stops the hand; the
envelope starts afresh when samples resume."""

from __future__ import annotations

import argparse
import asyncio
import sys
import threading
from collections.abc import Callable

import numpy as np

from lpc_core.devices.emg_envelope import (
    EnvelopeParams,
    EnvelopeState,
    envelope_state,
    envelope_step,
)
from lpc_core.sim.emg_sim import PERIOD_NS, Tick, UserParams, UserState, user_step
from schemas import EmgSample
from services.drivers.emg import HandEmg, SerialEmg
from services.drivers.emg_raw import LSL_SCOPES, BrainFlowEmg, LslEmg
from services.drivers.errors import DriverError
from services.runtime import Bus, Ticks, run_service, service_parser

RAW = ("lsl", "brainflow")  # sources of raw EMG, filtered here


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    if args.source == "sim":
        await _simulated_user(bus, args)
    elif args.source in RAW:
        await _raw_device(bus, args)
    else:
        await _device(bus, args)


async def _simulated_user(bus: Bus, args: argparse.Namespace) -> None:
    out = bus.publisher("lpc/emg")
    user = UserState(seed=args.seed, user=UserParams(exercise_wrist=not args.no_wrist))
    # What the person perceives is read when the tick fires, all of it, in the order it
    # arrived and at the time it did: a task per topic woken per message (the hand's status,
    # the cue: about 200 task steps a second) changed nothing until the next tick.
    # Not prompt: a cue or status that arrives from another thread does not wake the loop for
    # a read that waits for the tick anyway.
    perceived = [
        bus.subscribe(k, latest=False, prompt=False)
        for k in ("lpc/controller/state", "lpc/prosthesis/state", "lpc/aim/cue")
    ]
    # Started on the clock's 10 ms grid and paced by the hand's status, as the controller's
    # ticks are: in the container the control loop wakes once a period for the status and both.
    timer = Ticks(bus, PERIOD_NS, pacing=perceived[1])
    t_ns = bus.clock.now_ns() // PERIOD_NS * PERIOD_NS
    while True:
        t_ns, fired_ns = await timer.until(t_ns + PERIOD_NS)
        messages = [got for sub in perceived for got in sub.take_queued()]
        for _, message, received_ns in sorted(messages, key=lambda got: got[2]):
            user, _ = user_step(user, message, received_ns)
        user, samples = user_step(user, Tick(fired_ns), fired_ns)
        for sample in samples:
            out.put(sample)
        behind = bus.clock.now_ns() - t_ns
        if behind > 20 * PERIOD_NS:  # stalled for 200 ms: skip ahead, do not burst
            bus.health.counters["skipped_samples"] += behind // PERIOD_NS
            t_ns += behind // PERIOD_NS * PERIOD_NS  # in the ticks' phase, the controller's


async def _device(bus: Bus, args: argparse.Namespace) -> None:
    """Envelope sources (serial, CAN): each reading is one sample, published as it comes."""
    out = bus.publisher("lpc/emg")
    stop = threading.Event()
    seq = 0

    def publish(channels: list[float], t_ns: int, _rate_hz: float) -> None:
        nonlocal seq
        seq += 1
        out.put(
            EmgSample(seq=seq, t_ns=t_ns, channels=channels, unit=args.unit, source=args.source)
        )

    thread = _read_thread(bus, args, publish, stop)
    try:
        await asyncio.Event().wait()
    finally:
        stop.set()
        await asyncio.to_thread(thread.join, 2.0)


def _read_thread(
    bus: Bus, args: argparse.Namespace, deliver: Callable, stop: threading.Event
) -> threading.Thread:
    """The driver's thread: blocking reads, each result handed to the loop by ``deliver``; a
    failed open or read is logged, and the source is reopened a second later."""
    loop = asyncio.get_running_loop()

    def read() -> None:
        source = None
        while not stop.is_set():
            try:
                if source is None:
                    source = _open(args)
                    what = getattr(source, "description", f"{args.source} EMG source")
                    loop.call_soon_threadsafe(bus.log, "info", f"{what} open")
                got = source.recv(timeout=0.1 if args.source not in RAW else 0.02)
            except DriverError as exc:
                loop.call_soon_threadsafe(bus.log, "error", f"EMG source: {exc}; reopening")
                loop.call_soon_threadsafe(bus.health.counters.update, ["source_errors"])
                if source is not None:
                    source.shutdown()
                source = None
                stop.wait(1.0)
                continue
            if got is not None:
                loop.call_soon_threadsafe(deliver, *got, getattr(source, "rate_hz", 100.0))
        if source is not None:
            source.shutdown()

    thread = threading.Thread(target=read, name="emg-source", daemon=True)
    thread.start()
    return thread


async def _raw_device(bus: Bus, args: argparse.Namespace) -> None:
    """Raw chunks in, 100 Hz envelopes out; silence beyond ``--outage-ms`` is an outage."""
    out = bus.publisher("lpc/emg")
    inbox: asyncio.Queue[tuple[np.ndarray, int, float]] = asyncio.Queue()
    stop = threading.Event()
    thread = _read_thread(bus, args, lambda *got: inbox.put_nowait(got), stop)
    state: EnvelopeState | None = None
    seq, silent_since_ns = 0, bus.clock.now_ns()
    try:
        while True:
            try:
                # Not asyncio.wait_for: before Python 3.12 it swallows a cancel (SIGINT) that
                # lands as the queue yields, and the service would never stop.
                async with asyncio.timeout(args.outage_ms / 1e3):
                    samples, t_ns, rate_hz = await inbox.get()
            except TimeoutError:
                if bus.status != "degraded":
                    bus.status = "degraded"
                    if state is not None:  # an outage, not the wait for the first samples
                        bus.health.counters["emg_outages"] += 1
                        bus.log("warning", f"no EMG samples for {args.outage_ms:g} ms: degraded")
                    state = None  # the envelope starts afresh with the next samples
                continue
            if bus.status == "degraded":
                gap_ms = (bus.clock.now_ns() - silent_since_ns) / 1e6
                bus.status = "ok"
                what = "resumed" if seq else "first samples"
                bus.log("info", f"EMG samples {what} after {gap_ms:.0f} ms")
            silent_since_ns = bus.clock.now_ns()
            try:
                if state is None or state.design.params.rate_hz != rate_hz:
                    params = EnvelopeParams(
                        rate_hz=rate_hz, mains_hz=args.mains, lowpass_hz=args.envelope_hz
                    )
                    state = envelope_state(params)
                    for note in state.design.notes:
                        bus.log("info", f"envelope: {note}")
                state, env = envelope_step(state, samples, t_ns)
            except ValueError as exc:
                bus.reject(args.source, str(exc))
                continue
            for t, values in zip(env.t_ns.tolist(), env.values.tolist(), strict=True):
                seq += 1
                out.put(
                    EmgSample(seq=seq, t_ns=t, channels=values, unit=args.unit, source=args.source)
                )
    finally:
        stop.set()
        await asyncio.to_thread(thread.join, 2.0)


def _open(args: argparse.Namespace) -> SerialEmg | HandEmg | LslEmg | BrainFlowEmg:
    if args.source == "serial":
        return SerialEmg(args.port, args.baudrate, tuple(args.channels))
    if args.source == "lsl":
        return LslEmg(
            tuple(args.channels),
            name=args.lsl_stream,
            stream_type=args.lsl_type,
            timeout=args.lsl_timeout,
            scope=args.lsl_scope,
        )
    if args.source == "brainflow":
        return BrainFlowEmg(
            tuple(args.channels),
            board=args.board,
            serial_port=args.serial_port,
            config=args.board_config,
        )
    return HandEmg(tuple(args.channels), profile="lpc", interface=args.interface, channel=args.can)


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("emg", __doc__ or "")
    parser.add_argument(
        "--source",
        choices=("sim", "serial", "can", *RAW),
        default="sim",
        help="sim (a scripted user), serial (envelope frames), can (the hand's status), lsl or "
        "brainflow (raw EMG, filtered here to 100 Hz envelopes)",
    )
    parser.add_argument("--port", default="/dev/ttyUSB0", help="serial port (or a pyserial URL)")
    parser.add_argument("--baudrate", type=int, default=115200)
    parser.add_argument("--interface", default="socketcan", help="python-can interface for can")
    parser.add_argument("--can", default="can0", help="CAN channel for --source can")
    parser.add_argument(
        "--channels", type=int, nargs=2, default=[0, 1], metavar=("FLEXOR", "EXTENSOR")
    )
    parser.add_argument("--lsl-stream", metavar="NAME", help="LSL stream name (default: by type)")
    parser.add_argument("--lsl-type", default="EMG", help="LSL stream type (default EMG)")
    parser.add_argument(
        "--lsl-timeout", type=float, default=5.0, help="seconds to find the LSL stream (5)"
    )
    parser.add_argument(
        "--lsl-scope",
        choices=LSL_SCOPES,
        help="LSL discovery scope (machine: this computer only, over loopback); default: "
        "liblsl's own configuration (lsl_api.cfg, scope site)",
    )
    parser.add_argument(
        "--board", default="synthetic", help="BrainFlow board: cyton, ganglion, synthetic, ..."
    )
    parser.add_argument("--serial-port", default="", help="serial port of the BrainFlow board")
    parser.add_argument(
        "--board-config",
        default="",
        metavar="CMD",
        help="settings command sent to the BrainFlow board before it streams",
    )
    parser.add_argument(
        "--mains", type=int, choices=(50, 60), default=50, help="mains notch, Hz (50)"
    )
    parser.add_argument(
        "--envelope-hz", type=float, default=8.0, help="envelope low-pass, Hz (8; raw sources)"
    )
    parser.add_argument(
        "--outage-ms",
        type=float,
        default=250.0,
        help="a raw source silent this long is an outage: degraded, counted, and the envelope "
        "restarts when samples resume (250, the controller's stale-EMG limit)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated user")
    parser.add_argument("--no-wrist", action="store_true", help="sim user: skip the rotation")
    args = parser.parse_args(argv)
    if min(args.channels) < 0:
        parser.error("--channels must be non-negative indices")
    if not 0 < args.envelope_hz < 50:
        parser.error("--envelope-hz must be in (0, 50)")
    if not args.outage_ms > 0:
        parser.error("--outage-ms must be positive")
    args.unit = {"sim": "V", "serial": "V", "can": "raw", "lsl": "raw", "brainflow": "uV"}[
        args.source
    ]
    return run_service("emg", serve, args)


if __name__ == "__main__":
    sys.exit(main())
