"""Reconstructor service: ``lpc/scans`` (``--method laser``) or ``lpc/camera/depth``
(``--method cloud``) in; ``lpc/reconstruction`` and ``lpc/grasp/target`` out.

Frames are reconstructed in worker processes fed through pipes (``services.pipe_pool``), one
frame per job, and published in ``seq`` order. ``--ahead`` frames (default 1) are handed to a
busy worker behind the one it runs, so that it starts the next the moment it is done, without
waiting for this service's loop to take the result; at most ``--max-pending`` more frames wait
here for a worker; when another arrives the oldest waiting frame is dropped and counted
(``dropped_frames``). The ordering is ``lpc_core.perception.reconstructor``'s pure bookkeeping. Each
worker reconstructs one synthetic frame before the service subscribes, so start-up costs
(imports, first calls) never count as drops. Depth is a sensor topic: when even the pump falls
behind, only the newest frame is kept.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import sys
import time

from lpc_core.perception.laser import LaserParams
from lpc_core.perception.reconstructor import (
    INPUT_TOPICS,
    Dropped,
    Output,
    PoolParams,
    PoolState,
    ReconstructState,
    Release,
    Submit,
    frame_arrived,
    frame_done,
    window_message,
)
from lpc_core.perception.window import WindowState
from schemas import decode
from services.mcap_log import read_header
from services.pipe_pool import PipePool
from services.reconstructor_worker import init_worker
from services.runtime import Bus, service_main, service_parser

# The workers' least niceness. When a worker and the set's control path (EMG, controller, hand
# commands) are ready to run at once, the control path goes first: under a CPU quota each
# frame the worker starts otherwise holds the controller's loop for the rest of a period. With
# a process per service, lpc up already runs this service, and so its workers, at nice 5.
WORKER_NICE = 5


def _yield_to_control(pids: list[int]) -> None:
    for pid in pids:
        with contextlib.suppress(OSError):  # a worker that has just exited
            niceness = os.getpriority(os.PRIO_PROCESS, pid)
            os.setpriority(os.PRIO_PROCESS, pid, max(niceness, WORKER_NICE))


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    # Workers' results that wait for the task below, in the order they came back (see
    # ``finished``); ``None`` once the frame pump has stopped, an exception once handling a
    # result in the pool's reader raised.
    results: asyncio.Queue[tuple[int, bytes | str] | BaseException | None] = asyncio.Queue()
    # A depth frame (about 600 kB) does not fit the pipe's socket buffer (208 kB): handed to a
    # busy worker, its write would hold the loop until that worker is done. Scans are 4-5 kB.
    ahead = args.ahead if args.method == "laser" else 0
    state = PoolState(
        params=PoolParams(workers=args.workers, max_pending=args.max_pending, ahead=ahead)
    )
    window = WindowState()
    reconstructions = bus.publisher("lpc/reconstruction")
    targets = bus.publisher("lpc/grasp/target")
    topic = INPUT_TOPICS[args.method]
    carrying = False  # inside carry_out

    def finished(seq: int, result: bytes | str) -> None:
        # Called by the pool's pipe reader on the loop: the result is handled there, as the
        # pump hands a frame on in its own step, not queued for the task below (one task
        # wake-up and loop pass a frame fewer). Queued only behind results that wait there
        # already (their order kept), and when the pool reports a result from inside
        # ``carry_out`` (a worker found dead as a frame is submitted): ``state`` is then
        # being replaced by the caller. What raises is raised by the task, as before.
        nonlocal state
        if carrying or not results.empty():
            results.put_nowait((seq, result))
            return
        try:
            state, outputs = frame_done(state, seq, result)
            carry_out(outputs)
        except Exception as exc:
            results.put_nowait(exc)

    started = time.monotonic()
    pool = PipePool(args.workers, init_worker, (args.method, initial_state(args).params), finished)
    niced = 0

    def carry_out(outputs: list[Output]) -> None:
        nonlocal carrying
        carrying = True
        try:
            _carry_out(outputs)
        finally:
            carrying = False

    def _carry_out(outputs: list[Output]) -> None:
        nonlocal window, niced
        bus.health.counters["worker_restarts"] = pool.restarts
        if pool.restarts != niced:  # a restarted worker starts at the service's niceness
            _yield_to_control(pool.pids)
            niced = pool.restarts
        for out in outputs:
            if isinstance(out, Submit):
                pool.submit(out.seq, out.job)
            elif isinstance(out, Dropped):
                bus.health.counters["dropped_frames"] += 1
            elif isinstance(out, Release) and isinstance(out.result, bytes):
                # Decoded for the window; published as the worker encoded it (the same
                # bytes: encoding is deterministic), not encoded a second time.
                message = decode("lpc/reconstruction", out.result)
                reconstructions.put_encoded(message, out.result)
                window, target = window_message(window, message)
                targets.put(target)
            elif isinstance(out, Release):
                bus.reject(topic, str(out.result))

    async def pump() -> None:
        # A frame is handed on in the pump's own step, not queued for the loop below: one
        # task hand-over a frame fewer. The bookkeeping runs between awaits, so the two never
        # interleave.
        nonlocal state
        # Depth frames are big: keep the newest only. Scans all queue, for in-order release.
        latest = args.method == "cloud"
        frames = bus.subscribe(topic, latest=latest, capacity=256, decode=False)
        while True:
            _, payload, _ = await frames.receive()
            header = read_header(payload)
            if header is None:
                bus.reject(topic, "no seq/t_ns header")
                continue
            state, outputs = frame_arrived(state, header[0], payload)
            carry_out(outputs)

    reader: asyncio.Task[None] | None = None
    try:
        # Subscribing only once every worker is warm keeps the start-up out of the drop count.
        await pool.ready()
        _yield_to_control(pool.pids)
        niced = pool.restarts
        ready_s = time.monotonic() - started
        bus.log("info", f"{args.workers} {args.method} worker(s) ready in {ready_s:.1f} s")
        reader = asyncio.create_task(pump())
        # The pump's error (a failed pool) stops the service, as the loop's own would.
        reader.add_done_callback(lambda _: results.put_nowait(None))
        while True:
            done = await results.get()
            if done is None:
                reader.result()
                return
            if isinstance(done, BaseException):
                raise done
            state, outputs = frame_done(state, *done)
            carry_out(outputs)
    finally:
        if reader is not None:
            reader.cancel()
        # A worker still importing or reconstructing would hold the exit past the 2 s that
        # every service has to stop in; its frame is lost anyway.
        pool.close()


def parser() -> argparse.ArgumentParser:
    """The service's flags (a replay parses the recorded ones with it)."""
    parser = service_parser("reconstructor", __doc__ or "")
    parser.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument(
        "--ahead",
        type=int,
        default=1,
        help="scans handed to each worker behind the one it runs, so that it starts the next "
        "without waiting for the service (default 1; --method cloud hands none ahead)",
    )
    parser.add_argument(
        "--max-pending", type=int, default=2, help="frames that may wait for a worker (default 2)"
    )
    parser.add_argument(
        "--method",
        choices=tuple(INPUT_TOPICS),
        default="laser",
        help="laser: the four scan lines (lpc/scans); cloud: the full point cloud of each depth "
        "frame (lpc/camera/depth) (default laser)",
    )
    parser.add_argument(
        "--variant", choices=("lpc", "paper"), default="lpc", help="the laser method's variant"
    )
    return parser


def initial_state(args: argparse.Namespace) -> ReconstructState:
    """The in-process step's state at start (the parameters the workers run with)."""
    return ReconstructState(params=LaserParams(variant=args.variant))


def main(argv: list[str] | None = None) -> int:
    def check(args: argparse.Namespace) -> None:
        PoolParams(workers=args.workers, max_pending=args.max_pending, ahead=args.ahead)

    return service_main("reconstructor", parser(), check, serve, argv)


if __name__ == "__main__":
    sys.exit(main())
