import numpy as np
import pytest

from indexes.errors import DimensionMismatchError, IdError, VectorError
from indexes.vectors import Metric, as_metric, prepare_ids, prepare_vectors


def test_prepare_vectors_copies_and_normalises_for_cosine() -> None:
    x = np.array([[3.0, 4.0], [0.0, 2.0]])
    out = prepare_vectors(x, 2, Metric.COSINE)
    assert out.dtype == np.float32 and out.flags.c_contiguous
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, rtol=1e-6)
    assert x[0, 0] == 3.0  # the caller's array is untouched
    np.testing.assert_array_equal(prepare_vectors(x, 2, Metric.L2), x.astype(np.float32))


def test_single_vector_becomes_one_row() -> None:
    assert prepare_vectors(np.ones(4), 4, Metric.L2).shape == (1, 4)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_names_the_row(bad: float) -> None:
    x = np.ones((5, 3))
    x[3, 1] = bad
    with pytest.raises(VectorError, match="row 3") as info:
        prepare_vectors(x, 3, Metric.L2)
    assert info.value.row == 3


def test_zero_vector_under_cosine_names_the_row() -> None:
    x = np.ones((4, 3))
    x[2] = 0
    with pytest.raises(VectorError, match="row 2"):
        prepare_vectors(x, 3, Metric.COSINE)
    prepare_vectors(x, 3, Metric.L2)  # fine for L2


def test_wrong_dimension_and_shape() -> None:
    with pytest.raises(DimensionMismatchError, match="dimension 5.*dimension 4"):
        prepare_vectors(np.ones((2, 5)), 4, Metric.L2)
    with pytest.raises(VectorError):
        prepare_vectors(np.ones((2, 2, 2)), None, Metric.L2)
    with pytest.raises(VectorError):
        prepare_vectors(np.array([["a", "b"]]), None, Metric.L2)


def test_ids_checks() -> None:
    np.testing.assert_array_equal(prepare_ids(None, 3, start=5), [5, 6, 7])
    with pytest.raises(IdError, match="duplicate ids.*4"):
        prepare_ids([1, 4, 4], 3)
    with pytest.raises(IdError, match="negative"):
        prepare_ids([1, -1, 2], 3)
    with pytest.raises(IdError, match="3 integers"):
        prepare_ids([1, 2], 3)
    with pytest.raises(IdError, match="integers"):
        prepare_ids([1.5, 2.0], 2)


def test_metric_vocabulary() -> None:
    assert as_metric("cosine") is Metric.COSINE
    with pytest.raises(ValueError, match="cosine, ip, l2"):
        as_metric("dot")
