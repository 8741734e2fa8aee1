"""The kernel's name of a thread (``/proc/PID/task/TID/comm``), for CPU per thread.

CPython 3.11 leaves every thread it starts named as the process (``python``), so the container's
event loops and the recorder's writer cannot be told apart from outside, where Zenoh's threads
carry their names (``rx-0``, ``tx-0``, ``net-0``, ``acc-0``). ``lpc bench footprint`` reads
these names to split the container's CPU by thread.
"""

from __future__ import annotations

import ctypes
import sys

_PR_SET_NAME = 15
_MAX_BYTES = 15  # the kernel keeps 16 bytes, the last a NUL

CONTROL_LOOP = "lpc-control"
RECORDER_WRITER = "mcap-writer"


def name_native_thread(name: str) -> bool:
    """Name the calling thread ``name`` (cut to 15 bytes) where the kernel allows it (Linux);
    whether it did. Never raises: a name is a convenience for whoever measures."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        # The process's own symbols hold libc's: no search for the library (find_library would
        # run ldconfig in a subprocess).
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_NAME, name.encode()[:_MAX_BYTES], 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False
