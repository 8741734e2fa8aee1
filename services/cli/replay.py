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
import functools
import importlib
import io
import math
import multiprocessing
import os
import sys
import time
from collections import Counter, defaultdict, deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec

from lpc_core.control import aim
from lpc_core.perception.pipeline import ScansState, scans_step
from lpc_core.perception.reconstructor import INPUT_TOPICS, reconstruct, release_step
from lpc_core.replay import (
    Node,
    Recorded,
    Replay,
    check,
    default_nodes,
    frame_id,
    match_fields,
    volatile_fields,
)
from schemas import BadMessage, decode, encode
from services.children import die_with_parent
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
    workers = _Workers(args.jobs) if args.jobs > 0 else None
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
    workers: _Workers | None,
    spent: Counter[str],
    hows: tuple[str, str, str],
    recorded: tuple[dict[str, LoggedMessage], list[str]],
) -> int:
    how, method, method_how = hows
    flags, flag_notes = recorded
    frames = replay.recorded
    reader = _ReadAhead(log, replay, frames, args, keep_payload=bool(args.out) or bool(workers))
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
    reader: _ReadAhead,
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


@dataclass(frozen=True)
class _Task:
    """A node's per-frame work that workers can do: ``compute(message)`` depends on the frame
    alone; ``finish(state, message, result)`` is the rest of the node's step, run in order."""

    key: str
    compute: Callable[[Any], Any]
    finish: Callable[[Any, Any, Any], Any]


DEPTH, SCANS = "lpc/camera/depth", "lpc/scans"


def _cut(state: ScansState, frame: Any) -> Any:
    """The scans node's step on one depth frame, from its initial parameters, but for ``seq``
    (the node's own count, given in order by ``_number``)."""
    return scans_step(ScansState(params=state.params), frame, 0)[1]


def _number(state: ScansState, frame: Any, scans: Any) -> tuple[ScansState, Any]:
    """The rest of the scans step: the scan lines cut by a worker get the node's next seq."""
    del frame
    state.seq += 1
    return state, msgspec.structs.replace(scans, seq=state.seq)


def _tasks(nodes: Iterable[Node], method: str) -> dict[str, _Task]:
    """The scan lines (the scans), the reconstruction (the reconstructor) and the objects in
    view without the supporting plane (the aim step), bound to each node's initial parameters."""
    tasks = {}
    for n in nodes:
        if n.name == "scans":
            tasks[n.name] = _Task(DEPTH, functools.partial(_cut, n.init()), _number)
        elif n.name == "reconstructor":
            tasks[n.name] = _Task(
                INPUT_TOPICS[method],
                functools.partial(reconstruct, n.init()),
                lambda state, message, result: release_step(state, result),
            )
        elif n.name == "aim":
            tasks[n.name] = _Task(
                SCANS,
                functools.partial(aim.frame_objects, params=n.init().params),
                aim.cue_step,
            )
    return tasks


