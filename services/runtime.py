"""The shared service runtime: one Zenoh session per process, typed publish/subscribe, the
asyncio bridge, the injected clock, liveliness, health counters and clean shutdown.

Zenoh calls its callbacks on its own threads; this module alone hands samples to the event loop
(``loop.call_soon_threadsafe``). Decoding happens on the loop, so a malformed payload is counted
and reported there and never reaches a step function.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import contextvars
import importlib
import itertools
import json
import os
import signal
import sys
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import msgspec
import zenoh

from lpc_core.control.pacing import PACE_WINDOW_NS, pace
from schemas import TOPICS, BadMessage, Health, Log, Topic, encode, json_schema, topic_for_key
from services.heap import keep_freed_memory

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
HEALTH_PERIOD_S = 1.0
YIELD_AFTER_NS = 2_000_000  # a backlogged subscription yields the loop after this long
# A subscription that is not ``prompt`` (the recorder's) is handed its samples at the first
# that comes this long after the last hand-over, riding a wake-up of its loop for something else
# (a frame), or by a timer twice this long after it on a loop that nothing else wakes.
UNPROMPTED_PERIOD_S = 0.05
UNPROMPTED_PERIOD_NS = int(UNPROMPTED_PERIOD_S * 1e9)
_NEVER = 2**63
# Samples that wake no one wait in a router's inbox for the loop's next wake-up; past this
# many the loop is woken to hand them over: its inbox stays bounded on a loop that nothing
# else wakes (a reader that only takes, no timer of its own), a second of the hand's status.
INBOX_WAKE = 100


# --------------------------------------------------------------------------- clock


class Clock(Protocol):
    """Where services get time. Live services use ``SystemClock``; tests inject their own."""

    def now_ns(self) -> int: ...

    async def sleep_until(self, t_ns: int) -> None: ...


class SystemClock:
    """Wall-clock nanoseconds (shared by processes on one host, so latencies add up)."""

    def now_ns(self) -> int:
        return time.time_ns()

    async def sleep_until(self, t_ns: int) -> None:
        # Always suspend, even when late: a loop that never yields never sees SIGTERM.
        await asyncio.sleep(max(0.0, (t_ns - time.time_ns()) / 1e9))


# --------------------------------------------------------------------------- config


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags every process shares: how to reach the bus."""
    group = parser.add_argument_group("bus")
    group.add_argument(
        "--mode", choices=("peer", "client"), default="peer", help="Zenoh mode (default: peer)"
    )
    group.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help=f"endpoint to connect to, repeatable (default: {DEFAULT_ENDPOINT})",
    )
    group.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to listen on, repeatable (default: tcp/127.0.0.1:0, loopback only)",
    )
    group.add_argument(
        "--config", metavar="FILE", help="a Zenoh JSON5 config file for multi-host use"
    )


# Zenoh's receive runtime with one worker thread instead of two (unless ZENOH_RUNTIME is set):
# at 100 Hz each message from another process woke both (one reads the socket, the other
# takes the task over), a thread wake-up that costs tens of µs of CPU on a virtual machine.
# The control path alone (lpc up --together, no camera): about 1,700 -> 1,500 wake-ups and
# 20.8 -> 18.5 % of a core (medians). Only the receive runtime: with every runtime folded into
# one thread the network-cut tests of tests/test_multihost.py failed (README, issue 17 stop 25).
ZENOH_RUNTIME = "(rx: (worker_threads: 1))"


def zenoh_config(
    *,
    mode: str = "peer",
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    config_file: str | None = None,
) -> zenoh.Config:
    """Peer mode on loopback with multicast scouting off, unless a config file says otherwise.

    Gossip stays on so that peers which reach one rendezvous peer form a full mesh.
    """
    # Read by Zenoh when its runtimes start, at the process's first session.
    os.environ.setdefault("ZENOH_RUNTIME", ZENOH_RUNTIME)
    if config_file:
        try:
            conf = zenoh.Config.from_file(config_file)
        except (zenoh.ZError, OSError, ValueError) as exc:
            raise SystemExit(f"error: cannot read Zenoh config {config_file}: {exc}") from exc
    else:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("scouting/gossip/enabled", "true")
        conf.insert_json5("timestamping/enabled", "true")
        # The default data queue (2 batches of 64 KB, drop after 1 ms) is smaller than one
        # depth frame: measured, it lost 1-3 sensor messages in 2 of 5 recorder runs; 8 batches
        # and 20 ms lost none in 5 of 5 (services/cli/bench/recorder.py).
        conf.insert_json5("transport/link/tx/queue/size/data", "8")
        conf.insert_json5(
            "transport/link/tx/queue/congestion_control/drop/wait_before_drop", "20000"
        )
    if connect is not None or not config_file:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect or [DEFAULT_ENDPOINT])))
    if listen is not None or (not config_file and mode == "peer"):
        conf.insert_json5("listen/endpoints", json.dumps(list(listen or ["tcp/127.0.0.1:0"])))
    return conf


def config_from_args(args: argparse.Namespace) -> zenoh.Config:
    return zenoh_config(
        mode=args.mode, connect=args.connect, listen=args.listen, config_file=args.config
    )


# --------------------------------------------------------------------------- counters


LATENCY_WINDOW = 2048  # a stream's latencies its health's p50/p99 are of


