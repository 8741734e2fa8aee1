"""The topic registry: key expression -> message type, kind and limits.

One encoder and one typed decoder per topic are built at import and reused. Decoding validates
types and value limits (msgspec ``Meta``), rejects payloads over the topic's size limit, payloads
of another version, and non-finite floats, raising ``BadMessage`` with a reason a person can read.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import msgspec

from schemas.messages import (
    AimCue,
    ControllerState,
    DepthFrame,
    EmgSample,
    GraspTarget,
    Health,
    Log,
    Message,
    ProsthesisCommand,
    ProsthesisState,
    Reconstruction,
    ScanLines,
    TactorCommand,
)

Kind = Literal["sensor", "command", "status"]

_ENCODER = msgspec.msgpack.Encoder()


class BadMessage(ValueError):
    """A payload that does not decode to its topic's type; ``reason`` says why."""

    def __init__(self, key: str, reason: str) -> None:
        super().__init__(f"{key}: {reason}")
        self.key = key
        self.reason = reason

    def __reduce__(self) -> tuple[type[BadMessage], tuple[str, str]]:
        # Rebuilt from both fields: it crosses process boundaries (the reconstructor's pool).
        return type(self), (self.key, self.reason)


@dataclass(frozen=True)
class Topic:
    """A bus topic. ``kind`` decides delivery: sensor topics keep only the newest sample and
    drop under congestion; command topics are FIFO and block rather than drop."""

    key: str
    type: type[Message]
    kind: Kind
    max_bytes: int = 64 * 1024
    decoder: msgspec.msgpack.Decoder = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "decoder", msgspec.msgpack.Decoder(self.type))

    @property
    def wildcard(self) -> bool:
        return self.key.endswith("/*")

    def matches(self, key: str) -> bool:
        if self.wildcard:
            prefix = self.key[:-1]
            rest = key[len(prefix) :]
            return key.startswith(prefix) and bool(rest) and "/" not in rest
        return key == self.key

    def decode(self, payload: bytes | memoryview, key: str | None = None) -> Any:
        key = key or self.key
        if len(payload) > self.max_bytes:
            raise BadMessage(key, f"payload of {len(payload)} bytes exceeds {self.max_bytes}")
        if type(payload) is not bytes:
            # A decoded array views its payload (NDArray): a view into a buffer that its owner
            # reuses or changes (a receive buffer) would change under the message.
            payload = bytes(payload)
        try:
            message = self.decoder.decode(payload)
        except msgspec.ValidationError as exc:
            raise BadMessage(key, f"invalid {self.type.__name__}: {exc}") from exc
        except (msgspec.DecodeError, ValueError) as exc:
            # ValueError covers what msgspec lets through, such as broken UTF-8 in a string.
            raise BadMessage(key, f"malformed payload: {exc}") from exc
        if message.version != 1:
            raise BadMessage(key, f"version {message.version} not supported (expected 1)")
        if not _finite_check(self.type)(message):
            raise BadMessage(key, f"non-finite value in field {_first_non_finite(message)}")
        return message


TOPICS: tuple[Topic, ...] = (
    Topic("lpc/camera/depth", DepthFrame, "sensor", max_bytes=16 * 1024 * 1024),
    Topic("lpc/scans", ScanLines, "sensor", max_bytes=1024 * 1024),
    Topic("lpc/reconstruction", Reconstruction, "sensor"),
    Topic("lpc/grasp/target", GraspTarget, "sensor"),
    Topic("lpc/aim/cue", AimCue, "sensor"),
    Topic("lpc/tactors/command", TactorCommand, "command"),
    Topic("lpc/emg", EmgSample, "sensor"),
    Topic("lpc/controller/state", ControllerState, "status"),
    Topic("lpc/prosthesis/command", ProsthesisCommand, "command"),
    Topic("lpc/prosthesis/state", ProsthesisState, "sensor"),
    Topic("lpc/health/*", Health, "status"),
    Topic("lpc/log/*", Log, "status"),
)

_BY_KEY = {t.key: t for t in TOPICS if not t.wildcard}


