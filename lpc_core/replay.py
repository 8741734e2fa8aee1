"""Deterministic replay, the pure part: recorded inputs in, the step functions' outputs out.

A replay runs the services' step functions in one process, on the inputs of a recording
(depth or scans, EMG, prosthesis state), merged by ``(log_time, file order)``. The recorded
clock drives it: a step's ``now_ns`` is the log time of the message it handles. The table
``NODES`` says which step handles which input topic, service by service, in data-flow order.

Two rules make a replay of a live recording reproduce what happened live, not an idealised run:

- **Gating.** A live service that keeps only the newest sample skips the frames it was too slow
  for. When the recording holds a node's output topic, the node handles only the frames whose
  output was recorded (``Route.gated``); frames are named by ``frame_seq`` (a depth frame by its
  ``seq``).
- **Delivery at the recorded time.** An output whose frame was recorded reaches the next node
  at the recorded ``(log_time, file order)`` of that recorded output, so the reconstruction of
  frame N reaches the aim step as late as it did live. Other outputs are delivered at once,
  right after the message that caused them.

With neither recorded (a recording of inputs only), every frame is handled and every output is
delivered at once. A replay's own output file records its outputs at their delivery times, so
replaying it again reproduces it byte for byte.

Nothing here reads a file or a clock: ``services/cli/replay.py`` is the shell around it.
"""

from __future__ import annotations

import dataclasses
import heapq
import itertools
import math
from collections import Counter
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from schemas import TOPICS, DepthFrame

Step = Callable[[Any, Any, int], tuple[Any, Any]]
Stamp = tuple[int, int, int]  # (log_time, file order, sub-order of derived messages)
TICK = "<tick>"

KEY_OF_TYPE: dict[type, str] = {t.type: t.key for t in TOPICS if not t.wildcard}


@dataclass(frozen=True)
class Route:
    """One input topic of a node and the step that handles it."""

    key: str
    step: Step
    gated: bool = False  # handle only the frames whose output was recorded (see module doc)
    # Fed back from a node later in the data flow (the controller's state to the aim step):
    # such a route alone does not enable its node.
    feedback: bool = False


@dataclass(frozen=True)
class Tick:
    """A node's timer: ``make(t_ns)`` builds the tick message, every ``period_ns``."""

    period_ns: int
    make: Callable[[int], Any]


@dataclass(frozen=True)
class Node:
    """A service's logic as replay runs it.

    ``gate`` is the output topic whose recorded frames select the gated inputs. ``volatile``
    names the fields a check must not compare: counters that depend on when a service started,
    and timings measured live.
    """

    name: str
    init: Callable[[], Any]
    routes: tuple[Route, ...]
    outputs: tuple[str, ...]
    gate: str | None = None
    volatile: frozenset[str] = frozenset({"seq"})
    errors: tuple[type[Exception], ...] = (ValueError,)
    tick: Tick | None = None
    match_by: str | None = None  # how a check pairs its outputs that carry no frame id


@dataclass(frozen=True)
class Recorded:
    """One recorded message offered to the replay."""

    key: str
    message: Any
    log_time: int
    order: int
    payload: bytes = b""


@dataclass(frozen=True)
class Event:
    """What the replay emits, in order: a recorded input as it is handled, or an output at its
    delivery time. ``source`` is the ``Recorded`` input, ``None`` for an output."""

    log_time: int
    key: str
    message: Any
    source: Recorded | None = None


def frame_id(message: Any) -> int | None:
    """The depth frame a message belongs to: ``frame_seq``, or a depth frame's own ``seq``."""
    if isinstance(message, DepthFrame):
        return message.seq
    value = getattr(message, "frame_seq", None)
    return value if isinstance(value, int) else None


# --------------------------------------------------------------------------- the engine


@dataclass
class Plan:
    """Which nodes run on a recording, which recorded topics feed them, what they produce."""

    nodes: tuple[Node, ...]
    inputs: frozenset[str]
    outputs: frozenset[str]


def plan(nodes: Sequence[Node], recorded_keys: Collection[str]) -> Plan:
    """Enable, in data-flow order, each node with an input that is recorded or produced by an
    enabled node. A recorded topic is an input unless an enabled node produces it (so with a
    depth topic, the recorded scans are outputs to compare; without, they are the input)."""
    produced: set[str] = set()
    enabled: list[Node] = []
    for node in nodes:
        if any(r.key in produced or r.key in recorded_keys for r in node.routes if not r.feedback):
            enabled.append(node)
            produced.update(node.outputs)
    inputs = {
        r.key
        for node in enabled
        for r in node.routes
        if r.key in recorded_keys and r.key not in produced
    }
    return Plan(tuple(enabled), frozenset(inputs), frozenset(produced))


