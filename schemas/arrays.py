"""Conversion between numpy arrays and the wire's ``NDArray``."""

from __future__ import annotations

import math

import numpy as np

from schemas.messages import NDArray


def to_wire(array: np.ndarray) -> NDArray:
    """Pack an array as little-endian bytes with its dtype and shape."""
    array = np.ascontiguousarray(array)
    if array.dtype.byteorder == ">":
        array = array.astype(array.dtype.newbyteorder("<"))
    dtype = array.dtype.str
    return NDArray(data=array.tobytes(), dtype=dtype, shape=list(array.shape))


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
