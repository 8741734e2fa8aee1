"""PipePool with real worker processes: results, failures and a worker killed mid-job."""

from __future__ import annotations

import asyncio
import socket

import pytest

from services.pipe_pool import PipePool
from tests.pipe_pool_work import broken_start, make_work


async def _collect(pool_size: int, jobs: list[bytes]) -> tuple[dict[int, bytes | str], PipePool]:
    done: dict[int, bytes | str] = {}
    finished = asyncio.Event()

    def on_done(tag: int, result: bytes | str) -> None:
        done[tag] = result
        if len(done) == len(jobs):
            finished.set()

    pool = PipePool(pool_size, make_work, (b"ok:",), on_done)
    try:
        async with asyncio.timeout(60):
            await pool.ready()
            for tag, job in enumerate(jobs):
                pool.submit(tag, job)
            await finished.wait()
    finally:
        pool.close()
    return done, pool


class Results(dict[int, bytes | str]):
    """What ``on_done`` reported, by tag; ``until(n)`` waits for the n-th report."""

    def __init__(self) -> None:
        super().__init__()
        self._arrived = asyncio.Event()

    def on_done(self, tag: int, result: bytes | str) -> None:
        self[tag] = result
        self._arrived.set()

    async def until(self, n: int) -> None:
        while len(self) < n:
            self._arrived.clear()
            await self._arrived.wait()


def test_every_job_comes_back_with_its_tag_spread_over_the_workers() -> None:
    jobs = [f"job{i}".encode() for i in range(40)]
    done, pool = asyncio.run(_collect(2, jobs))
    assert sorted(done) == list(range(40))
    for tag, result in done.items():
        assert isinstance(result, bytes) and result.startswith(b"ok:" + jobs[tag] + b"@")
    pids = {r.split(b"@")[1] for r in done.values() if isinstance(r, bytes)}
    assert len(pids) == 2  # both workers took jobs
    assert pool.restarts == 0


def test_a_refused_job_is_reported_as_its_reason() -> None:
    done, _ = asyncio.run(_collect(1, [b"a", b"fail", b"b"]))
    assert done[1] == "cannot do 'fail'"
    assert isinstance(done[0], bytes) and isinstance(done[2], bytes)


def test_a_dead_worker_is_reported_for_its_job_and_replaced() -> None:
    async def run() -> tuple[dict[int, bytes | str], int]:
        done = Results()
        pool = PipePool(1, make_work, (b"ok:",), done.on_done)
        try:
            async with asyncio.timeout(60):
                await pool.ready()
                # Sent together, both wait on the one worker: 'die' kills it with 'b' unread.
                pool.submit(0, b"a")
                pool.submit(1, b"die")
                pool.submit(2, b"b")
                await done.until(3)
                pool.submit(3, b"c")
                await done.until(4)
        finally:
            pool.close()
        return done, pool.restarts

    done, restarts = asyncio.run(run())
    assert isinstance(done[0], bytes) and done[0].startswith(b"ok:a@")
    # The job that killed it and the one queued behind it are reported, not lost.
    assert isinstance(done[1], str) and "died (exit code 3)" in done[1]
    assert isinstance(done[2], str) and "died" in done[2]
    assert restarts == 1
    # The replacement works, in another process.
    assert isinstance(done[3], bytes) and done[3].startswith(b"ok:c@")
    assert done[3].split(b"@")[1] != done[0].split(b"@")[1]


def test_results_sent_before_a_worker_died_are_kept_when_a_submit_finds_it_dead() -> None:
    """The worker answers 'a' and dies on 'die' before 'b' is sent: the send meets a closed
    pipe, and the answer to 'a' still in the pipe is a result, not a death."""

    async def run() -> dict[int, bytes | str]:
        done = Results()
        pool = PipePool(1, make_work, (b"ok:",), done.on_done)
        try:
            async with asyncio.timeout(60):
                await pool.ready()
                pool.submit(0, b"a")
                pool.submit(1, b"die")
                # Block the loop until it has exited, so that nothing reads the pipe meanwhile.
                process = pool._workers[0].process
                assert process.wait(30) == 3
                pool.submit(2, b"b")
                await done.until(3)
        finally:
            pool.close()
        return done

    done = asyncio.run(run())
    assert isinstance(done[0], bytes) and done[0].startswith(b"ok:a@")
    assert isinstance(done[1], str) and "died (exit code 3)" in done[1]
    assert isinstance(done[2], str) and "died" in done[2]


def test_bad_size() -> None:
    async def make() -> None:
        PipePool(0, make_work, (b"",), lambda tag, result: None)

    with pytest.raises(ValueError, match="workers must be >= 1"):
        asyncio.run(make())


def test_a_worker_that_cannot_start_fails_the_pool_instead_of_respawning() -> None:
    async def run() -> PipePool:
        pool = PipePool(2, broken_start, (b"x",), lambda tag, result: None)
        try:
            async with asyncio.timeout(60):
                with pytest.raises(RuntimeError, match=r"exited \(code 1\) before it was ready"):
                    await pool.ready()
            with pytest.raises(RuntimeError, match="before it was ready"):
                pool.submit(0, b"job")
        finally:
            pool.close()
        return pool

    pool = asyncio.run(run())
    assert pool.restarts == 0


def test_results_are_taken_whole_however_the_pipe_splits_or_joins_them() -> None:
    """The pool reads what the pipe holds: two results in one read, and one result cut at
    every byte (its length included), come out whole, in order, each with its tag."""
    from multiprocessing.connection import Connection

    async def run() -> Results:
        done = Results()
        pool = PipePool(1, make_work, (b"ok:",), done.on_done)
        try:
            async with asyncio.timeout(60):
                await pool.ready()
            worker = pool._workers[0]
            ours, theirs = socket.socketpair()
            with ours, theirs:
                # What a worker's Connection.send_bytes writes, read back as raw bytes.
                sender = Connection(theirs.detach())
                for body in (b"Rfirst", b"Esecond", b"R" + b"x" * 300):
                    sender.send_bytes(body)
                sender.close()
                wire = ours.recv(4096)
            assert len(wire) == 3 * 4 + 6 + 7 + 301
            worker.jobs.extend([0, 1, 2])
            two = 4 + 6 + 4 + 7
            pool._take(worker, wire[:two])  # two results in one read
            for i in range(two, len(wire)):  # the third a byte at a time
                pool._take(worker, wire[i : i + 1])
            assert worker.partial == b""
        finally:
            pool.close()
        return done

    done = asyncio.run(run())
    assert done == {0: b"first", 1: "second", 2: b"x" * 300}