@dataclass
class _Stream:
    """Counters of one topic as seen by one process."""

    count: int = 0
    dropped: int = 0
    rejected: int = 0
    stamps: collections.deque[int] = field(default_factory=lambda: collections.deque(maxlen=512))
    # The latencies since the last health snapshot, appended per message; a snapshot folds them
    # into ``window_ms``, the last 2,048 of the stream (see ``latency_window``).
    latencies_ms: collections.deque[float] = field(
        default_factory=lambda: collections.deque(maxlen=LATENCY_WINDOW)
    )
    window_ms: Any = ()

    def rate_hz(self, now_ns: int, window_ns: int = 2_000_000_000) -> float:
        # Stamps are appended in time order: walk back from the newest to the window's start
        # instead of testing all 512 (a snapshot per second of each service spent ~20 us per
        # stream on that).
        n = 0
        first = newest = 0
        for t in reversed(self.stamps):
            if now_ns - t > window_ns:
                break
            if n == 0:
                newest = t
            first = t
            n += 1
        if n < 2:
            return 0.0
        return (n - 1) / ((newest - first) / 1e9 or 1e-9)

    def latency_window(self) -> Any:
        """The stream's last 2,048 latencies, oldest first: a float64 array where numpy is
        loaded, else a deque. Kept between snapshots rather than rebuilt from all 2,048 floats
        each time (``numpy.fromiter`` over them was 80 of a two-stream snapshot's 135 us):
        only the ~90 a second that came since the last are converted."""
        recent = self.latencies_ms
        numpy = sys.modules.get("numpy")
        if numpy is None:
            if not isinstance(self.window_ms, collections.deque):
                self.window_ms = collections.deque(self.window_ms, maxlen=LATENCY_WINDOW)
            self.window_ms.extend(recent)
        elif recent or not isinstance(self.window_ms, numpy.ndarray):
            old = numpy.asarray(self.window_ms, dtype=float)
            new = numpy.fromiter(recent, dtype=float, count=len(recent))
            drop = max(0, old.size + new.size - LATENCY_WINDOW)
            self.window_ms = numpy.concatenate((old[drop:], new[max(0, drop - old.size) :]))
        recent.clear()
        return self.window_ms


def _quantile(ordered: Sequence[float], q: float) -> float:
    """numpy's default (linear) percentile of sorted samples. In plain Python: for the 2,048
    latencies of a stream it costs no more than numpy's (480 against 580 us here), and
    processes that pass only small messages (the hand's bridge) then never load numpy (12 MB).
    In Python floats either way: numpy's float64 would round the interpolation otherwise."""
    k = (len(ordered) - 1) * q
    i = int(k)
    j = min(i + 1, len(ordered) - 1)
    lo, hi = float(ordered[i]), float(ordered[j])
    return lo + (hi - lo) * (k - i)


def _latency_quantiles(windows: list[Any]) -> tuple[float, float] | None:
    """The p50 and p99 (``_quantile``) of all the latency samples (``_Stream.latency_window``
    of each stream), ``None`` if there are none.

    Where numpy is loaded, its sort of the joined windows: for the 4,096 samples of a service
    that publishes two streams 18 us here, where a partition at the four order statistics the
    two quantiles read took 31 and Python's sort 200. The same floats either way.
    """
    numpy = sys.modules.get("numpy")
    if numpy is None:
        ordered = sorted(itertools.chain.from_iterable(windows))
        if not ordered:
            return None
        return _quantile(ordered, 0.50), _quantile(ordered, 0.99)
    samples = numpy.concatenate([numpy.asarray(w, dtype=float) for w in windows] or [()])
    if samples.size == 0:
        return None
    samples.sort()
    return _quantile(samples, 0.50), _quantile(samples, 0.99)


class HealthCounters:
    """What a service reports on ``lpc/health/<service>``."""

    def __init__(self, service: str, argv: list[str] | None = None) -> None:
        self.service = service
        self.argv = list(argv or [])
        self.published: dict[str, _Stream] = collections.defaultdict(_Stream)
        self.received: dict[str, _Stream] = collections.defaultdict(_Stream)
        self.counters: collections.Counter[str] = collections.Counter()
        self.detail = ""
        self.seq = 0

    def snapshot(self, now_ns: int, status: str = "ok") -> Health:
        rates = {k: round(s.rate_hz(now_ns), 2) for k, s in self.published.items()}
        latency: dict[str, float] = {}
        quantiles = _latency_quantiles([s.latency_window() for s in self.published.values()])
        if quantiles is not None:
            p50, p99 = quantiles
            latency = {"p50": round(p50, 3), "p99": round(p99, 3)}
        counters = dict(self.counters)
        counters["received"] = sum(s.count for s in self.received.values())
        counters["published"] = sum(s.count for s in self.published.values())
        counters["dropped"] = sum(s.dropped for s in self.received.values())
        counters["rejected"] = sum(s.rejected for s in self.received.values())
        self.seq += 1
        return Health(
            seq=self.seq,
            t_ns=now_ns,
            service=self.service,
            pid=os.getpid(),
            status=status,  # type: ignore[arg-type]
            rates_hz=rates,
            latency_ms=latency,
            counters=counters,
            rss_bytes=_rss_bytes(),
            detail=self.detail,
            argv=self.argv,
        )


def _rss_bytes() -> int:
    try:
        with open("/proc/self/statm", "rb") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


# --------------------------------------------------------------------------- pub / sub


