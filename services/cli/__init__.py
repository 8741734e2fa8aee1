"""The ``lpc`` command.

Each sub-command lives in its own module under ``services.cli`` and defines
``add_arguments(parser)`` and ``run(args) -> int``. ``COMMANDS`` is the one table of them.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys

# name -> (module, one-line help). Modules are imported only when their command runs.
COMMANDS: dict[str, tuple[str, str]] = {
    "up": ("services.cli.up", "start the service set on the bus (simulated scene by default)"),
    "sim-camera": (
        "services.cli.sim_camera",
        "the simulated depth camera as a device of its own (for --source sim-device)",
    ),
    "topics": ("services.cli.topics", "list the topics seen on the bus, with rates"),
    "echo": ("services.cli.echo", "print the messages of one key expression as JSON lines"),
    "schemas": ("services.cli.schemas", "print the JSON schema of every topic"),
    "bench": ("services.cli.bench", "benchmarks that print their figures"),
    "tactors": ("services.cli.tactors", "pulse each tactor in turn to fit a user (tactors test)"),
    "emg": ("services.cli.emg", "EMG: record rest and maximal contraction (emg calibrate)"),
    "info": ("services.cli.info", "summarise an MCAP recording: topics, counts, rates, duration"),
    "replay": ("services.cli.replay", "re-run the pipeline on a recording; --check compares"),
    "reconstruct": (
        "services.cli.reconstruct",
        "shape, grasp width and wrist angle of depth frames, one JSON line each",
    ),
    "certs": ("services.cli.certs", "make a local CA and per-service certificates (secure mode)"),
    "export": ("services.cli.export", "re-log a recording in Foxglove's schemas (--foxglove)"),
    "trials": ("services.cli.trials", "the paper's pick-and-place experiment with virtual users"),
}


def build_parser(chosen: str | None = None) -> argparse.ArgumentParser:
    """The parser; with ``chosen``, only that command's module is imported (fast start-up)."""
    parser = argparse.ArgumentParser(
        prog="lpc",
        description=(
            "lpc: semi-autonomous prosthesis control from four depth scan lines. "
            "Run 'lpc up --duration 10 --record out.mcap' to see the whole loop on a "
            "simulated scene, no hardware needed."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        if chosen is None or chosen == name:
            importlib.import_module(module).add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    chosen = argv[0] if argv and argv[0] in COMMANDS else None
    args = build_parser(chosen).parse_args(argv)
    module = importlib.import_module(args._module)
    try:
        return int(module.run(args) or 0)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # The reader went away (``lpc replay X | head``): stop quietly, as a pipe stage does.
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
