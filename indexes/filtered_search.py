"""k-NN search of a FAISS index restricted to some ids, never short of results that exist.

FAISS filters inside the search through ID selectors; an approximate index meets only the vectors in
the lists it probes (IVF) or the graph nodes it visits (HNSW), so a selective filter, or many
tombstones, can leave a row with fewer than k results although k vectors qualify. This module answers
each search so that a row is short only when fewer than k vectors qualify:

* a filter that passes at most :data:`EXACT_FILTER_MAX` vectors, or so few that the probed lists or
  the visited graph would meet too few of them, is answered by exact search over just those vectors;
* otherwise FAISS searches with a selector (the allowed ids, or every id but the tombstones); the rows
  that come back short are searched again with the knob (``nprobe``/``efSearch``) raised fourfold at a
  time up to its limit, and then exactly over the allowed vectors (up to :data:`EXACT_FALLBACK_MAX`).

Results follow FAISS: ``D`` and ``I`` are (nq, k), ``I`` holds ids sorted by closeness, and where fewer
than k vectors qualify ``I`` is −1 and ``D`` is the metric's missing score.
"""

# D and I are FAISS's names for the (nq, k) score and id tables.
# ruff: noqa: E741

from __future__ import annotations

from collections.abc import Callable

import faiss
import numpy as np

from indexes.errors import IndexesError, faiss_message
from indexes.tuning import Knob, faiss_threads_for, get_knob, knob_limit, search_parameters, unwrap
from indexes.vectors import Metric

#: Filters passing at most this many vectors are answered by exact search over just those vectors:
#: cheaper than a selector scan and never short of results.
EXACT_FILTER_MAX = 4096
#: Exact search over a filtered subset is also the last fallback, up to this many vectors.
EXACT_FALLBACK_MAX = 262_144


def filtered_search(index: faiss.Index, metric: Metric, factory: str, knob: Knob, live: np.ndarray,
                    tombstones: np.ndarray, reconstruct: Callable[[np.ndarray], np.ndarray], x: np.ndarray, k: int,
                    allowed: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest of the allowed vectors to each query.

    Args:
        index: the FAISS index; ``factory`` names it in errors, ``knob`` is its search knob.
        metric: the index's metric (its missing score pads short rows).
        live: (N,) sorted ids of the vectors in the index.
        tombstones: (T,) sorted ids still in ``index`` but removed: never returned.
        reconstruct: ids (M,) → their stored vectors (M, d), for exact search.
        x: (nq, d) prepared queries.
        k: results per query, 1 … N.
        allowed: (M,) sorted live ids allowed in the results, or None for every live id.

    Returns:
        D: (nq, k) float32 scores; I: (nq, k) int64 ids, −1 where fewer than k vectors qualify.

    Raises:
        IndexesError: the index takes no selector and the filter passes more than
            :data:`EXACT_FALLBACK_MAX` vectors.
    """
    if allowed is not None and _prefer_exact(index, knob, len(allowed), len(live)):
        return _exact_search(metric, reconstruct, x, k, allowed)
    sel_refs = _selector(allowed, tombstones)
    try:
        D, I = _faiss_search(index, x, k, sel_refs[0] if sel_refs else None)
    except RuntimeError as exc:
        # Some kinds (e.g. flat PQ) take no search parameters, hence no selector.
        subset = live if allowed is None else allowed
        if not sel_refs or len(subset) > EXACT_FALLBACK_MAX:
            raise IndexesError(f"factory {factory!r} cannot search with a filter: "
                               f"{faiss_message(exc)}") from None
        return _exact_search(metric, reconstruct, x, k, subset)
    expected = min(k, len(live) if allowed is None else len(allowed))
    # FAISS puts padding last, so a row is short exactly when its expected-th result is −1.
    if expected == 0 or I[:, expected - 1].min() >= 0:
        if expected < k:
            D[I < 0] = metric.missing_score
        return D, I
    short = np.flatnonzero(I[:, expected - 1] < 0)
    if knob is not Knob.NONE:
        # Filters and tombstones can leave an approximate search short: look further.
        value, limit = get_knob(index), knob_limit(index)
        while len(short) and value < limit:
            value = min(limit, value * 4)
            sel = sel_refs[0] if sel_refs else None
            D2, I2 = _faiss_search(index, x[short], k, sel, value)
            D[short], I[short] = D2, I2
            short = short[I2[:, expected - 1] < 0]
    if len(short):
        subset = live if allowed is None else allowed
        if len(subset) <= EXACT_FALLBACK_MAX:
            D[short], I[short] = _exact_search(metric, reconstruct, x[short], k, subset)
    D[I < 0] = metric.missing_score
    return D, I


def _prefer_exact(index: faiss.Index, knob: Knob, n_allowed: int, size: int) -> bool:
    if n_allowed <= EXACT_FILTER_MAX:
        return True
    if knob is Knob.NPROBE:
        ivf = faiss.extract_index_ivf(unwrap(index))
        # Expected allowed vectors met per query in the probed lists; too few → short results.
        return n_allowed * ivf.nprobe / max(ivf.nlist, 1) < 64
    if knob is Knob.EF_SEARCH:
        return n_allowed < 0.02 * size
    return False


def _selector(allowed: np.ndarray | None, tombstones: np.ndarray) -> list[faiss.IDSelector]:
    """Selector for a search, plus every object it points to (kept alive by the list)."""
    if allowed is not None:
        return [faiss.IDSelectorBatch(allowed)]
    if len(tombstones):
        inner = faiss.IDSelectorBatch(tombstones)
        return [faiss.IDSelectorNot(inner), inner]
    return []


def _faiss_search(index: faiss.Index, x: np.ndarray, k: int, sel: faiss.IDSelector | None,
                  knob_value: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    with faiss_threads_for(len(x)):
        if sel is None and knob_value is None:
            D, I = index.search(x, k)
        else:
            params = search_parameters(index, sel, knob_value)
            D, I = index.search(x, k, params=params)
    return np.asarray(D), np.asarray(I)


def _exact_search(metric: Metric, reconstruct: Callable[[np.ndarray], np.ndarray], x: np.ndarray, k: int,
                  subset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact k-NN of ``x`` (nq, d) among the vectors with ids ``subset`` (M,), padded with −1."""
    nq = len(x)
    D = np.full((nq, k), metric.missing_score, dtype=np.float32)
    I = np.full((nq, k), -1, dtype=np.int64)
    if len(subset) == 0:
        return D, I
    xb = reconstruct(subset)
    kk = min(k, len(subset))
    with faiss_threads_for(len(x)):
        d_sub, i_sub = faiss.knn(x, xb, kk, metric=metric.faiss_metric)
    D[:, :kk] = d_sub
    I[:, :kk] = np.where(i_sub >= 0, subset[np.maximum(i_sub, 0)], -1)
    return D, I