class Replay:
    """Run ``nodes`` on recorded inputs.

    ``recorded`` maps an output topic to the recorded frames of it: frame id -> the
    ``(log_time, file order)`` at which it was recorded. It may be filled while the replay
    runs, as long as each frame is in before the replay reaches its log time (the shell reads
    ahead). Gating applies to a node whose gate topic is among ``recorded_keys``;
    ``all_frames`` turns it off.
    After ``run``, ``errors`` counts the messages each node refused (its step raised one of
    the node's ``errors``), ``gated`` those it skipped, and ``offered`` holds, per output
    topic, the frames its producer was offered (a check ignores recorded outputs of frames
    the recording does not hold the input of).
    """

    def __init__(
        self,
        nodes: Sequence[Node],
        recorded_keys: Collection[str],
        recorded: Mapping[str, Mapping[int, tuple[int, int]]] | None = None,
        *,
        all_frames: bool = False,
    ) -> None:
        self.plan = plan(nodes, recorded_keys)
        self.recorded_keys = frozenset(recorded_keys)
        self.recorded = recorded if recorded is not None else {}
        self.all_frames = all_frames
        self.states: dict[str, Any] = {n.name: n.init() for n in self.plan.nodes}
        self.errors: Counter[str] = Counter()
        self.first_error: dict[str, str] = {}
        self.gated: Counter[str] = Counter()
        self.offered: dict[str, set[int]] = {}
        self._routes: dict[str, list[tuple[Node, Route]]] = {}
        for node in self.plan.nodes:
            for route in node.routes:
                if route.key in self.plan.inputs or route.key in self.plan.outputs:
                    self._routes.setdefault(route.key, []).append((node, route))
        self._heap: list[tuple[Stamp, int, str, Any]] = []
        self._counter = itertools.count(1)

    @property
    def inputs(self) -> frozenset[str]:
        return self.plan.inputs

    @property
    def outputs(self) -> frozenset[str]:
        return self.plan.outputs

    def run(self, inputs: Iterable[Recorded]) -> Iterator[Event]:
        """Handle ``inputs`` (sorted by ``(log_time, order)``; other topics are ignored) and
        yield every input handled and every output, in delivery order."""
        ticks: list[tuple[int, Node]] | None = None
        for item in inputs:
            if item.key not in self.plan.inputs:
                continue
            if ticks is None:  # timers start with the first input
                ticks = [(item.log_time + n.tick.period_ns, n) for n in self.plan.nodes if n.tick]
            stamp: Stamp = (item.log_time, item.order, 0)
            yield from self._until(stamp, ticks)
            yield Event(item.log_time, item.key, item.message, item)
            self._dispatch(item.key, item.message, stamp)
        yield from self._until(None, ticks or [])

    def _until(self, stamp: Stamp | None, ticks: list[tuple[int, Node]]) -> Iterator[Event]:
        """Deliver the outputs and ticks due before ``stamp``; with ``None``, every output still
        scheduled (and the ticks among them)."""
        while True:
            due = self._heap[0][0] if self._heap else None
            if due is not None and stamp is not None and due >= stamp:
                due = None
            bound = due if due is not None else stamp
            if bound is None:
                return
            if ticks:
                i = min(range(len(ticks)), key=lambda j: ticks[j][0])
                t_tick, node = ticks[i]
                if (t_tick, -1, 0) < bound:  # a tick goes before a message of the same time
                    assert node.tick is not None
                    ticks[i] = (t_tick + node.tick.period_ns, node)
                    self._step(node, _tick_route(node), node.tick.make(t_tick), (t_tick, -1, 0))
                    continue
            if due is None:
                return
            at, _, key, message = heapq.heappop(self._heap)
            yield Event(at[0], key, message)
            self._dispatch(key, message, at)

    def skips(self, node: Node, route: Route, message: Any) -> bool:
        """Whether ``node`` skips ``message`` on ``route``, as the live service did (gating)."""
        if not route.gated or node.gate is None or self.all_frames:
            return False
        frame = frame_id(message)
        return (
            frame is not None
            and node.gate in self.recorded_keys
            and frame not in self.recorded.get(node.gate, ())
        )

    def _dispatch(self, key: str, message: Any, stamp: Stamp) -> None:
        for node, route in self._routes.get(key, ()):
            if route.gated and node.gate is not None:
                frame = frame_id(message)
                if frame is not None:
                    self.offered.setdefault(node.gate, set()).add(frame)
                if self.skips(node, route, message):
                    self.gated[node.name] += 1
                    continue
            self._step(node, route, message, stamp)

    def _step(self, node: Node, route: Route, message: Any, stamp: Stamp) -> None:
        try:
            state, outputs = route.step(self.states[node.name], message, stamp[0])
        except node.errors as exc:
            self.errors[node.name] += 1
            self.first_error.setdefault(node.name, f"{type(exc).__name__}: {exc}")
            return
        self.states[node.name] = state
        for output in _as_list(outputs):
            key = KEY_OF_TYPE.get(type(output))
            if key is None:
                raise TypeError(f"node {node.name} returned {type(output).__name__}: no topic")
            at: Stamp = (stamp[0], stamp[1], next(self._counter))
            frame = frame_id(output)
            recorded = self.recorded.get(key)
            if recorded and frame is not None and frame in recorded:
                t, order = recorded[frame]
                if t > stamp[0]:  # recorded later: it took that long live
                    at = (t, order, 0)
            heapq.heappush(self._heap, (at, next(self._counter), key, output))


