"""Bus message schemas: one msgspec Struct per topic, and the registry from key to type."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from schemas.messages import (
    AimCue,
    CameraIntrinsics,
    ControllerState,
    DepthFrame,
    EmgSample,
    GraspTarget,
    Health,
    LineModel,
    Log,
    Message,
    NDArray,
    ObjectTruth,
    ProsthesisCommand,
    ProsthesisState,
    Reconstruction,
    ScanLine,
    ScanLines,
    TactorCommand,
)
from schemas.registry import (
    TOPICS,
    BadMessage,
    Topic,
    decode,
    encode,
    json_schema,
    topic_for_key,
)

if TYPE_CHECKING:
    from schemas.arrays import from_wire, joined_points, to_wire, to_wire_rows

__all__ = [
    "TOPICS",
    "AimCue",
    "BadMessage",
    "CameraIntrinsics",
    "ControllerState",
    "DepthFrame",
    "EmgSample",
    "GraspTarget",
    "Health",
    "LineModel",
    "Log",
    "Message",
    "NDArray",
    "ObjectTruth",
    "ProsthesisCommand",
    "ProsthesisState",
    "Reconstruction",
    "ScanLine",
    "ScanLines",
    "TactorCommand",
    "Topic",
    "decode",
    "encode",
    "from_wire",
    "joined_points",
    "json_schema",
    "to_wire",
    "to_wire_rows",
    "topic_for_key",
]


def __getattr__(name: str) -> Any:
    # The array conversions load numpy (about 12 MB of a process's memory) on first use, so
    # that processes which only pass small messages (the supervisor, the hand's bridge) need not.
    if name in ("from_wire", "joined_points", "to_wire", "to_wire_rows"):
        from schemas import arrays

        return getattr(arrays, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
