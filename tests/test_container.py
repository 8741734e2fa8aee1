"""The service container (``lpc up --together``): services as tasks of one process on one Zenoh
session, still on the bus's topics; a service that raises is restarted in place."""

from __future__ import annotations

import argparse
import asyncio
import contextvars
import os
import socket
import time

import pytest
import zenoh

from schemas import EmgSample, decode, encode
from services.container import _RUNNER, ContainerLoop, ServiceRunner, run_container
from services.runtime import Bus, LoadedService, Router, load_service
from tests.conftest import until


def _args(endpoint: str) -> argparse.Namespace:
    return argparse.Namespace(mode="peer", connect=[endpoint], listen=None, config=None, quiet=True)


def test_container_loop_times_the_reader_callbacks_a_service_registers() -> None:
    """A reader callback runs outside every task: the container's loop adds its CPU time to the
    service that registered it (the camera's frame socket through its transport, the
    reconstructor's worker pipes through ``add_reader``), not to no service; a reader
    registered outside any service stays untimed."""
    burn_ns = 5_000_000

    def burn() -> None:
        start = time.thread_time_ns()
        while time.thread_time_ns() - start < burn_ns:
            pass

    class Burner(asyncio.Protocol):
        def data_received(self, data: bytes) -> None:
            burn()
            got.set_result(data)

    runner = ServiceRunner.__new__(ServiceRunner)
    runner.cpu_ns = 0
    service = contextvars.copy_context()
    service.run(_RUNNER.set, runner)
    loop = ContainerLoop()
    pairs = [socket.socketpair() for _ in range(3)]
    try:
        got = loop.create_future()
        transport, _ = loop.run_until_complete(
            loop.create_task(loop.create_connection(Burner, sock=pairs[0][0]), context=service)
        )
        pairs[0][1].send(b"frame")
        assert loop.run_until_complete(got) == b"frame"
        assert runner.cpu_ns >= burn_ns, "the transport's reads are the service's"
        for (a, b), context in ((pairs[1], service), (pairs[2], contextvars.Context())):
            before = runner.cpu_ns
            got = loop.create_future()
            context.run(
                loop.add_reader,
                a.fileno(),
                lambda a=a, got=got: (a.recv(1), burn(), got.set_result(1)),
            )
            b.send(b"x")
            loop.run_until_complete(got)
            loop.remove_reader(a.fileno())
            timed = runner.cpu_ns - before
            assert timed >= burn_ns if context is service else timed == 0
        transport.close()
    finally:
        loop.close()
        for a, b in pairs:
            a.close()
            b.close()


def test_container_load_service_parses_the_services_own_flags() -> None:
    loaded = load_service("services.scans", ["--band-mm", "0.8", "--quiet"])
    assert loaded.name == "scans" and loaded.args.band_mm == 0.8
    assert loaded.args.argv == ["--band-mm", "0.8", "--quiet"]
    with pytest.raises(SystemExit) as exc:
        load_service("services.scans", ["--band-mm", "nope"])
    assert exc.value.code == 2


def test_container_restarts_a_service_that_raises(endpoint: str, rendezvous: zenoh.Session) -> None:
    """The first run raises, the second runs on: one restart, counted and logged; the other
    service of the container is not disturbed."""
    runs: list[int] = []
    steady: list[int] = []
    health: dict[str, list] = {}
    logs: list[str] = []

    def on_health(sample: zenoh.Sample) -> None:
        h = decode(str(sample.key_expr), sample.payload.to_bytes())
        health.setdefault(h.service, []).append(h)

    def on_log(sample: zenoh.Sample) -> None:
        logs.append(decode(str(sample.key_expr), sample.payload.to_bytes()).text)

    async def flaky(bus: Bus, args: argparse.Namespace) -> None:
        runs.append(len(runs))
        await asyncio.sleep(0.05)
        if len(runs) == 1:
            raise RuntimeError("first run fails")
        await asyncio.Event().wait()

    async def calm(bus: Bus, args: argparse.Namespace) -> None:
        steady.append(1)
        await asyncio.Event().wait()

    subs = [
        rendezvous.declare_subscriber("lpc/health/*", on_health),
        rendezvous.declare_subscriber("lpc/log/*", on_log),
    ]
    ns = argparse.Namespace(argv=[])
    services = [LoadedService("flaky", flaky, ns), LoadedService("calm", calm, ns)]

    async def main() -> None:
        stop = asyncio.Event()
        container = asyncio.create_task(run_container(services, _args(endpoint), stop))
        await until(lambda: len(runs) == 2, 10, "the restart")
        await until(
            lambda: any(h.counters.get("restarts") == 1 for h in health.get("flaky", [])),
            10,
            "the restart in flaky's health",
        )
        stop.set()
        async with asyncio.timeout(10):
            assert await container == 0

    asyncio.run(main())
    for sub in subs:
        sub.undeclare()
    assert steady == [1], "the other service ran once, undisturbed"
    assert any("failed: RuntimeError: first run fails; restart #1" in t for t in logs)
    assert {h.pid for hs in health.values() for h in hs} == {os.getpid()}
    assert health["container"][-1].counters["restarts:flaky"] == 1