def _tick_route(node: Node) -> Route:
    for route in node.routes:
        if route.key == TICK:
            return route
    raise ValueError(f"node {node.name} has a tick but no route for {TICK!r}")


def _as_list(outputs: Any) -> list[Any]:
    if outputs is None:
        return []
    if isinstance(outputs, list | tuple):
        return list(outputs)
    return [outputs]


# --------------------------------------------------------------------------- the check


@dataclass(frozen=True)
class Difference:
    """One way a replayed output differs from the recorded one."""

    key: str
    where: str  # "frame 123" or "#7"
    path: str  # the first differing field, "" when a whole message is missing
    recorded: str
    replayed: str

    def describe(self) -> str:
        field_ = f" {self.path}" if self.path else ""
        return (
            f"{self.key} {self.where}{field_}: recorded {self.recorded}, replayed {self.replayed}"
        )


@dataclass
class CheckResult:
    """Differences (the first ``limit`` kept), and how many messages each topic compared."""

    differences: list[Difference] = field(default_factory=list)
    total: int = 0
    compared: Counter[str] = field(default_factory=Counter)
    differing: Counter[str] = field(default_factory=Counter)

    @property
    def ok(self) -> bool:
        return self.total == 0


def check(
    recorded: Mapping[str, Sequence[Any]],
    replayed: Mapping[str, Sequence[Any]],
    *,
    volatile: Mapping[str, frozenset[str]] | None = None,
    offered: Mapping[str, Collection[int]] | None = None,
    match_by: Mapping[str, str] | None = None,
    cut: bool = False,
    all_frames: bool = False,
    rel_tol: float = 0.0,
    limit: int = 20,
) -> CheckResult:
    """Compare outputs topic by topic.

    Messages with a frame id are matched by frame, those of a topic in ``match_by`` by that
    field (a tactor command by its frame's ``t_ns``), others by position. A recorded output
    whose frame was never offered to its producer (its input is not in the recording) is
    skipped. Replayed outputs the recording lacks are differences, except past the end of a
    ``cut`` recording (or a replay of only its beginning: then only the overlap is compared),
    or with ``all_frames`` (no gating) for frames the live service skipped. Floats within
    ``rel_tol`` of each other are equal (see `first_difference`).
    """
    volatile = volatile or {}
    result = CheckResult()

    def add(diff: Difference) -> None:
        result.total += 1
        result.differing[diff.key] += 1
        if len(result.differences) < limit:
            result.differences.append(diff)

    for key in sorted(set(recorded) | set(replayed)):
        ignore = volatile.get(key, frozenset())
        rec, rep = list(recorded.get(key, ())), list(replayed.get(key, ()))
        field_ = (match_by or {}).get(key)
        by_frame = all(frame_id(m) is not None for m in itertools.chain(rec, rep))
        if (by_frame or field_) and (rec or rep):

            def ident(m: Any, by_frame: bool = by_frame, field_: str | None = field_) -> Any:
                return frame_id(m) if by_frame else getattr(m, field_ or "", None)

            seen = offered.get(key) if offered is not None and by_frame else None
            rec_by = {ident(m): m for m in rec if seen is None or ident(m) in seen}
            rep_by = {ident(m): m for m in rep}
            last = max(rec_by, default=-1)
            if cut and rep_by:  # the recording may go on past what was replayed
                end = max(rep_by)
                rec_by = {k: m for k, m in rec_by.items() if k <= end}
            for frame in sorted(set(rec_by) | set(rep_by)):
                a, b = rec_by.get(frame), rep_by.get(frame)
                where = f"frame {frame}" if by_frame else f"{field_}={frame}"
                if a is None:
                    if not (all_frames or (cut and frame > last)):
                        add(Difference(key, where, "", "nothing", _short(b)))
                elif b is None:
                    add(Difference(key, where, "", _short(a), "nothing"))
                else:
                    result.compared[key] += 1
                    diff = first_difference(a, b, ignore, rel_tol)
                    if diff is not None:
                        add(Difference(key, where, *diff))
        else:
            for i, (a, b) in enumerate(zip(rec, rep, strict=False)):
                result.compared[key] += 1
                diff = first_difference(a, b, ignore, rel_tol)
                if diff is not None:
                    add(Difference(key, f"#{i}", *diff))
            if len(rec) > len(rep) and not cut:
                add(
                    Difference(
                        key, f"#{len(rep)}", "", f"{len(rec)} messages", f"{len(rep)} messages"
                    )
                )
            elif len(rep) > len(rec) and not (cut or all_frames):
                add(
                    Difference(
                        key, f"#{len(rec)}", "", f"{len(rec)} messages", f"{len(rep)} messages"
                    )
                )
    return result


