"""Evaluation figures: hand-checked cases, baselines, and the orchestrator on a stand-in model."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from retrieval_fakes import (
    CAPTIONING_SEQUENCES,
    FakeEmbedder,
    HashTextEncoder,
    captioning_caption,
    make_clips_dir,
    make_run_dir,
)

from encoders.metrics import (
    average_precision,
    caption_queries,
    first_relevant_ranks,
    precision_at_k,
    random_text_to_clip,
    relevance_by_caption,
    text_to_clip_figures,
    text_to_clip_metrics,
)
from retrieval.embedding import model_hash
from retrieval.evaluation import (
    camera_clip_figures,
    caption_generator,
    evaluate,
    reverse_steps,
    temporal_order_accuracy,
    text_order_figures,
)
from retrieval.freeform import FREEFORM_QUERIES, freeform_figures
from retrieval.hybrid import WEIGHTS, WeightChoice
from retrieval.metrics_tables import metrics_table


def test_ranks_and_average_precision_by_hand() -> None:
    sim = np.array([[0.9, 0.8, 0.1, 0.5],
                    [0.1, 0.2, 0.3, 0.4]])
    rel = np.array([[False, True, False, True],
                    [True, False, False, False]])
    assert first_relevant_ranks(sim, rel).tolist() == [2, 4]
    # Query 0: relevant at ranks 2 and 3 → AP = (1/2 + 2/3) / 2; query 1: rank 4 → 1/4.
    np.testing.assert_allclose(average_precision(sim, rel), [(0.5 + 2 / 3) / 2, 0.25])
    figures = text_to_clip_figures(sim, rel)
    assert figures["R@1"] == 0.0 and figures["R@5"] == 1.0
    assert figures["median_rank"] == 3.0
    assert figures["mAP"] == pytest.approx(((0.5 + 2 / 3) / 2 + 0.25) / 2)


def test_ties_count_against_the_model() -> None:
    sim = np.zeros((1, 5))
    rel = np.array([[False, False, True, False, False]])
    assert first_relevant_ranks(sim, rel).tolist() == [5]
    assert average_precision(sim, rel).tolist() == [0.2]


def test_training_validation_and_eval_agree_on_ties() -> None:
    # Coarse embeddings: several clips share a score with a query, relevant and irrelevant ones alike.
    text = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])  # queries "a", "b", "c"
    clips = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 1.0], [0.5, 0.5], [0.0, 0.0]])
    captions = ["a", "b", "b", "a", "c", "c"]
    sim = text @ clips.T  # (3, 6)
    rel = relevance_by_caption(["a", "b", "c"], captions)
    validation = text_to_clip_metrics(sim, rel)  # what training writes to metrics.jsonl
    evaluation = text_to_clip_figures(sim, rel)  # what `scenesearch eval` writes to metrics.json
    for key in ("R@1", "R@5", "mAP"):
        assert validation[key] == evaluation[key]
    # "a": clip 1 (irrelevant) ties clip 0 on top, so the first hit ranks 2nd; "b" likewise (clip 3
    # before clip 2); "c": the four clips scoring 1 rank before clip 4.
    assert first_relevant_ranks(sim, rel).tolist() == [2, 2, 5]
    assert evaluation["R@1"] == 0.0 and evaluation["R@5"] == 1.0
    # Relevant clips after their ties: a at ranks 2 and 6, b at 2 and 6, c at 5 and 6.
    assert evaluation["mAP"] == pytest.approx(np.mean([(1 / 2 + 2 / 6) / 2, (1 / 2 + 2 / 6) / 2, (1 / 5 + 2 / 6) / 2]))


def test_a_constant_score_model_gets_no_credit() -> None:
    rel = relevance_by_caption(["a", "b"], ["a", "b", "b", "a"])
    for figures in (text_to_clip_metrics(np.ones((2, 4)), rel), text_to_clip_figures(np.ones((2, 4)), rel)):
        assert figures["R@1"] == 0.0 and figures["median_rank"] == 3.0
        assert figures["mAP"] == pytest.approx((1 / 3 + 2 / 4) / 2)


def test_caption_queries_are_the_distinct_captions_in_order() -> None:
    queries, rel = caption_queries(["b", "a", "b", "c"])
    assert queries == ["a", "b", "c"]
    assert rel.tolist() == [[False, True, False, False], [True, False, True, False], [False, False, False, True]]
    assert rel.tolist() == relevance_by_caption(queries, ["b", "a", "b", "c"]).tolist()


def test_perfect_and_random_rankings() -> None:
    captions = ["a", "b", "c", "a", "b", "c", "d", "d"] * 5
    _, rel = caption_queries(captions)
    perfect = rel.astype(float)
    assert text_to_clip_figures(perfect, rel)["R@1"] == 1.0
    figures, curve = random_text_to_clip(rel, seed=0, draws=50)
    # 10 of 40 clips relevant: P(none of the top 1) = 30/40 → R@1 ≈ 0.25.
    assert figures["R@1"] == pytest.approx(0.25, abs=0.08)
    assert curve == sorted(curve) and len(curve) == 40
    with pytest.raises(ValueError, match="no relevant clip"):
        text_to_clip_figures(np.zeros((1, 3)), np.zeros((1, 3), bool))


def test_rankings_taken_by_rows_give_the_figures_of_a_whole_ranking(monkeypatch: pytest.MonkeyPatch) -> None:
    """Queries are ranked a few rows at a time, so that a large split fits in memory: every figure,
    the random baseline's draws included, is what one (Q, N) ranking gives."""
    from encoders import metrics

    rng = np.random.default_rng(3)
    sim = np.round(rng.random((11, 40)), 1).astype(np.float32)  # rounded: many ties, broken against the query
    rel = rng.random((11, 40)) < 0.2
    rel[np.arange(11), rng.integers(0, 40, 11)] = True
    answered = rel.copy()
    answered[4] = False  # precision@k leaves a query without relevant clips as NaN

    def everything() -> list[object]:
        return [text_to_clip_figures(sim, rel), metrics.recall_curve(sim, rel), average_precision(sim, rel).tolist(),
                precision_at_k(sim, answered, 5).tolist(), text_to_clip_metrics(sim, answered),
                random_text_to_clip(rel, seed=1, draws=3)]

    monkeypatch.setattr(metrics, "ROWS_AT_ONCE", 10**9)
    whole = everything()
    monkeypatch.setattr(metrics, "ROWS_AT_ONCE", 3)
    assert repr(everything()) == repr(whole)  # NaN compares equal as text


