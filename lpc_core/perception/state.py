"""Step-function state is immutable: ``evolve`` makes the changed copy (for every layer:
``lpc_core.control.state`` passes it on)."""

from __future__ import annotations

from typing import Any, TypeVar

T = TypeVar("T")
_set_attribute = object.__setattr__


def evolve(record: T, **changes: Any) -> T:
    """A copy of the frozen dataclass ``record`` with ``changes`` applied.

    ``dataclasses.replace`` without re-running ``__init__`` and ``__post_init__``: those check
    parameters, and a state update never needs them, while a controller step makes several
    copies (``dataclasses.replace`` took ~10 us each, a third of the controller's time in a
    replay; the reconstructor's pool bookkeeping and the camera's shed gate made about five a
    frame, 6.0 against 1.4 us each). Parameters still change through ``dataclasses.replace``,
    which checks them.
    """
    fields = record.__dict__
    values = fields.copy()
    values.update(changes)
    # An unknown name adds a key: the length tells, without a set difference on every copy.
    if len(values) != len(fields):
        unknown = changes.keys() - fields.keys()
        raise TypeError(f"{type(record).__name__} has no field(s) {sorted(unknown)}")
    copy = object.__new__(type(record))
    _set_attribute(copy, "__dict__", values)  # a frozen dataclass refuses plain assignment
    return copy
