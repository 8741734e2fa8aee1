"""Step-function state is immutable: ``evolve`` (``lpc_core.perception.state``, the lowest
layer, whose steps use it too) makes the changed copy."""

from __future__ import annotations

from lpc_core.perception.state import evolve

__all__ = ["evolve"]
