"""Worker processes that the event loop feeds and reads through pipes.

``concurrent.futures.ProcessPoolExecutor`` hands every job and every result through a
management thread in the parent: two more thread wake-ups and GIL hand-offs per job. Measured
here (``asyncio`` parent, 8 KB jobs, one worker, a job every 10 ms): 1.1 ms of the parent's
CPU and 1.15 ms p50 round trip per job through the executor, 0.4 ms and 0.3 ms through a pipe
the loop reads itself (``loop.add_reader``). At 90 frames a second that is 6 % of a core.

Each worker runs one job at a time, in the order sent; a job is bytes in, and the worker's
``work`` function returns bytes or a ``str`` saying why it could not. A worker that dies is
reported for the job it held (``on_done(tag, "worker ... died")``) and started again; one
that dies before it is ready (its initializer failed) fails the pool instead: ``ready()`` and
``submit()`` raise ``RuntimeError`` saying so, and the service stops with it, to be restarted
with backoff by its supervisor rather than respawning a broken worker in a loop.

Workers are plain ``python -m services.pipe_pool FD`` processes on one end of a socket pair,
not ``multiprocessing``'s spawned ones. A spawned child first imports its parent's main module
(the service, with Zenoh: 12 MB a worker) and brings a resource-tracker process along (13 MB)
that nothing here uses. The worker gets the parent's ``sys.path``, then the pickled initializer,
over the socket, so it imports only what ``initializer`` needs.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import os
import pickle
import socket
import subprocess
import sys
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

from services.children import die_with_parent

Work = Callable[[bytes], bytes | str]

_RESULT, _ERROR, _READY = b"R", b"E", b"W"
# Read at most this much of a worker's pipe at once (its results are about 1 kB).
_READ_SIZE = 65536


def _worker_main(fd: int, parent_pid: int) -> None:
    # A worker must not outlive its service, even one killed with SIGKILL.
    die_with_parent(parent_pid=parent_pid)
    conn = Connection(fd)
    sys.path[:] = pickle.loads(conn.recv_bytes())
    initializer, initargs = pickle.loads(conn.recv_bytes())
    work = initializer(*initargs)
    conn.send_bytes(_READY)
    while True:
        try:
            job = conn.recv_bytes()
        except (EOFError, OSError):
            return  # the service closed the pipe: nothing more to do
        result = work(job)
        if isinstance(result, bytes):
            conn.send_bytes(_RESULT + result)
        else:
            conn.send_bytes(_ERROR + str(result).encode())


class _Worker:
    def __init__(self, process: subprocess.Popen[bytes], conn: Connection) -> None:
        self.process = process
        self.conn = conn
        self.ready = False
        self.jobs: collections.deque[Any] = collections.deque()  # tags, in the order sent
        self.partial = b""  # the start of a message not yet whole


class PipePool:
    """``workers`` processes made by ``initializer(*initargs)`` (which returns the ``work``
    function); ``submit(tag, job)`` runs a job on the worker with the fewest jobs, and
    ``on_done(tag, result)`` is called on the loop with its bytes or the reason it failed."""

    def __init__(
        self,
        workers: int,
        initializer: Callable[..., Work],
        initargs: tuple,
        on_done: Callable[[Any, bytes | str], None],
    ) -> None:
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if getattr(initializer, "__module__", None) == "__main__":
            raise ValueError(
                f"initializer {initializer.__qualname__} must be importable by the workers: "
                "define it in a module, not in the script that runs"
            )
        self._loop = asyncio.get_running_loop()
        # Pickled once, as a spawned process would get it; a new interpreter, not a fork:
        # forking after a Zenoh session is open hangs.
        self._setup = (pickle.dumps(sys.path), pickle.dumps((initializer, initargs)))
        self._on_done = on_done
        self._all_ready = asyncio.Event()
        self.failed: str | None = None
        self.restarts = 0
        self._closed = False
        self._workers = [self._start() for _ in range(workers)]

    def _start(self) -> _Worker:
        ours, theirs = socket.socketpair()
        with theirs:
            fd = theirs.fileno()
            argv = [sys.executable, "-m", "services.pipe_pool", str(fd), str(os.getpid())]
            process = subprocess.Popen(argv, pass_fds=(fd,))
        worker = _Worker(process, Connection(ours.detach()))
        for part in self._setup:
            # Before the reader is added: the worker reads these first, whatever it sends.
            worker.conn.send_bytes(part)
        self._loop.add_reader(worker.conn.fileno(), self._readable, worker)
        return worker

    async def ready(self) -> None:
        """Until every worker has run its initializer (imports, first calls)."""
        await self._all_ready.wait()
        if self.failed is not None:
            raise RuntimeError(self.failed)

    def submit(self, tag: Any, job: bytes) -> None:
        if self.failed is not None:
            raise RuntimeError(self.failed)
        worker = min(self._workers, key=lambda w: len(w.jobs))
        worker.jobs.append(tag)
        try:
            # An idle worker reads as we write, so this waits at most for one job's bytes.
            worker.conn.send_bytes(job)
        except OSError:
            self._died(worker)

    def _readable(self, worker: _Worker) -> None:
        # One read of what is there, not ``Connection.recv_bytes``'s two (length, then body)
        # through two buffers: the loop is told the pipe is readable, so this does not wait.
        try:
            chunk = os.read(worker.conn.fileno(), _READ_SIZE)
        except OSError:
            chunk = b""
        if not chunk:
            self._died(worker)
            return
        self._take(worker, chunk)

    def _take(self, worker: _Worker, chunk: bytes) -> None:
        # Messages framed as ``Connection.send_bytes`` frames them (a 4-byte big-endian length,
        # then the body): each whole one is handled, the rest kept for the next read.
        data = worker.partial + chunk if worker.partial else chunk
        start, end = 0, len(data)
        while end - start >= 4:
            stop = start + 4 + int.from_bytes(data[start : start + 4], "big")
            if stop > end:
                break
            self._handle(worker, data[start + 4 : start + 5], data[start + 5 : stop])
            start = stop
        worker.partial = data[start:] if start < end else b""

    def _handle(self, worker: _Worker, kind: bytes, body: bytes) -> None:
        if kind == _READY:
            worker.ready = True
            if all(w.ready for w in self._workers):
                self._all_ready.set()
        elif worker.jobs:
            tag = worker.jobs.popleft()
            self._on_done(tag, body if kind == _RESULT else body.decode(errors="replace"))

    def _died(self, worker: _Worker) -> None:
        # Results it sent before it died may still be in the pipe (a submit that met the
        # closed pipe gets here before the loop has read them): they are results, not losses.
        with contextlib.suppress(EOFError, OSError):
            while worker.conn.poll(0) and (chunk := os.read(worker.conn.fileno(), _READ_SIZE)):
                self._take(worker, chunk)
        # Its pipe closed: it is exiting. A moment for it to finish says why, in its exit code.
        self._stop(worker, grace_s=2.0)
        if self._closed or worker not in self._workers:
            return
        code = worker.process.returncode
        for tag in worker.jobs:
            self._on_done(tag, f"worker {worker.process.pid} died (exit code {code})")
        if not worker.ready:
            self.failed = (
                f"worker {worker.process.pid} exited (code {code}) before it was ready: "
                "its start-up failed (see its output above)"
            )
            self._all_ready.set()  # wake ready(), which raises
            return
        self.restarts += 1
        self._workers[self._workers.index(worker)] = self._start()

    def _stop(self, worker: _Worker, grace_s: float = 0.0) -> None:
        with contextlib.suppress(ValueError, OSError):  # already removed or closed
            self._loop.remove_reader(worker.conn.fileno())
        worker.conn.close()
        with contextlib.suppress(subprocess.TimeoutExpired):
            worker.process.wait(grace_s)
        if worker.process.poll() is None:
            worker.process.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                worker.process.wait(0.1)

    @property
    def pids(self) -> list[int]:
        return [w.process.pid for w in self._workers]

    def close(self) -> None:
        """Stop every worker; a job still running is lost (the service is stopping)."""
        self._closed = True
        for worker in self._workers:
            self._stop(worker)


if __name__ == "__main__":
    _worker_main(int(sys.argv[1]), int(sys.argv[2]))