class _Workers:
    """Worker processes for the nodes' per-frame work (``_tasks``).

    ``ahead`` reads the replay's inputs until ``depth`` frames are under way, starting each
    node's work on a frame as its input is read (unless the live service skipped the frame),
    in batches of ``batch`` frames: each hand-over to the pool's threads costs the replay a
    switch of the interpreter lock (~1 ms), so one per frame ate most of the gain. The
    wrapped step then finishes with its frame's result, or runs whole in-process on a frame
    that was not started (one whose recorded output arrived later than the read-ahead).

    When the replay cuts the scan lines from recorded depth, ``ahead`` cuts them as it reads
    the frame (the scans task, ~0.1 ms) and hands the workers the lines (~4 KB), not the
    frame (200 KB: piping 90 frames a second cost more than cutting them), so the tasks on
    ``lpc/scans`` are under way before the scans step has numbered the lines. Before, a depth
    replay did every frame's work in this process: 5.2x real time on 2 cores.
    """

    def __init__(self, jobs: int, batch: int = 8) -> None:
        self.batch = batch
        self.depth = batch * (jobs + 1)
        # Forked workers start at once with every module already imported; elsewhere the
        # platform's default start method.
        methods = multiprocessing.get_all_start_methods()
        context = multiprocessing.get_context("fork" if "fork" in methods else None)
        self.pool = ProcessPoolExecutor(
            max_workers=jobs, mp_context=context, initializer=die_with_parent
        )
        self.tasks: dict[str, _Task] = {}
        # (node, frame) -> the result when it is done, and whether it was made from scan lines
        # cut here (whose seq the scans step has not given yet).
        self.started: dict[tuple[str, int], tuple[Callable[[], Any], bool]] = {}

    def wrap(self, nodes: Iterable[Node], method: str) -> tuple[Node, ...]:
        """The nodes, each task's route finishing with the workers' results."""
        nodes = tuple(nodes)
        self.tasks = _tasks(nodes, method)

        def pooled(name: str, task: _Task, step: Any) -> Any:
            def step_(state: Any, message: Any, now_ns: int) -> Any:
                started = self.started.pop((name, frame_id(message)), None)  # type: ignore[arg-type]
                if started is None:
                    return step(state, message, now_ns)
                result_of, from_cut = started
                result = result_of()
                if isinstance(result, ValueError):
                    raise result
                if from_cut and isinstance(result, msgspec.Struct):
                    # A reconstruction carries its scans' seq, which the cut lines lack.
                    result = msgspec.structs.replace(result, seq=message.seq)
                return task.finish(state, message, result)

            return step_

        def wrapped(n: Node) -> Node:
            task = self.tasks.get(n.name)
            if task is None:
                return n
            routes = tuple(
                dataclasses.replace(r, step=pooled(n.name, task, r.step))
                if r.key == task.key
                else r
                for r in n.routes
            )
            return dataclasses.replace(n, routes=routes)

        return tuple(wrapped(n) for n in nodes)

    def ahead(self, inputs: Iterator[Recorded], replay: Replay) -> Iterator[Recorded]:
        # Each task's topic and route. A task on scan lines cut here from recorded depth is
        # looked at only once the scans node has taken the frame (its gate passed).
        cut = "scans" in self.tasks and DEPTH in replay.inputs
        routes: list[tuple[str, str, Node, Any]] = [
            (node.name, route.key, node, route)
            for node in replay.plan.nodes
            if (task := self.tasks.get(node.name)) is not None
            for route in node.routes
            if route.key == task.key
            and (route.key in replay.inputs or (cut and route.key == SCANS))
        ]

        def names(key: str, message: Any, frame: int) -> list[str]:
            return [
                name
                for name, key_, node, route in routes
                if key_ == key
                and not replay.skips(node, route, message)
                and (name, frame) not in self.started
            ]

        ready: deque[tuple[Recorded, bool]] = deque()
        batch: list[tuple[int, str, bytes, tuple[str, ...], bool]] = []
        running = 0
        for item in inputs:
            frame = frame_id(item.message)
            started = False
            if frame is not None:
                here = names(item.key, item.message, frame)
                if "scans" in here:
                    here.remove("scans")
                    lines = _attempt(self.tasks["scans"].compute, item.message)
                    self.started[("scans", frame)] = (lambda lines=lines: lines, False)
                    on_lines = [] if isinstance(lines, ValueError) else names(SCANS, lines, frame)
                    if on_lines:
                        batch.append((frame, SCANS, encode(lines), tuple(on_lines), True))
                        started = True
                if here:
                    batch.append((frame, item.key, item.payload, tuple(here), False))
                    started = True
            if started:
                running += 1
                if len(batch) >= self.batch:
                    self._submit(batch)
            ready.append((item, started))
            while running >= self.depth:
                head, job = ready[0]
                if job and any(f == frame_id(head.message) for f, *_ in batch):
                    self._submit(batch)  # the next frame's batch must be under way
                ready.popleft()
                running -= job
                yield head
        self._submit(batch)
        for item, _ in ready:
            yield item

    def _submit(self, batch: list[tuple[int, str, bytes, tuple[str, ...], bool]]) -> None:
        if batch:
            computes = {name: task.compute for name, task in self.tasks.items()}
            work = [(key, payload, names) for _, key, payload, names, _ in batch]
            future = self.pool.submit(_work, computes, work)
            for index, (frame, _, _, names, from_cut) in enumerate(batch):
                for name in names:
                    result_of = functools.partial(_result, future, index, name)
                    self.started[(name, frame)] = (result_of, from_cut)
            batch.clear()

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


def _result(future: Future[Any], index: int, name: str) -> Any:
    return future.result()[index][name]


