"""Hybrid search: standardised model and rule-caption scores mixed; the weight chosen on validation clips;
exact top-k over an index, with brute-force mixing as the reference."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from indexes.clip_index import ClipIndex
from indexes.integrity import seal
from retrieval import hybrid
from retrieval.errors import IndexDirError
from retrieval.hybrid import (
    DEFAULT_WEIGHT,
    HybridScorer,
    InvalidWeightError,
    WeightChoice,
    check_weight,
    choice_sample,
    choose_for_index,
    choose_for_rows,
    choose_weight,
    mix,
    standardise,
)
from retrieval.querying import Query, build_query
from retrieval.scenesearch import SceneSearch


def test_standardise_and_mix() -> None:
    rng = np.random.default_rng(0)
    model, rules = rng.normal(size=(3, 40)), 5 + 0.1 * rng.normal(size=(3, 40))
    z = standardise(model)
    assert np.allclose(z.mean(axis=1), 0) and np.allclose(z.std(axis=1), 1)
    assert np.all(standardise(np.ones((2, 5))) == 0)  # no spread: no information, no NaN
    # The ends of the weight are the sources alone: the same rankings.
    assert np.array_equal(np.argsort(mix(model, rules, 0.0), axis=1), np.argsort(model, axis=1))
    assert np.array_equal(np.argsort(mix(model, rules, 1.0), axis=1), np.argsort(rules, axis=1))
    # Standardised first: the rule scores' offset and small spread do not drown the model's.
    half = mix(model, rules, 0.5)
    assert np.allclose(half, 0.5 * standardise(model) + 0.5 * standardise(rules))
    with pytest.raises(ValueError, match=r"must both be \(Q, N\)"):
        mix(model, rules[:, :10], 0.5)


@pytest.mark.parametrize("weight", [-0.1, 1.5, math.nan, "0.5", True, None])
def test_a_weight_outside_zero_to_one_is_refused(weight: object) -> None:
    with pytest.raises(InvalidWeightError, match=r"must be a number in \[0, 1\]"):
        check_weight(weight)


def test_the_weight_is_chosen_by_both_query_sets() -> None:
    # Rules find the caption queries' clips, the model the free-form ones: the best mean needs both sources.
    rng = np.random.default_rng(0)
    n = 20
    relevant = np.eye(4, n, dtype=bool)  # caption query q: clip q
    cap_rules = relevant.astype(float)
    cap_model = np.tile(np.linspace(1, 0, n), (4, 1))
    cap_model[relevant] = 0.6  # ranked after 8 others by the model
    free_relevant = np.zeros((2, n), dtype=bool)
    free_relevant[0, :10] = free_relevant[1, 10:] = True
    free_model, free_rules = free_relevant.astype(float), rng.normal(size=(2, n))
    choice = choose_weight((cap_model, cap_rules, relevant), (free_model, free_rules, free_relevant),
                           weights=(0.0, 0.5, 1.0))
    curve = {p["weight"]: p for p in choice.curve}
    assert curve[0.0]["caption_R@5"] == 0.0 and curve[0.0]["freeform_P@10"] == 1.0
    assert curve[1.0]["caption_R@5"] == 1.0 and curve[1.0]["freeform_P@10"] < 1.0
    assert curve[0.5]["objective"] > max(curve[0.0]["objective"], curve[1.0]["objective"])
    assert choice.weight == 0.5
    assert choice.split == "val" and choice.clips == n and choice.caption_queries == 4 and choice.freeform_queries == 2
    # Ties go to the smaller weight.
    tie = choose_weight((cap_rules, cap_rules, relevant), (free_model, free_model, free_relevant), weights=(0.2, 0.1))
    assert tie.weight == 0.1


def test_the_choice_round_trips_and_an_old_index_takes_the_default() -> None:
    choice = WeightChoice(0.3, "val", clips=10, split_clips=10, caption_queries=4, freeform_queries=2,
                          curve=({"weight": 0.3, "objective": 0.5},))
    assert WeightChoice.from_json(json.loads(json.dumps(choice.to_json()))) == choice
    assert choice.origin == "chosen on 10 val clips"
    given = WeightChoice(1.0, given=True)
    assert WeightChoice.from_json(given.to_json()) == given and given.origin == "given when the index was built"
    assert WeightChoice(DEFAULT_WEIGHT).origin == "the default (no validation clips)"
    assert WeightChoice.from_json(None) == WeightChoice(DEFAULT_WEIGHT) == WeightChoice.from_json({})
    with pytest.raises(InvalidWeightError):
        WeightChoice.from_json({"weight": 2})


def _brute_force(xb: np.ndarray, rules: np.ndarray, xq: np.ndarray, allowed: np.ndarray, k: int,
                 w: float, step: int = 1) -> np.ndarray:
    """The reference: every clip scored by both, standardised over the whole index (the model's moments
    from every ``step``-th clip), mixed, sorted (ties by id)."""
    xb = xb / np.linalg.norm(xb, axis=1, keepdims=True)
    model = xb @ (xq / np.linalg.norm(xq))
    z_model = (model - model[::step].mean()) / model[::step].std()
    mixed = (1 - w) * z_model + w * standardise(rules[None])[0]
    order = np.lexsort((allowed, -mixed[allowed]))
    return allowed[order][:k]


@pytest.mark.parametrize(("min_candidates", "permuted"), [(64, True), (1, True), (64, False), (1, False)])
def test_top_k_equals_brute_force_mixing(min_candidates: int, permuted: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(hybrid, "MIN_CANDIDATES", min_candidates)  # 1: the bound does most of the work
    rng = np.random.default_rng(1)
    n, d = 300, 16
    xb = rng.normal(size=(n, d)).astype(np.float32)
    rows = [{"clip_id": f"c{i:03d}", "category": ["car", "bus"][i % 2]} for i in range(n)]
    index = ClipIndex.build(xb, rows, metric="cosine")
    caption_order = rng.permutation(n) if permuted else np.arange(n)  # caption rows in another order, or the same
    scorer = HybridScorer(index, [f"c{i:03d}" for i in caption_order])
    buses = np.arange(1, n, 2)
    scored_beyond = []
    for trial in range(12):
        xq = rng.normal(size=d).astype(np.float32)
        rules_by_clip = rng.normal(size=n) + 0.8 * (xb @ xq) / np.linalg.norm(xq)  # partly agreeing sources
        rules_by_row = rules_by_clip[caption_order]
        w, k = [0.0, 0.3, 0.5, 0.8, 1.0, 0.6][trial % 6], [1, 5, 10, 40][trial % 4]
        ids, scores = scorer.top_k(xq, rules_by_row, Query(k, None), w)
        scored_beyond.append(scorer.last_extra)
        assert ids.tolist() == _brute_force(xb, rules_by_clip, xq, np.arange(n), k, w).tolist()
        assert np.all(np.diff(scores) <= 0)
        filtered = build_query(k, {"category": "bus"}, index.metadata, n)
        ids, _ = scorer.top_k(xq, rules_by_row, filtered, w)
        assert ids.tolist() == _brute_force(xb, rules_by_clip, xq, buses, k, w).tolist()
    # The bound let clips outside the model's top K in where the rules could lift them, and only then.
    assert max(scored_beyond) > 0 and max(scored_beyond) < n


def test_ties_go_to_the_smaller_id_and_the_moments_sample_spreads(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(hybrid, "MOMENT_SAMPLE", 64)  # 300 clips: every 5th in the sample, from first to last
    rng = np.random.default_rng(3)
    n, d = 300, 16
    distinct = rng.normal(size=(10, d)).astype(np.float32)
    group = rng.integers(10, size=n)
    xb = distinct[group]  # 10 distinct vectors: many clips tie on the model's score
    index = ClipIndex.build(xb, [{"clip_id": f"c{i:03d}"} for i in range(n)], metric="cosine")
    scorer = HybridScorer(index, [f"c{i:03d}" for i in range(n)])
    assert len(scorer._sample) == 60
    for trial in range(8):
        xq = rng.normal(size=d).astype(np.float32)
        rules = rng.normal(size=10)[group]  # and on the rules' (one caption per vector)
        w, k = [0.0, 0.4, 0.7, 1.0][trial % 4], [3, 12][trial % 2]
        ids, _ = scorer.top_k(xq, rules, Query(k, None), w)
        assert ids.tolist() == _brute_force(xb, rules, xq, np.arange(n), k, w, step=5).tolist()


def test_sources_that_disagree_deepen_the_model_list() -> None:
    rng = np.random.default_rng(4)
    n, d = 2000, 16
    xb = rng.normal(size=(n, d)).astype(np.float32)
    index = ClipIndex.build(xb, [{"clip_id": f"c{i:04d}"} for i in range(n)], metric="cosine")
    scorer = HybridScorer(index, [f"c{i:04d}" for i in range(n)])
    deepened = []
    for _ in range(6):
        xq, rules = rng.normal(size=d).astype(np.float32), rng.normal(size=n)  # rules unrelated to the model
        ids, _ = scorer.top_k(xq, rules, Query(5, None), 0.7)
        assert ids.tolist() == _brute_force(xb, rules, xq, np.arange(n), 5, 0.7).tolist()
        deepened.append(scorer.last_candidates)
        assert scorer.last_extra <= scorer.last_candidates  # never more rescoring than the list it searched
    assert max(deepened) > hybrid.MIN_CANDIDATES


def test_top_k_with_nothing_allowed_and_a_clip_without_caption() -> None:
    xb = np.eye(4, dtype=np.float32)
    index = ClipIndex.build(xb, [{"clip_id": f"c{i}", "category": "car"} for i in range(4)], metric="cosine")
    scorer = HybridScorer(index, ["c0", "c1", "c2", "c3"])
    nothing = build_query(3, "category != car", index.metadata, 4)
    ids, scores = scorer.top_k(xb[0], np.zeros(4), nothing, 0.5)
    assert len(ids) == len(scores) == 0
    with pytest.raises(IndexDirError, match="no rule caption"):
        HybridScorer(index, ["c0", "c1"])


# ---------------------------------------------------------------------- over an index


def test_the_index_records_the_weight_chosen_on_its_validation_clips(built: dict[str, Any]) -> None:
    search = SceneSearch.open(built["index"], embedder=built["embedder"], text_encoder=built["search"].captions.encoder)
    raw = json.loads((built["index"] / "manifest.json").read_text())["hybrid"]
    assert search.hybrid == WeightChoice.from_json(raw)
    assert search.hybrid.split == "val" and search.hybrid.clips == 14 and len(search.hybrid.curve) == 11
    assert any(line.startswith("index: hybrid weight") for line in built["progress"])


def test_the_choice_sample_is_bounded_and_does_not_depend_on_order() -> None:
    ids = [f"log{i % 7}:{i}" for i in range(50)]
    assert choice_sample(ids[:12], limit=12).tolist() == list(range(12))
    kept = choice_sample(ids, limit=12)
    assert len(kept) == 12 and np.all(np.diff(kept) > 0)
    order = np.random.default_rng(0).permutation(50)
    assert {ids[order[i]] for i in choice_sample([ids[i] for i in order], limit=12)} == {ids[i] for i in kept}
    grown = ids + [f"log9:{i}" for i in range(50)]  # more clips: most of the sample stays
    assert len({ids[i] for i in kept} & {grown[i] for i in choice_sample(grown, limit=12)}) >= 3


def test_an_index_chooses_on_a_sample_of_its_validation_clips(built: dict[str, Any],
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """Above :data:`CHOICE_CLIPS` the weight is chosen on the sample alone, with rule-caption scores of
    those rows only: the same choice as scoring every caption row and keeping the sample's."""
    from encoders.clips.layout import read_clip_table
    from retrieval.captions_search import caption_rows

    search = SceneSearch.open(built["index"], embedder=built["embedder"], text_encoder=built["search"].captions.encoder)
    rows, _ = caption_rows(read_clip_table(built["clips"]))
    monkeypatch.setattr(hybrid, "CHOICE_CLIPS", 6)
    choice = choose_for_index(rows, search.views["fused"], search.captions, built["embedder"].embed_texts)
    assert (choice.clips, choice.split_clips) == (6, 14)
    assert choice.origin == "chosen on 6 val clips (a sample of the 14)"
    val = [r for r in rows.to_pylist() if r["split"] == "val"]
    sample = [val[i] for i in choice_sample([r["clip_id"] for r in val], limit=6)]
    captions = search.captions
    pos = captions.metadata.positions(captions.metadata.ids_of([r["clip_id"] for r in sample]))

    def every_row(texts: Any, _rows: Any) -> np.ndarray:  # the reference: every caption row scored
        xq = np.asarray(captions.encoder(list(texts)), np.float32)
        return np.stack([captions.scores(q)[pos] for q in xq]) if len(xq) else np.zeros((0, len(pos)))

    x = search.views["fused"].reconstruct([r["clip_id"] for r in sample])
    reference = choose_for_rows(sample, x, built["embedder"].embed_texts, every_row)
    assert choice.weight == reference.weight
    for ours, theirs in zip(choice.curve, reference.curve, strict=True):
        assert ours == pytest.approx(theirs, abs=1e-6)


