"""Child processes never outlive their parent, and stop when asked."""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import subprocess


def die_with_parent(sig: int = signal.SIGTERM, parent_pid: int | None = None) -> None:
    """Ask the kernel for ``sig`` when the parent process dies (Linux; elsewhere nothing), so
    that no child outlives a supervisor, a service or a replay killed with SIGKILL.

    A spawned worker asks only once it has imported its modules (seconds on a loaded board): if
    its parent (``parent_pid``, or ``multiprocessing``'s parent) died meanwhile, it gets ``sig``
    now."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, sig)  # PR_SET_PDEATHSIG
    if parent_pid is None:
        parent = multiprocessing.parent_process()
        parent_pid = None if parent is None else parent.pid
    if parent_pid is not None and os.getppid() != parent_pid:
        os.kill(os.getpid(), sig)


def stop(process: subprocess.Popen[bytes], sig: int = signal.SIGTERM, grace_s: float = 10.0) -> int:
    """Ask ``process`` to stop with ``sig`` and wait ``grace_s`` for it; then kill it (and its
    process group, when it leads one: an ``lpc up`` takes its services with it). Its exit code."""
    if process.poll() is None:
        process.send_signal(sig)
        try:
            return process.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                if os.getpgid(process.pid) == process.pid:
                    os.killpg(process.pid, signal.SIGKILL)
            process.kill()
    return process.wait()