def test_container_services_talk_over_the_bus(endpoint: str, rendezvous: zenoh.Session) -> None:
    """Camera and scans in one container: an outside subscriber sees both topics, the scans
    made from the frames it sees, and each service's health and liveliness token."""
    depth: list[int] = []
    scans: list[int] = []
    subs = [
        rendezvous.declare_subscriber(
            "lpc/camera/depth",
            lambda s: depth.append(decode("lpc/camera/depth", s.payload.to_bytes()).seq),
        ),
        rendezvous.declare_subscriber(
            "lpc/scans",
            lambda s: scans.append(decode("lpc/scans", s.payload.to_bytes()).frame_seq),
        ),
    ]
    services = [
        load_service("services.scans", ["--quiet"]),
        load_service("services.camera", ["--quiet", "--rate", "30"]),
    ]

    async def main() -> set[str]:
        stop = asyncio.Event()
        container = asyncio.create_task(run_container(services, _args(endpoint), stop))
        await until(lambda: len(scans) >= 10, 30, "scans from the container")
        alive = {str(r.ok.key_expr) for r in rendezvous.liveliness().get("lpc/alive/*") if r.ok}
        stop.set()
        async with asyncio.timeout(10):
            assert await container == 0
        return alive

    alive = asyncio.run(main())
    for sub in subs:
        sub.undeclare()
    assert {"lpc/alive/scans", "lpc/alive/camera", "lpc/alive/container"} <= alive
    # The outside subscriber learns of the camera's publisher over the loopback link, so the
    # first frames may reach the scans service in the container before it: compare from the
    # first frame it saw.
    seen = [s for s in scans if s >= min(depth)]
    assert len(seen) >= 8 and set(seen) <= set(depth), "every scan comes from a frame on the bus"


def test_container_hands_its_own_samples_over_once(
    endpoint: str, rendezvous: zenoh.Session
) -> None:
    """A sample published in the container reaches the subscriptions of both its loops once
    each and in order, without a round through Zenoh, and an outside subscriber still gets it
    once through Zenoh."""
    heard: dict[str, list[int]] = {"main": [], "control": []}
    outside: list[int] = []
    sent: list[int] = []
    ready: set[str] = set()

    def listener(where: str) -> LoadedService:
        async def serve(bus: Bus, args: argparse.Namespace) -> None:
            sub = bus.subscribe("lpc/emg", latest=False)
            ready.add(where)
            async for message in sub:
                heard[where].append(message.seq)

        return LoadedService(f"listener_{where}", serve, argparse.Namespace(argv=[]))

    async def talk(bus: Bus, args: argparse.Namespace) -> None:
        emg = bus.publisher("lpc/emg")
        while len(ready) < 2:
            await asyncio.sleep(0.005)
        while True:
            sent.append(len(sent) + 1)
            emg.put(EmgSample(seq=sent[-1], t_ns=bus.clock.now_ns(), channels=[0.1, 0.2]))
            await asyncio.sleep(0.002)

    sub = rendezvous.declare_subscriber(
        "lpc/emg", lambda s: outside.append(decode("lpc/emg", s.payload.to_bytes()).seq)
    )
    services = [
        listener("main"),
        listener("control"),
        LoadedService("talker", talk, argparse.Namespace(argv=[])),
    ]

    async def main() -> None:
        stop = asyncio.Event()
        container = asyncio.create_task(
            run_container(services, _args(endpoint), stop, control_loop=("listener_control",))
        )
        await until(lambda: len(outside) >= 200, 30, "the talker's samples outside")
        stop.set()
        async with asyncio.timeout(10):
            assert await container == 0

    asyncio.run(main())
    sub.undeclare()
    for where, seqs in heard.items():
        assert seqs == sent[: len(seqs)], f"{where}: every sample once, in order"
        assert len(seqs) >= 200, where
    assert outside == sorted(set(outside)), "outside: no sample twice"
    assert len(outside) >= 200