def first_difference(
    a: Any, b: Any, ignore: Collection[str] = (), rel_tol: float = 0.0
) -> tuple[str, str, str] | None:
    """``(path, a, b)`` of the first field where two messages differ, ``None`` if equal.
    Top-level fields named in ``ignore`` are skipped. Two floats within ``rel_tol`` of the
    larger are equal: another CPU or BLAS kernel rounds the same algorithm's sums differently
    in the last bits, and that is not a change of the algorithm."""
    return _diff(a, b, "", ignore, rel_tol)


def _diff(
    a: Any, b: Any, path: str, ignore: Collection[str], rel_tol: float
) -> tuple[str, str, str] | None:
    if isinstance(a, memoryview) or isinstance(b, memoryview):
        # A decoded array's data views its payload; one built by a step holds bytes.
        a, b = (bytes(x) if isinstance(x, memoryview) else x for x in (a, b))
    if type(a) is not type(b):
        return path or "<message>", _short(a), _short(b)
    fields = getattr(type(a), "__struct_fields__", None)
    if fields is None and dataclasses.is_dataclass(a):
        fields = tuple(f.name for f in dataclasses.fields(a))
    if fields is not None:
        for name in fields:
            if not path and name in ignore:
                continue
            found = _diff(
                getattr(a, name),
                getattr(b, name),
                f"{path}.{name}" if path else name,
                (),
                rel_tol,
            )
            if found is not None:
                return found
        return None
    if isinstance(a, list | tuple):
        if len(a) != len(b):
            return f"{path}", f"{len(a)} items", f"{len(b)} items"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            found = _diff(x, y, f"{path}[{i}]", (), rel_tol)
            if found is not None:
                return found
        return None
    if isinstance(a, dict):
        for k in sorted(set(a) | set(b), key=str):
            found = _diff(a.get(k), b.get(k), f"{path}[{k!r}]", (), rel_tol)
            if found is not None:
                return found
        return None
    if isinstance(a, float) and (
        (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=rel_tol)
    ):
        return None
    if a != b:
        if isinstance(a, bytes):
            at = next(
                (i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y),
                min(len(a), len(b)),
            )
            return path, f"{len(a)} bytes", f"{len(b)} bytes, first difference at byte {at}"
        return path, _short(a), _short(b)
    return None


def _short(value: Any, width: int = 80) -> str:
    text = repr(value)
    if hasattr(value, "__struct_fields__"):
        text = f"{type(value).__name__}(seq={getattr(value, 'seq', '?')}, ...)"
    return text if len(text) <= width else text[: width - 3] + "..."


