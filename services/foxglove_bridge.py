"""Foxglove bridge: every ``lpc/**`` message, re-logged in Foxglove's schemas, on a WebSocket.

Serves Foxglove's WebSocket protocol (foxglove-sdk, the optional extra ``lpc[foxglove]``) on
loopback by default; open ``ws://127.0.0.1:8765`` in Foxglove and load
``deploy/foxglove-layout.json``. ``lpc_core.foxglove_convert`` does the conversion; a message
that fails to convert is counted as rejected and skipped. Once every channel a key feeds is
known and no viewer watches any of them, that key's messages are not converted at all.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import sys
from typing import Any

import msgspec

from lpc_core.foxglove_convert import Output, convert, schema_for
from schemas import BadMessage, decode
from services.runtime import Bus, run_service, service_parser

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
QUEUE_CAPACITY = 256  # ~1 s of everything; a slow viewer drops (counted) rather than lags


class Channels:
    """One Foxglove channel per output topic, made on first use, and the channels each lpc key
    feeds (so that a key nobody watches can be skipped)."""

    def __init__(self, foxglove: Any, context: Any) -> None:
        self._foxglove = foxglove
        self._context = context
        self._by_topic: dict[str, Any] = {}
        self._feeds: dict[str, list[Any]] = {}

    def watched(self, key: str) -> bool:
        feeds = self._feeds.get(key)
        return feeds is None or any(channel.has_sinks() for channel in feeds)

    def log(self, key: str, outputs: list[tuple[Output, bytes]], source: type, t_ns: int) -> None:
        feeds = []
        for out, data in outputs:
            channel = self._by_topic.get(out.topic)
            if channel is None:
                schema = json.dumps(schema_for(out.schema, source)).encode()
                channel = self._by_topic[out.topic] = self._foxglove.Channel(
                    out.topic,
                    schema=self._foxglove.Schema(
                        name=out.schema, encoding="jsonschema", data=schema
                    ),
                    message_encoding="json",
                    context=self._context,
                )
            channel.log(data, log_time=t_ns)
            feeds.append(channel)
        self._feeds[key] = feeds


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    import foxglove  # the optional extra: main() has checked it is there

    context = foxglove.Context()
    try:
        server = foxglove.start_server(name="lpc", host=args.host, port=args.port, context=context)
    except RuntimeError as exc:
        raise RuntimeError(f"cannot serve Foxglove on {args.host}:{args.port}: {exc}") from exc
    bus.log("info", f"serving Foxglove WebSocket on ws://{args.host}:{server.port}")
    channels = Channels(foxglove, context)
    encode = msgspec.json.Encoder().encode
    sent = bus.health.published["foxglove"]
    # Decoded here, not by the runtime, so that unwatched keys cost no decoding.
    sub = bus.subscribe("lpc/**", latest=False, capacity=QUEUE_CAPACITY, decode=False)
    try:
        while True:
            key, payload, _ = await sub.receive()
            if not channels.watched(key):
                bus.health.counters["unwatched"] += 1
                continue
            try:
                message = decode(key, payload)
            except (BadMessage, KeyError) as exc:
                bus.health.received[key].rejected += 1
                bus.reject(key, str(exc))
                continue
            try:
                outputs = [(out, encode(out.payload)) for out in convert(key, message)]
            except Exception as exc:  # one bad message must never stop the viewer's stream
                bus.reject(key, f"conversion failed: {type(exc).__name__}: {exc}")
                continue
            now = bus.clock.now_ns()
            channels.log(key, outputs, type(message), now)
            sent.count += 1
            sent.stamps.append(now)
            sent.latencies_ms.append((now - message.t_ns) / 1e6)
    finally:
        server.stop()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--host",
        default=DEFAULT_HOST,
        help=f"address to serve on (default {DEFAULT_HOST}, loopback only)",
    )
    parser.add_argument(
        "--port",
        type=int,
        default=DEFAULT_PORT,
        help=f"WebSocket port (default {DEFAULT_PORT}; 0 picks a free one)",
    )


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("foxglove_bridge", __doc__ or "")
    add_arguments(parser)
    args = parser.parse_args(argv)
    if not 0 <= args.port <= 65535:
        parser.error("--port must be in [0, 65535]")
    try:
        import foxglove  # noqa: F401
    except ImportError:
        print(
            "[foxglove] error: foxglove-sdk is not installed; pip install 'lpc[foxglove]'",
            file=sys.stderr,
        )
        return 2
    if not _loopback(args.host):
        print(
            f"[foxglove] warning: serving on {args.host}, reachable beyond this machine",
            file=sys.stderr,
        )
    return run_service("foxglove", serve, args)


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


if __name__ == "__main__":
    sys.exit(main())
