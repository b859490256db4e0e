"""Text → clip retrieval metrics, pure numpy: recall and precision at k, median rank and mean average precision.

The one implementation behind training validation (``metrics.jsonl``) and ``scenesearch eval``, so
both report the same figures for the same embeddings.

Ties count against the model: a relevant clip that scores the same as an irrelevant one ranks
after it. A model that gives every clip the same score therefore ranks each query's relevant
clips last, not first.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence

import numpy as np

from captioning.text import caption_halves

KS = (1, 5, 10)
CURVE_MAX_K = 50
#: Queries ranked at a time. A ranking's temporaries are several (rows, N) float64 and int64 arrays,
#: so taken by rows a large split's figures fit in memory, with the same values
#: (docs/research/eval-memory.md).
ROWS_AT_ONCE = 256


def _check_pair(sim: np.ndarray, relevant: np.ndarray, dtype: type | None = np.float64
                ) -> tuple[np.ndarray, np.ndarray]:
    """``sim`` (as ``dtype``; None: as given) and ``relevant`` as bool, both (Q, N)."""
    sim = np.asarray(sim, dtype=dtype)
    relevant = np.asarray(relevant, dtype=bool)
    if sim.ndim != 2 or sim.shape != relevant.shape:
        raise ValueError(f"sim {sim.shape} and relevant {relevant.shape} must both be (Q, N)")
    return sim, relevant


def _check_every_query_has_a_relevant_clip(relevant: np.ndarray) -> None:
    empty = np.flatnonzero(~relevant.any(axis=1))
    if len(empty):
        raise ValueError(f"query row {int(empty[0])} has no relevant clip ({len(empty)} such rows)")


def _rows(sim: np.ndarray, relevant: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(rows, N) slices of ``sim`` (as float64) and ``relevant`` (as bool), :data:`ROWS_AT_ONCE` queries at a time."""
    sim, relevant = _check_pair(sim, relevant, dtype=None)
    for start in range(0, sim.shape[0], ROWS_AT_ONCE):
        yield _check_pair(sim[start:start + ROWS_AT_ONCE], relevant[start:start + ROWS_AT_ONCE])


def _by_rows(per_query: Callable[[np.ndarray, np.ndarray], np.ndarray], sim: np.ndarray,
             relevant: np.ndarray) -> np.ndarray:
    """(Q,) ``per_query`` of each slice of :func:`_rows`, joined."""
    parts = [per_query(s, r) for s, r in _rows(sim, relevant)]
    return np.concatenate(parts) if parts else np.zeros(0)


def ranked_relevance(sim: np.ndarray, relevant: np.ndarray) -> np.ndarray:
    """(Q, N) bool: each query's relevance in ranked order, best first, relevant clips after tied irrelevant ones.

    Args:
        sim: (Q, N) scores, higher is closer.
        relevant: (Q, N) bool.
    """
    sim, relevant = _check_pair(sim, relevant)
    # lexsort's last key is the primary one: by score (descending), then irrelevant before relevant.
    order = np.lexsort((relevant, -sim), axis=1)
    return np.take_along_axis(relevant, order, axis=1)


def first_relevant_ranks(sim: np.ndarray, relevant: np.ndarray) -> np.ndarray:
    """(Q,) 1-based rank of the best-ranked relevant clip of each query (ties broken against the query).

    Args:
        sim: (Q, N) scores, higher is closer.
        relevant: (Q, N) bool; every row needs at least one True.
    """
    _check_every_query_has_a_relevant_clip(np.asarray(relevant, dtype=bool))

    def ranks(sim: np.ndarray, relevant: np.ndarray) -> np.ndarray:
        best = np.where(relevant, sim, -np.inf).max(axis=1)
        # An irrelevant clip scoring equal to the best relevant one ranks before it.
        return np.asarray(1 + ((sim > best[:, None]) | ((sim == best[:, None]) & ~relevant)).sum(axis=1))

    return _by_rows(ranks, sim, relevant).astype(np.int64)


def average_precision(sim: np.ndarray, relevant: np.ndarray) -> np.ndarray:
    """(Q,) average precision of each query's full ranking (ties broken against the query; 0 without
    a relevant clip)."""

    def precision(sim: np.ndarray, relevant: np.ndarray) -> np.ndarray:
        hits = ranked_relevance(sim, relevant)
        precision = np.cumsum(hits, axis=1) / np.arange(1, hits.shape[1] + 1)[None, :]
        return np.asarray((precision * hits).sum(axis=1) / np.maximum(hits.sum(axis=1), 1))

    return _by_rows(precision, sim, relevant)


def precision_at_k(sim: np.ndarray, relevant: np.ndarray, k: int = 10) -> np.ndarray:
    """(Q,) share of relevant clips among each query's top ``k`` (ties broken against the query).

    Queries without any relevant clip get NaN: they say nothing about the ranking.

    Args:
        sim: (Q, N) scores, higher is closer.
        relevant: (Q, N) bool.
    """
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")

    def precision(sim: np.ndarray, relevant: np.ndarray) -> np.ndarray:
        ranked = ranked_relevance(sim, relevant)[:, :k]  # (rows, min(k, N))
        out = ranked.sum(axis=1) / float(min(k, ranked.shape[1]) if ranked.shape[1] else 1)
        return np.where(relevant.any(axis=1), out, np.nan)

    return _by_rows(precision, sim, relevant)


