"""A short-lived session for the inspection commands (``topics``, ``echo``, ``schemas --bus``)."""

from __future__ import annotations

import argparse
import sys

import zenoh

from services.runtime import DEFAULT_ENDPOINT, zenoh_config


def add_connect_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help=f"where the bus is (default: {DEFAULT_ENDPOINT}, the rendezvous of 'lpc up')",
    )
    parser.add_argument("--config", metavar="FILE", help="a Zenoh JSON5 config file")


def open_session(args: argparse.Namespace) -> zenoh.Session:
    conf = zenoh_config(
        mode="client" if not args.config else "peer",
        connect=args.connect,
        listen=[] if not args.config else None,
        config_file=args.config,
    )
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        endpoints = ", ".join(args.connect or [DEFAULT_ENDPOINT])
        print(f"lpc: error: cannot reach the bus at {endpoints}: {exc}", file=sys.stderr)
        raise SystemExit(2) from exc
