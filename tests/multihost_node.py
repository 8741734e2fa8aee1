"""Small Zenoh programs the multi-host tests start inside a host's namespace.

``router CONFIG``: a Zenoh router (zenoh-python, the config says ``mode: "router"``) until
SIGINT. ``probe CONFIG KEY...``: one JSON line per sample on stdout (key, seq, times, and the
fields the tests read). ``intrude CONFIG --as NAME``: try to open a session; if it opens,
subscribe to ``lpc/**`` and publish hand commands for a while, then print one JSON line saying
what happened.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time

import zenoh

from schemas import ProsthesisCommand, encode, topic_for_key
from services.mcap_log import read_header

# Fields printed with the header, per key; the rest of a message is not needed.
FIELDS = {
    "lpc/prosthesis/command": ("grasp", "wrist", "source"),
    "lpc/controller/state": ("state", "previous", "event", "reason"),
    "lpc/log/recorder": ("level", "text"),
    "lpc/health/recorder": ("counters",),
    "lpc/health/prosthesis_bridge": ("counters",),
}


def _wait_for_signal() -> None:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()


def router(args: argparse.Namespace) -> int:
    # Zenoh's warnings (it logs to stdout): a refused handshake says why.
    zenoh.init_log_from_env_or("warn")
    with zenoh.open(zenoh.Config.from_file(args.config)):
        print(json.dumps({"ready": True}), flush=True)
        _wait_for_signal()
    return 0


def probe(args: argparse.Namespace) -> int:
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        received = time.time_ns()
        key, payload = str(sample.key_expr), sample.payload.to_bytes()
        line: dict[str, object] = {"k": key, "r": received}
        header = read_header(payload)
        if header is not None:
            line["s"], line["t"] = header
        names = FIELDS.get(key)
        if names:
            try:
                message = topic_for_key(key).decode(payload, key)
                line.update({n: getattr(message, n) for n in names})
            except Exception as exc:
                line["error"] = str(exc)
        with lock:
            sys.stdout.write(json.dumps(line) + "\n")
            sys.stdout.flush()

    with zenoh.open(zenoh.Config.from_file(args.config)) as session:
        subs = [session.declare_subscriber(key, on_sample) for key in args.keys]
        print(json.dumps({"ready": True}), flush=True)
        _wait_for_signal()
        for sub in subs:
            sub.undeclare()
    return 0


def intrude(args: argparse.Namespace) -> int:
    report: dict[str, object] = {"as": args.name, "config": args.config}
    zenoh.init_log_from_env_or("warn")  # the handshake's failure, on stdout before the report
    try:
        session = zenoh.open(zenoh.Config.from_file(args.config))
    except zenoh.ZError as exc:
        report.update(connected=False, error=str(exc).strip().splitlines()[-1][:200])
        print(json.dumps(report), flush=True)
        return 0
    received: list[str] = []
    with session:
        session.declare_subscriber("lpc/**", lambda s: received.append(str(s.key_expr)))
        # Remote only: a session's own subscriber would otherwise get its own puts locally.
        publisher = session.declare_publisher(
            "lpc/prosthesis/command", allowed_destination=zenoh.Locality.REMOTE
        )
        sent = 0
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            sent += 1
            # Full speed open: what a forged command would make the hand do.
            command = ProsthesisCommand(
                seq=sent, t_ns=time.time_ns(), grasp=-1.0, wrist=1.0, source=args.name
            )
            publisher.put(encode(command))
            time.sleep(0.01)
        report.update(
            connected=True,
            commands_sent=sent,
            received=len(received),
            received_keys=sorted(set(received))[:20],
        )
    print(json.dumps(report), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.multihost_node", description=__doc__)
    sub = parser.add_subparsers(dest="what", required=True)
    r = sub.add_parser("router")
    r.add_argument("config")
    p = sub.add_parser("probe")
    p.add_argument("config")
    p.add_argument("keys", nargs="+")
    i = sub.add_parser("intrude")
    i.add_argument("config")
    i.add_argument("--as", dest="name", required=True)
    i.add_argument("--seconds", type=float, default=2.0)
    args = parser.parse_args(argv)
    return {"router": router, "probe": probe, "intrude": intrude}[args.what](args)


if __name__ == "__main__":
    sys.exit(main())
