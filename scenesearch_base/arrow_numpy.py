"""Arrow columns as numpy arrays, and numpy arrays as Arrow, without pyarrow's pandas bridge.

``pyarrow``'s own ``to_numpy`` converts through its pandas layer, whose first use in a process imports
pandas (a large share of a one-query command's time: ``docs/research/cli-startup.md``). The columns a
query reads are fixed-width numbers without nulls, whose values buffer *is* the numpy array:
:func:`to_numpy` views it, and reads strings as Python objects, as pyarrow would. ``pa.array`` asks
pandas whether a numpy array is one of its own before converting it: :func:`from_numpy` builds the
Arrow array from the buffer.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pyarrow as pa


def to_numpy(values: pa.Array | pa.ChunkedArray) -> np.ndarray:
    """``values`` (N,) as numpy: a read-only view of an integer or floating column without nulls (one
    copy when it has several chunks), strings without nulls as an object array; anything else through
    ``pyarrow``'s ``to_numpy``."""
    if isinstance(values, pa.ChunkedArray):
        if values.num_chunks == 1:
            return to_numpy(values.chunk(0))
        if values.num_chunks:
            return np.concatenate([to_numpy(chunk) for chunk in values.chunks])
        if _fixed_width(values.type):
            return np.empty(0, np.dtype(values.type.to_pandas_dtype()))
        return np.empty(0, object) if is_string(values.type) else values.to_numpy()
    if not values.null_count and is_string(values.type):
        return np.array(values.to_pylist(), dtype=object)
    if values.null_count or not _fixed_width(values.type):
        return values.to_numpy(zero_copy_only=False)
    dtype = np.dtype(values.type.to_pandas_dtype())  # a numpy type for these types: no pandas involved
    data = values.buffers()[1]
    if data is None:  # an empty array may have no values buffer
        return np.empty(0, dtype)
    return np.frombuffer(data, dtype=dtype, count=len(values), offset=values.offset * dtype.itemsize)


def is_string(dtype: pa.DataType) -> bool:
    """Whether ``dtype`` is Arrow's ``string`` or ``large_string``."""
    return bool(pa.types.is_string(dtype) or pa.types.is_large_string(dtype))


def _fixed_width(dtype: pa.DataType) -> bool:
    return bool(pa.types.is_integer(dtype) or pa.types.is_floating(dtype))


def from_numpy(values: np.ndarray) -> pa.Array:
    """A one-dimensional numeric or boolean numpy array (N,) as an Arrow array without nulls."""
    values = np.ascontiguousarray(values)
    if values.ndim != 1:
        raise ValueError(f"expected a one-dimensional array, got shape {values.shape}")
    if values.dtype == np.bool_:
        bits = np.packbits(values, bitorder="little")  # Arrow's booleans: one bit each, least significant first
        return pa.Array.from_buffers(pa.bool_(), len(values), [None, pa.py_buffer(bits)])
    if values.dtype.kind not in "iuf":
        raise TypeError(f"expected numbers or booleans, got {values.dtype}")
    return pa.Array.from_buffers(pa.from_numpy_dtype(values.dtype), len(values), [None, pa.py_buffer(values)])


def strings(values: Sequence[str]) -> pa.Array:
    """Python strings (N,) as an Arrow ``string`` array without nulls."""
    encoded = [str(v).encode() for v in values]
    offsets = np.zeros(len(encoded) + 1, np.int64)
    np.cumsum([len(b) for b in encoded], out=offsets[1:])
    if offsets[-1] >= 2**31:
        return pa.Array.from_buffers(pa.large_string(), len(encoded),
                                     [None, pa.py_buffer(offsets), pa.py_buffer(b"".join(encoded))])
    return pa.Array.from_buffers(pa.string(), len(encoded),
                                 [None, pa.py_buffer(offsets.astype(np.int32)), pa.py_buffer(b"".join(encoded))])


def scalar(value: Any, dtype: pa.DataType) -> pa.Scalar:
    """``value`` as an Arrow scalar of ``dtype``: numbers, booleans, timestamps, durations and strings built
    from buffers, other types by ``pa.scalar``.

    Raises:
        ValueError, TypeError, OverflowError: ``value`` does not fit ``dtype``.
    """
    if is_string(dtype):
        if not isinstance(value, str):
            raise TypeError(f"expected a string, got {type(value).__name__}")
        return strings([value]).cast(dtype)[0]
    if pa.types.is_boolean(dtype):
        if not isinstance(value, (bool, np.bool_)):
            raise TypeError(f"expected true or false, got {type(value).__name__}")
        return from_numpy(np.array([value], dtype=bool))[0]
    if pa.types.is_integer(dtype) or pa.types.is_floating(dtype):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise TypeError(f"expected a number, got {type(value).__name__}")
        numpy_type = np.dtype(dtype.to_pandas_dtype())
        if numpy_type.kind in "iu":
            if value != int(value):
                raise ValueError(f"{value!r} is not an integer")
            info = np.iinfo(numpy_type)
            if not info.min <= int(value) <= info.max:
                raise OverflowError(f"{value!r} is out of the range of {dtype}")
        return from_numpy(np.array([value], dtype=numpy_type))[0]
    if pa.types.is_timestamp(dtype) or pa.types.is_duration(dtype):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            return pa.scalar(value, type=dtype)  # datetimes and timedeltas: pyarrow's own conversion
        return pa.Array.from_buffers(dtype, 1, [None, pa.py_buffer(np.array([value], np.int64))])[0]
    return pa.scalar(value, type=dtype)


def mask(values: pa.Array | pa.ChunkedArray) -> np.ndarray:
    """A boolean Arrow array (N,) as a numpy bool mask, nulls counted as false."""
    if isinstance(values, pa.ChunkedArray):
        if values.num_chunks == 0:
            return np.zeros(0, bool)
        return np.concatenate([mask(chunk) for chunk in values.chunks])
    if not pa.types.is_boolean(values.type):
        raise TypeError(f"expected booleans, got {values.type}")
    validity, data = values.buffers()[:2]
    out = _bits(data, values.offset, len(values))
    if validity is not None and values.null_count:
        out &= _bits(validity, values.offset, len(values))
    return out


def _bits(buffer: pa.Buffer | None, offset: int, n: int) -> np.ndarray:
    if buffer is None:
        return np.zeros(n, bool)
    bits = np.unpackbits(np.frombuffer(buffer, np.uint8), bitorder="little")
    return bits[offset:offset + n].astype(bool)
