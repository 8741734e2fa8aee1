"""The service runtime over a real Zenoh session on loopback."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
import textwrap
import threading
import time

import msgspec
import numpy as np
import pytest
import zenoh

from schemas import EmgSample, Health, decode, encode
from services.runtime import INBOX_WAKE, UNPROMPTED_PERIOD_S, Bus, Router, zenoh_config
from tests.conftest import spawn_service, until, wait_for

PUBLISHER = textwrap.dedent(
    """
    import asyncio, sys
    from schemas import EmgSample
    from services.runtime import run_service, service_parser

    async def serve(bus, args):
        pub = bus.publisher("lpc/emg")
        # Wait until the test's subscriber is matched, then send a numbered burst.
        while not bus.session.liveliness().get("lpc/alive/listener").recv().ok:
            await asyncio.sleep(0.01)
        for i in range(args.n):
            pub.put(EmgSample(seq=i, t_ns=bus.clock.now_ns(), channels=[i * 0.001, 0.0]))
            await asyncio.sleep(0.002)

    parser = service_parser("publisher", "")
    parser.add_argument("--n", type=int)
    sys.exit(run_service("publisher", serve, parser.parse_args()))
    """
)


def _alive_tokens(session: zenoh.Session) -> set[str]:
    return {str(r.ok.key_expr) for r in session.liveliness().get("lpc/alive/*") if r.ok}


def test_runtime_two_process_publish_subscribe(endpoint: str, rendezvous: zenoh.Session) -> None:
    received: list[EmgSample] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        with lock:
            received.append(decode(str(sample.key_expr), sample.payload.to_bytes()))

    sub = rendezvous.declare_subscriber("lpc/emg", on_sample)
    token = rendezvous.liveliness().declare_token("lpc/alive/listener")
    proc = subprocess.Popen(
        [sys.executable, "-c", PUBLISHER, "--connect", endpoint, "--quiet", "--n", "300"],
        stderr=subprocess.PIPE,
    )
    try:
        assert proc.wait(timeout=30) == 0, proc.stderr.read().decode()
        wait_for(lambda: len(received) >= 300, timeout=5, what="300 samples")
    finally:
        token.undeclare()
        sub.undeclare()
    assert [m.seq for m in received] == list(range(300))
    assert received[123].channels == [pytest.approx(0.123), 0.0]


def test_runtime_service_shuts_down_cleanly_on_sigterm(
    endpoint: str, rendezvous: zenoh.Session
) -> None:
    proc = spawn_service("services.scans", endpoint)
    try:
        wait_for(lambda: "lpc/alive/scans" in _alive_tokens(rendezvous), 30, "scans token")
        start = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=5)
        elapsed = time.monotonic() - start
    finally:
        proc.kill()
    assert code == 0
    assert elapsed < 2.0
    wait_for(lambda: "lpc/alive/scans" not in _alive_tokens(rendezvous), 5, "token gone")


def test_runtime_bad_payloads_are_counted_and_service_carries_on(
    endpoint: str, rendezvous: zenoh.Session
) -> None:
    healths: list[Health] = []

    def on_health(sample: zenoh.Sample) -> None:
        healths.append(decode(str(sample.key_expr), sample.payload.to_bytes()))

    sub = rendezvous.declare_subscriber("lpc/health/scans", on_health)
    proc = spawn_service("services.scans", endpoint)
    depth = rendezvous.declare_publisher("lpc/camera/depth")
    try:
        wait_for(lambda: "lpc/alive/scans" in _alive_tokens(rendezvous), 30, "scans token")
        # Alive comes before the service's own subscriptions: wait until it listens.
        wait_for(lambda: depth.matching_status.matching, 30, "the scans subscriber")
        garbage = [
            b"\xc1",  # not msgpack
            encode(EmgSample(seq=1, t_ns=1, channels=[0.0])),  # another topic's type
            msgspec.msgpack.encode({"seq": 1, "t_ns": 1, "version": 9}),
        ]
        # Sensor subscriptions keep only the newest sample: space the puts out until each
        # one has been counted, so the count is exact.
        for n, payload in enumerate(garbage, start=1):
            depth.put(payload)
            wait_for(
                lambda n=n: healths and healths[-1].counters.get("rejected", 0) >= n,
                10,
                f"{n} rejections",
            )
        assert proc.poll() is None
        assert healths[-1].counters["rejected"] == 3
        assert healths[-1].counters["published"] == 0
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=5)
        sub.undeclare()


def test_runtime_schemas_queryable_answers(endpoint: str, rendezvous: zenoh.Session) -> None:
    proc = spawn_service("services.scans", endpoint)
    try:
        wait_for(lambda: "lpc/alive/scans" in _alive_tokens(rendezvous), 30, "scans token")
        replies = [r.ok for r in rendezvous.get("lpc/schemas/lpc/scans") if r.ok]
        assert replies, "no schema reply"
        schema = msgspec.json.decode(replies[0].payload.to_bytes())
        assert "ScanLines" in schema["$defs"]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=5)


def test_runtime_default_config_is_loopback_without_multicast() -> None:
    conf = zenoh_config()
    text = str(conf)
    assert '"multicast"' in text or "multicast" in text
    assert conf.get_json("scouting/multicast/enabled") == "false"
    assert "127.0.0.1" in conf.get_json("listen/endpoints")
    assert "127.0.0.1" in conf.get_json("connect/endpoints")


def test_service_flags_are_kept_and_reported_in_health() -> None:
    # A replay rebuilds each service's parameters from the flags its health reported.
    from services.runtime import HealthCounters, service_parser

    parser = service_parser("scans", "")
    parser.add_argument("--band-mm", type=float, default=0.5)
    args = parser.parse_args(["--band-mm", "2", "--quiet"])
    assert args.argv == ["--band-mm", "2", "--quiet"] and args.band_mm == 2.0
    health = HealthCounters("scans", args.argv).snapshot(now_ns=5)
    assert decode("lpc/health/scans", encode(health)).argv == ["--band-mm", "2", "--quiet"]


def test_health_rate_and_latency_cover_the_window_only() -> None:
    """A stream's rate counts the stamps of the last 2 s only (100 Hz, after 50 Hz before);
    the latency percentiles are over every published stream's recent samples."""
    from services.runtime import HealthCounters

    health = HealthCounters("x")
    stream = health.published["lpc/emg"]
    now = 10**12
    stamps = [now - 5_000_000_000 + i * 20_000_000 for i in range(100)]  # 50 Hz, long ago
    stamps += [now - 1_990_000_000 + i * 10_000_000 for i in range(200)]  # 100 Hz, recent
    stream.stamps.extend(stamps)
    stream.latencies_ms.extend([1.0] * 50 + [3.0] * 50)
    health.published["lpc/prosthesis/command"].latencies_ms.extend([100.0] * 3)
    snapshot = health.snapshot(now)
    assert snapshot.rates_hz["lpc/emg"] == 100.0
    assert snapshot.rates_hz["lpc/prosthesis/command"] == 0.0
    assert snapshot.latency_ms == {"p50": 3.0, "p99": 100.0}


