"""``lpc info FILE.mcap``: what a recording holds — topics, counts, rates, times, duration.

It reads the file record by record rather than trusting its summary, so a file cut short by a
crash is summarised up to its last good chunk, with a note saying where the cut is. Gaps (a
steady topic silent, a ``seq`` that jumped: ``lpc_core.gaps``, as the recorder logs them) are
listed with where they start and how many messages they lost.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path

from lpc_core.gaps import SOURCE_SEQ_KEYS, Gap, GapState, gap_steps
from services.mcap_log import McapLog, McapLogError, format_time

MAX_GAPS_SHOWN = 20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE.mcap", help="the recording")
    parser.add_argument(
        "--validate",
        action="store_true",
        help="decode every message against its topic's schema; exit 1 if any fails",
    )


@dataclass
class TopicStats:
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    invalid: int = 0
    first_error: str = ""
    schema: str = ""

    def rate_hz(self) -> float:
        span = self.last_ns - self.first_ns
        return (self.count - 1) / (span / 1e9) if self.count > 1 and span > 0 else 0.0


_GAP_SLICE = 4096


@dataclass
class Summary:
    topics: dict[str, TopicStats] = field(default_factory=dict)
    first_ns: int | None = None
    last_ns: int | None = None
    gaps: list[Gap] = field(default_factory=list)

    @property
    def messages(self) -> int:
        return sum(t.count for t in self.topics.values())


def summarise(log: McapLog, *, validate: bool = False) -> Summary:
    summary = Summary()
    gaps = GapState()
    # The file's own order is the order the recorder received them in; stepped a slice at
    # a time, as the recorder does, where a new state a message copied every track.
    pending: list[tuple[str, int, int]] = []
    for m in log.messages(ordered=False, decode=validate):
        if not m.key.startswith("lpc/_rejected/"):
            pending.append((m.key, m.sequence, m.log_time))
            if len(pending) == _GAP_SLICE:
                gaps, found = gap_steps(gaps, pending)
                summary.gaps.extend(found)
                pending.clear()
        stats = summary.topics.get(m.key)
        if stats is None:
            stats = summary.topics[m.key] = TopicStats(first_ns=m.log_time, last_ns=m.log_time)
        stats.count += 1
        stats.first_ns = min(stats.first_ns, m.log_time)
        stats.last_ns = max(stats.last_ns, m.log_time)
        if validate and m.message is None:
            stats.invalid += 1
            stats.first_error = stats.first_error or m.error
        if summary.first_ns is None or m.log_time < summary.first_ns:
            summary.first_ns = m.log_time
        if summary.last_ns is None or m.log_time > summary.last_ns:
            summary.last_ns = m.log_time
    gaps, found = gap_steps(gaps, pending)
    summary.gaps.extend(found)
    by_topic = {c.topic: c for c in log.channels.values()}
    for key, stats in summary.topics.items():
        channel = by_topic.get(key)
        schema = log.schemas.get(channel.schema_id) if channel is not None else None
        stats.schema = schema.name if schema is not None else "-"
    return summary


def render(path: Path, log: McapLog, summary: Summary, *, validate: bool) -> list[str]:
    start = summary.first_ns or 0
    duration = ((summary.last_ns or start) - start) / 1e9
    state = "complete" if log.complete and log.cut is None else "CUT SHORT"
    compression = ", ".join(sorted(log.compressions)) or "-"
    lines = [
        f"file         {path}",
        f"size         {log.size / 1e6:.2f} MB, compression {compression}, {state}",
        f"written by   {log.library or '-'} (profile {log.profile or '-'})",
        f"start        {format_time(start) + ' s (log time)' if summary.first_ns else '-'}",
        f"duration     {duration:.3f} s",
        f"messages     {summary.messages} on {len(summary.topics)} topics",
        "",
    ]
    width = max([len("topic")] + [len(k) for k in summary.topics])
    swidth = max([len("schema")] + [len(t.schema) for t in summary.topics.values()])
    header = (
        f"{'topic':<{width}}  {'count':>7}  {'rate Hz':>8}  {'first s':>9}  {'last s':>9}  "
        f"{'schema':<{swidth}}"
    )
    lines.append((header + ("  invalid" if validate else "")).rstrip())
    for key in sorted(summary.topics):
        t = summary.topics[key]
        rate = f"{t.rate_hz():8.2f}" if t.count > 1 else f"{'-':>8}"
        line = (
            f"{key:<{width}}  {t.count:>7}  {rate}  {(t.first_ns - start) / 1e9:>9.3f}  "
            f"{(t.last_ns - start) / 1e9:>9.3f}  {t.schema:<{swidth}}"
        )
        if validate:
            line += f"  {t.invalid}" + (f" (first: {t.first_error[:120]})" if t.first_error else "")
        lines.append(line.rstrip())
    if summary.gaps:
        silent = [g for g in summary.gaps if g.silent]
        missing = sum(g.missing for g in summary.gaps)
        lines += [
            "",
            f"gaps         {len(summary.gaps)} ({len(silent)} silences), {missing} messages "
            "missing by seq",
        ]
        # Silences say where a link or a producer was lost: each on its own line. Short seq
        # jumps (a dropped message here and there) are summed per topic.
        lines += [f"  {g.describe(start)}" for g in silent[:MAX_GAPS_SHOWN]]
        if len(silent) > MAX_GAPS_SHOWN:
            lines.append(f"  ... and {len(silent) - MAX_GAPS_SHOWN} more silences")
        jumps: dict[str, list[int]] = {}
        for g in summary.gaps:
            if not g.silent:
                jumps.setdefault(g.key, []).append(g.missing)
        for key in sorted(jumps):
            n, lost = len(jumps[key]), sum(jumps[key])
            lines.append(f"  seq jumps on {key}: {n}, {lost} missing")
    else:
        skipped = ", ".join(sorted(SOURCE_SEQ_KEYS))
        lines += ["", f"gaps         none (seq jumps on {skipped} are skipped frames)"]
    if log.cut is not None:
        lines += ["", f"note: {log.cut.describe()}; nothing after it is readable"]
    return lines


def run(args: argparse.Namespace) -> int:
    path = Path(args.file)
    try:
        with McapLog(path) as log:
            summary = summarise(log, validate=args.validate)
            print("\n".join(render(path, log, summary, validate=args.validate)))
    except McapLogError as exc:
        print(f"lpc info: error: {exc}", file=sys.stderr)
        return 2
    if args.validate and any(t.invalid for t in summary.topics.values()):
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="lpc info", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
