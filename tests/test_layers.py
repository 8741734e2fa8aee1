"""lpc_core's layers, read from the imports: a lower layer never imports a higher one.

The allowed edges are those of ``lpc_core/__init__.py``'s docstring. Imports inside functions
count too: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parents[1] / "lpc_core"

# layer -> the layers its modules may import ("" is lpc_core's own top-level modules).
ALLOWED: dict[str, set[str]] = {
    "perception": {"perception"},
    "control": {"control", "perception"},
    "devices": {"devices", "perception"},
    "sim": {"sim", "devices", "control", "perception"},
    "": {"", "sim", "devices", "control", "perception"},
}


def layer_of(module: str) -> str | None:
    """``lpc_core.sim.scene`` -> ``"sim"``; ``lpc_core.replay`` -> ``""``; others ``None``."""
    parts = module.split(".")
    if parts[0] != "lpc_core":
        return None
    if len(parts) > 1 and parts[1] in ALLOWED:
        return parts[1]
    return ""


def imported_modules(source: str, package: str) -> list[tuple[int, str]]:
    """Every module a source imports, absolute, with its line: relative imports resolved
    against ``package``, and ``from lpc_core import sim`` counted as ``lpc_core.sim``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            if base == "lpc_core":  # from lpc_core import sim: the names are the modules
                found += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
            else:
                found.append((node.lineno, base))
    return found


def upward_imports(source: str, module: str) -> list[str]:
    """The imports of ``module`` (dotted name, its source given) that break the layering."""
    package = module.rsplit(".", 1)[0]
    own = layer_of(module)
    assert own is not None, module
    broken = []
    for line, target in imported_modules(source, package):
        layer = layer_of(target)
        if layer is not None and layer not in ALLOWED[own] and target != "lpc_core":
            broken.append(f"{module}:{line} imports {target} ({own or 'top'} -> {layer or 'top'})")
    return broken


def core_modules() -> list[tuple[str, Path]]:
    modules = []
    for path in sorted(CORE.rglob("*.py")):
        parts = path.relative_to(CORE.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = (*parts[:-1], "__init__")
        modules.append((".".join(parts), path))
    return modules


def test_layers_every_module_imports_only_its_layer_or_lower() -> None:
    broken = [
        problem
        for module, path in core_modules()
        for problem in upward_imports(path.read_text(), module)
    ]
    assert broken == []


def test_layers_every_module_lives_in_a_layer() -> None:
    top = {m for m, _ in core_modules() if layer_of(m) == "" and m.count(".") == 1}
    assert top == {
        "lpc_core.__init__",
        "lpc_core.replay",
        "lpc_core.trials",
        "lpc_core.foxglove_convert",
        "lpc_core.gaps",
    }


@pytest.mark.parametrize(
    ("module", "source"),
    [
        ("lpc_core.perception.fake", "from lpc_core.control.aim import aim_step\n"),
        ("lpc_core.perception.fake", "def f():\n    from lpc_core import sim\n"),
        ("lpc_core.perception.fake", "import lpc_core.devices.hand as h\n"),
        ("lpc_core.perception.fake", "from ..sim import scene\n"),
        ("lpc_core.control.fake", "from lpc_core.devices.can_protocol import encode\n"),
        ("lpc_core.devices.fake", "from lpc_core.control import controller\n"),
        ("lpc_core.sim.fake", "from lpc_core import replay\n"),
    ],
)
def test_layers_upward_import_in_a_synthetic_module_is_caught(module: str, source: str) -> None:
    assert len(upward_imports(source, module)) == 1


@pytest.mark.parametrize(
    ("module", "source"),
    [
        ("lpc_core.sim.fake", "from lpc_core.perception import scans\nimport numpy as np\n"),
        (
            "lpc_core.control.fake",
            "from .state import evolve\nfrom lpc_core.perception import fit\n",
        ),
        ("lpc_core.replay", "from lpc_core.sim import scene\nfrom lpc_core.control import aim\n"),
    ],
)
def test_layers_downward_and_sideways_imports_pass(module: str, source: str) -> None:
    assert upward_imports(source, module) == []