class _Matching:
    """Whether a remote subscriber matches a publisher, as Zenoh's matching listener said last
    (on Zenoh's thread, in the order the declarations arrive). A cell of its own, not a method
    of the publisher: the listener holds it, and would otherwise hold the publisher too."""

    __slots__ = ("remote",)

    def __init__(self, *, remote: bool) -> None:
        self.remote = remote

    def __call__(self, status: zenoh.MatchingStatus) -> None:
        self.remote = status.matching


class Publisher:
    """A typed publisher: encodes with the topic's schema and counts what it sends."""

    def __init__(self, bus: Bus, key: str) -> None:
        self.key = key
        self.topic = topic_for_key(key)
        sensor = self.topic.kind == "sensor"
        # In the container the routers of this process take the sample from here; Zenoh only
        # carries it to other processes (see ``Router.deliver``).
        self._local = Router.on_session(bus.session) if bus.router is not None else []
        self._zpub = bus.session.declare_publisher(
            key,
            congestion_control=(
                zenoh.CongestionControl.DROP if sensor else zenoh.CongestionControl.BLOCK
            ),
            priority=zenoh.Priority.DATA if sensor else zenoh.Priority.INTERACTIVE_HIGH,
            express=not sensor,
            allowed_destination=zenoh.Locality.REMOTE if self._local else zenoh.Locality.ANY,
        )
        # In the container Zenoh carries a sample only to other processes, and in the default
        # set none subscribes to most topics: a put then still copied the payload into Zenoh's
        # buffer (200 kB for a depth frame) and took the GIL round Zenoh's routing for nothing.
        # Zenoh's matching listener says when a remote subscriber comes or goes (the same
        # declarations Zenoh routes by; one that matches already is told at once), so the put
        # is skipped only while none would get it. No status query besides: its answer could
        # land after a newer call of the listener's and undo it.
        self._match = _Matching(remote=not self._local)
        self._listener = self._zpub.declare_matching_listener(self._match) if self._local else None
        self._bus = bus
        self._stream = bus.health.published[key]

    def put(self, message: msgspec.Struct) -> None:
        self._check(message)
        self._send(message, encode(message))

    def put_encoded(self, message: msgspec.Struct, payload: bytes) -> None:
        """``put`` of a message that arrived encoded (a worker process's result, decoded only
        to be read): ``payload`` must be ``encode(message)``, and is sent as it is."""
        self._check(message)
        self._send(message, payload)

    def _check(self, message: msgspec.Struct) -> None:
        if not isinstance(message, self.topic.type):
            raise TypeError(f"{self.key} carries {self.topic.type.__name__}, not {type(message)}")

    def _send(self, message: msgspec.Struct, payload: bytes) -> None:
        if self._match.remote:
            self._zpub.put(payload)
        for router in self._local:
            router.deliver(self.key, payload)
        now = self._bus.clock.now_ns()
        self._stream.count += 1
        self._stream.stamps.append(now)
        t_ns = getattr(message, "t_ns", None)
        if t_ns:
            self._stream.latencies_ms.append((now - t_ns) / 1e6)


