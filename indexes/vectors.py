"""Vector batches: the metric vocabulary and the checks every batch passes before FAISS sees it.

FAISS crashes or silently misbehaves on NaN, wrong dtypes or strided arrays, so every public entry
point converts its input here into a C-contiguous float32 (N, d) copy and names the first bad row.
"""

from __future__ import annotations

from enum import Enum

import faiss
import numpy as np

from indexes.errors import DimensionMismatchError, IdError, VectorError
from scenesearch_base.config import parse_choice


class Metric(str, Enum):
    """How similar two vectors are. The string values are used in manifests and arguments."""

    COSINE = "cosine"  # inner product on L2-normalised vectors; scores in [-1, 1], higher is closer
    INNER_PRODUCT = "ip"  # raw inner product, higher is closer
    L2 = "l2"  # squared Euclidean distance, lower is closer

    @property
    def faiss_metric(self) -> int:
        return faiss.METRIC_L2 if self is Metric.L2 else faiss.METRIC_INNER_PRODUCT

    @property
    def higher_is_closer(self) -> bool:
        return self is not Metric.L2

    @property
    def missing_score(self) -> float:
        """Score reported beside the id −1 where fewer than k results exist."""
        return float("-inf") if self.higher_is_closer else float("inf")


def as_metric(metric: Metric | str) -> Metric:
    """Accept a :class:`Metric` or its string value; raise ``ValueError`` listing valid ones."""
    return parse_choice(Metric, metric, "metric", "valid metrics")


def prepare_vectors(x: np.ndarray, dim: int | None, metric: Metric, what: str = "vectors") -> np.ndarray:
    """Return a checked float32 copy of ``x`` ready for FAISS; normalised rows for cosine.

    Args:
        x: (N, d) or (d,) array-like of numbers; a single vector is treated as one row.
        dim: the dimension the index expects, or None to accept any.
        metric: for :attr:`Metric.COSINE` rows are scaled to unit length.
        what: name of the argument, used in error messages.

    Returns:
        (N, d) float32, C-contiguous, never the caller's array.

    Raises:
        VectorError: not 1-D/2-D, empty dimension, NaN/inf in a row, or a zero row under cosine.
        DimensionMismatchError: ``d != dim``.
    """
    arr = np.asarray(x)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2:
        raise VectorError(f"{what} must be a (N, d) array, got shape {arr.shape}")
    if arr.dtype.kind not in "fiu":
        raise VectorError(f"{what} must hold numbers, got dtype {arr.dtype}")
    if arr.shape[1] == 0:
        raise VectorError(f"{what} have dimension 0")
    if dim is not None and arr.shape[1] != dim:
        raise DimensionMismatchError(dim, arr.shape[1], what)
    out = np.array(arr, dtype=np.float32, order="C", copy=True)
    # One pass over the whole batch first; rows are located only when something is wrong.
    if not np.isfinite(out).all():
        rows = np.flatnonzero(~np.isfinite(out).all(axis=1))
        raise VectorError(f"{what} hold NaN or inf ({len(rows)} bad rows in all)", row=int(rows[0]))
    if metric is Metric.COSINE and len(out):
        norms = np.sqrt(np.einsum("ij,ij->i", out, out))
        if not norms.all():
            raise VectorError(f"{what} hold a zero vector, which has no direction for cosine",
                              row=int(np.flatnonzero(norms == 0)[0]))
        out /= norms[:, None]
    return out


def prepare_ids(ids: np.ndarray | list[int] | None, n: int, start: int = 0) -> np.ndarray:
    """Return checked int64 ids for ``n`` vectors; ``start, start + 1, …`` when ``ids`` is None.

    Args:
        ids: (N,) integers, unique and ≥ 0 (−1 marks missing results), or None.
        n: number of vectors the ids label.
        start: first id when ids are generated.

    Returns:
        (N,) int64, C-contiguous.

    Raises:
        IdError: wrong length, negative or duplicated ids.
    """
    if ids is None:
        return np.arange(start, start + n, dtype=np.int64)
    arr = np.asarray(ids)
    if arr.ndim != 1 or len(arr) != n:
        raise IdError(f"ids must be a 1-D array of {n} integers, got shape {arr.shape}")
    if len(arr) and not np.issubdtype(arr.dtype, np.integer):
        raise IdError(f"ids must be integers, got dtype {arr.dtype}")
    out = np.ascontiguousarray(arr, dtype=np.int64)
    negative = out < 0
    if negative.any():
        raise IdError("ids must be ≥ 0 (−1 marks missing results); negative ids", out[negative].tolist())
    uniq, counts = np.unique(out, return_counts=True)
    if (counts > 1).any():
        raise IdError("duplicate ids in one batch", uniq[counts > 1].tolist())
    return out
