"""``lpc echo KEY``: print the messages of a key expression as JSON lines (arrays summarised)."""

from __future__ import annotations

import argparse
import contextlib
import queue
import sys
import time

import msgspec
import zenoh

from schemas import BadMessage, NDArray, decode
from services.cli._bus import add_connect_argument, open_session


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("key", help="key expression, e.g. lpc/grasp/target or 'lpc/health/*'")
    parser.add_argument("-n", "--count", type=int, default=0, help="stop after N messages")
    parser.add_argument("--seconds", type=float, default=0.0, help="stop after S seconds")
    parser.add_argument("--full", action="store_true", help="print array bytes in full (base64)")
    add_connect_argument(parser)


def _summarise(obj: object) -> object:
    if isinstance(obj, NDArray):
        return {"dtype": obj.dtype, "shape": obj.shape, "bytes": len(obj.data)}
    raise NotImplementedError


def run(args: argparse.Namespace) -> int:
    if not args.key.startswith("lpc/"):
        print(f"lpc echo: error: key {args.key!r} is not under lpc/", file=sys.stderr)
        return 2
    encoder = msgspec.json.Encoder(enc_hook=None if args.full else _summarise)
    samples: queue.Queue[tuple[str, bytes]] = queue.Queue(maxsize=1000)

    def on_sample(sample: zenoh.Sample) -> None:
        with contextlib.suppress(queue.Full):
            samples.put_nowait((str(sample.key_expr), sample.payload.to_bytes()))

    printed = 0
    deadline = None
    with open_session(args) as session:
        if args.seconds > 0:
            deadline = time.monotonic() + args.seconds
        sub = session.declare_subscriber(args.key, on_sample)
        try:
            while args.count <= 0 or printed < args.count:
                timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
                try:
                    key, payload = samples.get(timeout=timeout if timeout is not None else 0.5)
                except queue.Empty:
                    if deadline is not None and time.monotonic() >= deadline:
                        break
                    continue
                try:
                    message = decode(key, payload)
                    line = encoder.encode({"key": key, "message": message}).decode()
                except (BadMessage, KeyError) as exc:
                    line = msgspec.json.encode({"key": key, "error": str(exc)}).decode()
                print(line, flush=True)
                printed += 1
        except KeyboardInterrupt:
            pass
        finally:
            sub.undeclare()
    return 0