class Subscription:
    """Samples of one key expression, handed from Zenoh's threads to the event loop.

    ``latest=True`` keeps only the newest undelivered sample (sensor topics: a slow consumer
    always gets the freshest frame; the ones it skipped are counted as dropped). Otherwise the
    queue is FIFO, bounded by ``capacity``; an overflow is counted, never silent.

    ``prompt=False`` (a subscriber that records rather than reacts): in a process with a
    ``Router``, a sample that arrives on another thread (Zenoh's, or the container's control
    loop) and that no prompt subscription of this loop wants does not wake the loop; it is
    handed over at the loop's next wake-up, or at the next hand-over. Nor does a sample wake
    the subscriber's task: that takes what is queued at a hand-over, in one go: at the first
    sample pushed ``UNPROMPTED_PERIOD_S`` after the last, or by a timer twice that long after
    it (the timer starts when a task first waits: a reader that only takes, ``take_queued``,
    starts none). A sample's receive time is still taken when it arrives.
    """

    def __init__(
        self,
        bus: Bus,
        key: str,
        *,
        latest: bool,
        capacity: int,
        decode: bool,
        prompt: bool = True,
    ) -> None:
        self._bus = bus
        self.key = key
        self._latest = latest
        self._decode = decode
        self.prompt = prompt
        self._queue: collections.deque[tuple[str, bytes, int]] = collections.deque(
            maxlen=1 if latest else capacity
        )
        # The task waiting in ``receive``, if one is: a bare future, not an ``asyncio.Event``,
        # whose wait looks the running loop up (a getpid system call) and keeps a list of
        # waiters for the one task that reads a subscription (about 1 us a sample less).
        self._waiter: asyncio.Future[None] | None = None
        self._loop = bus.loop
        self._closed = False
        self._resumed_ns = 0
        self.awaited = False  # a task has waited in ``receive``
        self.paces: Ticks | None = None  # a timer that this subscription's samples pace
        self._router = bus.router if bus.router is not None and bus.router.covers(key) else None
        self._zsub: zenoh.Subscriber | None = None
        if self._router is not None:
            self._router.add(self)
        else:
            self._zsub = bus.session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Zenoh's thread: copy the payload out and hand it over; nothing else.
        item = (str(sample.key_expr), sample.payload.to_bytes(), self._bus.clock.now_ns())
        with contextlib.suppress(RuntimeError):  # loop already closed at shutdown
            self._loop.call_soon_threadsafe(self._push, item)

    def _push(self, item: tuple[str, bytes, int]) -> None:
        if len(self._queue) == self._queue.maxlen:
            self._bus.health.received[item[0]].dropped += 1
        self._queue.append(item)
        if self.prompt or self._router is None:
            self._wake()
        elif item[2] >= self._router.hand_over_due_ns:
            self._router.hand_over_soon()
        if self.paces is not None:
            self.paces.arrived(item[2])

    async def receive(self) -> tuple[str, Any, int]:
        """The next ``(key, message, received_ns)``; bad payloads are counted and skipped."""
        while True:
            if self._queue and time.monotonic_ns() - self._resumed_ns > YIELD_AFTER_NS:
                # Yield when backlogged too, so signals, health and the other tasks still run
                # while a slow consumer catches up; but not after every message: in a shared
                # loop (the container) a consumer that yields per message drains one message
                # per loop pass, and a busy loop passes a few hundred times a second.
                await asyncio.sleep(0)
                self._resumed_ns = time.monotonic_ns()
            while not self._queue:
                if not self.awaited:
                    self.awaited = True
                    if not self.prompt and self._router is not None:
                        self._router.hand_over_periodically()
                self._waiter = self._loop.create_future()
                try:
                    await self._waiter
                finally:
                    self._waiter = None
                self._resumed_ns = time.monotonic_ns()
            got = self._take()
            if got is not None:
                return got

    def _wake(self) -> None:
        """Wake the task waiting in ``receive``, if one is."""
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def take_queued(self) -> list[tuple[str, Any, int]]:
        """Every sample queued now, as ``receive`` returns them, without waiting: for a
        service that reads an input when its own timer fires, not in a task woken per sample.
        Samples waiting in the router's inbox are handed over first."""
        if self._router is not None:
            self._router.hand_over_now()
        taken = []
        while self._queue:
            got = self._take()
            if got is not None:
                taken.append(got)
        return taken

    def _take(self) -> tuple[str, Any, int] | None:
        # The oldest queued sample, counted and decoded; a bad one is counted and reported.
        key, payload, received_ns = self._queue.popleft()
        stream = self._bus.health.received[key]
        stream.count += 1
        stream.stamps.append(received_ns)
        if not self._decode:
            return key, payload, received_ns
        try:
            if self._router is not None:
                return key, self._router.decode(key, payload), received_ns
            return key, topic_for_key(key).decode(payload, key), received_ns
        except (BadMessage, KeyError) as exc:
            stream.rejected += 1
            self._bus.reject(key, str(exc))
            return None

    @property
    def queued(self) -> int:
        """Samples handed to this subscription and not yet received."""
        return len(self._queue)

    def __aiter__(self) -> AsyncIterator[Any]:
        return self._messages()

    async def _messages(self) -> AsyncIterator[Any]:
        while True:
            _, message, _ = await self.receive()
            yield message

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            if self._zsub is not None:
                self._zsub.undeclare()
            if self._router is not None:
                self._router.remove(self)


class Ticks:
    """A service's timer of ``period_ns`` that a subscription's samples may pace
    (``lpc_core.control.pacing``): the control loop's 10 ms tick fires with the hand's status,
    in the wake-up the status costs anyway, instead of waking the loop a second time each
    period; without such samples it keeps its own period. On the subscription's loop."""

    def __init__(self, bus: Bus, period_ns: int, pacing: Subscription | None = None) -> None:
        self._clock = bus.clock
        self._loop = bus.loop
        self.period_ns = period_ns
        self._t_ns = 0  # the nominal time of the tick waited for
        self._previous_ns: int | None = None  # the previous pacing sample's receive time
        self._waited_ns: int | None = None  # the last one handed over while a tick waited
        self.paced = False  # the last tick fired with a sample
        self._waiter: asyncio.Future[tuple[int, int, bool]] | None = None
        self._timer: asyncio.TimerHandle | None = None
        if pacing is not None:
            pacing.paces = self

    async def until(self, t_ns: int) -> tuple[int, int]:
        """Wait for the tick nominally at ``t_ns``: its nominal time (which pacing may move)
        and the time it fired at (a pacing sample's receive time, or the nominal time)."""
        self._t_ns = t_ns
        self._waiter = self._loop.create_future()
        # While the stream's samples come as the loop waits (not only handed over at this
        # tick's reads), the timer waits out the window for the next one.
        running = self._waited_ns is not None and t_ns - self._waited_ns <= 2 * self.period_ns
        self._arm(t_ns + PACE_WINDOW_NS if running else t_ns, t_ns)
        try:
            t_ns, fired_ns, self.paced = await self._waiter
        finally:
            self._waiter = None
            if self._timer is not None:
                self._timer.cancel()
        return t_ns, fired_ns

    def arrived(self, received_ns: int) -> None:
        """A pacing sample was handed over on the loop."""
        previous, self._previous_ns = self._previous_ns, received_ns
        waiter = self._waiter
        if waiter is None or waiter.done():
            return
        self._waited_ns = received_ns
        paced = pace(self.period_ns, self._t_ns, previous, received_ns)
        if paced is None:
            return
        if paced[1] == received_ns:
            waiter.set_result((*paced, True))
        else:
            self._t_ns = paced[0]
            self._arm(paced[1], paced[0])

    def _arm(self, due_ns: int, t_ns: int) -> None:
        if self._timer is not None:
            self._timer.cancel()
        delay = max(0.0, (due_ns - self._clock.now_ns()) / 1e9)
        self._timer = self._loop.call_later(delay, self._fire, t_ns)

    def _fire(self, t_ns: int) -> None:
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result((t_ns, t_ns, False))


