"""``lpc replay FILE.mcap``: run the pipeline's step functions in-process on a recording.

The recorded inputs (depth or scans, EMG, prosthesis state) are merged by log time, then file
order, and handed to the same step functions the services run, with the recorded clock (see
``lpc_core.replay``). The reconstructor runs the method its service ran live, as the recorded
``lpc/reconstruction`` names it: ``laser`` on the scans, ``cloud`` on the depth frames
(``--method`` overrides). ``--out`` writes the inputs and the new outputs to an MCAP file (itself
replayable: replaying it reproduces it byte for byte). ``--check`` compares the new outputs
with the recorded ones, topic by topic, prints the first differences and exits 1 if any;
floats within ``--rel-tol`` of each other are equal (another CPU's BLAS rounds differently).

The file is read once: recorded outputs are indexed ``--horizon`` seconds of log time ahead
of the inputs handed to the step functions, which is how the replay knows which frames the
live services handled and when their outputs arrived.

As live, the reconstructions run in worker processes (``--jobs``), and so does the aim step's
search for the objects in view (the supporting plane set aside, the objects clustered and
measured): each starts as soon as its input is read, a few frames ahead of the replay, and the
node's step finishes with the result, in frame order. From recorded depth, the scan lines are
cut as each frame is read and only they go to the workers. The workers run the in-process
steps' own functions, so the outputs are the same bytes with any number of workers.

Exit status: 0 when the replay ran (and the check passed); 1 when the check found differences;
2 when the file cannot be replayed. A file cut short is replayed up to its last good chunk and
the cut is reported (status 0); if nothing before the cut is readable, status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib
import io
import math
import os
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import msgspec

from lpc_core.replay import (
    Node,
    Replay,
    check,
    default_nodes,
    match_fields,
    volatile_fields,
)
from schemas import BadMessage, decode
from services.cli._replay_ahead import ReadAhead, Workers
from services.mcap_log import (
    COMPRESSIONS,
    DEFAULT_COMPRESSION,
    Cut,
    LoggedMessage,
    LogWriter,
    McapLog,
    McapLogError,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE.mcap", help="the recording to replay")
    parser.add_argument("--out", metavar="OUT.mcap", help="write the inputs and new outputs here")
    parser.add_argument(
        "--check",
        action="store_true",
        help="compare the new outputs with the recorded ones; exit 1 on any difference",
    )
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument(
        "--speed", type=float, metavar="X", help="pace the replay at X times the recorded rate"
    )
    pace.add_argument("--fast", action="store_true", help="as fast as possible (the default)")
    parser.add_argument(
        "--all-frames",
        action="store_true",
        help="handle every recorded frame, not only those the live services handled",
    )
    parser.add_argument(
        "--compression",
        choices=sorted(COMPRESSIONS),
        default=DEFAULT_COMPRESSION,
        help=f"compression of --out (default {DEFAULT_COMPRESSION})",
    )
    parser.add_argument(
        "--without",
        action="append",
        default=[],
        metavar="KEY",
        help="act as if the recording lacked this topic (repeatable); e.g. --without "
        "lpc/camera/depth replays from the recorded scans",
    )
    parser.add_argument(
        "--from",
        dest="start",
        type=float,
        default=0.0,
        metavar="S",
        help="skip the inputs of the first S seconds (log time) of the recording",
    )
    parser.add_argument(
        "--until",
        type=float,
        metavar="S",
        help="skip the inputs after S seconds (log time) from the start of the recording",
    )
    parser.add_argument(
        "--horizon",
        type=float,
        default=2.0,
        metavar="S",
        help="how far ahead, in log time, an input's recorded outputs may come (default 2 s)",
    )
    parser.add_argument(
        "--profile",
        metavar="FILE",
        help="the user profile the controller ran with (default: the simulated user's "
        "calibration when the recorded EMG is simulated, as 'lpc up' runs it; else the "
        "default profile)",
    )
    parser.add_argument(
        "--method",
        choices=("laser", "cloud"),
        help="the reconstructor's method (default: the one the recorded lpc/reconstruction "
        "names; laser if none is recorded)",
    )
    parser.add_argument(
        "--camera-fixed",
        action="store_true",
        help="the controller ran with --camera-fixed (implied for a simulated user)",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=DEFAULT_JOBS,
        metavar="N",
        help="worker processes that reconstruct (and find the objects in view) ahead of the "
        f"replay; 0 does it all in this process (default {DEFAULT_JOBS}: the CPUs)",
    )
    parser.add_argument(
        "--rel-tol",
        type=_rel_tol,
        default=DEFAULT_REL_TOL,
        metavar="R",
        help="with --check, floats that differ by at most R of the larger are equal "
        f"(default {DEFAULT_REL_TOL:g}: round-off from another CPU's or BLAS's kernels, far "
        "below any change of the method; 0 asks for bit-identical outputs)",
    )
    parser.add_argument(
        "--max-differences", type=int, default=20, metavar="N", help="print at most N (20)"
    )


# Another machine's BLAS kernel moved recorded widths by up to ~2e-14 relative; a change of
# the method moves them by 1e-4 and more.
DEFAULT_REL_TOL = 1e-9


def _rel_tol(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and 0.0 <= value < 1.0):
        raise argparse.ArgumentTypeError(f"--rel-tol must be in [0, 1), not {text}")
    return value


# One per CPU: the replay's own loop mostly waits on them once their share is the larger.
DEFAULT_JOBS = max(1, os.cpu_count() or 1)


def run(args: argparse.Namespace) -> int:
    if args.speed is not None and not args.speed > 0:
        return _fail("--speed must be positive")
    if not args.horizon >= 0:
        return _fail("--horizon must be >= 0")
    if not args.start >= 0:
        return _fail("--from must be >= 0")
    if args.until is not None and not args.until > args.start:
        return _fail("--until must be after --from")
    if args.jobs < 0:
        return _fail("--jobs must be >= 0")
    path = Path(args.file)
    try:
        log = McapLog(path)
    except McapLogError as exc:
        return _fail(str(exc))
    with log:
        return _replay(args, path, log)


def _fail(text: str) -> int:
    print(f"lpc replay: error: {text}", file=sys.stderr)
    return 2


def _timed(nodes: tuple[Node, ...], spent: Counter[str]) -> tuple[Node, ...]:
    """The nodes with their steps timed (the shell's clock, never the step's)."""

    def wrap(name: str, step: Any) -> Any:
        def timed(state: Any, message: Any, now_ns: int) -> Any:
            start = time.perf_counter()
            try:
                return step(state, message, now_ns)
            finally:
                spent[name] += time.perf_counter() - start

        return timed

    return tuple(
        dataclasses.replace(
            n, routes=tuple(dataclasses.replace(r, step=wrap(n.name, r.step)) for r in n.routes)
        )
        for n in nodes
    )


# The services whose step functions replay runs; each defines parser() and initial_state(args).
FLAGGED = ("scans", "reconstructor", "aim", "controller")


def _recorded_flags(log: McapLog) -> dict[str, LoggedMessage]:
    """Per service of the pipeline, its first recorded health message: it holds the service's
    flags (``argv``). A replay's own output keeps the ones it used."""
    wanted = {f"lpc/health/{name}" for name in FLAGGED} & log.topics()
    found: dict[str, LoggedMessage] = {}
    for m in log.messages(sorted(wanted), ordered=False) if wanted else ():
        name = m.key.rsplit("/", 1)[1]
        if name not in found:
            found[name] = m
        if len(found) == len(wanted):
            break
    return found