def test_health_latency_percentiles_are_numpys_linear_ones() -> None:
    from services.runtime import _quantile

    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 2048, 4096):
        ordered = sorted(rng.exponential(2.0, n).tolist())
        expected = np.percentile(ordered, [50, 99])
        got = [_quantile(ordered, 0.50), _quantile(ordered, 0.99)]
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


def _counted_wakes(loop: asyncio.AbstractEventLoop) -> list[object]:
    """The callbacks handed to ``loop`` from other threads from now on (each a wake-up)."""
    wakes: list[object] = []
    call_soon_threadsafe = loop.call_soon_threadsafe

    def counted(callback, *args, **kwargs):  # type: ignore[no-untyped-def]
        wakes.append(callback)
        return call_soon_threadsafe(callback, *args, **kwargs)

    loop.call_soon_threadsafe = counted  # type: ignore[method-assign]
    return wakes


def test_router_hands_unprompted_samples_over_without_waking_the_loop(endpoint: str) -> None:
    """Samples from another thread that only a ``prompt=False`` subscription wants (the
    recorder's) wait for the loop's next wake-up instead of waking it, and still arrive all,
    in order, stamped when they were published; a prompt subscription on the key wakes it."""

    async def main() -> None:
        loop = asyncio.get_running_loop()
        wakes = _counted_wakes(loop)
        session = zenoh.open(zenoh_config(connect=[endpoint]))
        router = Router(session, loop, wildcard=False)
        bus = Bus(session, "recorder", loop=loop, router=router, quiet=True)
        lazy = bus.subscribe("lpc/emg", latest=False, prompt=False)
        stamps: list[tuple[int, int]] = []
        waiting = asyncio.create_task(lazy.receive())
        await asyncio.sleep(0)  # the task waits (and the hand-over timer starts)
        router.deliver("lpc/emg", encode(EmgSample(seq=1000, t_ns=1, channels=[0.0])))
        await asyncio.sleep(0)
        await asyncio.sleep(0)
        assert lazy._queue and not waiting.done(), "its task is not woken per sample"
        assert (await waiting)[1].seq == 1000, "but within the hand-over period"

        def publish(first: int) -> None:  # another thread: the control loop's, say
            for seq in range(first, first + 50):
                before = time.time_ns()
                router.deliver("lpc/emg", encode(EmgSample(seq=seq, t_ns=before, channels=[0.0])))
                stamps.append((before, time.time_ns()))

        thread = threading.Thread(target=publish, args=(0,))
        thread.start()
        thread.join()
        assert wakes == [], "no wake-up for the unprompted subscription"
        got = [await lazy.receive() for _ in range(50)]
        assert [message.seq for _, message, _ in got] == list(range(50))
        for (_, _, received_ns), (before, after) in zip(got, stamps, strict=True):
            assert before <= received_ns <= after, "stamped when published, not handed over"

        prompt = bus.subscribe("lpc/emg", latest=False)
        thread = threading.Thread(target=publish, args=(50,))
        thread.start()
        thread.join()
        assert wakes, "a prompt subscription wakes the loop"
        assert [(await prompt.receive())[1].seq for _ in range(50)] == list(range(50, 100))
        assert [(await lazy.receive())[1].seq for _ in range(50)] == list(range(50, 100))
        bus.close()
        router.close()
        session.close()

    asyncio.run(main())


