"""Search-time knobs (``nprobe``, ``efSearch``, threads) and tuning them to a target recall.

Tuning searches a held-out sample of the collection's own vectors: each sampled vector is a query
whose own id is dropped from both the exact and the approximate answer, so the sample behaves like
a query that is not in the collection (otherwise the trivial self match would inflate recall).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from enum import Enum
from typing import Any

import faiss
import numpy as np
from faiss.contrib.evaluation import knn_intersection_measure

from indexes.factory import AutoConfig
from indexes.vectors import Metric


class Knob(str, Enum):
    """The parameter that trades speed for recall in a given index kind."""

    NONE = "none"  # exact or fixed-cost index
    NPROBE = "nprobe"  # IVF: lists scanned per query
    EF_SEARCH = "efSearch"  # HNSW: candidate list length


def unwrap(index: faiss.Index) -> faiss.Index:
    """The innermost index that does the searching: through IDMap, PreTransform and Refine."""
    while True:
        if isinstance(index, faiss.IndexIDMap | faiss.IndexIDMap2 | faiss.IndexPreTransform):
            index = faiss.downcast_index(index.index)
        elif isinstance(index, faiss.IndexRefine):
            index = faiss.downcast_index(index.base_index)
        else:
            return index


def knob_of(index: faiss.Index) -> Knob:
    inner = unwrap(index)
    if faiss.try_extract_index_ivf(inner) is not None:
        return Knob.NPROBE
    if isinstance(inner, faiss.IndexHNSW):
        return Knob.EF_SEARCH
    return Knob.NONE


def _knob_holder(index: faiss.Index) -> tuple[Knob, Any]:
    """The knob of ``index`` and the FAISS object whose attribute of that name holds it (None: no knob)."""
    inner = unwrap(index)
    knob = knob_of(inner)
    if knob is Knob.NPROBE:
        return knob, faiss.extract_index_ivf(inner)
    if knob is Knob.EF_SEARCH:
        return knob, inner.hnsw  # type: ignore[attr-defined]
    return knob, None


def get_knob(index: faiss.Index) -> int:
    knob, holder = _knob_holder(index)
    return 0 if holder is None else int(getattr(holder, knob.value))


def set_knob(index: faiss.Index, value: int) -> None:
    knob, holder = _knob_holder(index)
    if holder is not None:
        setattr(holder, knob.value, int(value))


#: Most candidates an HNSW search is widened to; beyond it a search costs more than exact search.
MAX_EF_SEARCH = 4096


def knob_limit(index: faiss.Index) -> int:
    """Largest sensible value: all lists for IVF, :data:`MAX_EF_SEARCH` candidates for HNSW."""
    knob, holder = _knob_holder(index)
    if knob is Knob.NPROBE:
        return int(holder.nlist)
    return MAX_EF_SEARCH if knob is Knob.EF_SEARCH else 0


def search_parameters(index: faiss.Index, sel: faiss.IDSelector | None,
                      knob_value: int | None = None) -> faiss.SearchParameters:
    """Per-call parameters of the right type for ``index``, carrying the selector and the knob.

    FAISS requires the parameter object to match the searching index (``SearchParametersIVF`` for
    IVF, …), and such an object replaces the index's own ``nprobe``/``efSearch``, so the current
    value is copied in.
    """
    value = get_knob(index) if knob_value is None else knob_value
    knob = knob_of(index)
    params: faiss.SearchParameters
    if knob is Knob.NPROBE:
        params = faiss.SearchParametersIVF(nprobe=int(value))  # type: ignore[call-arg]
    elif knob is Knob.EF_SEARCH:
        params = faiss.SearchParametersHNSW(efSearch=int(value))  # type: ignore[attr-defined]
    else:
        params = faiss.SearchParameters()
    if sel is not None:
        params.sel = sel
    return params


#: Below this many queries FAISS searches one query per thread (flat and IVF alike, under its BLAS
#: threshold), so extra threads only spin at the barrier afterwards, taking CPU from the caller's
#: own threads (e.g. the text encoder's) for milliseconds: such searches run on one thread.
SMALL_BATCH_QUERIES = 20


@contextmanager
def faiss_threads_for(nq: int) -> Iterator[None]:
    """Run FAISS on one thread while searching fewer than :data:`SMALL_BATCH_QUERIES` queries.

    OpenMP's thread count is per calling thread, so concurrent searches in other threads (the
    service) keep theirs.
    """
    if nq >= SMALL_BATCH_QUERIES:
        yield
        return
    before = faiss.omp_get_max_threads()
    faiss.omp_set_num_threads(1)
    try:
        yield
    finally:
        faiss.omp_set_num_threads(before)


@dataclass(frozen=True)
class TuningResult:
    """Outcome of :func:`tune`; stored in the manifest.

    Attributes:
        knob: name of the tuned parameter (``none`` for exact indexes).
        value: chosen value.
        recall_at_k: recall@k measured on the held-out sample at that value (None: not measured).
        k: the k of that recall.
        target_recall: what had to be reached; ``recall_at_k`` may stay below it for compressed codes.
        margin: tuning aimed at ``target_recall + margin`` (see ``AutoConfig.tune_margin``).
        n_queries: sample size.
        curve: (value, recall) pairs tried, in order.
    """

    knob: str
    value: int
    recall_at_k: float | None
    k: int
    target_recall: float
    margin: float
    n_queries: int
    curve: list[tuple[int, float]]

    def to_dict(self) -> dict[str, object]:
        d = asdict(self)
        d["curve"] = [list(p) for p in self.curve]
        return d


SearchFn = Callable[[int, int], np.ndarray]


def recall_excluding_self(i_exact: np.ndarray, i_found: np.ndarray, self_ids: np.ndarray, k: int) -> float:
    """Mean recall@k after dropping each query's own id from both (nq, k + 1) id tables."""
    return knn_intersection_measure(_drop_self(i_exact, self_ids, k), _drop_self(i_found, self_ids, k))


