"""``lpc export --foxglove IN.mcap OUT.mcap``: a recording re-logged in Foxglove's schemas.

The same conversion as the live bridge (``lpc_core.foxglove_convert``), offline: depth as
RawImage, scan lines as PointCloud, the reconstruction as SceneUpdate, logs as Log, everything
else as plottable JSON. ``log_time``, ``publish_time`` and ``sequence`` are kept, so the
export lines up with the recording. A recording cut short by a crash is exported up to its
last good chunk. The output is written next to OUT and renamed into place when complete, and
identical input gives a byte-identical file. Needs only ``mcap``, not foxglove-sdk.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import struct
import sys
import time
from pathlib import Path
from typing import BinaryIO, TextIO

import msgspec
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import Writer

from lpc_core.foxglove_convert import convert, schema_for
from services.mcap_log import COMPRESSIONS, McapLog, McapLogError

CHUNK_BYTES = 4 * 1024 * 1024


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--foxglove",
        action="store_true",
        help="export in Foxglove's schemas (the one format so far; required)",
    )
    parser.add_argument("input", metavar="IN.mcap", help="an lpc recording")
    parser.add_argument("output", metavar="OUT.mcap", help="the file to write")
    parser.add_argument(
        "--compression",
        choices=sorted(COMPRESSIONS),
        default="zstd",
        help="chunk compression of the output (default zstd)",
    )
    parser.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr (default: when stderr is a terminal)",
    )


class Progress:
    """A one-line bar on ``stream``, redrawn at most ten times a second."""

    def __init__(self, stream: TextIO, total: int | None, enabled: bool) -> None:
        self.stream = stream
        self.total = total
        self.enabled = enabled
        self.start = time.monotonic()
        self._drawn = 0.0

    def update(self, done: int, final: bool = False) -> None:
        now = time.monotonic()
        if not self.enabled or (not final and now - self._drawn < 0.1):
            return
        self._drawn = now
        rate = done / max(now - self.start, 1e-9)
        if self.total:
            fraction = min(done / self.total, 1.0)
            bar = "#" * int(30 * fraction)
            head = f"[{bar:<30}] {100 * fraction:5.1f}% {done}/{self.total}"
        else:
            head = f"{done} messages"
        self.stream.write(f"\rlpc export: {head}  {rate:,.0f} msg/s")
        if final:
            self.stream.write("\n")
        self.stream.flush()


def run(args: argparse.Namespace) -> int:
    if not args.foxglove:
        return _fail("choose the format: --foxglove")
    source, target = Path(args.input), Path(args.output)
    if source.resolve() == target.resolve():
        return _fail("IN and OUT are the same file")
    try:
        log = McapLog(source)
    except McapLogError as exc:
        return _fail(str(exc))
    show = sys.stderr.isatty() if args.progress is None else args.progress
    progress = Progress(sys.stderr, _message_count(source), show)
    partial = target.with_name(target.name + ".partial")
    started = time.monotonic()
    try:
        with log, open(partial, "wb") as out:
            counts = _export(log, out, args.compression, progress)
        os.replace(partial, target)
    except OSError as exc:
        partial.unlink(missing_ok=True)
        return _fail(f"cannot write {target}: {exc.strerror or exc}")
    elapsed = time.monotonic() - started
    if log.cut is not None:
        print(f"lpc export: warning: {source} {log.cut.describe()}", file=sys.stderr)
    for key, (n, reason) in sorted(counts.skipped.items()):
        print(f"lpc export: skipped {n} message(s) on {key}: {reason}", file=sys.stderr)
    size_mb = source.stat().st_size / 1e6
    print(
        f"lpc export: {counts.read} messages -> {counts.written} on {len(counts.topics)} "
        f"Foxglove topics in {target} ({elapsed:.2f} s, {size_mb / max(elapsed, 1e-9):.1f} MB/s"
        f" read); skipped {sum(n for n, _ in counts.skipped.values())}",
        file=sys.stderr,
    )
    return 0


class _Counts:
    def __init__(self) -> None:
        self.read = 0
        self.written = 0
        self.topics: collections.Counter[str] = collections.Counter()
        self.skipped: dict[str, tuple[int, str]] = {}

    def skip(self, key: str, reason: str) -> None:
        n, first = self.skipped.get(key, (0, reason))
        self.skipped[key] = (n + 1, first)


def _export(log: McapLog, out: BinaryIO, compression: str, progress: Progress) -> _Counts:
    writer = Writer(out, chunk_size=CHUNK_BYTES, compression=COMPRESSIONS[compression])
    writer.start(profile="", library="lpc export")
    encode = msgspec.json.Encoder().encode
    schemas: dict[str, int] = {}
    channels: dict[str, int] = {}
    counts = _Counts()
    for m in log.messages(decode=True):
        counts.read += 1
        progress.update(counts.read)
        if m.message is None:
            counts.skip(m.key, m.error or f"encoding {m.encoding!r}")
            continue
        try:
            outputs = convert(m.key, m.message)
        except ValueError as exc:
            counts.skip(m.key, str(exc))
            continue
        for output in outputs:
            channel = channels.get(output.topic)
            if channel is None:
                schema = schemas.get(output.schema)
                if schema is None:
                    data = json.dumps(schema_for(output.schema, type(m.message))).encode()
                    schema = schemas[output.schema] = writer.register_schema(
                        output.schema, "jsonschema", data
                    )
                channel = channels[output.topic] = writer.register_channel(
                    output.topic, "json", schema
                )
            writer.add_message(
                channel,
                log_time=m.log_time,
                data=encode(output.payload),
                publish_time=m.publish_time,
                sequence=m.sequence,
            )
            counts.written += 1
            counts.topics[output.topic] += 1
    writer.finish()
    progress.update(counts.read, final=True)
    return counts


def _message_count(path: Path) -> int | None:
    """From the summary of a complete file; ``None`` for a file cut short (no summary)."""
    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except (McapError, OSError, ValueError, EOFError, struct.error):
        return None
    if summary is None or summary.statistics is None:
        return None
    return summary.statistics.message_count


def _fail(text: str) -> int:
    print(f"lpc export: error: {text}", file=sys.stderr)
    return 2
