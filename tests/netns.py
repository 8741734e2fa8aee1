"""Hosts in Linux network namespaces for multi-host tests: a wearable, a laptop and an intruder
on one bridge, with the repository's secure Zenoh configs and a throw-away CA.

Every namespace is named ``lpcmh-<pid>-<n>-<host>``; the bridge lives in a fourth one (``-hub``),
and each host's veth pair is created straight inside its two namespaces, so nothing is ever
added to the namespace the tests run in and deleting the namespaces deletes every link.
Addresses are 10.213.0.0/24 and exist only inside those namespaces. ``Hosts.close()`` runs
from the fixture's finalizer and from ``atexit``; ``remove_stale()`` deletes what a killed run
(a pid no longer alive) left behind.

Processes start inside a host with ``ip netns exec``. The configs are the shipped files in
``deploy/`` with their ``/certs`` paths, listen and connect addresses replaced (as
``tests/test_security.py`` does), written to the run's temporary directory.
"""

from __future__ import annotations

import atexit
import contextlib
import itertools
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ROUTER_CONF = ROOT / "deploy" / "zenoh-router-secure.json5"
SERVICE_CONF = ROOT / "deploy" / "zenoh-service-secure.json5"
PREFIX = "lpcmh-"
SUBNET = "10.213.0"
ADDRESSES = {"wearable": f"{SUBNET}.1", "laptop": f"{SUBNET}.2", "intruder": f"{SUBNET}.3"}
PORT = 7447
_RUNS = itertools.count()


def unavailable() -> str | None:
    """Why namespaces cannot be made here, or ``None`` when they can."""
    if sys.platform != "linux":
        return "network namespaces are Linux only"
    if os.geteuid() != 0:
        return "making network namespaces needs root (CI runs the multi-host tests as root)"
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is not installed"
    if shutil.which("openssl") is None:
        return "lpc certs needs the openssl command"
    probe = f"{PREFIX}{os.getpid()}-probe"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"ip netns add failed: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def _ip(*argv: str) -> None:
    result = subprocess.run(["ip", *argv], capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"ip {' '.join(argv)}: {result.stderr.strip()}")


def ours() -> list[str]:
    """Namespaces named by this harness, of any run."""
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    return [line.split()[0] for line in out.splitlines() if line.startswith(PREFIX)]


def remove_stale() -> list[str]:
    """Delete namespaces of earlier runs whose process is gone (a run killed with SIGKILL)."""
    removed = []
    for name in ours():
        match = re.match(rf"{PREFIX}(\d+)-", name)
        if match is None:
            continue
        pid = int(match.group(1))
        if pid != os.getpid() and not os.path.exists(f"/proc/{pid}"):
            subprocess.run(["ip", "netns", "del", name], capture_output=True)
            removed.append(name)
    return removed


class Hosts:
    """Three hosts on a bridge; processes started in them; links cut and mended."""

    def __init__(self, workdir: Path, names: Iterable[str] = tuple(ADDRESSES)) -> None:
        self.workdir = workdir
        self.tag = f"{PREFIX}{os.getpid()}-{next(_RUNS)}"
        self.ns = {host: f"{self.tag}-{host}" for host in names}
        self.hub = f"{self.tag}-hub"
        self.processes: list[subprocess.Popen[str]] = []
        self._closed = False
        atexit.register(self.close)
        try:
            self._build()
        except Exception:
            self.close()
            raise

    def _build(self) -> None:
        _ip("netns", "add", self.hub)
        _ip("-n", self.hub, "link", "add", "br0", "type", "bridge")
        _ip("-n", self.hub, "link", "set", "br0", "up")
        for host, ns in self.ns.items():
            _ip("netns", "add", ns)
            _ip("-n", ns, "link", "set", "lo", "up")
            # Both ends made inside their namespaces: the test's own namespace never sees them.
            _ip("-n", ns, "link", "add", "eth0", "type", "veth", "peer", "name", host,
                "netns", self.hub)  # fmt: skip
            _ip("-n", ns, "addr", "add", f"{ADDRESSES[host]}/24", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")
            _ip("-n", self.hub, "link", "set", host, "master", "br0")
            _ip("-n", self.hub, "link", "set", host, "up")

    # ------------------------------------------------------------------ links

    def link(self, host: str, up: bool) -> None:
        """Plug or unplug ``host``'s cable at the bridge (its own interface stays configured)."""
        _ip("-n", self.hub, "link", "set", host, "up" if up else "down")

    # ------------------------------------------------------------------ processes

    def start(
        self, host: str, argv: list[str], *, name: str, on_line: Callable[[str], None] | None = None
    ) -> subprocess.Popen[str]:
        """``python argv...`` inside ``host``; stdout lines go to ``on_line``, stderr to a log."""
        log = open(self.workdir / f"{host}-{name}.log", "w")  # noqa: SIM115 - closed by the reader
        process = subprocess.Popen(
            ["ip", "netns", "exec", self.ns[host], sys.executable, *argv],
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE if on_line else subprocess.DEVNULL,
            stderr=log,
            text=True,
            bufsize=1,
        )
        self.processes.append(process)
        if on_line is not None:

            def pump() -> None:
                assert process.stdout is not None
                for line in process.stdout:
                    on_line(line)
                log.close()

            threading.Thread(target=pump, daemon=True).start()
        return process

    def stop(self, process: subprocess.Popen[str], timeout: float = 10.0) -> int:
        """SIGINT (services finish their files), then SIGKILL if it does not exit in time."""
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        return process.returncode

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for process in reversed(self.processes):
            if process.poll() is None:
                process.kill()
        for process in self.processes:
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(5)
        for ns in [*self.ns.values(), self.hub]:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)

    def remaining(self) -> list[str]:
        """Namespaces of this run still present (empty after ``close``)."""
        return [n for n in ours() if n.startswith(self.tag + "-")]


# ------------------------------------------------------------------ configs


def config(
    path: Path,
    certs: Path,
    role: str,
    out: Path,
    *,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
    name: str = "",
) -> Path:
    """A shipped config with its ``/certs`` paths pointed at ``certs`` (``role``'s certificate)
    and its endpoints replaced when given, written to ``out``."""
    text = path.read_text()
    text = text.replace('"/certs/service/', f'"{certs}/{role}/').replace('"/certs/', f'"{certs}/')
    if connect is not None:
        text = re.sub(r"connect: \{ endpoints: \[[^\]]*\] \}", _endpoints("connect", connect), text)
    if listen is not None:
        text = re.sub(r"listen: \{ endpoints: \[[^\]]*\] \}", _endpoints("listen", listen), text)
    file = out / f"{name or role}-{path.name}"
    file.write_text(text)
    return file


def _endpoints(kind: str, endpoints: list[str]) -> str:
    return f"{kind}: {{ endpoints: {json.dumps(endpoints)} }}"


def wait_until(
    condition: Callable[[], bool], timeout: float, what: str, every: float = 0.01
) -> float:
    """Poll until ``condition`` holds; the seconds it took. ``TimeoutError`` names ``what``."""
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > timeout:
            raise TimeoutError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(every)
    return time.monotonic() - start
