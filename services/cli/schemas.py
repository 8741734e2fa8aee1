"""``lpc schemas``: the JSON schema of every topic, from this install or from the bus."""

from __future__ import annotations

import argparse
import json
import sys

from schemas import TOPICS, json_schema
from services.cli._bus import add_connect_argument, open_session


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("key", nargs="?", help="only this topic, e.g. lpc/scans")
    parser.add_argument(
        "--bus", action="store_true", help="ask the running services (queryable lpc/schemas/**)"
    )
    add_connect_argument(parser)


def run(args: argparse.Namespace) -> int:
    if args.bus:
        selector = "lpc/schemas/" + (args.key or "**")
        found: dict[str, object] = {}
        with open_session(args) as session:
            for reply in session.get(selector, timeout=2.0):
                if reply.ok is not None:
                    key = str(reply.ok.key_expr).removeprefix("lpc/schemas/")
                    found[key] = json.loads(reply.ok.payload.to_bytes())
        if not found:
            print(f"lpc schemas: error: no service answered {selector}", file=sys.stderr)
            return 1
    else:
        found = {t.key: json_schema(t.type) for t in TOPICS if args.key in (None, t.key)}
        if not found:
            known = ", ".join(t.key for t in TOPICS)
            print(
                f"lpc schemas: error: unknown topic {args.key!r}; known: {known}", file=sys.stderr
            )
            return 2
    json.dump(found, sys.stdout, indent=2, sort_keys=True)
    print()
    return 0
