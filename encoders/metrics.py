"""Retrieval metrics, pure numpy: text → clip recall at k, median rank and mean average precision."""

from __future__ import annotations

import numpy as np


def text_to_clip_metrics(sim: np.ndarray, relevant: np.ndarray, ks: tuple[int, ...] = (1, 5, 10)) -> dict[str, float]:
    """Retrieval quality of Q queries over N gallery items.

    Args:
        sim: (Q, N) similarity of each query to each item (higher is better).
        relevant: (Q, N) bool, true where the item answers the query.
        ks: cut-offs for recall.

    Returns:
        ``R@k``: share of queries with a relevant item in the top k; ``median_rank``: median over queries
        of the 1-based rank of the first relevant item; ``mAP``: mean average precision; ``queries``: Q
        (queries with no relevant item are left out).
    """
    sim = np.asarray(sim, dtype=np.float64)
    relevant = np.asarray(relevant, dtype=bool)
    if sim.ndim != 2 or sim.shape != relevant.shape:
        raise ValueError(f"sim {sim.shape} and relevant {relevant.shape} must both be (Q, N)")
    keep = relevant.any(axis=1)
    sim, relevant = sim[keep], relevant[keep]
    out: dict[str, float] = {"queries": float(len(sim))}
    if len(sim) == 0:
        return {**out, **{f"R@{k}": float("nan") for k in ks}, "median_rank": float("nan"), "mAP": float("nan")}
    order = np.argsort(-sim, axis=1, kind="stable")  # (Q, N)
    hits = np.take_along_axis(relevant, order, axis=1)  # (Q, N) relevance in ranked order
    first = hits.argmax(axis=1) + 1  # (Q,) 1-based rank of the first relevant item
    for k in ks:
        out[f"R@{k}"] = float((first <= k).mean())
    out["median_rank"] = float(np.median(first))
    ranks = np.arange(1, hits.shape[1] + 1)
    precision = np.cumsum(hits, axis=1) / ranks  # (Q, N)
    out["mAP"] = float(((precision * hits).sum(axis=1) / hits.sum(axis=1)).mean())
    return out