def _states_from_flags(
    args: argparse.Namespace, flags: dict[str, LoggedMessage]
) -> tuple[dict[str, Any], list[str]]:
    """Each step function's initial state, built by its service's own code from the recorded
    flags, and what was used. The controller's flags give way to ``--profile`` and
    ``--camera-fixed``; flags that do not apply here (a profile file this machine lacks)
    leave that service on the defaults, and say so."""
    states: dict[str, Any] = {}
    notes: list[str] = []
    for name in FLAGGED:
        m = flags.get(name)
        if m is None:
            continue
        if name == "controller" and (args.profile or args.camera_fixed):
            notes.append(f"{name}: --profile/--camera-fixed given, its recorded flags not used")
            continue
        try:
            argv = list(decode(m.key, m.payload).argv)
        except BadMessage as exc:
            notes.append(f"{name}: its recorded health does not decode ({exc.reason})")
            continue
        module = importlib.import_module(f"services.{name}")
        errors = io.StringIO()
        try:
            with contextlib.redirect_stderr(errors):
                states[name] = module.initial_state(module.parser().parse_args(argv))
        except (SystemExit, ValueError) as exc:
            why = str(exc) if isinstance(exc, ValueError) else errors.getvalue().strip()
            notes.append(f"{name}: the recorded flags {argv} do not apply here ({why}); defaults")
            continue
        shown = " ".join(a for a in argv if a) or "no flags"
        notes.append(f"{name}: the recorded flags ({shown})")
    return states, notes