class Newest(Subscription):
    """The newest sample of a key, taken when wanted (``take``) instead of delivered: a state
    that a service reads when something else drives it (aim reads the wrist angle, the grasp
    target and the controller's state when a frame arrives).

    A sample wakes neither the loop nor a task: from Zenoh's thread it is stored as it is (no
    call into the loop), and in a process with a ``Router`` it waits, like a ``prompt=False``
    subscription's, for the loop's next wake-up, which ``take`` does not wait for: it hands
    over what waits first. A sample that a newer one replaces before it is taken is counted
    as received, not as dropped: only the newest was wanted. The loop woke for every sample
    of aim's three state topics: the hand's status alone is 100 a second from another thread.
    """

    def __init__(self, bus: Bus, key: str) -> None:
        # Before the subscription is declared: a sample may arrive as soon as it is.
        self._cell_lock = threading.Lock()
        self._stream = bus.health.received[key]
        super().__init__(bus, key, latest=True, capacity=1, decode=True, prompt=False)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Zenoh's thread: stored, not handed to the loop (``take`` reads it there).
        self._push((str(sample.key_expr), sample.payload.to_bytes(), self._bus.clock.now_ns()))

    def _push(self, item: tuple[str, bytes, int]) -> None:
        with self._cell_lock:
            self._queue.append(item)
            self._stream.count += 1
            self._stream.stamps.append(item[2])

    def take(self) -> Any | None:
        """The newest message that arrived since the last ``take``, decoded, or ``None``
        (none did, or it did not decode: then it is counted as rejected)."""
        if self._router is not None:
            self._router.hand_over_now()
        with self._cell_lock:
            if not self._queue:
                return None
            key, payload, _ = self._queue.popleft()
        try:
            if self._router is not None:
                return self._router.decode(key, payload)
            return topic_for_key(key).decode(payload, key)
        except (BadMessage, KeyError) as exc:
            self._stream.rejected += 1
            self._bus.reject(key, str(exc))
            return None

    async def receive(self) -> tuple[str, Any, int]:
        raise TypeError("a Newest subscription is read with take(), not awaited")


