"""Child processes never outlive their parent."""

from __future__ import annotations

import contextlib
import ctypes
import signal


def die_with_parent(sig: int = signal.SIGTERM) -> None:
    """Ask the kernel for ``sig`` when the parent process dies (Linux; elsewhere nothing), so
    that no child outlives a supervisor, a service or a replay killed with SIGKILL."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, sig)  # PR_SET_PDEATHSIG