def test_container_hands_outside_samples_to_both_loops_through_one_subscriber(
    endpoint: str, rendezvous: zenoh.Session
) -> None:
    """A sample from another process reaches the subscriptions of both loops once each and in
    order, copied out by the main loop's subscriber on lpc/**: the control loop declares no
    Zenoh subscriber of its own."""
    heard: dict[str, list[int]] = {"main": [], "control": []}
    ready: set[str] = set()
    routers: dict[str, Router] = {}

    def listener(where: str) -> LoadedService:
        async def serve(bus: Bus, args: argparse.Namespace) -> None:
            sub = bus.subscribe("lpc/emg", latest=False)
            assert bus.router is not None
            routers[where] = bus.router
            ready.add(where)
            async for message in sub:
                heard[where].append(message.seq)

        return LoadedService(f"listener_{where}", serve, argparse.Namespace(argv=[]))

    services = [listener("main"), listener("control")]
    pub = rendezvous.declare_publisher("lpc/emg")

    async def main() -> None:
        stop = asyncio.Event()
        container = asyncio.create_task(
            run_container(services, _args(endpoint), stop, control_loop=("listener_control",))
        )
        await until(lambda: len(ready) == 2, 30, "both listeners")
        await until(lambda: pub.matching_status.matching, 30, "the container's subscriber")
        for seq in range(1, 201):
            pub.put(encode(EmgSample(seq=seq, t_ns=time.time_ns(), channels=[0.1, 0.2])))
            await asyncio.sleep(0.002)
        await until(lambda: min(map(len, heard.values())) >= 200, 10, "the samples in both")
        assert routers["control"]._by_key == {}, "the control loop has no subscriber"
        stop.set()
        async with asyncio.timeout(10):
            assert await container == 0

    asyncio.run(main())
    pub.undeclare()
    for where, seqs in heard.items():
        assert seqs == list(range(1, 201)), f"{where}: every sample once, in order"


def test_container_hands_its_health_over_once(endpoint: str, rendezvous: zenoh.Session) -> None:
    """A service's health report reaches the health subscriptions of both loops once each and
    in order (handed over in the process, as the camera's shedder reads it) and an outside
    subscriber once through Zenoh."""
    heard: dict[str, list[int]] = {"main": [], "control": []}
    outside: list[int] = []

    def listener(where: str) -> LoadedService:
        async def serve(bus: Bus, args: argparse.Namespace) -> None:
            async for health in bus.subscribe("lpc/health/*"):
                if health.service == "reporter":
                    heard[where].append(health.seq)

        return LoadedService(f"listener_{where}", serve, argparse.Namespace(argv=[]))

    async def report(bus: Bus, args: argparse.Namespace) -> None:
        await asyncio.Event().wait()  # its runner reports its health, once a second

    def on_health(sample: zenoh.Sample) -> None:
        health = decode(str(sample.key_expr), sample.payload.to_bytes())
        if health.service == "reporter":
            outside.append(health.seq)

    sub = rendezvous.declare_subscriber("lpc/health/*", on_health)
    services = [
        listener("main"),
        listener("control"),
        LoadedService("reporter", report, argparse.Namespace(argv=[])),
    ]

    async def main() -> None:
        stop = asyncio.Event()
        container = asyncio.create_task(
            run_container(services, _args(endpoint), stop, control_loop=("listener_control",))
        )
        await until(lambda: min(map(len, heard.values())) >= 3, 30, "three reports in both")
        await until(lambda: len(outside) >= 2, 10, "the reports outside")
        stop.set()
        async with asyncio.timeout(10):
            assert await container == 0

    asyncio.run(main())
    sub.undeclare()
    for where, seqs in heard.items():
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), f"{where}: once each, in order"
    assert outside == sorted(set(outside)), "outside: no report twice"
