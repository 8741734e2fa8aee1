"""Shared fixtures: a private loopback rendezvous per test, so tests never share a bus."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator

import pytest
import zenoh

from schemas import decode
from services.runtime import zenoh_config


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def rendezvous(endpoint: str) -> Iterator[zenoh.Session]:
    """A Zenoh session listening on ``endpoint``: what ``lpc up`` gives its services."""
    with zenoh.open(zenoh_config(connect=[], listen=[endpoint])) as session:
        yield session


def wait_for(condition: Callable[[], bool], timeout: float = 10.0, what: str = "") -> None:
    """Poll ``condition`` until it holds; fail the test after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout} s waiting for {what or condition}")
        time.sleep(0.01)


async def until(condition: Callable[[], bool], timeout: float = 10.0, what: str = "") -> None:
    """``wait_for`` inside an event loop: poll without blocking the services running on it."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        await asyncio.sleep(0.005)


class Listener:
    """Decodes what arrives on ``keys`` into ``messages`` (and the arrival times into
    ``received_ns``), on Zenoh's callback thread while the test reads them."""

    def __init__(self, session: zenoh.Session, *keys: str) -> None:
        self.messages: dict[str, list] = {k: [] for k in keys}
        self.received_ns: dict[str, list[int]] = {k: [] for k in keys}
        self._subs = [session.declare_subscriber(k, lambda s, k=k: self._on(k, s)) for k in keys]

    def _on(self, key: str, sample: zenoh.Sample) -> None:
        self.received_ns[key].append(time.monotonic_ns())
        self.messages[key].append(decode(str(sample.key_expr), sample.payload.to_bytes()))

    def snapshot(self, key: str) -> list:
        """The messages so far, copied in one step: two passes over ``messages[key]`` itself
        can see different lengths, since the callback thread appends between them."""
        return list(self.messages[key])

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


def spawn_service(module: str, endpoint: str, *args: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", module, "--connect", endpoint, "--quiet", *args],
        stdin=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
