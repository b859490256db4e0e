"""Text → clip recall broken down by what the queried object does: per lane, motion, own action,
context and category, so that a rare action (a lane change, braking at a crossing) is not hidden in
the mean over common ones.

A query's *facets* are the values its caption's steps take (``lane=left``, ``motion=approach``,
``action=braking``, ``context=on_crosswalk``) and its object's category (``category=cyclist``). Each
facet's figure is the recall at k over the queries that have it, beside the same figure of other
rankings of the same queries (shuffled frames, rule captions) and of random ranking (analytic), with
the number of queries and of clips that show the facet: a facet with a handful of them says little.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from captioning.tags import split_neighbor_tag
from encoders.metrics import first_relevant_ranks

#: Recall is read at this cut-off.
BREAKDOWN_K = 5


def facets(tags: Sequence[str], category: str = "") -> set[str]:
    """The facets of one caption: ``lane=…``, ``motion=…``, ``action=…``, ``context=…`` of each step
    (unified neighbour tags, :func:`captioning.tags.split_neighbor_tag`) and ``category=…``."""
    out = {f"category={category}"} if category else set()
    for tag in tags:
        lane, motion, action, context = split_neighbor_tag(tag)
        out.add(f"lane={lane}")
        if motion:
            out.add(f"motion={motion}")
        if action:
            out.add(f"action={action}")
        if context:
            out.add(f"context={context}")
    return out


def random_recall_at_k(relevant: np.ndarray, k: int = BREAKDOWN_K) -> np.ndarray:
    """(Q,) chance that random ranking puts one of each query's relevant clips in its top k.

    Args:
        relevant: (Q, N) bool.
    """
    relevant = np.asarray(relevant, dtype=bool)
    n = relevant.shape[1]
    r = relevant.sum(axis=1)
    # P(no relevant clip among k drawn without replacement) = Π_{i<k} (N − r − i) / (N − i).
    miss = np.ones(len(r))
    for i in range(min(k, n)):
        miss *= np.clip(n - r - i, 0, None) / (n - i)
    return np.asarray(1.0 - miss)


def recall_by_facet(sims: Mapping[str, np.ndarray], relevant: np.ndarray, query_facets: Sequence[set[str]],
                    clip_facets: Sequence[set[str]], k: int = BREAKDOWN_K) -> dict[str, dict[str, Any]]:
    """Recall at ``k`` per facet, for every ranking in ``sims`` and for random ranking.

    Args:
        sims: name → (Q, N) query × clip scores, higher is closer.
        relevant: (Q, N) bool; every query needs a relevant clip.
        query_facets: (Q,) each query's facets (:func:`facets`).
        clip_facets: (N,) each clip's facets.
        k: the recall cut-off.

    Returns:
        ``{facet: {"queries", "clips", "R@k" of each name in sims, "random"}}``, facets sorted by
        name.
    """
    relevant = np.asarray(relevant, dtype=bool)
    if len(query_facets) != relevant.shape[0] or len(clip_facets) != relevant.shape[1]:
        raise ValueError(f"{len(query_facets)} query and {len(clip_facets)} clip facet sets for relevance "
                         f"{relevant.shape}")
    hits = {name: first_relevant_ranks(sim, relevant) <= k for name, sim in sims.items()}  # (Q,) each
    hits_random = random_recall_at_k(relevant, k)
    out: dict[str, dict[str, Any]] = {}
    for facet in sorted(set().union(*query_facets) if query_facets else set()):
        rows = np.asarray([facet in f for f in query_facets])
        entry: dict[str, Any] = {"queries": int(rows.sum()), "clips": sum(facet in f for f in clip_facets)}
        for name, hit in hits.items():
            entry[f"{name}_R@{k}"] = float(hit[rows].mean())
        entry[f"random_R@{k}"] = float(hits_random[rows].mean())
        out[facet] = entry
    return out
