"""Keep freed memory in the process instead of handing it back to the kernel after every frame.

glibc serves a large allocation (a depth frame's payload, an MCAP chunk of 1 MiB, zstd's output
buffer) from the heap once it has seen one freed, but it gives the top of the heap back to the
kernel as soon as more than twice that lies free there. A service that allocates and frees a
few such buffers per frame then maps the same pages again for the next frame and the kernel
zeroes each one on first touch: 71 page faults per recorded depth frame, 0.15 ms of its 0.77 ms
(``perf record`` put the write loop's kernel time in ``exc_page_fault``, ``clear_page_erms`` and
``__do_sys_brk``).

``keep_freed_memory`` raises both thresholds once for the process: allocations below
``mmap_threshold`` come from the heap, and up to ``trim_threshold`` bytes free at its top stay
mapped for the next frame. Elsewhere than glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

MMAP_THRESHOLD = 4 * 1024 * 1024  # above a 1 MiB chunk, its compressed copy and a frame
TRIM_THRESHOLD = 8 * 1024 * 1024  # the most a quiet heap keeps beyond what it uses


def keep_freed_memory(
    mmap_threshold: int = MMAP_THRESHOLD, trim_threshold: int = TRIM_THRESHOLD
) -> bool:
    """Set glibc's thresholds for this process; ``False`` where there is no glibc to ask."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False  # musl has no mallopt
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    # Setting either turns off glibc's own adjustment of both, so both are set.
    return bool(mallopt(_M_MMAP_THRESHOLD, mmap_threshold)) and bool(
        mallopt(_M_TRIM_THRESHOLD, trim_threshold)
    )
