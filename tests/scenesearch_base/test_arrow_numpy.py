"""Arrow ↔ numpy without pyarrow's pandas bridge: the same values as pyarrow's conversions, and no pandas."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

from scenesearch_base.arrow_numpy import from_numpy, mask, scalar, strings, to_numpy


@pytest.mark.parametrize("dtype", [pa.int64(), pa.int32(), pa.uint8(), pa.float32(), pa.float64()])
def test_numbers_round_trip_through_sliced_and_chunked_arrays(dtype: pa.DataType) -> None:
    values = np.arange(10).astype(dtype.to_pandas_dtype())
    arr = from_numpy(values)
    assert arr.type == dtype
    np.testing.assert_array_equal(to_numpy(arr), values)
    np.testing.assert_array_equal(to_numpy(arr.slice(3, 4)), values[3:7])  # an offset into the buffer
    chunked = pa.chunked_array([arr.slice(0, 4), arr.slice(4)])
    np.testing.assert_array_equal(to_numpy(chunked), values)
    assert to_numpy(pa.chunked_array([], type=dtype)).dtype == np.dtype(dtype.to_pandas_dtype())


def test_strings_and_columns_with_nulls_read_as_pyarrow_reads_them() -> None:
    words = ["car", "", "bicycle", "ünïcode"]
    arr = strings(words)
    assert arr.type == pa.string() and arr.to_pylist() == words
    assert to_numpy(arr).tolist() == words
    with_nulls = pa.array([1, None, 3])
    np.testing.assert_array_equal(to_numpy(with_nulls), with_nulls.to_numpy(zero_copy_only=False))


def test_boolean_masks_count_nulls_as_false_at_any_offset() -> None:
    values = np.array([True, False, True, True, False, False, True, True, True, False, True])
    arr = from_numpy(values)
    assert arr.to_pylist() == values.tolist()
    np.testing.assert_array_equal(mask(arr), values)
    np.testing.assert_array_equal(mask(arr.slice(3, 6)), values[3:9])
    with_nulls = pa.array([True, None, False, True])
    np.testing.assert_array_equal(mask(with_nulls), [True, False, False, True])
    np.testing.assert_array_equal(mask(pc.equal(pa.chunked_array([[1, 2], [2]]), scalar(2, pa.int64()))),
                                  [False, True, True])


def test_scalars_match_pyarrow_and_refuse_what_does_not_fit() -> None:
    for value, dtype in [(5, pa.int32()), (2.5, pa.float32()), (3, pa.float64()), (True, pa.bool_()),
                         ("car", pa.string()), ("car", pa.large_string()), (7, pa.timestamp("ns")),
                         (7, pa.duration("ns"))]:
        assert scalar(value, dtype) == pa.scalar(value, type=dtype)
    with pytest.raises(OverflowError):
        scalar(300, pa.uint8())
    with pytest.raises(ValueError):
        scalar(1.5, pa.int64())
    with pytest.raises(TypeError):
        scalar("5", pa.int64())
    with pytest.raises(TypeError):
        scalar(True, pa.int64())
    with pytest.raises(TypeError):
        scalar(5, pa.string())


def test_from_numpy_refuses_other_shapes_and_types() -> None:
    with pytest.raises(ValueError, match="one-dimensional"):
        from_numpy(np.zeros((2, 2)))
    with pytest.raises(TypeError):
        from_numpy(np.array(["a"]))


def test_no_conversion_imports_pandas() -> None:
    code = """
import sys
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from scenesearch_base.arrow_numpy import from_numpy, mask, scalar, strings, to_numpy
ids = from_numpy(np.arange(5))
to_numpy(pa.chunked_array([ids, ids]))
mask(pc.equal(ids, scalar(3, pa.int64())))
to_numpy(strings(["a", "b"]))
pc.is_in(strings(["a", "b"]), value_set=strings(["b"]))
assert "pandas" not in sys.modules, "pandas was imported"
"""
    subprocess.run([sys.executable, "-c", code], check=True)
