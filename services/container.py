"""Service container (``lpc up --together``): several services in one process, as asyncio tasks
on one event loop and one Zenoh session, as ROS 2 runs components in a component container.

Each service is the same ``serve`` its own process runs, with its flags parsed and checked by its
own ``main`` (``services.runtime.load_service``), and its own ``Bus`` on the shared session: it
still publishes and subscribes on the same ``lpc/**`` topics, reports ``lpc/health/<service>``
and holds ``lpc/alive/<service>``, so recording, replay, dashboards and outside subscribers see
what they see when every service has its process. A sample one of its services publishes is
handed by the publisher straight to the subscriptions of both loops (``Router.deliver``); Zenoh
carries it only to other processes. Samples from other processes reach each loop through one
subscriber on ``lpc/**`` (``services.runtime.Router``), once for all the services that want
them. A service that raises is restarted inside the container with backoff (counted in its
health, logged); the process itself is restarted by ``lpc up``. On SIGINT/SIGTERM the services
are stopped in reverse start order (the recorder, first, is last).

Each service's health also carries ``cpu_ms``: the CPU time its tasks took on the shared loop
(Zenoh's own threads and the loop's bookkeeping are the container's).
"""

from __future__ import annotations

import argparse
import asyncio
import collections.abc
import contextlib
import contextvars
import functools
import json
import math
import os
import signal
import sys
import threading
import time
from typing import Any

import zenoh

from services.heap import keep_freed_memory
from services.runtime import (
    HEALTH_PERIOD_S,
    Bus,
    LoadedService,
    Router,
    add_bus_arguments,
    config_from_args,
    load_service,
)
from services.thread_names import CONTROL_LOOP, name_native_thread

NAME = "container"
SWITCH_INTERVAL_S = 0.001


class ServiceRunner:
    """One service in the container: runs its ``serve`` and restarts it when it raises."""

    def __init__(
        self, loaded: LoadedService, session: zenoh.Session, router: Router, quiet: bool
    ) -> None:
        self.loaded = loaded
        self.session = session
        self.router = router
        self.quiet = quiet
        self.cpu_ns = 0
        self.restarts = 0
        # Threading events: the runner may be on the control loop's thread.
        self.started = threading.Event()
        self.done = threading.Event()

    @property
    def name(self) -> str:
        return self.loaded.name

    async def run(self) -> None:
        try:
            await self._run()
        finally:
            self.done.set()

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        context = contextvars.copy_context()
        context.run(_RUNNER.set, self)
        while True:
            bus = Bus(
                self.session,
                self.name,
                loop=loop,
                quiet=self.quiet,
                argv=getattr(self.loaded.args, "argv", None),
                router=self.router,
            )
            bus.log("info", f"started in the container (pid {os.getpid()})")
            bus.status = "ok"
            self.started.set()
            # In the service's context: its health (a snapshot and a put a second) is its own.
            health = loop.create_task(self._health(bus), context=context)
            work = loop.create_task(self.loaded.serve(bus, self.loaded.args), context=context)
            try:
                await asyncio.wait({work})
            except asyncio.CancelledError:
                bus.status = "stopping"
                work.cancel()
                await asyncio.gather(work, return_exceptions=True)
                health.cancel()
                await asyncio.gather(health, return_exceptions=True)
                self._close(bus, "stopped")
                raise
            health.cancel()
            await asyncio.gather(health, return_exceptions=True)
            self.restarts += 1
            backoff = min(0.25 * 2 ** (self.restarts - 1), 5.0)
            error = work.exception() if not work.cancelled() else None
            why = f"failed: {type(error).__name__}: {error}" if error else "returned"
            bus.log(
                "error" if error else "warning",
                f"{why}; restart #{self.restarts} in {backoff:.2f} s",
            )
            self._close(bus, None)
            await asyncio.sleep(backoff)

    async def _health(self, bus: Bus) -> None:
        while True:
            bus.health.counters["cpu_ms"] = self.cpu_ns // 1_000_000
            bus.health.counters["restarts"] = self.restarts
            bus.publish_health()
            await until_health_report()

    def _close(self, bus: Bus, last_words: str | None) -> None:
        bus.health.counters["cpu_ms"] = self.cpu_ns // 1_000_000
        bus.health.counters["restarts"] = self.restarts
        bus.publish_health()
        if last_words:
            bus.log("info", last_words)
        bus.close()


# The service whose task is running (tasks inherit it from the task that created them).
_RUNNER: contextvars.ContextVar[ServiceRunner | None] = contextvars.ContextVar(
    "_RUNNER", default=None
)


