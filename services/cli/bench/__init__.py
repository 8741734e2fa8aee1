"""``lpc bench NAME``: benchmarks that print their figures (speed belongs here, not in tests)."""

from __future__ import annotations

import argparse
import importlib

# name -> (module, one-line help); each module defines add_arguments(parser) and run(args).
BENCHES: dict[str, tuple[str, str]] = {
    "accuracy": (
        "services.cli.bench.accuracy",
        "shape, width and angle accuracy on the paper's suites",
    ),
    "speed": ("services.cli.bench.speed", "per-stage time of the four-line method, with a profile"),
    "soak": ("services.cli.bench.soak", "the whole set for N minutes: rates, drops, memory slope"),
    "fit": ("services.cli.bench.fit", "time the scan-line fits (line, circle, ellipse, all three)"),
    "loop": ("services.cli.bench.loop", "closed-loop session: states, pre-shapes, 100 Hz rates"),
    "latency": ("services.cli.bench.latency", "depth frame capture to bytes on the tactor line"),
    "compare": ("services.cli.bench.compare", "the four-line method against the full cloud"),
    "recorder": ("services.cli.bench.recorder", "MCAP write cost, recorder loss, replay speed"),
    "render": ("services.cli.bench.render", "simulated camera and scan-cut speed"),
    "stereo": ("services.cli.bench.stereo", "the stereo camera's artifacts and cost per frame"),
    "sweep": (
        "services.cli.bench.sweep",
        "both methods over many stereo camera settings, one row each, before -> after",
    ),
    "foxglove": ("services.cli.bench.foxglove", "Foxglove conversion, export and bridge figures"),
    "emg": ("services.cli.bench.emg", "lpc/emg rate from LSL or BrainFlow raw EMG; an outage"),
    "pool": ("services.cli.bench.pool", "the reconstructor's pipe-fed workers against an executor"),
    "footprint": (
        "services.cli.bench.footprint",
        "the whole set under a CPU quota: CPU, memory, rates, drops, latency per service",
    ),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bench", metavar="NAME", required=True)
    for name, (module, help_text) in BENCHES.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_bench_module=module)
        importlib.import_module(module).add_arguments(p)


def run(args: argparse.Namespace) -> int:
    return int(importlib.import_module(args._bench_module).run(args) or 0)