def topic_for_key(key: str) -> Topic:
    """The registered topic a concrete key expression belongs to; ``KeyError`` if none."""
    topic = _BY_KEY.get(key)
    if topic is not None:
        return topic
    for candidate in TOPICS:
        if candidate.wildcard and candidate.matches(key):
            return candidate
    raise KeyError(f"no schema registered for key {key!r}")


def encode(message: Message) -> bytes:
    """Encode any registered message as msgpack."""
    return _ENCODER.encode(message)


def decode(key: str, payload: bytes | memoryview) -> Any:
    """Decode a payload received on ``key``; raises ``BadMessage`` (or ``KeyError``)."""
    return topic_for_key(key).decode(payload, key)


def json_schema(message_type: type[Message]) -> dict[str, Any]:
    """The JSON schema of one message type, self-contained, for MCAP and outside subscribers."""
    return msgspec.json.schema(message_type)


Check = Callable[[Any], bool]


def _finite_float(v: Any) -> bool:
    """A float field's check (one function: a struct's check tests such fields inline)."""
    return not isinstance(v, float) or math.isfinite(v)


# A tuple, not ``list | tuple``: that expression builds a union object at every test.
_SEQUENCE = (list, tuple)


def _finite_floats(v: Any) -> bool:
    """A list-of-floats field's check (one function, as ``_finite_float``: a struct's check
    tests such fields inline; a scan line's two, of each of a frame's four lines)."""
    return not isinstance(v, _SEQUENCE) or all(map(math.isfinite, v))


@functools.cache
def _finite_check(message_type: type) -> Check:
    """A check that every float in a message of ``message_type`` is finite, built once per type
    from its schema so that only the fields that can hold floats are visited (the generic walk
    below, which names the bad field, cost ~40 us per message)."""
    return _check_of(msgspec.inspect.type_info(message_type), repeats=False) or (lambda _: True)


def _check_of(t: msgspec.inspect.Type, *, repeats: bool = True) -> Check | None:
    """The check for values of type ``t``; ``None`` when ``t`` holds no float. Each check passes
    values of other types, so a union's checks can all run on its value. ``repeats``: a value
    of ``t`` may be the same from message to message (a field's; not the message's own, nor
    an item of a list, tuple or dict, which differ from their neighbours)."""
    mi = msgspec.inspect
    if isinstance(t, mi.FloatType):
        return _finite_float
    if isinstance(t, mi.UnionType):
        parts = [c for x in t.types if (c := _check_of(x, repeats=repeats)) is not None]
        if not parts:
            return None
        return parts[0] if len(parts) == 1 else _all_of(parts)
    if isinstance(t, mi.ListType | mi.VarTupleType | mi.SetType | mi.FrozenSetType):
        if isinstance(t.item_type, mi.FloatType):
            return _finite_floats
        item = _check_of(t.item_type, repeats=False)
        return (
            None if item is None else (lambda v: not isinstance(v, _SEQUENCE) or all(map(item, v)))
        )
    if isinstance(t, mi.TupleType):
        items = [(i, c) for i, x in enumerate(t.item_types) if (c := _check_of(x, repeats=False))]
        return (
            (lambda v: not isinstance(v, _SEQUENCE) or all(c(v[i]) for i, c in items))
            if items
            else None
        )
    if isinstance(t, mi.DictType):
        value = _check_of(t.value_type, repeats=False)
        return (
            None
            if value is None
            else (lambda v: not isinstance(v, dict) or all(map(value, v.values())))
        )
    if isinstance(t, mi.StructType):
        fields = [(f.name, c) for f in t.fields if (c := _check_of(f.type)) is not None]
        if not fields:
            return None
        remember = repeats and t.cls.__struct_config__.frozen and _scalars_only(t)
        return _struct_check(t.cls, fields, remember=remember)
    if isinstance(t, _NO_FLOAT):
        return None
    if isinstance(t, mi.LiteralType | mi.EnumType):
        return None
    return lambda v: _first_non_finite(v) is None  # anything else: the generic walk