def test_router_hands_over_on_a_timer_only_for_a_task_that_waits(endpoint: str) -> None:
    """A ``prompt=False`` subscription that is only taken from (``take_queued``: the
    controller's targets and cues, the simulated user's perceptions) starts no hand-over
    timer, which woke the control loop 20 times a second for nothing; samples from another
    thread then wake the loop once per ``INBOX_WAKE`` (its inbox stays bounded), and all
    arrive, in order. A task that waits in ``receive`` starts the timer."""

    async def main() -> None:
        loop = asyncio.get_running_loop()
        session = zenoh.open(zenoh_config(connect=[endpoint]))
        router = Router(session, loop, wildcard=False)
        fired: list[float] = []
        hand_over = router._hand_over

        def counted() -> None:
            fired.append(loop.time())
            hand_over()

        router._hand_over = counted  # type: ignore[method-assign]
        bus = Bus(session, "controller", loop=loop, router=router, quiet=True)
        taken = bus.subscribe("lpc/emg", latest=False, capacity=1000, prompt=False)
        wakes = _counted_wakes(loop)
        await asyncio.sleep(3 * UNPROMPTED_PERIOD_S)
        assert fired == [], "no hand-over timer for a reader that takes"

        def publish(first: int, n: int) -> None:  # another thread: the main loop's, say
            for seq in range(first, first + n):
                router.deliver("lpc/emg", encode(EmgSample(seq=seq, t_ns=seq + 1, channels=[0.0])))

        for first, n in ((0, INBOX_WAKE - 1), (INBOX_WAKE - 1, 1)):
            thread = threading.Thread(target=publish, args=(first, n))
            thread.start()
            thread.join()
            assert len(wakes) == (0 if first == 0 else 1), "one wake-up per INBOX_WAKE samples"
        await asyncio.sleep(0)  # the drain it woke the loop for
        assert taken.queued == INBOX_WAKE
        assert [m.seq for _, m, _ in taken.take_queued()] == list(range(INBOX_WAKE))

        waiting = bus.subscribe("lpc/emg", latest=False, prompt=False)
        task = asyncio.create_task(waiting.receive())
        thread = threading.Thread(target=publish, args=(INBOX_WAKE, 1))
        thread.start()
        thread.join()
        async with asyncio.timeout(1.0):
            assert (await task)[1].seq == INBOX_WAKE, "handed over by the timer"
        assert len(fired) == 1 and len(wakes) == 1
        assert [m.seq for _, m, _ in taken.take_queued()] == [INBOX_WAKE]
        bus.close()
        router.close()
        session.close()

    asyncio.run(main())