# --------------------------------------------------------------------------- the table


def default_nodes(
    controller_params: Any = None,
    reconstructor_method: str = "laser",
    *,
    states: Mapping[str, Any] | None = None,
) -> tuple[Node, ...]:
    """The pipeline as the services run it, in data-flow order: input topic -> step.

    ``controller_params`` (a ``ControllerParams``) are the controller service's, which come
    from its flags and the user's profile; ``reconstructor_method`` is the reconstructor's
    ``--method``: ``laser`` reconstructs the scan lines, ``cloud`` the whole depth frame.
    ``states`` gives a node's initial state by name (``scans``, ``reconstructor``, ``aim``,
    ``controller``), as its service built it from its flags; the others start from their
    defaults (the aim's tactors follow the wrist when the controller's camera is on the hand).
    """
    from lpc_core.control import aim, controller
    from lpc_core.perception import pipeline, reconstructor

    params = controller_params or controller.ControllerParams()
    given = dict(states or {})

    def initial(name: str, default: Callable[[], Any]) -> Callable[[], Any]:
        if name not in given:
            return default
        state = given[name]  # frozen: one instance serves every replay of the nodes
        return lambda: state

    if reconstructor_method == "laser":
        reconstruct = Route("lpc/scans", reconstructor.reconstruct_step, gated=True)
        # Live, compute_ms is the worker's measured time; seq follows the scans'.
        volatile = frozenset({"seq", "compute_ms"})
    elif reconstructor_method == "cloud":
        reconstruct = Route("lpc/camera/depth", reconstructor.reconstruct_cloud_step, gated=True)
        volatile = frozenset({"compute_ms"})  # seq is the depth frame's
    else:
        raise ValueError(
            f"reconstructor_method must be 'laser' or 'cloud', got {reconstructor_method!r}"
        )

    return (
        Node(
            name="scans",
            init=initial("scans", pipeline.ScansState),
            routes=(Route("lpc/camera/depth", pipeline.scans_step, gated=True),),
            outputs=("lpc/scans",),
            gate="lpc/scans",
        ),
        Node(
            name="reconstructor",
            init=initial("reconstructor", reconstructor.ReconstructState),
            routes=(reconstruct,),
            outputs=("lpc/reconstruction", "lpc/grasp/target"),
            gate="lpc/reconstruction",
            volatile=volatile,
        ),
        Node(
            name="aim",
            init=initial(
                "aim",
                lambda: aim.AimState(params=aim.AimParams(follow_wrist=params.camera_on_hand)),
            ),
            routes=(
                Route("lpc/scans", aim.aim_step, gated=True),
                Route("lpc/grasp/target", aim.aim_step),
                # Cues off while the controller has stopped the hand.
                Route("lpc/controller/state", aim.aim_step, feedback=True),
                # The tactor directions turn with the wrist when the camera does.
                Route("lpc/prosthesis/state", aim.aim_step, feedback=True),
            ),
            outputs=("lpc/aim/cue", "lpc/tactors/command"),
            gate="lpc/aim/cue",
            match_by="t_ns",  # a tactor command carries its frame's capture time
        ),
        Node(
            name="controller",
            init=initial("controller", lambda: controller.ControllerCore(params=params)),
            routes=(
                Route("lpc/emg", controller.controller_step),
                Route("lpc/grasp/target", controller.controller_step),
                Route("lpc/aim/cue", controller.controller_step),
                Route("lpc/prosthesis/state", controller.controller_step),
                Route(TICK, controller.controller_step),
            ),
            outputs=("lpc/controller/state", "lpc/prosthesis/command"),
            # Its messages carry the time it handled them: live, its own clock.
            volatile=frozenset({"seq", "t_ns"}),
            errors=(ValueError, controller.TransitionError),
            tick=Tick(10_000_000, controller.Tick),
        ),
    )


def volatile_fields(nodes: Iterable[Node]) -> dict[str, frozenset[str]]:
    """Per output topic, the fields a check skips."""
    return {key: node.volatile for node in nodes for key in node.outputs}


def match_fields(nodes: Iterable[Node]) -> dict[str, str]:
    """Per output topic without frame ids, the field a check pairs messages by."""
    return {key: node.match_by for node in nodes if node.match_by for key in node.outputs}
