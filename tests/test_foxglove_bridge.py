"""The Foxglove bridge over a real bus and a real WebSocket client speaking Foxglove's protocol."""

from __future__ import annotations

import asyncio
import base64
import json
import signal
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import zenoh

from lpc_core import foxglove_convert as fc
from schemas import decode, encode, to_wire
from services import foxglove_bridge
from tests.conftest import free_port, spawn_service, wait_for
from tests.test_foxglove_convert import T_NS, depth_frame, one_of_each

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")

# foxglove-sdk 0.30 speaks the protocol as "foxglove.sdk.v1"; the app offers both names.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01
DEADLINE_S = 30.0


class FoxgloveClient:
    """Just enough of a Foxglove WebSocket client: advertisements, subscriptions, message data."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.channels: dict[int, dict[str, Any]] = {}
        self.subscriptions: dict[int, int] = {}  # subscription id -> channel id
        self.messages: dict[str, list[tuple[int, dict[str, Any]]]] = {}
        self.server_info: dict[str, Any] = {}

    async def step(self) -> None:
        frame = await self.ws.recv()
        if isinstance(frame, str):
            op = json.loads(frame)
            if op["op"] == "serverInfo":
                self.server_info = op
            elif op["op"] == "advertise":
                for channel in op["channels"]:
                    self.channels[channel["id"]] = channel
                await self._subscribe([c["id"] for c in op["channels"]])
            return
        assert frame[0] == MESSAGE_DATA, f"unexpected binary opcode {frame[0]}"
        subscription, log_time = struct.unpack_from("<IQ", frame, 1)
        channel = self.channels[self.subscriptions[subscription]]
        assert channel["encoding"] == "json"
        payload = json.loads(frame[13:])
        self.messages.setdefault(channel["topic"], []).append((log_time, payload))

    async def _subscribe(self, channel_ids: list[int]) -> None:
        subs = []
        for channel_id in channel_ids:
            sub_id = len(self.subscriptions) + 1
            self.subscriptions[sub_id] = channel_id
            subs.append({"id": sub_id, "channelId": channel_id})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def schema(self, topic: str) -> tuple[str, dict[str, Any]]:
        channel = next(c for c in self.channels.values() if c["topic"] == topic)
        assert channel["schemaEncoding"] == "jsonschema"
        return channel["schemaName"], json.loads(channel["schema"])


async def collect(
    port: int, topics: set[str], until: Callable[[], bool] = lambda: True, what: str = ""
) -> FoxgloveClient:
    """Connect (retrying while the server starts), subscribe to everything, and read until
    every topic in ``topics`` has delivered a message and ``until()`` holds: the client keeps
    watching meanwhile, and the bridge handles (and counts) only what someone watches."""
    deadline = time.monotonic() + DEADLINE_S
    while True:
        try:
            ws = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.05)
    async with ws:
        assert ws.subprotocol in SUBPROTOCOLS
        client = FoxgloveClient(ws)
        while not (topics <= set(client.messages) and until()):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                missing = topics - set(client.messages)
                if missing:
                    pytest.fail(f"no message on {sorted(missing)} within {DEADLINE_S} s")
                pytest.fail(f"timed out after {DEADLINE_S} s waiting for {what or until}")
            async with asyncio.timeout(remaining):
                await client.step()
        return client


class Feeder:
    """Publishes one message of every topic, a depth frame that cannot be shown and a payload
    that does not decode, every 20 ms."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.messages = one_of_each()
        bad = depth_frame(seed=9)
        self.bad = encode(
            type(bad)(
                seq=9,
                t_ns=T_NS,
                intrinsics=bad.intrinsics,
                depth=to_wire(np.zeros((240, 424), np.float32)),
            )
        )
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        payloads = [(key, encode(message)) for key, message in self.messages.items()]
        while not self.stop.wait(0.02):
            for key, payload in payloads:
                self.session.put(key, payload)
            self.session.put("lpc/camera/depth", self.bad)
            self.session.put("lpc/emg", b"\xc1 not msgpack")

    def __enter__(self) -> Feeder:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(timeout=5)


