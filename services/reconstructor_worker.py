"""The reconstructor's worker processes: an encoded input frame in, an encoded reconstruction
out (``services.pipe_pool`` runs them).

Its own module, so that a worker imports the method and the schemas but not the service around
it (Zenoh and the bus: about 12 MB of each worker's memory).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import msgspec

from lpc_core.perception.laser import LaserParams
from lpc_core.perception.pipeline import ScansState, scans_step
from lpc_core.perception.reconstructor import (
    INPUT_TOPICS,
    reconstruct_cloud_message,
    reconstruct_message,
    warmup_frame,
)
from schemas import BadMessage, decode, encode

_METHOD = "laser"
_PARAMS = LaserParams()


def init_worker(method: str, params: LaserParams) -> Callable[[bytes], bytes | str]:
    """Set the worker's method and parameters, and return ``work``."""
    global _METHOD, _PARAMS
    _METHOD, _PARAMS = method, params
    # Pay the imports and first calls now, before the service subscribes.
    frame = warmup_frame()
    work(encode(frame if method == "cloud" else scans_step(ScansState(), frame, 0)[1]))
    return work


def work(payload: bytes) -> bytes | str:
    """One input payload to an encoded reconstruction, or why not."""
    try:
        message = decode(INPUT_TOPICS[_METHOD], payload)
        start = time.process_time()
        if _METHOD == "cloud":
            result = reconstruct_cloud_message(message)
        else:
            result = reconstruct_message(message, _PARAMS)
        compute_ms = 1000.0 * (time.process_time() - start)
        return encode(msgspec.structs.replace(result, compute_ms=compute_ms))
    except (BadMessage, ValueError) as exc:
        return str(exc)
