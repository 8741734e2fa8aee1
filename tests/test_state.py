"""``evolve``: the changed copy of a step's state."""

from __future__ import annotations

from dataclasses import FrozenInstanceError, dataclass, field

import pytest

from lpc_core.control.state import evolve


@dataclass(frozen=True)
class Counter:
    count: int = 0
    seen: tuple[str, ...] = ()
    label: str = field(default="a")

    def __post_init__(self) -> None:
        if self.count < 0:
            raise ValueError("count must be >= 0")


def test_evolve_changes_only_the_named_fields_of_a_copy() -> None:
    old = Counter(count=1, seen=("x",))
    new = evolve(old, count=2)
    assert new == Counter(count=2, seen=("x",)) and type(new) is Counter
    assert old == Counter(count=1, seen=("x",))
    with pytest.raises(FrozenInstanceError):
        new.count = 3  # type: ignore[misc]


def test_evolve_rejects_an_unknown_field() -> None:
    with pytest.raises(TypeError, match=r"Counter has no field\(s\) \['cuont'\]"):
        evolve(Counter(), cuont=1)


def test_evolve_does_not_rerun_post_init() -> None:
    # State updates skip the parameter checks: that is what makes them cheap.
    assert evolve(Counter(), count=-1).count == -1
