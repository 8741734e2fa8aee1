"""``lpc topics``: listen to ``lpc/**`` for a while and list each key with its type and rate."""

from __future__ import annotations

import argparse
import collections
import threading
import time

import zenoh

from schemas import topic_for_key
from services.cli._bus import add_connect_argument, open_session


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=float, default=2.0, help="how long to listen (2 s)")
    add_connect_argument(parser)


def run(args: argparse.Namespace) -> int:
    if args.seconds <= 0:
        print("lpc topics: error: --seconds must be positive")
        return 2
    counts: collections.Counter[str] = collections.Counter()
    sizes: collections.Counter[str] = collections.Counter()
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with lock:
            counts[key] += 1
            sizes[key] += len(sample.payload)

    with open_session(args) as session:
        sub = session.declare_subscriber("lpc/**", on_sample)
        time.sleep(args.seconds)  # the listening window itself, not a synchronisation
        sub.undeclare()
    if not counts:
        print("no lpc/** traffic seen; is 'lpc up' running?")
        return 1
    print(f"{'key':<32} {'type':<18} {'count':>7} {'rate Hz':>8} {'avg bytes':>10}")
    for key in sorted(counts):
        try:
            name = topic_for_key(key).type.__name__
        except KeyError:
            name = "(unregistered)"
        n = counts[key]
        print(f"{key:<32} {name:<18} {n:>7} {n / args.seconds:>8.1f} {sizes[key] / n:>10.0f}")
    return 0