def test_caption_scores_of_some_rows_equal_every_rows_scores_there(built: dict[str, Any]) -> None:
    captions = built["search"].captions
    rng = np.random.default_rng(0)
    rows = rng.permutation(len(captions))[: len(captions) // 2]
    xq = captions.text_embeddings[rng.integers(0, len(captions.texts), 5)]
    xq[0] = -xq[0]
    reference = np.stack([captions.scores(q)[rows] for q in xq])
    np.testing.assert_allclose(captions.scores_of(xq, rows), reference, atol=1e-6)


def test_search_hybrid(built: dict[str, Any]) -> None:
    search = SceneSearch.open(built["index"], embedder=built["embedder"], text_encoder=built["search"].captions.encoder)
    query = "a car in the left lane approaches, then moves into the host lane"
    results = search.search_hybrid(query, k=5)
    assert [r.rank for r in results] == [1, 2, 3, 4, 5] and all(r.view == "fused" for r in results)
    assert results[0].caption == query and all(a.score >= b.score for a, b in zip(results, results[1:]))
    # The ends of the weight give the model's and the rule captions' own rankings.
    assert [r.clip_id for r in search.search_hybrid(query, k=8, weight=0.0)] == \
        [r.clip_id for r in search.search_text(query, k=8)]
    assert {r.clip_id for r in search.search_hybrid(query, k=3, weight=1.0)} == \
        {r.clip_id for r in search.search_captions(query, k=3)}
    trucks = search.search_hybrid(query, k=4, filters={"category": "truck"}, view="bev")
    assert trucks and all(r.category == "truck" and r.view == "bev" for r in trucks)
    with pytest.raises(InvalidWeightError):
        search.search_hybrid(query, weight=1.2)


def _with_hybrid(built: dict[str, Any], tmp_path: Path, value: Any) -> Path:
    index = tmp_path / "index"
    shutil.copytree(built["index"], index)
    path = index / "manifest.json"
    raw = json.loads(path.read_text())
    raw.pop("content_sha256", None)
    if value is None:
        raw.pop("hybrid")
    else:
        raw["hybrid"] = value
    path.write_text(json.dumps(seal(raw), indent=2))
    return index


def test_an_index_without_its_hybrid_weight_is_refused(built: dict[str, Any], tmp_path: Path) -> None:
    with pytest.raises(IndexDirError, match=r"missing fields \['hybrid'\]"):
        SceneSearch.open(_with_hybrid(built, tmp_path, None), embedder=built["embedder"],
                         text_encoder=built["search"].captions.encoder)


@pytest.mark.parametrize(("value", "message"), [
    ({"weight": 7}, r"\[0, 1\]"), ({"weight": "0.5"}, r"\[0, 1\]"), (0.5, "must be an object"),
    ({"weight": 0.5, "clips": "x"}, "'clips' must be a count"), ({"weight": 0.5, "given": "yes"}, "'given'"),
    ({"weight": 0.5, "split": 3}, "'split'"), ({"weight": 0.5, "curve": [1]}, "'curve'"),
])
def test_a_bad_recorded_weight_is_refused_naming_the_field(built: dict[str, Any], tmp_path: Path, value: Any,
                                                           message: str) -> None:
    with pytest.raises(IndexDirError, match=rf"manifest.json, field 'hybrid': .*{message}"):
        SceneSearch.open(_with_hybrid(built, tmp_path, value))