def _work(
    computes: dict[str, Callable[[Any], Any]], batch: list[tuple[str, bytes, tuple[str, ...]]]
) -> list[dict[str, Any]]:
    """A worker's batch: per frame, each named node's result, or the ``ValueError`` it raised
    (the replay raises it in that node's step, which counts it)."""
    results: list[dict[str, Any]] = []
    for key, payload, names in batch:
        try:
            message = decode(key, payload)
        except BadMessage as exc:
            results.append(dict.fromkeys(names, exc))
            continue
        results.append({name: _attempt(computes[name], message) for name in names})
    return results


def _attempt(compute: Callable[[Any], Any], message: Any) -> Any:
    """``compute(message)``, or the ``ValueError`` it raised."""
    try:
        return compute(message)
    except ValueError as exc:
        return exc


class _FrameOf(msgspec.Struct):
    """Just enough of an output message to name its frame."""

    frame_seq: int | None = None


_FRAME_DECODER = msgspec.msgpack.Decoder(_FrameOf)


class _ReadAhead:
    """One pass over the log. Recorded outputs are indexed ``horizon`` seconds of log time
    before the inputs they follow are handed out, so the replay knows, when it reaches a
    frame, whether the live service handled it and when its output arrived; the file is read
    and decompressed once."""

    def __init__(
        self,
        log: McapLog,
        replay: Replay,
        frames: Any,
        args: argparse.Namespace,
        *,
        keep_payload: bool,
    ) -> None:
        self.log = log
        self.replay = replay
        self.frames = frames
        self.check = args.check
        self.speed = args.speed
        self.horizon_ns = int(args.horizon * 1e9)
        self.start_ns = int(args.start * 1e9)
        self.until_ns = None if args.until is None else int(args.until * 1e9)
        self.keep_payload = keep_payload
        self.recorded: dict[str, list[tuple[int, int, Any]]] = defaultdict(list)
        self.bad_recorded: Counter[str] = Counter()
        self.undecodable: Counter[str] = Counter()
        self.late = 0
        self.begin_ns = 0  # log time of the first input replayed
        self._start: tuple[float, int] | None = None

    def inputs(self) -> Iterator[Recorded]:
        inputs, outputs = self.replay.inputs, self.replay.outputs
        pending: deque[LoggedMessage] = deque()
        first_ns = begin_ns = end_ns = None
        for m in self.log.messages():
            if first_ns is None and m.key in inputs:
                first_ns = m.log_time
                begin_ns = self.begin_ns = first_ns + self.start_ns
                if self.until_ns is not None:
                    end_ns = first_ns + self.until_ns
            if end_ns is not None and m.log_time > end_ns + self.horizon_ns:
                break
            if m.key in outputs:
                self._index(m)
            elif (
                m.key in inputs
                and begin_ns is not None
                and m.log_time >= begin_ns
                and (end_ns is None or m.log_time <= end_ns)
            ):
                pending.append(m)
            while pending and pending[0].log_time + self.horizon_ns <= m.log_time:
                item = self._input(pending.popleft())
                if item is not None:
                    yield item
        while pending:
            item = self._input(pending.popleft())
            if item is not None:
                yield item

    def _index(self, m: LoggedMessage) -> None:
        try:
            frame = _FRAME_DECODER.decode(m.payload).frame_seq
        except (msgspec.DecodeError, msgspec.ValidationError):
            frame = None
        if frame is not None and frame not in self.frames[m.key]:
            self.frames[m.key][frame] = (m.log_time, m.order)
            if frame in self.replay.offered.get(m.key, ()):
                self.late += 1  # its input was already handled, or skipped
        if self.check:
            try:
                self.recorded[m.key].append((m.log_time, m.order, decode(m.key, m.payload)))
            except (BadMessage, KeyError):
                self.bad_recorded[m.key] += 1

    def _input(self, m: LoggedMessage) -> Recorded | None:
        try:
            message = decode(m.key, m.payload)
        except (BadMessage, KeyError):
            self.undecodable[m.key] += 1
            return None
        if self.speed is not None:
            self._pace(m.log_time)
        payload = m.payload if self.keep_payload else b""
        return Recorded(m.key, message, m.log_time, m.order, payload)

    def _pace(self, log_time: int) -> None:
        # Recording time and wall time kept apart: sleep until this input is due.
        if self._start is None:
            self._start = (time.perf_counter(), log_time)
        wall0, log0 = self._start
        delay = wall0 + (log_time - log0) / 1e9 / self.speed - time.perf_counter()
        if delay > 0:
            time.sleep(delay)


def _report_check(
    args: argparse.Namespace,
    replay: Replay,
    reader: _ReadAhead,
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