def test_bridge_defaults_to_loopback_port_8765() -> None:
    parser = foxglove_bridge.service_parser("foxglove_bridge", "")
    foxglove_bridge.add_arguments(parser)
    args = parser.parse_args([])
    assert (args.host, args.port) == ("127.0.0.1", 8765)
    assert foxglove_bridge._loopback("127.0.0.1") and foxglove_bridge._loopback("::1")
    assert not foxglove_bridge._loopback("0.0.0.0")


def test_bridge_serves_every_topic_to_a_websocket_client(
    endpoint: str, rendezvous: zenoh.Session
) -> None:
    health: list[dict[str, int]] = []

    def on_health(sample: zenoh.Sample) -> None:
        health.append(decode(str(sample.key_expr), sample.payload.to_bytes()).counters)

    health_sub = rendezvous.declare_subscriber("lpc/health/foxglove", on_health)
    port = free_port()
    proc = spawn_service("services.foxglove_bridge", endpoint, "--port", str(port))
    try:
        with Feeder(rendezvous) as feeder:
            # Before anyone watches, the bridge converts each key once (to advertise it), then
            # skips it.
            wait_for(lambda: any(c.get("unwatched", 0) > 0 for c in health), DEADLINE_S, "skips")
            expected = {
                out.topic for key, msg in feeder.messages.items() for out in fc.convert(key, msg)
            }
            # The bad payloads are decoded (and rejected) only while a viewer watches their
            # keys: the client stays subscribed until the health report counts both.
            client = asyncio.run(
                collect(
                    port,
                    expected,
                    until=lambda: any(
                        c.get("rejected:lpc/camera/depth", 0) > 0
                        and c.get("rejected:lpc/emg", 0) > 0
                        for c in list(health)
                    ),
                    what="the bad depth frame and the bad EMG payload counted as rejected",
                )
            )
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        health_sub.undeclare()
        if proc.poll() is None:
            proc.kill()
            proc.wait()

    assert client.server_info["name"] == "lpc"
    for topic in expected:
        name, schema = client.schema(topic)
        assert schema["title"] == name
    stamp = {"sec": T_NS // 10**9, "nsec": T_NS % 10**9}

    name, _ = client.schema("/lpc/camera/depth")
    _, image = client.messages["/lpc/camera/depth"][0]
    assert name == "foxglove.RawImage"
    assert (image["encoding"], image["width"], image["height"]) == ("16UC1", 424, 240)
    assert image["timestamp"] == stamp
    sent = feeder.messages["lpc/camera/depth"]
    assert base64.b64decode(image["data"]) == sent.depth.data

    assert client.schema("/lpc/scans")[0] == "foxglove.PointCloud"
    _, cloud = client.messages["/lpc/scans"][0]
    points = np.frombuffer(base64.b64decode(cloud["data"]), "<f4").reshape(-1, 4)
    n = sum(line.points.shape[0] for line in feeder.messages["lpc/scans"].lines)
    assert points.shape == (n, 4)

    assert client.schema("/lpc/reconstruction/scene")[0] == "foxglove.SceneUpdate"
    _, scene = client.messages["/lpc/reconstruction/scene"][0]
    solid = next(e for e in scene["entities"] if e["id"] == "solid")
    assert len(solid["cylinders"]) == 1 and solid["frame_id"] == "camera"

    assert client.schema("/lpc/log")[0] == "foxglove.Log"
    assert client.schema("/tf")[0] == "foxglove.FrameTransforms"
    _, emg = client.messages["/lpc/emg"][0]
    assert emg["channels"] == [0.1, 0.7] and emg["timestamp"] == stamp
    _, cue = client.messages["/lpc/aim/cue"][0]
    assert cue["amplitudes"] == [0.0, 0.5, 0.0, 0.0]
    _, hand = client.messages["/lpc/prosthesis/state"][0]
    assert hand["aperture_mm"] == 80.0