class _Timed(collections.abc.Coroutine):
    """A task's coroutine that adds the CPU time of each of its steps to its service."""

    def __init__(self, coro: collections.abc.Coroutine, runner: ServiceRunner) -> None:
        self._coro = coro
        self._runner = runner
        self.__qualname__ = getattr(coro, "__qualname__", type(coro).__name__)

    def send(self, value: Any) -> Any:
        return _timed_call(self._runner, self._coro.send, value)

    def __next__(self) -> Any:
        return self.send(None)

    def throw(self, *exc: Any) -> Any:
        return _timed_call(self._runner, self._coro.throw, *exc)

    def close(self) -> None:
        self._coro.close()

    def __await__(self) -> Any:
        return self

    def __iter__(self) -> Any:
        return self


def _task_factory(loop: asyncio.AbstractEventLoop, coro: Any, **kwargs: Any) -> asyncio.Task[Any]:
    context = kwargs.get("context")
    runner = context.get(_RUNNER) if context is not None else _RUNNER.get()
    if runner is not None:
        coro = _Timed(coro, runner)
    return asyncio.Task(coro, loop=loop, **kwargs)


class ContainerLoop(asyncio.SelectorEventLoop):
    """The container's event loops: a reader callback that a service registers (the camera's
    frame socket, its transport's ``_read_ready``; the reconstructor's worker pipes) adds its
    CPU time to that service, as its tasks' steps do (``_Timed``). They ran outside every
    task, so ``lpc bench footprint`` put them in no service's own time: cProfile of the main
    loop (thread CPU, 25 s at 60 Hz) 0.24 s in the camera's socket reads and 0.12 s in the
    pool's pipe reader, a third of what that loop spent outside the services' steps."""

    def _add_reader(
        self, fd: Any, callback: collections.abc.Callable[..., object], *args: Any
    ) -> Any:
        # Every reader goes through here: add_reader and the transports alike. Called in the
        # registering code's context (a transport registers from a handle that copied it).
        runner = _RUNNER.get()
        if runner is not None:
            callback = functools.partial(_timed_call, runner, callback)
        return super()._add_reader(fd, callback, *args)


def _timed_call(
    runner: ServiceRunner, callback: collections.abc.Callable[..., Any], *args: Any
) -> Any:
    """``callback(*args)``, its CPU time added to ``runner``'s service (a task's step, a
    reader callback)."""
    start = time.thread_time_ns()
    try:
        return callback(*args)
    finally:
        runner.cpu_ns += time.thread_time_ns() - start


def load_all(specs: list[dict[str, Any]]) -> list[LoadedService]:
    """Each spec ``{"module": ..., "argv": [...]}`` parsed by the service's own ``main``."""
    loaded = []
    for spec in specs:
        try:
            loaded.append(load_service(spec["module"], list(spec.get("argv", []))))
        except SystemExit as exc:
            if exc.code not in (0, None):
                raise SystemExit(f"[{NAME}] error: bad flags for {spec['module']}") from exc
            raise
    return loaded


async def run_container(
    loaded: list[LoadedService],
    args: argparse.Namespace,
    stop: asyncio.Event | None = None,
    control_loop: tuple[str, ...] = (),
) -> int:
    """Run ``loaded`` until SIGINT/SIGTERM (or ``stop``, when given), then stop them in
    reverse order. The services named in ``control_loop`` run on a loop of their own."""
    loop = asyncio.get_running_loop()
    loop.set_task_factory(_task_factory)
    if stop is None:
        stop = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
    try:
        session = zenoh.open(config_from_args(args))
    except zenoh.ZError as exc:
        print(f"[{NAME}] error: cannot open the Zenoh session: {exc}", file=sys.stderr)
        return 2
    with session:
        router = Router(session, loop)
        control = _ControlLoop(session) if any(s.name in control_loop for s in loaded) else None
        runners, stoppers = [], []
        for service in loaded:
            if control is not None and service.name in control_loop:
                runner = ServiceRunner(service, session, control.router, args.quiet)
                stoppers.append(control.start(runner.run()).cancel)
            else:
                runner = ServiceRunner(service, session, router, args.quiet)
                stoppers.append(asyncio.create_task(runner.run(), name=runner.name).cancel)
            runners.append(runner)
        while not all(r.started.is_set() for r in runners):
            await asyncio.sleep(0.01)
        # The container's own token last: 'lpc up' waits for it, so all services are on.
        own = Bus(session, NAME, loop=loop, quiet=args.quiet, argv=sys.argv[1:])
        own.health.detail = "services: " + ", ".join(r.name for r in runners)
        own.status = "ok"
        own.log("info", f"{len(runners)} services in one process (pid {os.getpid()})")
        health = asyncio.create_task(_container_health(own, runners))
        await stop.wait()
        own.status = "stopping"
        health.cancel()
        for runner, stop_runner in reversed(list(zip(runners, stoppers, strict=True))):
            stop_runner()
            await asyncio.to_thread(runner.done.wait)
        _publish_container_health(own, runners)
        own.log("info", "stopped")
        own.close()
        router.close()
        if control is not None:
            control.close()
    return 0