class Router:
    """The subscriptions of all the services on one event loop of one process (the container),
    each sample handed to the loop once and to every local subscription it is for.

    A subscriber per subscription would copy each payload out once per subscriber, each on its
    own Zenoh callback thread contending for the GIL, and wake the loop once per copy. Here
    samples reach the loop in batches: one wake-up for all that arrived while it was busy. With
    ``wildcard`` one subscriber on ``lpc/**`` serves every subscription (a loop that records
    wants everything anyway). A router without it (a loop that wants a few small topics should
    not be handed every depth frame) rides on a wildcard router of the same session when there
    is one: that router's callback, which has copied the sample out already, queues it for this
    loop too when one of its subscriptions wants it. Only without such a router does it declare
    one subscriber per distinct key. One subscriber per process instead of two: each remote
    sample (the hand's status at 100 Hz) is copied out once, by one Zenoh thread taking the GIL
    once.
    """

    PREFIX = "lpc/**"
    # The routers of this process, by session: a ``Publisher`` on one of these sessions hands
    # its samples to them itself. Through Zenoh a sample published and subscribed in one
    # process is still copied out on a Zenoh thread that must take the GIL and wake the loop:
    # py-spy on ``lpc up --together --record`` (no quota, 90 Hz) put 20 % of the container's
    # samples in those threads and 14 % in the loop's select.
    _local: ClassVar[dict[int, list[Router]]] = {}

    @classmethod
    def on_session(cls, session: zenoh.Session) -> list[Router]:
        """The routers on ``session``: a live list, that routers made later join."""
        return cls._local.setdefault(id(session), [])

    def __init__(
        self, session: zenoh.Session, loop: asyncio.AbstractEventLoop, *, wildcard: bool = True
    ) -> None:
        self._session = session
        self._loop = loop
        self._subs: list[Subscription] = []
        self._routes: dict[str, list[Subscription]] = {}  # concrete key -> its subscriptions
        self._prompt: dict[str, bool] = {}  # concrete key -> whether a sample wakes the loop
        self._unprompted: asyncio.Handle | None = None
        # A sample received from then on for a subscription that is not prompt hands over.
        self.hand_over_due_ns = _NEVER
        self._by_key: dict[str, tuple[zenoh.Subscriber, list[Subscription]]] = {}
        self._inbox: collections.deque[tuple[str | None, tuple[str, bytes, int]]] = (
            collections.deque()
        )
        self._scheduled = False
        # The sample decoded last on this loop, with its payload: the subscriptions of several
        # services that take one sample (the hand's status: the controller and the simulated
        # user; the controller's state) decode it once. Messages are frozen structs.
        self._decoded: tuple[bytes, str, Any] | None = None
        self._lock = threading.Lock()
        self._clock = SystemClock()
        self._prefix = zenoh.KeyExpr(self.PREFIX)
        # Routers on other loops fed from this one's subscriber; a tuple, replaced whole, as
        # Zenoh's thread reads it while a loop adds or removes a router.
        self._riders: tuple[Router, ...] = ()
        self._host: Router | None = None
        self._wildcard = (
            session.declare_subscriber(self.PREFIX, lambda s: self._on_sample(None, s))
            if wildcard
            else None
        )
        if not wildcard:
            self._host = next(
                (r for r in Router.on_session(session) if r._wildcard is not None), None
            )
            if self._host is not None:
                self._host._riders = (*self._host._riders, self)
        Router.on_session(session).append(self)

    def covers(self, key: str) -> bool:
        return self._prefix.includes(zenoh.KeyExpr(key))

    def add(self, sub: Subscription) -> None:
        with self._lock:
            self._subs.append(sub)
            self._routes.clear()
            self._prompt.clear()
        if self._wildcard is None and self._host is None:
            if sub.key not in self._by_key:
                zsub = self._session.declare_subscriber(
                    sub.key, lambda s, k=sub.key: self._on_sample(k, s)
                )
                self._by_key[sub.key] = (zsub, [])
            self._by_key[sub.key][1].append(sub)

    def remove(self, sub: Subscription) -> None:
        with self._lock:
            with contextlib.suppress(ValueError):
                self._subs.remove(sub)
            self._routes.clear()
            self._prompt.clear()
        entry = self._by_key.get(sub.key)
        if entry is not None:
            with contextlib.suppress(ValueError):
                entry[1].remove(sub)
            if not entry[1]:
                del self._by_key[sub.key]
                entry[0].undeclare()

    def _on_sample(self, route: str | None, sample: zenoh.Sample) -> None:
        # Zenoh's thread: copy the payload out and queue it; wake the loop only if it sleeps.
        item = (str(sample.key_expr), sample.payload.to_bytes(), self._clock.now_ns())
        self._enqueue(route, item, route is not None or self._wakes(item[0]))
        for rider in self._riders:
            subs, wakes = rider._route(item[0])
            if subs:
                rider._enqueue(None, item, wakes)

    def deliver(self, key: str, payload: bytes) -> None:
        """A sample published in this process, for the subscriptions of this router that want
        it: pushed at once from this router's own loop, queued for it from any other thread."""
        subs, wakes = self._route(key)  # one look-up (under the lock) for both
        if not subs:
            return  # a loop woken for nothing costs more than the check
        item = (key, payload, self._clock.now_ns())
        # Whether this thread runs the loop (``asyncio.get_running_loop() is self._loop``)
        # without asking asyncio: its answer costs a getpid system call, at every put of the
        # process for each of its routers.
        if self._loop._thread_id != threading.get_ident():  # type: ignore[attr-defined]
            self._enqueue(None, item, wakes)
            return
        for sub in subs:
            sub._push(item)

    def decode(self, key: str, payload: bytes) -> Any:
        """``topic_for_key(key).decode(payload, key)``, once for a payload that every
        subscription of this loop is handed as the same object under the same key (a bad one
        raises each time; one bytes object put on two topics decodes for each)."""
        last = self._decoded
        if last is not None and last[0] is payload and last[1] == key:
            return last[2]
        message = topic_for_key(key).decode(payload, key)
        self._decoded = (payload, key, message)
        return message

    def _subs_for(self, key: str) -> list[Subscription]:
        return self._route(key)[0]

    def _wakes(self, key: str) -> bool:
        """Whether a sample on ``key`` from another thread is to wake this loop: a prompt
        subscription wants it (or none does: the drain then finds nothing to do)."""
        return self._route(key)[1]

    def _route(self, key: str) -> tuple[list[Subscription], bool]:
        # Under the lock: a publisher on another loop's thread reads the routes while this
        # loop adds a subscription, and a route cached from before the add would miss it.
        with self._lock:
            subs = self._routes.get(key)
            if subs is None:
                concrete = zenoh.KeyExpr(key)
                subs = [s for s in self._subs if zenoh.KeyExpr(s.key).intersects(concrete)]
                self._routes[key] = subs
                self._prompt[key] = not subs or any(s.prompt for s in subs)
            return subs, self._prompt[key]

    def hand_over_periodically(self) -> None:
        """On this router's loop, for a task about to wait on a subscription that is not
        prompt: hand samples over about every ``UNPROMPTED_PERIOD_S`` from now on. Only such a task
        needs the timer: a reader that takes (``take_queued``, ``Newest.take``) is handed its
        samples when it takes, and the controller's and the simulated user's timer woke the
        control loop 20 times a second for nothing."""
        if self._unprompted is None:
            self._rearm()

    def hand_over_soon(self) -> None:
        """On this router's loop, woken for something else: a sample came for a subscription
        that is not prompt ``UNPROMPTED_PERIOD_S`` after the last hand-over, so hand over now,
        once this pass is done, and push the timer back. On a loop that wakes for frames the
        hand-overs ride its wake-ups: the timer fired 20 times a second into an idle loop."""
        self.hand_over_due_ns = _NEVER
        if self._unprompted is not None:
            self._unprompted.cancel()
        self._unprompted = self._loop.call_soon(self._hand_over)

    def _hand_over(self) -> None:
        # On the loop: what waited for a wake-up is handed over now, at the latest, and the
        # subscribers that are not prompt are woken for all they have queued since the last time.
        self.hand_over_due_ns = _NEVER  # the drain's pushes are this hand-over's
        self._unprompted = None
        self._drain()
        for sub in self._subs:
            if not sub.prompt and sub._queue:
                sub._wake()
        if any(not s.prompt and s.awaited for s in self._subs):
            self._rearm()

    def _rearm(self) -> None:
        # The next hand-over: at the first sample after the period, or by the timer a period
        # later if none comes (a loop that nothing else wakes).
        self.hand_over_due_ns = self._clock.now_ns() + UNPROMPTED_PERIOD_NS
        self._unprompted = self._loop.call_later(2 * UNPROMPTED_PERIOD_S, self._hand_over)

    def _enqueue(self, route: str | None, item: tuple[str, bytes, int], wake: bool) -> None:
        # A sample that wakes no one waits in the inbox for the next drain: the loop's next
        # wake-up for any other reason, or the hand-over timer. One loop wake-up costs more
        # than handing a sample over (the recorder alone took ~300 of them a second).
        self._inbox.append((route, item))
        if (wake or len(self._inbox) >= INBOX_WAKE) and not self._scheduled:
            self._scheduled = True
            with contextlib.suppress(RuntimeError):  # loop already closed at shutdown
                self._loop.call_soon_threadsafe(self._drain)

    def hand_over_now(self) -> None:
        """On this router's loop: hand the samples that wait for its next wake-up over now."""
        if self._inbox:
            self._drain()

    def _drain(self) -> None:
        # Cleared before emptying the inbox: a sample queued meanwhile schedules another drain.
        self._scheduled = False
        inbox = self._inbox
        while inbox:
            route, item = inbox.popleft()
            if route is not None:
                entry = self._by_key.get(route)
                subs = entry[1] if entry is not None else []
            else:
                subs = self._subs_for(item[0])
            for sub in subs:
                sub._push(item)

    def close(self) -> None:
        if self._unprompted is not None:
            self._unprompted.cancel()
            self._unprompted = None
        with contextlib.suppress(ValueError):
            Router.on_session(self._session).remove(self)
        if self._host is not None:
            self._host._riders = tuple(r for r in self._host._riders if r is not self)
        if self._wildcard is not None:
            self._wildcard.undeclare()
        for zsub, _ in self._by_key.values():
            zsub.undeclare()
        self._by_key.clear()