def _controller_params(args: argparse.Namespace, log: McapLog) -> tuple[Any, str]:
    """The controller's parameters as its service had them live, and how they were chosen,
    when its flags were not recorded."""
    from lpc_core.control.controller import ControllerParams
    from lpc_core.control.emg import EmgProfile
    from lpc_core.sim.emg_sim import sim_user_params
    from services.drivers.emg import load_emg_profile

    first = next(log.messages(["lpc/emg"], decode=True, ordered=False), None)
    if args.profile is None and first is not None and getattr(first.message, "source", "") == "sim":
        return (
            sim_user_params(),
            "simulated user's calibration, camera fixed (the EMG is simulated: as 'lpc up')",
        )
    profile = load_emg_profile(args.profile)
    how = f"profile {args.profile}" if args.profile else "the default profile"
    if profile is None:
        how = "no EMG profile: the default calibration"
    camera = "camera fixed" if args.camera_fixed else "camera on the hand"
    params = ControllerParams(profile=profile or EmgProfile(), camera_on_hand=not args.camera_fixed)
    return params, f"{how}, {camera}"


class _MethodOf(msgspec.Struct):
    """Just enough of a reconstruction to name its method."""

    method: str = "laser"


_METHOD_DECODER = msgspec.msgpack.Decoder(_MethodOf)


def _reconstructor_method(args: argparse.Namespace, log: McapLog) -> tuple[str, str]:
    """The reconstructor's method as its service ran it live, and how it was chosen."""
    if args.method is not None:
        return args.method, "--method"
    first = next(log.messages(["lpc/reconstruction"], ordered=False), None)
    if first is None:
        return "laser", "the default: no lpc/reconstruction recorded"
    try:
        method = _METHOD_DECODER.decode(first.payload).method
    except (msgspec.DecodeError, msgspec.ValidationError):
        return "laser", "the default: the first lpc/reconstruction does not decode"
    if method not in ("laser", "cloud"):
        raise ValueError(f"the recorded lpc/reconstruction names an unknown method {method!r}")
    return method, "the recorded lpc/reconstruction's"


def _replay(args: argparse.Namespace, path: Path, log: McapLog) -> int:
    spent: Counter[str] = Counter()
    flags = _recorded_flags(log)
    states, flag_notes = _states_from_flags(args, flags)
    try:
        if "controller" in states:
            controller_params, how = states["controller"].params, "as its recorded flags say"
        else:
            controller_params, how = _controller_params(args, log)
        method, method_how = _reconstructor_method(args, log)
    except ValueError as exc:
        return _fail(str(exc))
    workers = Workers(args.jobs) if args.jobs > 0 else None
    nodes = default_nodes(controller_params, reconstructor_method=method, states=states)
    if workers is not None:
        nodes = workers.wrap(nodes, method)
    nodes = _timed(nodes, spent)
    frames: dict[str, dict[int, tuple[int, int]]] = defaultdict(dict)
    keys = log.topics() - set(args.without)
    replay = Replay(nodes, keys, frames, all_frames=args.all_frames)
    if not replay.inputs:
        if log.cut is not None:
            return _fail(f"{path}: {log.cut.describe()}; no replay input before the cut")
        wanted = sorted({r.key for n in nodes for r in n.routes if not r.key.startswith("<")})
        return _fail(f"{path} holds none of the replay inputs ({', '.join(wanted)})")
    try:
        return _run(
            args, path, log, replay, workers, spent, (how, method, method_how), (flags, flag_notes)
        )
    finally:
        if workers is not None:
            workers.close()


def _run(
    args: argparse.Namespace,
    path: Path,
    log: McapLog,
    replay: Replay,
    workers: Workers | None,
    spent: Counter[str],
    hows: tuple[str, str, str],
    recorded: tuple[dict[str, LoggedMessage], list[str]],
) -> int:
    how, method, method_how = hows
    flags, flag_notes = recorded
    frames = replay.recorded
    reader = ReadAhead(log, replay, frames, args, keep_payload=bool(args.out) or bool(workers))
    inputs = reader.inputs() if workers is None else workers.ahead(reader.inputs(), replay)
    out_tmp = Path(f"{args.out}.partial") if args.out else None
    writer = LogWriter(out_tmp, compression=args.compression) if out_tmp else None
    if writer is not None:
        # Every output topic, even one that stays empty: replaying the output file then gates
        # the same nodes (a node whose recorded topic is empty handles no frame).
        for key in sorted(replay.outputs):
            writer.declare(key)
        # The flags used, so that replaying the output runs the same parameters.
        for m in flags.values():
            writer.write_raw(
                m.key,
                m.payload,
                log_time=m.log_time,
                publish_time=m.publish_time,
                sequence=m.sequence,
            )
    replayed: dict[str, list[Any]] = defaultdict(list)
    counts: Counter[str] = Counter()
    first_ns = last_ns = 0
    started = time.perf_counter()
    try:
        for event in replay.run(inputs):
            first_ns = first_ns or event.log_time
            last_ns = event.log_time
            source = event.source
            if source is not None:
                counts["<inputs>"] += 1
                if writer is not None:
                    writer.write_raw(
                        event.key,
                        source.payload,
                        log_time=source.log_time,
                        publish_time=event.message.t_ns,
                        sequence=event.message.seq,
                    )
                continue
            counts[event.key] += 1
            if writer is not None:
                writer.write(event.key, event.message, event.log_time)
            if args.check:
                replayed[event.key].append(event.message)
    except KeyboardInterrupt:
        if out_tmp is not None:
            print(f"lpc replay: interrupted; the part replayed is in {out_tmp}", file=sys.stderr)
        raise
    finally:
        if writer is not None:
            writer.finish()
    elapsed = time.perf_counter() - started
    if out_tmp is not None:
        os.replace(out_tmp, args.out)
    _report_run(args, path, replay, reader, counts, (last_ns - first_ns) / 1e9, elapsed)
    for note in flag_notes:
        print(f"  {note}")
    print(f"  controller: {how}")
    where = f"{args.jobs} worker processes" if workers else "in this process"
    print(f"  reconstructor: {method} ({method_how}), {where}")
    steps = ", ".join(
        f"{name} {spent[name]:.3f} s" for name in sorted(spent, key=spent.get, reverse=True)
    )
    print(
        f"  time in steps: {steps}; the rest (read, decode, write) "
        f"{elapsed - sum(spent.values()):.3f} s"
    )

    cut = log.cut
    if cut is not None:
        if counts["<inputs>"] == 0:
            return _fail(f"{path}: {cut.describe()}; nothing before the cut to replay")
        print(f"warning: {path}: {cut.describe()}; replayed the readable part", file=sys.stderr)
    if not args.check:
        return 0
    return _report_check(args, replay, reader, replayed, cut)


