"""``lpc certs make DIR``: a local certificate authority and one certificate per service, for
the secure multi-host deployment (``deploy/zenoh-*-secure.json5``, ``docs/security.md``).

The Zenoh router admits only peers whose certificate the CA signed (mutual TLS), and its access
control rules match the certificate's common name (CN): the CN is the service's role name.
Keys are EC P-256 in PKCS#8 PEM; every certificate serves both ends of a TLS link (server and
client auth). Uses the ``openssl`` command line tool, nothing from PyPI.
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

# Roles named in the router's access control (deploy/zenoh-router-secure.json5). The CN is the
# role; a service uses its role's certificate.
ROLES: tuple[str, ...] = (
    "router",
    "controller",
    "prosthesis_bridge",
    "tactor_bridge",
    "emg",
    "camera",
    "scans",
    "reconstructor",
    "aim",
    "recorder",
    "foxglove",
    "supervisor",
    "viewer",
)
ROUTER_NAMES: tuple[str, ...] = ("router", "localhost", "127.0.0.1")


class CertError(RuntimeError):
    """openssl is missing or failed."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    make = sub.add_parser("make", help="create a CA and a certificate per role in DIR")
    make.add_argument("dir", metavar="DIR", help="output directory (created)")
    make.add_argument(
        "--roles",
        nargs="+",
        metavar="ROLE",
        default=list(ROLES),
        help="roles to issue (default: all of them; the router always gets one)",
    )
    make.add_argument(
        "--router-name",
        action="append",
        default=[],
        metavar="NAME",
        help="extra DNS name or IP address the router is reached at (repeatable); "
        f"always included: {', '.join(ROUTER_NAMES)}",
    )
    make.add_argument("--days", type=int, default=365, help="validity in days (default 365)")
    make.add_argument("--force", action="store_true", help="replace existing files in DIR")


def run(args: argparse.Namespace) -> int:
    bad = [r for r in args.roles if not r.replace("_", "").isalnum()]
    if bad:
        print(f"lpc certs: error: role names must be [A-Za-z0-9_]: {bad}", file=sys.stderr)
        return 2
    if not 1 <= args.days <= 3650:
        print("lpc certs: error: --days must be in [1, 3650]", file=sys.stderr)
        return 2
    out = Path(args.dir)
    if (out / "ca.pem").exists() and not args.force:
        print(f"lpc certs: error: {out}/ca.pem exists; use --force to replace", file=sys.stderr)
        return 2
    try:
        made = make_certs(out, roles=args.roles, router_names=args.router_name, days=args.days)
    except CertError as exc:
        print(f"lpc certs: error: {exc}", file=sys.stderr)
        return 1
    for role, (cert, key) in made.items():
        print(f"{role:<18} {cert}  {key}")
    print(f"CA: {out / 'ca.pem'} (keep {out / 'ca-key.pem'} off the devices)")
    return 0


def make_certs(
    out: Path,
    *,
    roles: list[str] | tuple[str, ...] = ROLES,
    router_names: list[str] | tuple[str, ...] = (),
    days: int = 365,
) -> dict[str, tuple[Path, Path]]:
    """Write ``ca.pem``, ``ca-key.pem`` and ``ROLE/cert.pem``, ``ROLE/key.pem`` per role."""
    if shutil.which("openssl") is None:
        raise CertError("the openssl command is not installed (apt-get install openssl)")
    out.mkdir(parents=True, exist_ok=True)
    ca, ca_key = out / "ca.pem", out / "ca-key.pem"
    _key(ca_key)
    _openssl(
        "req", "-x509", "-new", "-key", ca_key, "-out", ca, "-days", str(days + 1),
        "-subj", "/O=lpc/CN=lpc local CA", "-sha256",
        "-addext", "basicConstraints=critical,CA:TRUE,pathlen:0",
        "-addext", "keyUsage=critical,keyCertSign,cRLSign",
    )  # fmt: skip
    made: dict[str, tuple[Path, Path]] = {}
    for role in dict.fromkeys(["router", *roles]):
        names = [*ROUTER_NAMES, *router_names] if role == "router" else [role, "localhost"]
        made[role] = _issue(out / role, role, names, ca, ca_key, days)
    return made


def _issue(
    folder: Path, cn: str, names: list[str], ca: Path, ca_key: Path, days: int
) -> tuple[Path, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    cert, key = folder / "cert.pem", folder / "key.pem"
    _key(key)
    san = ",".join(_san(n) for n in dict.fromkeys(names))
    ext = (
        "basicConstraints=critical,CA:FALSE\n"
        "keyUsage=critical,digitalSignature,keyEncipherment\n"
        "extendedKeyUsage=serverAuth,clientAuth\n"
        f"subjectAltName={san}\n"
    )
    with tempfile.TemporaryDirectory() as tmp:
        csr, extfile = Path(tmp) / "req.csr", Path(tmp) / "ext.cnf"
        extfile.write_text(ext)
        _openssl("req", "-new", "-key", key, "-out", csr, "-subj", f"/O=lpc/CN={cn}")
        _openssl(
            "x509", "-req", "-in", csr, "-CA", ca, "-CAkey", ca_key, "-CAcreateserial",
            "-out", cert, "-days", str(days), "-sha256", "-extfile", extfile,
        )  # fmt: skip
    return cert, key


def _san(name: str) -> str:
    try:
        return f"IP:{ipaddress.ip_address(name)}"
    except ValueError:
        return f"DNS:{name}"


def _key(path: Path) -> None:
    _openssl("genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out", path)
    os.chmod(path, 0o600)


def _openssl(*argv: str | Path) -> None:
    result = subprocess.run(
        ["openssl", *map(str, argv)], capture_output=True, text=True, check=False
    )
    if result.returncode != 0:
        raise CertError(f"openssl {argv[0]} failed: {result.stderr.strip()}")