def test_router_hands_over_at_the_first_sample_a_period_after_the_last(endpoint: str) -> None:
    """On a loop woken for something else (the camera's frames), a ``prompt=False``
    subscription's task is handed its samples at the first one pushed ``UNPROMPTED_PERIOD_S``
    after the last hand-over, by the router's clock, not by a timer's wake-up of its own; the
    timer is pushed back a period past the next hand-over."""

    class Clock:
        t_ns = 0

        def now_ns(self) -> int:
            return self.t_ns

    async def main() -> None:
        loop = asyncio.get_running_loop()
        session = zenoh.open(zenoh_config(connect=[endpoint]))
        router = Router(session, loop, wildcard=False)
        clock = router._clock = Clock()  # type: ignore[assignment]
        fired: list[int] = []
        hand_over = router._hand_over

        def counted() -> None:
            fired.append(clock.t_ns)
            hand_over()

        router._hand_over = counted  # type: ignore[method-assign]
        bus = Bus(session, "recorder", loop=loop, router=router, quiet=True)
        sub = bus.subscribe("lpc/emg", latest=False, prompt=False)
        task = asyncio.create_task(sub.receive())
        await asyncio.sleep(0)  # it waits: the hand-overs start, the first due a period on
        period_ns = round(UNPROMPTED_PERIOD_S * 1e9)
        assert router.hand_over_due_ns == period_ns
        timer = router._unprompted
        assert isinstance(timer, asyncio.TimerHandle)
        assert timer.when() - loop.time() > 1.5 * UNPROMPTED_PERIOD_S, "a backstop, pushed back"
        for seq, t_ns in enumerate((1, period_ns - 1, period_ns, period_ns + 1)):
            clock.t_ns = t_ns  # the receive time: a sample published on the loop's thread
            router.deliver("lpc/emg", encode(EmgSample(seq=seq, t_ns=t_ns, channels=[0.0])))
            await asyncio.sleep(0)
            await asyncio.sleep(0)
            assert task.done() == (t_ns >= period_ns), t_ns
        assert fired == [period_ns], "one hand-over, at the first sample due"
        assert timer.cancelled() and router.hand_over_due_ns == 2 * period_ns
        assert [m.seq for _, m, _ in [await task, *sub.take_queued()]] == [0, 1, 2, 3]
        bus.close()
        router.close()
        session.close()

    asyncio.run(main())


def test_newest_takes_the_last_sample_without_waking_the_loop(endpoint: str) -> None:
    """A ``Bus.newest`` subscription (aim's wrist angle, target and controller state) is not
    handed samples by waking the loop, with or without a router: ``take`` returns the newest
    one that arrived, then ``None`` until another does; every sample counts as received, none
    that a newer one replaced as dropped."""

    async def main() -> None:
        loop = asyncio.get_running_loop()
        wakes = _counted_wakes(loop)
        session = zenoh.open(zenoh_config(connect=[endpoint]))
        router = Router(session, loop, wildcard=False)
        routed = Bus(session, "aim", loop=loop, router=router, quiet=True)
        plain = Bus(session, "aim", loop=loop, quiet=True)  # a process of its own: no router
        for bus in (routed, plain):
            newest = bus.newest("lpc/emg")
            assert newest.take() is None

            def publish(first: int, bus: Bus = bus) -> None:  # another thread, 30 samples
                for seq in range(first, first + 30):
                    payload = encode(EmgSample(seq=seq, t_ns=seq + 1, channels=[0.0]))
                    if bus is routed:
                        router.deliver("lpc/emg", payload)
                    else:
                        session.put("lpc/emg", payload)

            thread = threading.Thread(target=publish, args=(0,))
            thread.start()
            thread.join()
            stream = bus.health.received["lpc/emg"]
            if bus is plain:  # stored by Zenoh's thread; a router's wait in its inbox
                wait_for(lambda stream=stream: stream.count == 30, 10.0, "30 samples")
            assert wakes == [], "no wake-up of the loop per sample"
            assert newest.take().seq == 29
            assert newest.take() is None
            assert (stream.count, stream.dropped, len(stream.stamps)) == (30, 0, 30)
            publish(30)
            if bus is plain:
                wait_for(lambda stream=stream: stream.count == 60, 10.0, "30 more")
            assert newest.take().seq == 59
            assert wakes == []
            bus.close()
        router.close()
        session.close()

    asyncio.run(main())