def test_temporal_order_and_reversal() -> None:
    assert temporal_order_accuracy(np.array([1.0, 0.5, 0.2]), np.array([0.5, 0.5, 0.4])) == pytest.approx(0.5)
    assert reverse_steps(["x", "y"], "x / y", generate=lambda tags: " / ".join(tags)) == "y / x"
    assert reverse_steps(["x"], "x", generate=lambda tags: " / ".join(tags)) is None
    assert reverse_steps(["x", "x"], "x / x", generate=lambda tags: " / ".join(tags)) is None


def test_reversal_uses_captioning_text() -> None:
    host = ["cruising:heading_straight"]
    tags = ["left:approach", "host:away"]
    generate = caption_generator("car", host)
    caption = generate(tags)
    rev = reverse_steps(tags, caption, generate)
    assert rev is not None and rev != caption and rev.startswith("The ego vehicle")
    assert "then" in rev and rev.index("move") < rev.index("approach")


def test_evaluate_with_stand_in_model(tmp_path: Path) -> None:
    clips = make_clips_dir(tmp_path / "clips", sequences=CAPTIONING_SEQUENCES, caption=captioning_caption)
    run = make_run_dir(tmp_path / "run")
    embedder = FakeEmbedder(model_hash(run))
    lines: list[str] = []
    metrics = evaluate(run, clips, split="test", embedder=embedder, progress=lines.append)
    json.dumps(metrics, allow_nan=False)  # valid JSON
    for key in ("text_to_clip", "temporal_order_accuracy", "clip_to_clip", "views", "baselines"):
        assert key in metrics
    assert set(metrics["text_to_clip"]) == {"R@1", "R@5", "R@10", "median_rank", "mAP"}
    assert set(metrics["views"]) == {"camera", "bev", "camera_clips"}
    seen = metrics["views"]["camera_clips"]
    assert set(seen) == {"clips", "queries", "fused", "random"} and 0 < seen["clips"] <= metrics["counts"]["clips"]
    assert set(metrics["baselines"]) == {"random", "bag_of_frames", "rule_captions"}
    # Rule-caption search over the clips' own captions finds a caption query's words far above chance, but
    # the frozen sentence encoder hardly sees the order of steps, so reversed captions compete at rank 1.
    rule = metrics["baselines"]["rule_captions"]["text_to_clip"]
    assert metrics["baselines"]["rule_captions"]["whole_text"] == "sentences"  # the default frozen encoder's form
    assert rule["R@5"] > metrics["baselines"]["random"]["text_to_clip"]["R@5"] + 0.3
    # The frozen sentence encoder barely tells a caption from its reversed steps.
    frozen = metrics["baselines"]["rule_captions"]["text_order"]
    assert frozen["pairs"] == metrics["counts"]["temporal_pairs"] and frozen["mean_cosine"] > 0.9
    assert set(metrics["text_order"]) == {"pairs", "mean_cosine", "kept_apart"}
    free = metrics["freeform"]
    assert free["queries"] == len(FREEFORM_QUERIES) and 0 < free["answered"] <= free["queries"]
    assert 0.0 <= free["precision@10"] <= 1.0
    c2c = metrics["clip_to_clip"]
    assert "action_precision@5" in c2c and "appearance_bias" in c2c
    assert c2c["action_precision@5"] <= c2c["action_precision@5_ceiling"] <= 1.0  # no ranking beats a perfect one
    assert c2c["action_precision@5_other_moments"] <= c2c["action_precision@5_ceiling_other_moments"]
    assert 0.0 <= c2c["same_moment_share_neighbours"] <= 1.0 and "appearance_bias_perfect_ranking" in c2c
    model, rnd = metrics["text_to_clip"], metrics["baselines"]["random"]["text_to_clip"]
    assert model["R@1"] > rnd["R@1"] + 0.3 and model["mAP"] > rnd["mAP"]
    order = metrics["temporal_order_accuracy"]
    assert order["num_captions"] > 0 and order["accuracy"] > 0.7
    # Shuffled frames lose the order of steps: the stand-in then cannot tell a caption from its reverse.
    assert metrics["baselines"]["bag_of_frames"]["temporal_order_accuracy"]["accuracy"] < order["accuracy"]
    assert metrics["counts"]["clips"] == 42
    # Each half of the captions asked alone: every clip of a half answers it, whatever its other half says.
    halves = metrics["halves"]
    assert set(halves) == {"object", "ego"} and halves["object"]["queries"] > 0
    for name in ("bag_of_frames", "random", "rule_captions"):
        assert set(metrics["baselines"][name]["halves"]) == {"object", "ego"}
    assert halves["object"]["mAP"] > metrics["baselines"]["random"]["halves"]["object"]["mAP"]
    # Hybrid search without an index: its weight chosen on the validation clips, never on the test clips.
    mixed = metrics["hybrid"]
    assert mixed["chosen_on"] == "val" and mixed["weight"] in WEIGHTS
    assert set(mixed) == {"weight", "chosen_on", "given", "origin", "text_to_clip", "temporal_order_accuracy",
                          "freeform"}
    assert mixed["given"] is False
    assert mixed["text_to_clip"]["R@5"] > metrics["baselines"]["random"]["text_to_clip"]["R@5"] + 0.3
    table = metrics_table(metrics)  # every figure of a real evaluation renders
    assert "text→clip R@1" in table and "temporal order" in table and "free-form precision@10" in table
    assert "object sentence alone mAP" in table and "rule captions" in table and "hybrid" in table
    with pytest.raises(ValueError, match="unknown split 'dev'; the clips have splits: test, train, val"):
        evaluate(run, clips, split="dev", embedder=embedder)