# Types that hold no float. A decoded array's bytes (``NDArray.data``, a memoryview) went
# through the generic walk (``_first_non_finite``) once per array: four a scan-lines message.
_NO_FLOAT = (
    msgspec.inspect.IntType,
    msgspec.inspect.StrType,
    msgspec.inspect.BytesType,
    msgspec.inspect.ByteArrayType,
    msgspec.inspect.MemoryViewType,
    msgspec.inspect.BoolType,
    msgspec.inspect.NoneType,
)


def _scalars_only(t: msgspec.inspect.Type) -> bool:
    """Whether values of ``t`` hold only numbers, strings, booleans and lists of them, so that
    comparing two costs less than testing one (not an array's bytes, compared item by item)."""
    mi = msgspec.inspect
    if isinstance(t, mi.StructType):
        return all(_scalars_only(f.type) for f in t.fields)
    if isinstance(t, mi.UnionType):
        return all(map(_scalars_only, t.types))
    if isinstance(t, mi.ListType | mi.VarTupleType):
        return _scalars_only(t.item_type)
    scalar = (mi.IntType, mi.FloatType, mi.StrType, mi.BoolType, mi.NoneType, mi.LiteralType)
    return isinstance(t, scalar)


def _all_of(parts: list[Check]) -> Check:
    """A union's check: every part's, in a loop (as ``_struct_check``)."""

    def check(v: Any) -> bool:
        for part in parts:  # noqa: SIM110 - all() over a generator is the cost saved
            if not part(v):
                return False
        return True

    return check


def _struct_check(cls: type, fields: list[tuple[str, Check]], *, remember: bool = False) -> Check:
    """A struct's check: loops, not ``all`` over a generator, whose frame and a call per field
    cost more than the tests (a reconstruction 14.8 -> 5.9 us, scan lines 10.2 -> 2.4 us; the
    same booleans on every recorded message with a NaN or an infinity put in a float of it).
    Float and list-of-float fields are tested inline, the rest through their own checks.

    ``remember`` (a frozen struct within a message): a value equal to the last one that passed
    passes without its fields' tests. Every frame repeats its camera's intrinsics and, for
    long runs, its truth: their tests were 2.3 of a depth frame's 5.3 us decode, one
    comparison in C costs a fraction of that. Exact: a float equal to a finite one is finite
    (NaN equals nothing), and the last passed value is kept only of a frozen struct."""
    floats = tuple(n for n, c in fields if c is _finite_float)
    float_lists = tuple(n for n, c in fields if c is _finite_floats)
    others = tuple((n, c) for n, c in fields if c is not _finite_float and c is not _finite_floats)
    isfinite = math.isfinite

    def check(v: Any) -> bool:
        if not isinstance(v, cls):
            return True
        for name in floats:
            x = getattr(v, name)
            if isinstance(x, float) and not isfinite(x):
                return False
        for name in float_lists:
            x = getattr(v, name)
            if isinstance(x, _SEQUENCE) and not all(map(isfinite, x)):
                return False
        for name, field_check in others:  # noqa: SIM110 - as above
            if not field_check(getattr(v, name)):
                return False
        return True

    if not remember:
        return check
    passed: list[Any] = [None]  # the last value of ``cls`` that passed (None passes anyway)

    def check_remembered(v: Any) -> bool:
        if v == passed[0]:
            return True
        if not check(v):
            return False
        if isinstance(v, cls):
            passed[0] = v
        return True

    return check_remembered


def _first_non_finite(value: Any, path: str = "") -> str | None:
    # Recursion over struct fields only; arrays travel as bytes and are checked when converted.
    if isinstance(value, float):
        return None if math.isfinite(value) else (path or "<value>")
    if isinstance(value, msgspec.Struct):
        for name in value.__struct_fields__:
            found = _first_non_finite(getattr(value, name), f"{path}.{name}" if path else name)
            if found is not None:
                return found
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            found = _first_non_finite(item, f"{path}[{i}]")
            if found is not None:
                return found
    elif isinstance(value, dict):
        for k, item in value.items():
            found = _first_non_finite(item, f"{path}[{k!r}]")
            if found is not None:
                return found
    return None
