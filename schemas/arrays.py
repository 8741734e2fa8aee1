"""Conversion between numpy arrays and the wire's ``NDArray``."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from schemas.messages import NDArray


def to_wire(array: np.ndarray) -> NDArray:
    """Pack an array as little-endian bytes with its dtype and shape."""
    array = _little_endian(array)
    return NDArray(data=array.tobytes(), dtype=array.dtype.str, shape=list(array.shape))


def to_wire_rows(array: np.ndarray, bounds: Sequence[int]) -> list[NDArray]:
    """``to_wire(array[a:b])`` for each consecutive ``a, b`` of ``bounds``, all cut from one
    conversion to bytes: the scans service sends its four lines' points so, where a
    conversion per line cost it four of numpy's calls (each dearer when the caches are cold,
    as in a shared loop)."""
    array = _little_endian(array)
    data, dtype, rest = array.tobytes(), array.dtype.str, list(array.shape[1:])
    row = math.prod(rest) * array.dtype.itemsize
    return [
        NDArray(data=data[a * row : b * row], dtype=dtype, shape=[b - a, *rest])
        for a, b in itertools.pairwise(bounds)
    ]


def _little_endian(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    if array.dtype.byteorder == ">":
        array = array.astype(array.dtype.newbyteorder("<"))
    return array


def from_wire(message: NDArray, *, finite: bool = True) -> np.ndarray:
    """Unpack an ``NDArray`` (a read-only view on its bytes).

    Raises ``ValueError`` when the byte count does not match dtype and shape, or when
    ``finite`` is set and a float array holds NaN or inf.
    """
    try:
        dtype = np.dtype(message.dtype)
    except TypeError as exc:
        raise ValueError(f"unknown array dtype {message.dtype!r}") from exc
    # math.prod, not np.prod: a few elements, where numpy's call costs more than the product
    # (half of this function's time per scan line); and no int64 wrap-around on a hostile shape.
    expected = math.prod(message.shape) * dtype.itemsize
    if len(message.data) != expected:
        raise ValueError(
            f"array data has {len(message.data)} bytes, expected {expected} for "
            f"{message.dtype} {tuple(message.shape)}"
        )
    array = np.frombuffer(message.data, dtype=dtype).reshape(message.shape)
    if finite and dtype.kind == "f" and not np.isfinite(array).all():
        raise ValueError("array holds NaN or inf")
    return array


def joined_points(messages: Sequence[NDArray]) -> np.ndarray | None:
    """The points of several float32 (N, 3) arrays as one read-only (sum N, 3) float32 array,
    or ``None`` unless every one is float32 (N, 3) with its bytes (then ``from_wire`` each).

    Raises ``ValueError`` as ``from_wire`` does when a point holds NaN or inf. The scans
    service sends its four scan lines so: one copy and one finiteness test for all of them
    instead of one of each per line (aim and the reconstructor read every frame's)."""
    if not messages or not all(
        m.dtype == "<f4"
        and len(m.shape) == 2
        and m.shape[1] == 3
        and len(m.data) == 12 * m.shape[0]
        for m in messages
    ):
        return None
    points = np.frombuffer(b"".join([m.data for m in messages]), dtype="<f4").reshape(-1, 3)
    if not np.isfinite(points).all():
        raise ValueError("array holds NaN or inf")
    return points