def _report_run(
    args: argparse.Namespace,
    path: Path,
    replay: Replay,
    reader: ReadAhead,
    counts: Counter[str],
    span_s: float,
    elapsed_s: float,
) -> None:
    inputs = counts["<inputs>"]
    outputs = sum(counts.values()) - inputs
    speed = f"{span_s / elapsed_s:.1f}x real time" if elapsed_s > 0 else "-"
    print(
        f"replayed {span_s:.3f} s of {path} in {elapsed_s:.3f} s ({speed}): "
        f"{inputs} inputs ({', '.join(sorted(replay.inputs))}), {outputs} outputs"
    )
    for key in sorted(replay.outputs):
        print(f"  {key:<24} {counts[key]:>7}")
    print(
        f"  nodes: {', '.join(n.name for n in replay.plan.nodes)}; "
        f"inputs the live services skipped: {dict(replay.gated) or 0}"
    )
    for name, n in replay.errors.items():
        print(f"  {name} refused {n} messages; first: {replay.first_error[name]}")
    for key, n in reader.undecodable.items():
        print(f"  skipped {n} undecodable {key} inputs")
    if reader.late:
        print(
            f"warning: {reader.late} recorded outputs came more than {args.horizon} s after "
            "their input; replay again with a larger --horizon",
            file=sys.stderr,
        )
    if args.out:
        print(f"wrote {args.out}")


def _report_check(
    args: argparse.Namespace,
    replay: Replay,
    reader: ReadAhead,
    replayed: dict[str, list[Any]],
    cut: Cut | None,
) -> int:
    compared = sorted(replay.outputs & replay.recorded_keys)
    if not compared:
        print(
            f"check: {args.file} holds none of the outputs "
            f"({', '.join(sorted(replay.outputs))}); nothing to compare"
        )
        return 1
    recorded = {
        k: [
            m for t, _, m in sorted(reader.recorded[k], key=lambda r: r[:2]) if t >= reader.begin_ns
        ]
        for k in compared
    }
    result = check(
        recorded,
        {k: replayed.get(k, []) for k in compared},
        volatile=volatile_fields(replay.plan.nodes),
        offered=replay.offered,
        match_by=match_fields(replay.plan.nodes),
        cut=cut is not None or args.until is not None or args.start > 0,
        all_frames=args.all_frames,
        rel_tol=args.rel_tol,
        limit=args.max_differences,
    )
    for key, n in reader.bad_recorded.items():
        print(f"check: {n} recorded {key} messages do not decode; not compared")
    summary = ", ".join(
        f"{k} {result.differing[k]}/{result.compared[k]}"
        if result.differing[k]
        else f"{k} {result.compared[k]}"
        for k in compared
    )
    missing = sorted(replay.outputs - set(compared))
    if missing:
        summary += f"; not in the recording: {', '.join(missing)}"
    if result.ok:
        print(f"check: no differences (compared {summary})")
        return 0
    print(
        f"check: {result.total} differences (differing/compared {summary}); "
        f"the first {len(result.differences)}:"
    )
    for diff in result.differences:
        print(f"  {diff.describe()}")
    return 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="lpc replay", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