def test_take_queued_returns_every_queued_sample_without_waiting(endpoint: str) -> None:
    """``take_queued`` gives what ``receive`` would, all at once: every sample queued, in
    order, with its receive time, those still in the router's inbox (another thread's)
    included; a bad payload is counted as rejected and left out; then nothing."""

    async def main() -> None:
        loop = asyncio.get_running_loop()
        session = zenoh.open(zenoh_config(connect=[endpoint]))
        router = Router(session, loop, wildcard=False)
        bus = Bus(session, "emg", loop=loop, router=router, quiet=True)
        sub = bus.subscribe("lpc/emg", latest=False)
        assert sub.take_queued() == []
        for seq in range(3):
            router.deliver("lpc/emg", encode(EmgSample(seq=seq, t_ns=seq + 1, channels=[0.0])))
        router.deliver("lpc/emg", b"not msgpack")
        late = encode(EmgSample(seq=3, t_ns=4, channels=[0.0]))
        thread = threading.Thread(target=router.deliver, args=("lpc/emg", late))
        thread.start()
        thread.join()  # queued in the router's inbox, not yet handed over
        taken = sub.take_queued()
        assert [m.seq for _, m, _ in taken] == [0, 1, 2, 3]
        stamps = [t for _, _, t in taken]
        assert stamps == sorted(stamps) and all(key == "lpc/emg" for key, _, _ in taken)
        stream = bus.health.received["lpc/emg"]
        assert (stream.count, stream.rejected) == (5, 1)
        assert sub.take_queued() == []
        bus.close()
        router.close()
        session.close()

    asyncio.run(main())