class Bus:
    """A service's view of the bus: typed publishers and subscriptions, health, logs."""

    def __init__(
        self,
        session: zenoh.Session,
        service: str,
        *,
        loop: asyncio.AbstractEventLoop,
        clock: Clock | None = None,
        quiet: bool = False,
        argv: list[str] | None = None,
        router: Router | None = None,
    ) -> None:
        self.session = session
        self.service = service
        self.router = router
        self.loop = loop
        self.clock: Clock = clock or SystemClock()
        self.health = HealthCounters(service, argv)
        self.quiet = quiet
        self.status = "starting"
        # In the container the health goes to this process's routers as a ``Publisher``'s
        # samples do (``Router.deliver``), and through Zenoh only to other processes: through
        # Zenoh's local routing each report took a Zenoh thread, the GIL and a wake-up of the
        # main loop (the camera's shedder reads every report), eight reports a second.
        self._health_key = f"lpc/health/{service}"
        self._health_local = Router.on_session(session) if router is not None else []
        self._health_pub = session.declare_publisher(
            self._health_key,
            allowed_destination=zenoh.Locality.REMOTE if self._health_local else zenoh.Locality.ANY,
        )
        self._log_pub = session.declare_publisher(f"lpc/log/{service}")
        self._log_seq = 0
        self._reject_reports: collections.Counter[str] = collections.Counter()
        # Alive last: a peer that sees the token can already query the schemas.
        self._schemas = session.declare_queryable("lpc/schemas/**", _answer_schema_query)
        self._token = session.liveliness().declare_token(f"lpc/alive/{service}")
        self._subs: list[Subscription] = []

    def publisher(self, key: str) -> Publisher:
        return Publisher(self, key)

    def subscribe(
        self,
        key: str,
        *,
        latest: bool | None = None,
        capacity: int = 4096,
        decode: bool = True,
        prompt: bool = True,
    ) -> Subscription:
        if latest is None:
            latest = topic_for_key(key).kind == "sensor" if "*" not in key else False
        sub = Subscription(
            self, key, latest=latest, capacity=capacity, decode=decode, prompt=prompt
        )
        self._subs.append(sub)
        return sub

    def newest(self, key: str) -> Newest:
        """The newest sample of ``key``, read with ``take()`` (see ``Newest``)."""
        sub = Newest(self, key)
        self._subs.append(sub)
        return sub

    def log(self, level: str, text: str) -> None:
        """One line on stderr, in a fixed format, and the same on ``lpc/log/<service>``."""
        if not self.quiet or level in ("warning", "error"):
            print(f"[{self.service}] {level}: {text}", file=sys.stderr, flush=True)
        self._log_seq += 1
        message = Log(
            seq=self._log_seq,
            t_ns=self.clock.now_ns(),
            service=self.service,
            level=level,  # type: ignore[arg-type]
            text=text,
        )
        with contextlib.suppress(zenoh.ZError):
            self._log_pub.put(encode(message))

    def reject(self, key: str, reason: str) -> None:
        """Count a rejected input; report the first few of each topic, then every 100th."""
        self.health.counters[f"rejected:{key}"] += 1
        n = self._reject_reports[key] = self._reject_reports[key] + 1
        if n <= 3 or n % 100 == 0:
            self.log("warning", f"rejected #{n} on {key}: {reason}")

    def publish_health(self) -> None:
        snapshot = self.health.snapshot(self.clock.now_ns(), self.status)
        payload = encode(snapshot)
        with contextlib.suppress(zenoh.ZError):
            self._health_pub.put(payload)
        for router in self._health_local:
            router.deliver(self._health_key, payload)

    async def health_loop(self) -> None:
        while True:
            self.publish_health()
            await asyncio.sleep(HEALTH_PERIOD_S)

    def close(self) -> None:
        for sub in self._subs:
            sub.close()
        self._schemas.undeclare()
        self._token.undeclare()
        # A service restarted inside a container gets a new Bus on the same session.
        self._health_pub.undeclare()
        self._log_pub.undeclare()