class _ControlLoop:
    """A second event loop, on a thread of its own, for the control path: a service there
    that wakes (EMG at 100 Hz, the controller, the tactor bridge) gets the interpreter within
    one GIL switch interval, where on the shared loop it would wait behind a frame's rendering
    or a chunk's compression."""

    def __init__(self, session: zenoh.Session) -> None:
        self.loop = ContainerLoop()
        self.loop.set_task_factory(_task_factory)
        # No subscriber of its own: the main loop's router, on the same session, copies out the
        # remote samples this loop wants and queues them here (it wants a few small topics).
        self.router = Router(session, self.loop, wildcard=False)
        self._thread = threading.Thread(target=self._run, name=CONTROL_LOOP, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        name_native_thread(CONTROL_LOOP)  # its CPU apart in lpc bench footprint
        self.loop.run_forever()

    def start(self, coro: Any) -> Any:
        """Run ``coro`` on the control loop; returns its concurrent future."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop)

    def close(self) -> None:
        self.router.close()
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(timeout=5)
        if not self._thread.is_alive():
            self.loop.close()


async def until_health_report() -> None:
    """Sleep until the next health report of a service in the container is due: on the grid
    of whole ``HEALTH_PERIOD_S`` of the running loop's clock (``time.monotonic``, which both of
    its loops read), at the grid point nearest one period from now. Each service on its own
    phase from its start took a wake-up of its loop per report, eight a second; on the grid
    they share one pass of each loop, their timers due at the very same time (``asyncio.sleep``
    would add its delay to a later reading of the clock, a few microseconds apart for each).
    Rounded, not floored: a timer that fires a hair before its grid point (the loop runs what
    is due within its clock's resolution) still waits a whole period, not a hair."""
    loop = asyncio.get_running_loop()
    due = math.floor(loop.time() / HEALTH_PERIOD_S + 1.5) * HEALTH_PERIOD_S
    report = loop.create_future()
    timer = loop.call_at(due, _resolve, report)
    try:
        await report
    finally:
        timer.cancel()


def _resolve(future: asyncio.Future[None]) -> None:
    if not future.done():  # not cancelled meanwhile
        future.set_result(None)


async def _container_health(bus: Bus, runners: list[ServiceRunner]) -> None:
    while True:
        _publish_container_health(bus, runners)
        await until_health_report()


def _publish_container_health(bus: Bus, runners: list[ServiceRunner]) -> None:
    for runner in runners:
        bus.health.counters[f"restarts:{runner.name}"] = runner.restarts
    bus.health.counters["restarts"] = sum(r.restarts for r in runners)
    bus.health.counters["cpu_ms"] = round(time.process_time() * 1000)
    bus.publish_health()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m services.{NAME}", description=__doc__)
    add_bus_arguments(parser)
    parser.add_argument("--quiet", action="store_true", help="log only warnings and errors")
    parser.add_argument(
        "--services",
        required=True,
        metavar="JSON",
        help='the services, in start order: [{"module": "services.scans", "argv": [...]}, ...]; '
        '"loop": "control" puts one on the control loop',
    )
    args = parser.parse_args(argv)
    try:
        specs = json.loads(args.services)
        if not isinstance(specs, list) or not all(
            isinstance(s, dict) and isinstance(s.get("module"), str) for s in specs
        ):
            raise ValueError("a list of {module, argv} objects")
    except ValueError as exc:
        parser.error(f"--services: {exc}")
    loaded = load_all(specs)
    control = tuple(
        service.name
        for spec, service in zip(specs, loaded, strict=True)
        if spec.get("loop") == "control"
    )
    # Zenoh's callback thread and the loop take turns at the GIL; at the default 5 ms a sample
    # may wait that long for the loop to let go. lpc bench footprint --cpus 1.0 --together
    # --record (loaded machine, one run each): camera 62 -> 70 Hz at 1 ms.
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    keep_freed_memory()  # as each service's own process does (services.runtime.run_service)
    with contextlib.suppress(KeyboardInterrupt), asyncio.Runner(loop_factory=ContainerLoop) as run:
        return run.run(run_container(loaded, args, control_loop=control))
    return 0


if __name__ == "__main__":
    sys.exit(main())
