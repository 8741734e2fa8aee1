"""Controller service: ``lpc/emg``, ``lpc/grasp/target``, ``lpc/aim/cue`` and
``lpc/prosthesis/state`` in; ``lpc/controller/state`` (every transition, and 10 Hz) and
``lpc/prosthesis/command`` (one per hand status, 100 Hz) out. A 100 Hz timer lets the
controller notice stale inputs when nothing arrives at all (it fires with the hand's status
when that comes within a few ms of it: ``services.runtime.Ticks``); its health counts the
timer's ``ticks``, the ``paced_ticks`` among them and the ``late_ticks`` that woke more than a
period late (the camera sheds frames when there are too many of them)."""

from __future__ import annotations

import argparse
import asyncio
import sys
from types import MappingProxyType

from lpc_core.control.controller import (
    EMG,
    HAND,
    TARGET,
    ControllerCore,
    ControllerParams,
    Tick,
    TransitionError,
    controller_step,
)
from lpc_core.control.emg import EmgProfile
from lpc_core.sim.emg_sim import sim_user_params
from schemas import ControllerState
from services.drivers.emg import load_emg_profile
from services.runtime import Bus, Subscription, Ticks, service_main, service_parser

TICK_NS = 10_000_000
# These and every EMG sample are stepped when the controller next steps for the hand's status
# or its tick (within 10 ms), not on arrival, every one in the order and at the time it
# arrived: the commands follow the hand's status anyway. Each grasp target woke the control
# loop on its own (90 a second, from the reconstructor's result on the main loop); each EMG
# sample (the simulated user's, published on the same loop at the tick) cost a task wake-up
# and an event-loop pass of its own, 100 a second, to step what the next status or tick would
# have stepped first anyway.
VISION = (TARGET, "lpc/aim/cue")


def parser() -> argparse.ArgumentParser:
    """The service's flags (a replay parses the recorded ones with it)."""
    parser = service_parser("controller", __doc__ or "")
    parser.add_argument("--profile", metavar="FILE", help="user profile JSON (its emg section)")
    parser.add_argument(
        "--sim-user",
        action="store_true",
        help="calibration of the simulated user (emg_sim defaults) instead of a profile",
    )
    parser.add_argument("--stale-emg-ms", type=float, default=250.0)
    parser.add_argument("--stale-hand-ms", type=float, default=200.0)
    parser.add_argument(
        "--stale-target-ms", type=float, default=1000.0, help="0: do not watch the grasp target"
    )
    parser.add_argument(
        "--camera-fixed",
        action="store_true",
        help="target angles are not relative to the wrist (camera not on the hand)",
    )
    return parser


def initial_state(args: argparse.Namespace) -> ControllerCore:
    """The step function's state at start, from the flags; ``ValueError`` if they are bad.
    Without ``--sim-user`` the EMG calibration is read from ``--profile`` (or the default
    profile); with none, the default calibration."""
    if min(args.stale_emg_ms, args.stale_hand_ms, args.stale_target_ms) < 0:
        raise ValueError("--stale-*-ms must be >= 0 (0 turns that watchdog off)")
    profile = sim_user_params().profile if args.sim_user else load_emg_profile(args.profile)
    stale = {EMG: args.stale_emg_ms, HAND: args.stale_hand_ms, TARGET: args.stale_target_ms}
    params = ControllerParams(
        profile=profile or EmgProfile(),
        stale_ms=MappingProxyType({k: v for k, v in stale.items() if v > 0}),
        camera_on_hand=not args.camera_fixed,
    )
    return ControllerCore(params=params)


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    core = initial_state(args)
    publishers = {
        "ControllerState": bus.publisher("lpc/controller/state"),
        "ProsthesisCommand": bus.publisher("lpc/prosthesis/command"),
    }
    now_ns = 0

    def handle(t_ns: int, message: object) -> None:
        # Stepped where it arrives: a queue to one stepping task cost a second task wake-up
        # per message (about 450 a second), for the same order of steps.
        nonlocal core, now_ns
        now_ns = max(now_ns, t_ns)  # the controller's time never goes back
        try:
            core, outputs = controller_step(core, message, now_ns)
        except TransitionError as exc:
            bus.health.counters["transition_errors"] += 1
            bus.log("warning", str(exc))
            return
        except ValueError as exc:
            bus.reject(type(message).__name__, str(exc))
            return
        for out in outputs:
            publishers[type(out).__name__].put(out)
            if isinstance(out, ControllerState) and out.event:
                bus.log("info", f"{out.previous} -> {out.state} on {out.event}: {out.reason}")

    # Every EMG sample, target and cue, in order (FIFO), at the time it arrived; they wake no
    # one. EMG keeps the default capacity: the detector's timing rules need every sample.
    queues = [bus.subscribe(EMG, latest=False, prompt=False)] + [
        bus.subscribe(k, latest=False, capacity=64, prompt=False) for k in VISION
    ]

    def step(t_ns: int, message: object) -> None:
        # The messages queued meanwhile go first, in the order they arrived and at the time
        # they did, as they were stepped when each woke a task of its own.
        queued = [got for sub in queues for got in sub.take_queued()]
        queued.append(("", message, t_ns))
        for _, got, received_ns in sorted(queued, key=lambda got: got[2]):
            handle(received_ns, got)

    # Each input carries the time it happened (received, or the tick's time), so that a stall
    # of this process is not taken for silence of its inputs.
    async def pump(sub: Subscription) -> None:
        while True:
            _, message, received_ns = await sub.receive()
            step(received_ns, message)

    hand = bus.subscribe(HAND, latest=True)
    # Started on the clock's 10 ms grid, as the EMG service's samples are, and both paced by
    # the hand's status: the control loop's two 100 Hz timers fire in the pass that hands the
    # status over, one wake-up a period where there were two (three before the shared grid).
    timer = Ticks(bus, TICK_NS, pacing=hand)

    async def ticks() -> None:
        t_ns = bus.clock.now_ns() // TICK_NS * TICK_NS
        while True:
            # At most one period behind after a stall, in the same phase (the EMG's).
            t_ns += max(1, (bus.clock.now_ns() - t_ns) // TICK_NS - 1) * TICK_NS
            t_ns, fired_ns = await timer.until(t_ns)
            # Its lateness is the camera's cue to shed frames (lpc_core.perception.shedding).
            bus.health.counters["ticks"] += 1
            bus.health.counters["paced_ticks"] += timer.paced
            if bus.clock.now_ns() - fired_ns > TICK_NS:
                bus.health.counters["late_ticks"] += 1
            step(fired_ns, Tick(fired_ns))

    tasks = [asyncio.create_task(pump(hand)), asyncio.create_task(ticks())]
    try:
        # Any task's failure ends the service (its supervisor restarts it).
        await asyncio.gather(*tasks)
    finally:
        for task in tasks:
            task.cancel()


def main(argv: list[str] | None = None) -> int:
    def check(args: argparse.Namespace) -> None:
        initial_state(args)
        if not args.sim_user and load_emg_profile(args.profile) is None:
            print("[controller] warning: no EMG profile: run 'lpc emg calibrate'", file=sys.stderr)

    return service_main("controller", parser(), check, serve, argv)


if __name__ == "__main__":
    sys.exit(main())
