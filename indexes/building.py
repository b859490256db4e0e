"""A trained, empty FAISS index for a collection: factory choice, the id map, training on a sample.

:class:`~indexes.vector_index.VectorIndex` and :class:`~indexes.sharded.ShardedIndex` both start
here; the shards of a sharded index share the one trained index this returns.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import faiss
import numpy as np

from indexes.errors import faiss_message
from indexes.factory import AutoConfig, choose_factory, train_points
from indexes.vectors import Metric, prepare_ids, prepare_vectors

IdsLike = np.ndarray | Sequence[int]


def prepare_build(xb: np.ndarray, ids: IdsLike | None, metric: Metric, factory: str,
                  memory_budget_bytes: int | None, config: AutoConfig) -> tuple[
        np.ndarray, np.ndarray, str, faiss.Index, dict[str, Any]]:
    """Check vectors and ids, choose the factory (``auto``) and train an empty FAISS index.

    Returns:
        (N, d) prepared vectors, (N,) ids, the factory string, the trained empty index and the
        build information (choice reason, training figures).
    """
    x = prepare_vectors(xb, None, metric, "xb")
    n, d = x.shape
    id_arr = prepare_ids(None if ids is None else np.asarray(ids), n)
    info: dict[str, Any] = {}
    if factory == "auto":
        choice = choose_factory(n, d, memory_budget_bytes, config)
        factory = choice.factory
        info.update(choice_reason=choice.reason, estimated_bytes=choice.estimated_bytes)
    index = new_faiss_index(factory, d, metric)
    info.update(train(index, factory, x, config))
    return x, id_arr, factory, index, info


def train(index: faiss.Index, factory: str, x: np.ndarray, config: AutoConfig) -> dict[str, Any]:
    """Train ``index`` (if it needs it) on a seeded sample of ``x`` (N, d); returns info fields."""
    if index.is_trained:
        return {}
    n = len(x)
    n_train = train_points(factory, n, config) or min(n, 100_000)
    rng = np.random.default_rng(config.seed)
    sample = np.sort(rng.choice(n, size=n_train, replace=False)) if n_train < n else np.arange(n)
    try:
        index.train(np.ascontiguousarray(x[sample]))
    except RuntimeError as exc:
        raise ValueError(f"factory {factory!r} cannot be trained on {n} vectors: {faiss_message(exc)}") from None
    return {"train_points": len(sample)}


def new_faiss_index(factory: str, d: int, metric: Metric) -> faiss.Index:
    """An empty FAISS index for ``factory`` that accepts the caller's ids and reconstructs by id."""
    try:
        index = faiss.index_factory(d, factory, metric.faiss_metric)
    except RuntimeError as exc:
        raise ValueError(f"FAISS rejects factory string {factory!r}: {faiss_message(exc)}") from None
    ivf = faiss.try_extract_index_ivf(index)
    if ivf is not None and not isinstance(index, faiss.IndexIDMap | faiss.IndexIDMap2):
        # IVF lists store ids natively; a hash-table map adds lookup (reconstruct) and removal by id.
        ivf.set_direct_map_type(faiss.DirectMap.Hashtable)  # type: ignore[attr-defined]
        return index
    if isinstance(index, faiss.IndexIDMap | faiss.IndexIDMap2):
        return index
    return faiss.IndexIDMap2(index)