def _drop_self(table: np.ndarray, self_ids: np.ndarray, k: int) -> np.ndarray:
    """(nq, k+1) → (nq, k): remove the query's own id, or the last column when it is absent."""
    keep = table != self_ids[:, None]
    # Rows where the self id is missing keep only their first k entries.
    over = keep.sum(axis=1) > k
    keep[over, k] = False
    return table[keep].reshape(len(table), k)


def tune(search: SearchFn, exact_ids: np.ndarray, self_ids: np.ndarray, k: int, knob: Knob,
         limit: int, target_recall: float, start: int = 1, margin: float = 0.0) -> TuningResult:
    """Smallest knob value whose recall@k reaches ``target_recall``.

    Doubles the value from ``start`` up to ``limit``, then bisects between the last two tried.
    Stops early when recall no longer improves (compressed codes have a ceiling below 1).

    Args:
        search: ``search(k + 1, value) -> (nq, k + 1)`` ids of the held-out queries.
        exact_ids: (nq, k + 1) ids from exact search of the same queries.
        self_ids: (nq,) the id of the vector each query was drawn from.
        k: recall is measured at k.
        knob: the parameter tuned.
        limit: the largest value tried.
        target_recall: recall to reach.
        start: the first value tried.
        margin: aim at ``min(1, target_recall + margin)``.
    """
    aim = min(1.0, target_recall + margin)
    curve: list[tuple[int, float]] = []

    def measure(value: int) -> float:
        r = recall_excluding_self(exact_ids, search(k + 1, value), self_ids, k)
        curve.append((value, float(r)))
        return float(r)

    value = max(1, min(start, limit))
    prev_value, prev_recall = 0, -1.0
    recall = measure(value)
    while recall < aim and value < limit:
        if recall <= prev_recall + 1e-4 and prev_value > 0 and value >= 4 * start:
            break  # plateau: more effort no longer helps
        prev_value, prev_recall = value, recall
        value = min(2 * value, limit)
        recall = measure(value)
    if recall >= aim and prev_value > 0:
        lo, hi, hi_recall = prev_value, value, recall
        while hi - lo > max(1, lo // 8):
            mid = (lo + hi) // 2
            r = measure(mid)
            if r >= aim:
                hi, hi_recall = mid, r
            else:
                lo = mid
        value, recall = hi, hi_recall
    elif recall < aim and curve:
        value, recall = max(curve, key=lambda p: (p[1], -p[0]))
    return TuningResult(knob.value, int(value), float(recall), k, target_recall, margin, len(self_ids), curve)


def tune_index(index: faiss.Index, metric: Metric, x: np.ndarray, ids: np.ndarray, config: AutoConfig,
               query_ids: np.ndarray | None = None) -> TuningResult:
    """Tune the knob of ``index`` (holding ``x``) with held-out queries drawn from ``x``, and set it.

    Args:
        index: a built index holding the rows of ``x`` under ``ids``.
        metric: the index's metric (exact answers use it too).
        x: (N, d) prepared vectors.
        ids: (N,) their ids, sorted.
        config: ``tune_k``, ``tune_queries``, ``target_recall``, ``tune_margin`` and ``seed``.
        query_ids: (M,) ids of the rows that query; a seeded sample of ``tune_queries`` rows when None.
    """
    k = config.tune_k
    knob = knob_of(index)
    exact = isinstance(unwrap(index), faiss.IndexFlat)
    if exact or len(ids) <= k + 1:
        # Exact search, or too few vectors to hold any out: nothing to tune or measure.
        return TuningResult(Knob.NONE.value, 0, 1.0 if exact else None, k, config.target_recall, 0.0, 0, [])
    rng = np.random.default_rng(config.seed)
    if query_ids is None:
        rows = np.sort(rng.choice(len(ids), size=min(config.tune_queries, len(ids)), replace=False))
    else:
        rows = np.searchsorted(ids, query_ids)
    xq = np.ascontiguousarray(x[rows])
    self_ids = ids[rows]
    _, rows_exact = faiss.knn(xq, x, k + 1, metric=metric.faiss_metric)
    exact_ids = np.where(rows_exact >= 0, ids[np.maximum(rows_exact, 0)], -1)

    def search(kk: int, value: int) -> np.ndarray:
        if knob is Knob.NONE:
            return np.asarray(index.search(xq, kk)[1])
        return np.asarray(index.search(xq, kk, params=search_parameters(index, None, value))[1])

    start = 16 if knob is Knob.EF_SEARCH else 1
    # Kinds without a knob (e.g. flat PQ codes) get their recall measured once.
    limit = knob_limit(index) if knob is not Knob.NONE else 1
    result = tune(search, exact_ids, self_ids, k, knob, limit, config.target_recall, start=start,
                  margin=config.tune_margin)
    if knob is Knob.NONE:
        result = dataclasses.replace(result, value=0)
    set_knob(index, result.value)
    return result
