"""``lpc bench pool``: the reconstructor's way of reaching its workers, against the standard one.

One asyncio parent sends a job of ``--bytes`` bytes every ``--interval-ms`` to one spawned
worker and waits for its answer: through ``services.pipe_pool.PipePool`` (pipes the event loop
reads itself) and through ``concurrent.futures.ProcessPoolExecutor`` (a management thread in
the parent). Both run in the same invocation, alternating ``--rounds`` times, and the bench
prints the parent's CPU per job and the round trip (p50/p99) of each, then their ratio.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from services.pipe_pool import PipePool


def _echo(job: bytes) -> bytes | str:
    return job[:64]


def _make_echo() -> Callable[[bytes], bytes | str]:
    return _echo


async def _measure(
    call: Callable[[bytes], Awaitable[object]], jobs: int, payload: bytes, interval_s: float
) -> tuple[float, list[float]]:
    """The parent's CPU over ``jobs`` calls (one warm-up call first) and each round trip."""
    await call(payload)  # the worker is up and warm
    trips, cpu = [], time.process_time()
    for _ in range(jobs):
        start = time.perf_counter()
        await call(payload)
        trips.append(time.perf_counter() - start)
        await asyncio.sleep(interval_s)
    return time.process_time() - cpu, trips


async def _through_executor(jobs: int, payload: bytes, interval_s: float) -> tuple[float, list]:
    loop = asyncio.get_running_loop()
    pool = ProcessPoolExecutor(1, multiprocessing.get_context("spawn"))
    try:
        return await _measure(
            lambda job: loop.run_in_executor(pool, _echo, job), jobs, payload, interval_s
        )
    finally:
        pool.shutdown()


async def _through_pipes(jobs: int, payload: bytes, interval_s: float) -> tuple[float, list]:
    answered: asyncio.Queue[bytes | str] = asyncio.Queue()
    pool = PipePool(1, _make_echo, (), lambda _tag, result: answered.put_nowait(result))

    async def call(job: bytes) -> bytes | str:
        pool.submit(None, job)
        return await answered.get()

    try:
        return await _measure(call, jobs, payload, interval_s)
    finally:
        pool.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--jobs", type=int, default=300, help="jobs per round (300)")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of each, alternating (2)")
    parser.add_argument("--bytes", type=int, default=8000, help="job size (8000: four scan lines)")
    parser.add_argument(
        "--interval-ms", type=float, default=10.0, help="pause between jobs, ms (10)"
    )


def run(args: argparse.Namespace) -> int:
    if args.jobs < 1 or args.rounds < 1 or args.bytes < 1 or args.interval_ms < 0:
        raise SystemExit(
            "lpc bench pool: --jobs, --rounds and --bytes must be >= 1, --interval-ms >= 0"
        )
    payload = os.urandom(args.bytes)
    ways = {"pipes (PipePool)": _through_pipes, "ProcessPoolExecutor": _through_executor}
    cpu = {name: 0.0 for name in ways}
    trips: dict[str, list[float]] = {name: [] for name in ways}
    for round_ in range(args.rounds):
        for name, way in ways.items():
            used, times = asyncio.run(way(args.jobs, payload, args.interval_ms / 1e3))
            cpu[name] += used
            trips[name] += times
            print(f"round {round_ + 1}/{args.rounds}: {name} done", flush=True)
    n = args.jobs * args.rounds
    print(f"\n{n} jobs of {args.bytes} B each way, one worker, {args.interval_ms:g} ms apart")
    print(f"{'way':22s} {'parent CPU/job':>15s} {'trip p50':>9s} {'trip p99':>9s}")
    for name in ways:
        p50, p99 = np.percentile(trips[name], [50, 99]) * 1e3
        print(f"{name:22s} {cpu[name] / n * 1e3:12.3f} ms {p50:6.3f} ms {p99:6.3f} ms")
    pipes, executor = (cpu[name] for name in ways)
    print(f"ratio, parent CPU per job: pipes / executor = {pipes / executor:.2f}")
    return 0