def _answer_schema_query(query: zenoh.Query) -> None:
    prefix = "lpc/schemas/"
    selector = str(query.key_expr)
    for topic in TOPICS:
        key = prefix + topic.key
        if zenoh.KeyExpr(key).intersects(zenoh.KeyExpr(selector)):
            query.reply(key, json.dumps(json_schema(topic.type)).encode())


# --------------------------------------------------------------------------- entry point

Serve = Callable[[Bus, argparse.Namespace], Awaitable[None]]


class ServiceParser(argparse.ArgumentParser):
    """A service's parser: the parsed namespace keeps the flags as given (``argv``), which the
    service reports in its health, so that a replay can rebuild its parameters."""

    def parse_args(self, args: Any = None, namespace: Any = None) -> Any:
        parsed = super().parse_args(args, namespace)
        parsed.argv = list(sys.argv[1:] if args is None else args)
        return parsed


def service_parser(name: str, description: str) -> argparse.ArgumentParser:
    parser = ServiceParser(prog=f"python -m services.{name}", description=description)
    add_bus_arguments(parser)
    parser.add_argument("--quiet", action="store_true", help="log only warnings and errors")
    return parser


def service_main(
    name: str,
    parser: argparse.ArgumentParser,
    check: Callable[[argparse.Namespace], Any],
    serve: Serve,
    argv: list[str] | None = None,
) -> int:
    """A service's ``main``: parse its flags, ``check`` them (a ``ValueError`` exits 2 with
    the reason, as a bad flag does), then run ``serve``."""
    args = parser.parse_args(argv)
    try:
        check(args)
    except ValueError as exc:
        parser.error(str(exc))
    return run_service(name, serve, args)


@dataclass(frozen=True)
class LoadedService:
    """A service's ``serve`` and its parsed flags, ready to run on a session opened elsewhere."""

    name: str
    serve: Serve
    args: argparse.Namespace


_LOADING: contextvars.ContextVar[list[LoadedService] | None] = contextvars.ContextVar(
    "_LOADING", default=None
)


def load_service(module: str, argv: list[str]) -> LoadedService:
    """Parse and check a service's flags with its own ``main`` and return what it would run,
    without opening a session: the service container (``lpc up --together``) runs it then on
    its shared one. Bad flags exit as they do on the command line (``SystemExit``)."""
    loaded: list[LoadedService] = []
    token = _LOADING.set(loaded)
    try:
        importlib.import_module(module).main(argv)
    finally:
        _LOADING.reset(token)
    if len(loaded) != 1:
        raise SystemExit(f"error: {module}.main did not reach run_service")
    return loaded[0]


def run_service(
    name: str,
    serve: Serve,
    args: argparse.Namespace,
    *,
    clock: Clock | None = None,
) -> int:
    """Open the session, run ``serve`` until it returns or SIGINT/SIGTERM arrives, close.

    Under ``load_service`` it only hands ``serve`` and the flags back."""
    loading = _LOADING.get()
    if loading is not None:
        loading.append(LoadedService(name, serve, args))
        return 0
    # Frames and chunks are allocated and freed at 90 Hz: without this glibc hands their pages
    # back and faults them in again (the camera: 8,000-15,000 page faults a second, 10 with it).
    keep_freed_memory()
    try:
        return asyncio.run(_run(name, serve, args, clock))
    except KeyboardInterrupt:
        return 0


async def _run(name: str, serve: Serve, args: argparse.Namespace, clock: Clock | None) -> int:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        session = zenoh.open(config_from_args(args))
    except zenoh.ZError as exc:
        print(f"[{name}] error: cannot open the Zenoh session: {exc}", file=sys.stderr)
        return 2
    with session:
        bus = Bus(
            session,
            name,
            loop=loop,
            clock=clock,
            quiet=getattr(args, "quiet", False),
            argv=getattr(args, "argv", None),
        )
        bus.log("info", f"started (pid {os.getpid()})")
        bus.status = "ok"
        health = asyncio.create_task(bus.health_loop())
        work = asyncio.create_task(serve(bus, args))
        stopper = asyncio.create_task(stop.wait())
        done, _ = await asyncio.wait({work, stopper}, return_when=asyncio.FIRST_COMPLETED)
        code = 0
        if work in done and work.exception() is not None:
            exc = work.exception()
            bus.log("error", f"failed: {type(exc).__name__}: {exc}")
            code = 1
        bus.status = "stopping"
        for task in (work, stopper, health):
            task.cancel()
        await asyncio.gather(work, stopper, health, return_exceptions=True)
        bus.publish_health()
        bus.log("info", "stopped")
        bus.close()
    return code


def topics_table() -> list[Topic]:
    return list(TOPICS)
