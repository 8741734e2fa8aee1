"""What ``lpc replay`` reads and computes ahead of the step functions.

:class:`ReadAhead` is the one pass over the log: it indexes the recorded outputs ``--horizon``
seconds of log time before it hands out the inputs they follow, so the replay knows which
frames the live services handled. :class:`Workers` runs the nodes' per-frame work (:func:`tasks`:
the scan lines, the reconstruction, the objects in view) in worker processes a few frames
ahead, and wraps the nodes so that each step finishes with its frame's result, in order.
Neither changes what the steps compute: the outputs are the same bytes with any number of
workers.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import multiprocessing
import time
from collections import Counter, defaultdict, deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import msgspec

from lpc_core.control import aim
from lpc_core.perception.pipeline import ScansState, scans_step
from lpc_core.perception.reconstructor import INPUT_TOPICS, reconstruct, release_step
from lpc_core.replay import Node, Recorded, Replay, frame_id
from schemas import BadMessage, decode, encode
from services.children import die_with_parent
from services.mcap_log import LoggedMessage, McapLog


@dataclass(frozen=True)
class Task:
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


def tasks(nodes: Iterable[Node], method: str) -> dict[str, Task]:
    """The scan lines (the scans), the reconstruction (the reconstructor) and the objects in
    view without the supporting plane (the aim step), bound to each node's initial parameters."""
    tasks = {}
    for n in nodes:
        if n.name == "scans":
            tasks[n.name] = Task(DEPTH, functools.partial(_cut, n.init()), _number)
        elif n.name == "reconstructor":
            tasks[n.name] = Task(
                INPUT_TOPICS[method],
                functools.partial(reconstruct, n.init()),
                lambda state, message, result: release_step(state, result),
            )
        elif n.name == "aim":
            tasks[n.name] = Task(
                SCANS,
                functools.partial(aim.frame_objects, params=n.init().params),
                aim.cue_step,
            )
    return tasks


class Workers:
    """Worker processes for the nodes' per-frame work (``tasks``).

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
        self.tasks: dict[str, Task] = {}
        # (node, frame) -> the result when it is done, and whether it was made from scan lines
        # cut here (whose seq the scans step has not given yet).
        self.started: dict[tuple[str, int], tuple[Callable[[], Any], bool]] = {}

    def wrap(self, nodes: Iterable[Node], method: str) -> tuple[Node, ...]:
        """The nodes, each task's route finishing with the workers' results."""
        nodes = tuple(nodes)
        self.tasks = tasks(nodes, method)

        def pooled(name: str, task: Task, step: Any) -> Any:
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


class ReadAhead:
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