def test_an_index_weight_chosen_on_the_clips_evaluated_is_not_used(tmp_path: Path) -> None:
    from retrieval.scenesearch import SceneSearch

    clips = make_clips_dir(tmp_path / "clips", sequences=CAPTIONING_SEQUENCES, caption=captioning_caption)
    run = make_run_dir(tmp_path / "run")
    embedder, sentences = FakeEmbedder(model_hash(run)), HashTextEncoder()
    SceneSearch.build(run, clips, tmp_path / "index", embedder=embedder, text_encoder=sentences)
    on_test = evaluate(run, clips, embedder=embedder, sentence_encoder=sentences, index_dir=tmp_path / "index")
    assert on_test["hybrid"]["chosen_on"] == "val" and on_test["hybrid"]["origin"] == "chosen on 14 val clips"
    for split in ("val", "all"):  # the weight was chosen on (some of) these clips: the default instead
        metrics = evaluate(run, clips, split=split, embedder=embedder, sentence_encoder=sentences,
                           index_dir=tmp_path / "index")
        assert metrics["hybrid"]["chosen_on"] is None and metrics["hybrid"]["weight"] == 0.5


@pytest.mark.parametrize("weight, source", [(0.0, "model"), (1.0, "rule_captions")])
def test_hybrid_at_either_end_of_the_weight_is_that_source(tmp_path: Path, weight: float, source: str) -> None:
    clips = make_clips_dir(tmp_path / "clips", sequences=CAPTIONING_SEQUENCES, caption=captioning_caption)
    run = make_run_dir(tmp_path / "run")
    metrics = evaluate(run, clips, embedder=FakeEmbedder(model_hash(run)), sentence_encoder=HashTextEncoder(),
                       hybrid=WeightChoice(weight))
    figures = metrics if source == "model" else metrics["baselines"]["rule_captions"]
    assert metrics["hybrid"]["weight"] == weight and metrics["hybrid"]["chosen_on"] is None
    assert metrics["hybrid"]["text_to_clip"] == pytest.approx(figures["text_to_clip"])
    assert metrics["hybrid"]["freeform"] == pytest.approx(figures["freeform"])
    assert metrics["hybrid"]["temporal_order_accuracy"]["accuracy"] == \
        pytest.approx(figures["temporal_order_accuracy"]["accuracy"])


