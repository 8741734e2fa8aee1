"""Work functions for tests/test_pipe_pool.py (importable by spawned workers)."""

from __future__ import annotations

import os
import time


def make_work(prefix: bytes):
    def work(job: bytes) -> bytes | str:
        if job == b"fail":
            return "cannot do 'fail'"
        if job == b"die":
            os._exit(3)
        if job.startswith(b"sleep"):
            time.sleep(float(job[5:]))
        return prefix + job + b"@" + str(os.getpid()).encode()

    return work


def broken_start(prefix: bytes):
    raise ImportError(f"cannot start: {prefix!r}")
