"""compose.yaml is valid against the compose specification and matches ``lpc up``'s set."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

from services.cli.up import SERVICES

ROOT = Path(__file__).resolve().parent.parent


def _check_jsonschema() -> str:
    exe = Path(sys.executable).with_name("check-jsonschema")
    return str(exe) if exe.exists() else (shutil.which("check-jsonschema") or "check-jsonschema")


def test_compose_validates_against_compose_spec() -> None:
    result = subprocess.run(
        [_check_jsonschema(), "--builtin-schema", "vendor.compose-spec", "compose.yaml"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_compose_runs_every_service_of_lpc_up() -> None:
    text = (ROOT / "compose.yaml").read_text()
    modules = set(re.findall(r'"(services\.[a-z_]+)"', text))
    wanted = {spec.module for spec in SERVICES.values()}
    assert wanted <= modules, f"missing from compose.yaml: {sorted(wanted - modules)}"
