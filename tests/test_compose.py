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
        [
            _check_jsonschema(),
            "--builtin-schema",
            "vendor.compose-spec",
            "compose.yaml",
            "deploy/compose.secure.yaml",
        ],
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


def test_secure_overlay_gives_every_service_its_tls_config_and_certificate() -> None:
    """Each service of compose.yaml runs in the secure overlay with the TLS client config, its
    own role's certificate and the same flags otherwise: a service left out would try the
    plain config against a TLS-only router and never join the bus."""
    from ruamel.yaml import YAML

    yaml = YAML(typ="safe")
    base = yaml.load(ROOT / "compose.yaml")["services"]
    secure = yaml.load(ROOT / "deploy" / "compose.secure.yaml")["services"]
    for name, service in base.items():
        if name == "router":
            continue
        assert name in secure, f"{name} is missing from deploy/compose.secure.yaml"
        command = secure[name]["command"]
        plain = service["command"]
        assert command == [
            "deploy/zenoh-service-secure.json5" if a == "deploy/zenoh-service.json5" else a
            for a in plain
        ], name
        assert f"./certs/{name}:/certs/service:ro" in secure[name]["volumes"], name