def test_precision_at_k_counts_ties_against_the_query() -> None:
    sim = np.array([[3.0, 2.0, 1.0, 0.0], [1.0, 1.0, 1.0, 1.0], [1.0, 2.0, 3.0, 4.0]])
    relevant = np.array([[1, 0, 1, 0], [1, 0, 0, 0], [0, 0, 0, 0]], dtype=bool)
    p = precision_at_k(sim, relevant, k=2)
    assert p[0] == 0.5 and p[1] == 0.0 and np.isnan(p[2])
    assert precision_at_k(sim[:1], relevant[:1], k=10)[0] == 0.5  # k past N: the share among all N
    with pytest.raises(ValueError, match="k must be >= 1"):
        precision_at_k(sim, relevant, k=0)


def test_text_order_and_freeform_figures() -> None:
    a = np.array([[1.0, 0.0], [0.0, 1.0]])
    b = np.array([[1.0, 0.0], [1.0, 0.0]])
    assert text_order_figures(a, b) == {"pairs": 2, "mean_cosine": 0.5, "kept_apart": 0.5}
    assert text_order_figures(np.zeros((0, 2)), np.zeros((0, 2)))["mean_cosine"] is None
    relevant = np.array([[1, 0], [0, 0]], dtype=bool)
    assert freeform_figures(np.array([[1.0, 0.0], [0.0, 1.0]]), relevant, k=1) == \
        {"queries": 2, "answered": 1, "precision@1": 1.0}


def test_camera_view_is_measured_over_the_clips_the_camera_saw() -> None:
    # 2 queries, 4 clips; the camera saw clips 0 and 2 only. Query 1's only relevant clip (3) is out of view.
    relevant = np.array([[1, 0, 1, 0], [0, 0, 0, 1]], dtype=bool)
    camera = np.array([[0.1, 0.9, 0.8, 0.9], [0.5, 0.5, 0.5, 0.5]])  # clip 1 would outrank clip 0 if it counted
    fused = np.array([[0.9, 0.1, 0.2, 0.3], [0.1, 0.2, 0.3, 0.9]])
    out = camera_clip_figures({"camera": camera, "fused": fused}, relevant, [True, False, True, False])
    assert out["counts"] == {"clips": 2, "queries": 1}
    assert out["camera"]["R@1"] == 1.0  # among clips 0 and 2, clip 2 (relevant) comes first
    assert out["camera"]["mAP"] == 1.0 and out["fused"]["mAP"] == 1.0  # both camera clips are relevant
    assert out["random"]["R@1"] == 1.0 and len(out["curve"]) > 0
    none = camera_clip_figures({"camera": camera, "fused": fused}, relevant, [False, True, False, False])
    assert none["camera"] is None and none["counts"] == {"clips": 1, "queries": 0}


def test_half_queries_ask_each_half_alone_and_a_clip_answers_the_halves_its_caption_has() -> None:
    from encoders.metrics import half_queries

    captions = ["The ego vehicle is stationary. A car stands in the ego lane.",
                "The ego vehicle is cruising straight. A car stands in the ego lane.",
                "The ego vehicle is cruising straight. A car in the left lane approaches.",
                "The ego vehicle is stationary."]  # an ego clip's caption: its ego sentence alone
    queries, relevant = half_queries(captions, 1)
    assert queries == ["A car in the left lane approaches.", "A car stands in the ego lane."]
    assert relevant.tolist() == [[False, False, True, False], [True, True, False, False]]
    queries, relevant = half_queries(captions, 0)
    assert queries == ["The ego vehicle is cruising straight.", "The ego vehicle is stationary."]
    assert relevant.tolist() == [[False, True, True, False], [True, False, False, True]]
