"""Recall per facet of the queried action: facets of a caption, analytic random recall, per-facet figures."""

from __future__ import annotations

import numpy as np
import pytest

from retrieval.action_breakdown import facets, random_recall_at_k, recall_by_facet


def test_facets_of_a_caption() -> None:
    assert facets(["left:approach:braking", "host:away:on_crosswalk"], "cyclist") == {
        "category=cyclist", "lane=left", "motion=approach", "action=braking", "lane=host", "motion=away",
        "context=on_crosswalk"}
    assert facets([]) == set()


def test_random_recall_matches_sampling() -> None:
    relevant = np.zeros((3, 20), dtype=bool)
    relevant[0, :1] = True
    relevant[1, :4] = True
    relevant[2, :] = True
    rng = np.random.default_rng(0)
    draws = np.mean([[row[rng.permutation(20)[:5]].any() for row in relevant] for _ in range(20000)], axis=0)
    assert random_recall_at_k(relevant, 5) == pytest.approx(draws, abs=0.01)
    assert random_recall_at_k(relevant, 5)[0] == pytest.approx(5 / 20)
    assert random_recall_at_k(relevant, 5)[2] == 1.0


def test_recall_by_facet() -> None:
    # 3 queries over 8 clips; query q's relevant clip is clip q. The model ranks queries 0 and 1 right
    # and query 2's clip last.
    relevant = np.zeros((3, 8), dtype=bool)
    relevant[[0, 1, 2], [0, 1, 2]] = True
    sim = np.tile(np.linspace(0.0, -0.7, 8), (3, 1))
    sim[0, 0] = sim[1, 1] = 1.0
    sim[2, 2] = -5.0
    query_facets = [{"action=braking", "lane=left"}, {"lane=left"}, {"action=braking"}]
    clip_facets = [query_facets[0], query_facets[1], query_facets[2]] + [set()] * 5
    out = recall_by_facet({"model": sim}, relevant, query_facets, clip_facets, k=1)
    assert list(out) == ["action=braking", "lane=left"]
    assert out["lane=left"] == {"queries": 2, "clips": 2, "model_R@1": 1.0, "random_R@1": pytest.approx(1 / 8)}
    assert out["action=braking"]["model_R@1"] == 0.5 and out["action=braking"]["clips"] == 2
    with pytest.raises(ValueError, match="facet sets"):
        recall_by_facet({"model": sim}, relevant, query_facets[:2], clip_facets)