def text_to_clip_figures(sim: np.ndarray, relevant: np.ndarray, ks: Sequence[int] = KS) -> dict[str, float]:
    """R@K (a relevant clip among the top K), median rank of the first relevant clip, and mAP.

    Args:
        sim: (Q, N) query × clip scores.
        relevant: (Q, N) bool relevance; every query needs a relevant clip.
        ks: cut-offs for recall.
    """
    return ranking_figures(first_relevant_ranks(sim, relevant), average_precision(sim, relevant), ks)


def ranking_figures(ranks: np.ndarray, average_precisions: np.ndarray, ks: Sequence[int] = KS) -> dict[str, float]:
    """:func:`text_to_clip_figures` from each query's first relevant rank (Q,) and average precision (Q,)."""
    out = {f"R@{k}": float(np.mean(ranks <= k)) for k in ks}
    out["median_rank"] = float(np.median(ranks))
    out["mAP"] = float(np.mean(average_precisions))
    return out


def text_to_clip_metrics(sim: np.ndarray, relevant: np.ndarray, ks: Sequence[int] = KS) -> dict[str, float]:
    """:func:`text_to_clip_figures` over the queries that have a relevant item, and their count.

    Args:
        sim: (Q, N) similarity of each query to each item (higher is better).
        relevant: (Q, N) bool, true where the item answers the query.
        ks: cut-offs for recall.

    Returns:
        ``R@k``, ``median_rank``, ``mAP`` (NaN when no query is left) and ``queries``: the queries
        kept (those with no relevant item are left out).
    """
    sim, relevant = _check_pair(sim, relevant, dtype=None)  # ranked by rows, in float64 then
    keep = relevant.any(axis=1)
    out: dict[str, float] = {"queries": float(keep.sum())}
    if not keep.any():
        return {**out, **{f"R@{k}": float("nan") for k in ks}, "median_rank": float("nan"), "mAP": float("nan")}
    return {**out, **text_to_clip_figures(sim[keep], relevant[keep], ks)}


def recall_curve(sim: np.ndarray, relevant: np.ndarray, max_k: int = CURVE_MAX_K) -> list[float]:
    """R@K for K = 1 … min(max_k, N)."""
    return ranks_curve(first_relevant_ranks(sim, relevant), np.asarray(sim).shape[1], max_k)


def ranks_curve(ranks: np.ndarray, num_clips: int, max_k: int = CURVE_MAX_K) -> list[float]:
    """:func:`recall_curve` from each query's first relevant rank (Q,) among ``num_clips`` clips."""
    return [float(np.mean(ranks <= k)) for k in range(1, min(max_k, num_clips) + 1)]


def random_text_to_clip(relevant: np.ndarray, seed: int = 0, draws: int = 20,
                        ks: Sequence[int] = KS) -> tuple[dict[str, float], list[float]]:
    """Expected figures (and recall curve) of random ranking: the mean over ``draws`` seeded random scores.

    Args:
        relevant: (Q, N) bool relevance.
    """
    relevant = np.asarray(relevant, dtype=bool)
    rng = np.random.default_rng(seed)
    figures: list[dict[str, float]] = []
    curves: list[list[float]] = []
    for _ in range(draws):
        # Drawn and ranked by rows (the same draws as one (Q, N) array): a draw of a large split is large.
        ranks, precisions = [], []
        for start in range(0, relevant.shape[0], ROWS_AT_ONCE):
            rows = relevant[start:start + ROWS_AT_ONCE]
            sim = rng.random(rows.shape)
            ranks.append(first_relevant_ranks(sim, rows))
            precisions.append(average_precision(sim, rows))
        figures.append(ranking_figures(np.concatenate(ranks), np.concatenate(precisions), ks))
        curves.append(ranks_curve(np.concatenate(ranks), relevant.shape[1]))
    mean = {key: float(np.mean([f[key] for f in figures])) for key in figures[0]}
    return mean, [float(v) for v in np.mean(np.asarray(curves), axis=0)]


def relevance_by_caption(query_captions: Sequence[str], clip_captions: Sequence[str]) -> np.ndarray:
    """(Q, N) bool: clip n is relevant to query q when their canonical captions are equal."""
    q = np.asarray(list(query_captions), dtype=object)
    c = np.asarray(list(clip_captions), dtype=object)
    return np.asarray(q[:, None] == c[None, :], dtype=bool)


def caption_queries(clip_captions: Sequence[str]) -> tuple[list[str], np.ndarray]:
    """The text queries of a set of clips: their distinct canonical captions, sorted, and (Q, N) relevance.

    Every evaluation of text → clip retrieval asks this way (validation, the camera weight's choice,
    ``scenesearch eval``), so that their figures count the same queries.
    """
    queries = sorted(set(clip_captions))
    return queries, relevance_by_caption(queries, clip_captions)


def half_queries(clip_captions: Sequence[str], half: int) -> tuple[list[str], np.ndarray]:
    """The queries of one half of a set of clips' canonical captions (0 the ego's sentence, 1 the
    object's: :func:`captioning.text.caption_halves`), as people type one: its distinct values, sorted,
    and (Q, N) relevance, a clip answering a half its caption has whatever its other half says."""
    said = [caption_halves(c)[half] for c in clip_captions]
    queries = sorted({s for s in said if s is not None})
    return queries, relevance_by_caption(queries, [s or "" for s in said])