def test_health_latency_quantiles_of_kept_windows_equal_the_sorted_ones(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A snapshot's p50/p99 come from each stream's window, folded from the latencies since the
    last snapshot: with numpy loaded or not (and numpy loaded in between), the same Python
    floats as ``_quantile`` of the stream's last 2,048 latencies sorted, ties, short streams
    and more than a window between two snapshots included."""
    from services.runtime import _latency_quantiles, _quantile, _Stream

    rng = np.random.default_rng(5)
    for numpy_at in (0, 2, 9):  # the snapshot from which numpy is loaded
        streams = [_Stream(), _Stream(), _Stream()]
        everything: list[list[float]] = [[], [], []]
        for snapshot, sizes in enumerate(
            ((1,), (2,), (0, 3), (7, 100), (2048, 2048), (2048, 5, 0), (3000, 1), (0, 0, 0))
        ):
            for stream, kept, n in zip(streams, everything, sizes, strict=False):
                latencies = np.round(rng.exponential(2.0, n), 1).tolist()
                stream.latencies_ms.extend(latencies)
                kept.extend(latencies)
            with monkeypatch.context() as m:
                if snapshot < numpy_at:
                    m.setitem(sys.modules, "numpy", None)
                windows = [s.latency_window() for s in streams]
                got = _latency_quantiles(windows)
            assert [len(w) for w in windows] == [min(len(kept), 2048) for kept in everything]
            ordered = sorted(x for kept in everything for x in kept[-2048:])
            if not ordered:
                assert got is None
                continue
            assert got == (_quantile(ordered, 0.50), _quantile(ordered, 0.99))
            assert all(type(q) is float for q in got)
    assert _latency_quantiles([_Stream().latency_window(), _Stream().latency_window()]) is None


def test_router_decodes_a_sample_once_for_all_its_subscriptions(endpoint: str) -> None:
    """Two services on one loop that take the same sample (the controller and the simulated
    user, the hand's status) get one decoded message; each still counts it, and a bad payload
    is rejected by each of them."""

    async def main() -> None:
        loop = asyncio.get_running_loop()
        session = zenoh.open(zenoh_config(connect=[endpoint]))
        router = Router(session, loop, wildcard=False)
        controller = Bus(session, "controller", loop=loop, router=router, quiet=True)
        user = Bus(session, "emg", loop=loop, router=router, quiet=True)
        subs = [bus.subscribe("lpc/emg", latest=False) for bus in (controller, user)]
        sample = EmgSample(seq=7, t_ns=1, channels=[0.25, 0.5])
        router.deliver("lpc/emg", encode(sample))
        (_, first, _), (_, second, _) = [await sub.receive() for sub in subs]
        assert first == sample and second is first, "decoded once, the same frozen message"
        router.deliver("lpc/emg", encode(EmgSample(seq=8, t_ns=2, channels=[0.0, 0.0])))
        third, fourth = [(await sub.receive())[1] for sub in subs]
        assert third.seq == fourth.seq == 8 and third is not first, "a new sample decoded anew"
        router.deliver("lpc/emg", b"\xc1 not msgpack")
        router.deliver("lpc/emg", encode(EmgSample(seq=9, t_ns=3, channels=[0.0, 0.0])))
        assert [(await sub.receive())[1].seq for sub in subs] == [9, 9]
        for bus in (controller, user):
            assert bus.health.received["lpc/emg"].count == 4
            assert bus.health.received["lpc/emg"].rejected == 1
            bus.close()
        router.close()
        session.close()

    asyncio.run(main())


def test_publisher_in_the_container_puts_on_zenoh_only_while_a_remote_subscriber_matches(
    endpoint: str, rendezvous: zenoh.Session
) -> None:
    """A sample put in the container still reaches its local subscriptions; Zenoh is handed it
    only while another process subscribes (the put copied a depth frame for no one), and a
    remote subscriber that comes, or was there first, gets every sample put after it matched."""

    async def main() -> None:
        loop = asyncio.get_running_loop()
        session = zenoh.open(zenoh_config(connect=[endpoint]))
        router = Router(session, loop, wildcard=False)
        bus = Bus(session, "scans", loop=loop, router=router, quiet=True)
        local = bus.subscribe("lpc/emg", latest=False)
        pub = bus.publisher("lpc/emg")
        handed: list[bytes] = []
        zpub = pub._zpub

        class Counting:  # Zenoh's publisher, counting what it is handed
            def put(self, payload: bytes) -> None:
                handed.append(payload)
                zpub.put(payload)

        pub._zpub = Counting()  # type: ignore[assignment]
        heard: list[int] = []
        for seq in range(10):
            pub.put(EmgSample(seq=seq, t_ns=seq + 1, channels=[0.0]))
        assert [(await local.receive())[1].seq for _ in range(10)] == list(range(10))
        assert handed == [], "no remote subscriber: nothing handed to Zenoh"
        remote = rendezvous.declare_subscriber(
            "lpc/emg", lambda s: heard.append(decode("lpc/emg", s.payload.to_bytes()).seq)
        )
        await until(lambda: pub._match.remote, 30, "the remote subscriber's match")
        for seq in range(10, 20):
            pub.put(EmgSample(seq=seq, t_ns=seq + 1, channels=[0.0]))
        await until(lambda: len(heard) == 10, 10, "the remote samples")
        assert heard == list(range(10, 20)) and len(handed) == 10
        # A publisher declared while the subscriber matches already is told so at once.
        late = bus.publisher("lpc/emg")
        await until(lambda: late._match.remote, 10, "the match at declaration")
        remote.undeclare()
        await until(lambda: not pub._match.remote and not late._match.remote, 30, "the unmatch")
        pub.put(EmgSample(seq=20, t_ns=21, channels=[0.0]))
        assert len(handed) == 10
        local.close()
        router.close()
        session.close()

    asyncio.run(main())
