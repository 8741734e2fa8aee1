"""services.heap: freed buffers stay in the process, so a loop that builds and drops MCAP-chunk
sized buffers stops faulting their pages in again. Each case runs in a fresh interpreter: the
thresholds are the process's, and the pytest process's heap is not a fresh service's."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

# What the recorder does per chunk: 1 MiB built from 204 KB payloads, then a copy of it.
_CHUNK_LOOP = """
import io, os, resource, sys
if sys.argv[1] == "keep":
    from services.heap import keep_freed_memory
    assert keep_freed_memory()
payload = os.urandom(204_000)
def chunk():
    buf = io.BytesIO()
    for _ in range(6):
        buf.write(payload)
    data = buf.getvalue()
    return data + data[:300_000]
chunk()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(50):
    chunk()
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 50)
"""


def _faults_per_chunk(mode: str) -> float:
    out = subprocess.run(
        [sys.executable, "-c", _CHUNK_LOOP, mode], capture_output=True, text=True, check=True
    )
    return float(out.stdout)


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's mallopt")
def test_kept_memory_is_not_faulted_in_again_chunk_after_chunk() -> None:
    default, kept = _faults_per_chunk("default"), _faults_per_chunk("keep")
    # glibc's default gives the pages back: hundreds of faults a chunk (712 here); kept, none.
    assert default > 100
    assert kept < 5
