"""Recorder service: every ``lpc/**`` message to MCAP, in the order it arrived.

One subscriber on ``lpc/**`` keeps arrival order across topics, but for the samples of other
threads in the container, which it takes at its loop's next wake-up (``prompt=False``) and so
may write after a later one of its own loop. ``log_time`` is the receive time (for those too,
when they arrived), ``publish_time`` the message's ``t_ns``. A payload without a readable
header is counted as rejected and kept raw on ``lpc/_rejected/<key>``. Files rotate past
``--max-mb``; the file is finished on SIGINT/SIGTERM, after the messages already received are
written.

Gaps (``lpc_core.gaps``: a steady topic silent for 10 of its periods and 0.5 s, or a ``seq``
that jumped) are counted in the health counters (``gaps``, ``missing``) and each is logged on
``lpc/log/recorder``, which the recorder itself records: the file says where its holes are, and
``lpc info`` finds the same ones from the messages.

Default compression, measured with ``python -m services.cli.bench.recorder`` (203 KB simulated
depth frames, 1 MiB chunks, mcap 1.6, this 2-core machine at load 5): zstd 1.1 ms per frame
and 4.4x smaller (4.2 MB/s at 90 Hz), LZ4 0.8 ms and 2.7x (6.7 MB/s), none 0.6 ms (18 MB/s).
zstd is the default: it releases the GIL while it compresses, where python-lz4 holds it and
stalls the Zenoh threads that hand samples over.

Its level (``--zstd-level``, default 1), measured with ``python -m services.cli.bench.recorder
write --zstd-levels=3,1,-1,-5`` (CPU time per frame, shared machine at load 3.5, three runs):
level 3 (zstd's own default, used until then) 1.5-1.7 ms and 4.40x (4.2 MB/s); level 1
1.0 ms and 3.77x (4.9 MB/s); level -1 1.0-1.1 ms and 3.36x; level -5 0.9 ms and 2.78x
(6.6 MB/s). Writing without compression already costs 0.65 ms (chunking, CRCs, the write), so
negative levels save little CPU over level 1 and cost a third more disk; level 1 takes 9% of
one core at 90 Hz against 14% at level 3. The files read with any zstd decoder (the stock
``mcap`` reader included). The whole recorder took 18-26% of one core on the full live mix
(depth and scans at 90 Hz, EMG and hand state at 100 Hz, cue and tactor command at 90 Hz) at
level 3.

Most of what was left beside zstd was the kernel's: each chunk, its compressed copy and each
frame's payload were new pages, faulted in and zeroed (71 page faults a frame, ``perf record``:
``exc_page_fault``, ``clear_page_erms``, ``__do_sys_brk``), because glibc handed the freed heap
back after every chunk. ``services.heap.keep_freed_memory``, which every service's process and
the container call at start, keeps it: the write loop went from 0.89 to 0.54 ms of CPU a frame
at level 1 (0.43 to 0.16 ms uncompressed), RSS unchanged.

What the writer thread spends beside zstd (callgrind of ``LogWriter`` on a recording's live mix,
per depth frame): a zstd chunk's integrity is zstd's own content checksum instead of MCAP's
chunk CRC, and every chunk is built in one buffer instead of a ``BytesIO`` that glibc moved as
each depth payload grew it: 6.20 -> 5.22 M instructions, about three quarters of them zstd's
(``services.mcap_log._ChunkZstd``, ``_ChunkBuffer``). Of the recorder's footprint row, the
loop's own share is small (0.5 % of a core at 90 Hz, about 7 us a message); the rest is the
writer thread. The thread then writes each batch in one call (``LogWriter.write_many``), packs
each message head in place and a chunk's message indexes in one pack each: its work beside
zstd 864k -> 569k instructions a depth frame on a live recording's stream (18 messages a
frame), the whole writer about 5.1 -> 4.85 M, zstd level 1 4.3 M of it. zstd is the floor: on
the same chunks every setting lies on one curve of CPU against size (level -1 8 % fewer
instructions for 13 % more bytes, -5 21 % for 36 %; LZ4 with a checksum takes the CPU time of
level -3 for the ratio of -5), so level 1 stays. On the loop, ``gap_step`` was most of the rest
(about 24k of 39k instructions a message); with its tracks as plain tuples, 17k of 31k.

The loop then takes what its subscription holds at a hand-over in one go (``take_queued``) and
steps the gap tracker over the batch (``gap_steps``: one copy of the tracks a batch, not one a
message): the loop's side, ``Subscription.receive`` included, 33.3k -> 20.6k instructions a
message on a live recording's stream (callgrind, 3,000 messages in 50 ms batches).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
import time
from pathlib import Path

from lpc_core.gaps import GapState, gap_steps
from services.mcap_log import (
    COMPRESSIONS,
    DEFAULT_COMPRESSION,
    DEFAULT_ZSTD_LEVEL,
    ZSTD_LEVELS,
    BackgroundLogWriter,
    check_zstd_level,
    free_path,
)
from services.runtime import Bus, run_service, service_parser

QUEUE_CAPACITY = 1 << 16  # ~6 s of everything at 90 Hz depth: a slow disk stalls, never drops
# At shutdown, write what is queued or still arriving, until the bus has been quiet this long,
# for at most DRAIN_MAX_S ('lpc up' stops the recorder last and gives each service 2 s).
DRAIN_IDLE_S = 0.25
DRAIN_MAX_S = 1.5
# A backlog is queued for the writer this many messages at a time (about 2 ms of the loop's),
# with the other tasks' turn between: what ``Subscription.receive`` gives a backlogged reader.
SLICE = 512


async def serve(bus: Bus, args: argparse.Namespace) -> None:
    max_bytes = None if args.max_mb is None else int(args.max_mb * 1024 * 1024)
    # Never overwrite a recording: a recorder restarted after a crash (or a second session
    # with the same --out) writes beside the file its predecessor left, not over it.
    out = free_path(Path(args.out))
    # The chunks are compressed and written on a thread of the writer's: on the container's
    # shared loop a chunk's compression and write held the camera, scans and aim for 4-9 ms
    # every five depth frames.
    writer = BackgroundLogWriter(
        out, compression=args.compression, max_bytes=max_bytes, zstd_level=args.zstd_level
    )
    # Not prompt: what other threads publish is written when the loop wakes anyway (a depth
    # frame, at 90 Hz), not at a wake-up of its own (see ``Subscription``).
    sub = bus.subscribe("lpc/**", latest=False, capacity=QUEUE_CAPACITY, decode=False, prompt=False)
    level = f" level {args.zstd_level}" if args.compression == "zstd" else ""
    bus.log("info", f"recording lpc/** to {out} ({args.compression}{level})")
    gaps = GapState()
    # Set per message only where they change (gaps, missing) or at each hand-over (files: the
    # thread rotates), not on every message.
    bus.health.counters.update(files=len(writer.paths), gaps=0, missing=0)
    batch: list[tuple[str, bytes, int]] = []  # taken from the subscription, not yet queued
    try:
        while True:
            # What the loop handed over, taken at once; then what the batch's gap logs added.
            batch = [await sub.receive(), *sub.take_queued()]
            while batch:
                gaps = _record(bus, writer, gaps, batch[:SLICE])
                batch = batch[SLICE:]
                if batch:  # a backlog: the other tasks run between slices
                    await asyncio.sleep(0)
                else:
                    batch = sub.take_queued()
            writer.hand_over()  # the batch the loop handed over is queued: the thread's turn
            bus.health.counters["writer_cpu_ms"] = writer.cpu_ns // 1_000_000
            bus.health.counters["files"] = len(writer.paths)
            if writer.backlog > QUEUE_CAPACITY:  # a slow disk: the subscription's queue fills
                await asyncio.to_thread(writer.drain)
    finally:
        # Cancelled by SIGINT/SIGTERM: keep what is already taken or queued, then finish the file.
        gaps = _record(bus, writer, gaps, batch + sub.take_queued())
        end = time.monotonic() + DRAIN_MAX_S
        with contextlib.suppress(TimeoutError):
            while time.monotonic() < end:
                async with asyncio.timeout(DRAIN_IDLE_S):
                    batch = [await sub.receive()]
                gaps = _record(bus, writer, gaps, batch + sub.take_queued())
        writer.finish()  # on the loop: a second cancellation must not leave the file unfinished
        bus.health.counters["writer_cpu_ms"] = writer.cpu_ns // 1_000_000
        bus.health.counters["files"] = len(writer.paths)
        dropped = sum(s.dropped for s in bus.health.received.values())
        rejected = sum(s.rejected for s in bus.health.received.values())
        files = ", ".join(str(p) for p in writer.paths)
        bus.log(
            "warning" if dropped else "info",
            f"wrote {writer.messages} messages to {files}; dropped {dropped}, rejected {rejected}"
            f"; {gaps.gaps} gaps, {gaps.missing} missing by seq",
        )


def _record(
    bus: Bus,
    writer: BackgroundLogWriter,
    gaps: GapState,
    batch: list[tuple[str, bytes, int]],
) -> GapState:
    """Queue a batch of ``(key, payload, received_ns)`` for the writer; log the gaps it shows."""
    stepped = []
    received = bus.health.received
    for key, payload, received_ns in batch:
        header = writer.write_received(key, payload, received_ns)
        if header is None:
            received[key].rejected += 1
            bus.reject(key, "no readable seq/t_ns header; kept raw on lpc/_rejected/" + key)
        elif not key.startswith("lpc/log/recorder"):
            stepped.append((key, header[0], received_ns))
    counters = bus.health.counters
    counters["written"] += len(batch)
    gaps, found = gap_steps(gaps, stepped)
    if found:
        for gap in found:
            bus.log("warning", gap.describe())
        counters["gaps"] = gaps.gaps
        counters["missing"] = gaps.missing
    return gaps


def main(argv: list[str] | None = None) -> int:
    parser = service_parser("recorder", __doc__ or "")
    parser.add_argument("--out", required=True, metavar="PATH", help="the MCAP file to write")
    parser.add_argument(
        "--compression",
        choices=sorted(COMPRESSIONS),
        default=DEFAULT_COMPRESSION,
        help=f"chunk compression (default {DEFAULT_COMPRESSION}, chosen by measurement)",
    )
    parser.add_argument(
        "--zstd-level",
        type=int,
        default=DEFAULT_ZSTD_LEVEL,
        metavar="N",
        help=f"zstd level, {ZSTD_LEVELS.start}..{ZSTD_LEVELS.stop - 1} (default "
        f"{DEFAULT_ZSTD_LEVEL}: half the CPU of level 3 for 15%% more bytes)",
    )
    parser.add_argument(
        "--max-mb",
        type=float,
        metavar="MB",
        help="start a new file (PATH-001.mcap, ...) past this size (default: never)",
    )
    args = parser.parse_args(argv)
    if args.max_mb is not None and args.max_mb <= 0:
        parser.error("--max-mb must be positive")
    try:
        check_zstd_level(args.zstd_level)
    except ValueError as exc:
        parser.error(f"--zstd-level: {exc}")
    return run_service("recorder", serve, args)


if __name__ == "__main__":
    sys.exit(main())
