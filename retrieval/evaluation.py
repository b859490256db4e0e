"""How well retrieval works, each figure beside baselines measured in the same run.

Pure functions on similarity matrices (``sim`` is (Q, N): queries × clips, higher is closer; the
text → clip figures are :mod:`encoders.metrics`, shared with training validation) and one
orchestrator, :func:`evaluate`, that embeds a split of a clips directory with a trained model and
returns the metrics dictionary written to ``metrics.json``::

    text_to_clip:            R@1, R@5, R@10, median_rank, mAP   (queries = the split's unique canonical captions;
                                                                a clip is relevant when its caption matches)
    temporal_order_accuracy: accuracy, num_captions           (true caption vs the same steps reversed)
    text_order:              pairs, mean_cosine, kept_apart     (the text tower alone: how far a caption's
                                                                embedding is from its reversed steps')
    freeform:                queries, answered, precision@10    (held-out everyday sentences, relevance from
                                                                each clip's tags: :mod:`retrieval.freeform`)
    halves:                  object / ego: the text_to_clip figures of each half of the captions asked alone
                             (queries = the split's distinct object sentences, or ego sentences; a clip is
                             relevant when its caption has that half: :func:`encoders.metrics.half_queries`)
    clip_to_clip:            action_precision@5, appearance_bias (+ the rates behind the bias), the share
                             of neighbours from the query's own log and own moment, and the same figures
                             among other logs' and other moments' clips, beside the biases of a perfect
                             ranking by the captions' content (``*_perfect_ranking``, :mod:`retrieval.clip_neighbours`)
    views:                   camera / bev: the text_to_clip figures of each single view. The camera
                             view is measured over the clips the camera saw (``has_camera``), for
                             the queries with a relevant one among them: a clip outside the camera's
                             field of view has nothing to show it. ``camera_clips`` holds their
                             counts and the fused model's and random ranking's figures on them
    hybrid:                  weight, chosen_on and the text_to_clip, temporal_order_accuracy and freeform
                             figures of hybrid search (the model's and rule-caption scores mixed with the
                             index's weight, or one chosen on the validation clips: :mod:`retrieval.hybrid`)
    baselines:               random / bag_of_frames / rule_captions: the same figures for random ranking,
                             for the model with frames shuffled in time, and for rule-caption search (the
                             frozen sentence encoder over each clip's rule captions, no trained model)
    by_facet:                R@5 per lane, motion, own action, context and category of the queries
                             (:mod:`retrieval.action_breakdown`), for the model, shuffled frames, rule
                             captions and random, with the queries and clips behind each
    curves:                  recall@K for K = 1 … 50 of the model and the baselines (for plots)
    frame_tags:              (a model with dense heads, clips with frame tags) each stream's accuracy on
                             every frame's rule tags beside the most frequent tag, and on the motion at
                             a clip's first and last tagged frame (:func:`encoders.inference.frame_tag_figures`)

The figures as a table beside their baselines are :mod:`retrieval.metrics_tables`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from captioning.text import HOST_HALF, OBJECT_HALF
from encoders.clips.layout import read_clip_table
from encoders.metrics import (
    CURVE_MAX_K,
    caption_queries,
    half_queries,
    random_text_to_clip,
    recall_curve,
    text_to_clip_figures,
)
from retrieval.action_breakdown import facets, recall_by_facet
from retrieval.captions_search import CaptionSearch, TextEncoder
from retrieval.clip_neighbours import clip_to_clip_figures, perfect_ranking_figures, random_clip_to_clip
from retrieval.embedding import Embedder, ModelEmbedder
from retrieval.freeform import FREEFORM_QUERIES, FreeformQuery, freeform_figures, freeform_relevance
from retrieval.hybrid import CHOICE_SPLIT, DEFAULT_WEIGHT, WeightChoice, choose_for_rows, mix
from retrieval.sentence_encoder import SentenceEncoder

#: A caption and its reversed steps count as kept apart by a text tower when their cosine is below this.
#: Frozen mean-pooled sentence encoders put such pairs close to 1 (``docs/research/text-order-options.md``);
#: 0.95 asks for a visible gap.
ORDER_COSINE_MAX = 0.95

# ---------------------------------------------------------------------- text → clip


def camera_clip_figures(sims: dict[str, np.ndarray], relevant: np.ndarray, has_camera: Sequence[bool],
                        seed: int = 0) -> dict[str, Any]:
    """Text → clip figures of the camera view (and, for reference, the fused view and random ranking)
    over the clips the camera saw, for the queries that have a relevant clip among them.

    Args:
        sims: view → (Q, N) similarities; ``camera`` and ``fused`` are read.
        relevant: (Q, N) bool relevance.
        has_camera: (N,) whether each clip has camera frames.
    Returns:
        ``camera``, ``fused``, ``random`` (figures, None without camera clips), ``curve`` (the camera
        view's recall curve) and ``counts`` (``clips``, ``queries``).
    """
    seen = np.asarray(has_camera, dtype=bool)
    rel = np.asarray(relevant, dtype=bool)[:, seen]  # (Q, Nc)
    keep = rel.any(axis=1)  # queries with a relevant camera clip
    counts = {"clips": int(seen.sum()), "queries": int(keep.sum())}
    if seen.sum() < 2 or not keep.any():
        return {"camera": None, "fused": None, "random": None, "curve": [], "counts": counts}
    rel = rel[keep]
    on = {view: np.asarray(sims[view])[keep][:, seen] for view in ("camera", "fused")}
    return {"camera": text_to_clip_figures(on["camera"], rel), "fused": text_to_clip_figures(on["fused"], rel),
            "random": random_text_to_clip(rel, seed=seed)[0], "curve": recall_curve(on["camera"], rel),
            "counts": counts}


# ---------------------------------------------------------------------- temporal order


def temporal_order_accuracy(true_scores: np.ndarray, reversed_scores: np.ndarray) -> float:
    """Share of clips whose true caption scores higher than its reversed form (ties count half).

    Args:
        true_scores: (M,) score of each clip with its own caption.
        reversed_scores: (M,) score of the same clip with the caption's steps reversed.
    """
    t = np.asarray(true_scores, dtype=np.float64)
    r = np.asarray(reversed_scores, dtype=np.float64)
    if t.shape != r.shape or t.ndim != 1:
        raise ValueError(f"expected two (M,) arrays, got {t.shape} and {r.shape}")
    if len(t) == 0:
        return float("nan")
    return float(np.mean((t > r) + 0.5 * (t == r)))


def reverse_steps(tags: Sequence[str], caption: str, generate: Callable[[Sequence[str]], str]) -> str | None:
    """The caption of the same steps in reverse order, or None when reversing changes nothing.

    Args:
        tags: the unified tag sequence (the steps) of the caption.
        caption: the caption of ``tags``.
        generate: tags → caption text (captioning's generator, with the row's category and host tags bound).
    """
    from encoders.negatives import reversed_steps

    reversed_tags = reversed_steps(tags)
    if reversed_tags is None:
        return None
    try:
        text = generate(reversed_tags)
    except (ValueError, KeyError):
        return None
    return text if text and text != caption else None


def caption_generator(category: str, host_tags: Sequence[str]) -> Callable[[Sequence[str]], str]:
    """captioning's tags → canonical caption text for one object (host tags kept as they are)."""
    from encoders.negatives import render_caption

    return lambda tags: render_caption(category, tags, host_tags)


def text_order_figures(t_true: np.ndarray, t_reversed: np.ndarray) -> dict[str, float | int | None]:
    """How far a text tower keeps each caption from its reversed steps.

    Args:
        t_true: (M, D) L2-normalised embeddings of captions.
        t_reversed: (M, D) the same captions with their steps reversed.
    """
    if len(t_true) == 0:
        return {"pairs": 0, "mean_cosine": None, "kept_apart": None}
    cosine = (np.asarray(t_true, dtype=np.float64) * np.asarray(t_reversed, dtype=np.float64)).sum(axis=1)
    return {"pairs": len(cosine), "mean_cosine": float(cosine.mean()),
            "kept_apart": float((cosine < ORDER_COSINE_MAX).mean())}


def rule_caption_scores(rows: Sequence[Mapping[str, Any]], queries: Sequence[str], encoder: TextEncoder) -> np.ndarray:
    """(Q, N) scores of rule-caption search (:class:`retrieval.captions_search.CaptionSearch`) over ``rows``."""
    import pyarrow as pa

    search = CaptionSearch.build(pa.Table.from_pylist(list(rows)), encoder=encoder)
    if len(search) != len(rows):
        raise ValueError(f"rule-caption search kept {len(search)} of {len(rows)} clips: {search.skipped[:3]}")
    xq = np.asarray(encoder(list(queries)), dtype=np.float32)
    return np.stack([search.scores(q) for q in xq]) if len(xq) else np.zeros((0, len(rows)))


# ---------------------------------------------------------------------- orchestration


#: The ``split`` of :func:`evaluate` that takes every clip.
ALL_SPLITS = "all"


def evaluate(run_dir: Path | str, clips_dir: Path | str, split: str = "test", embedder: Embedder | None = None,
             seed: int = 0, progress: Callable[[str], None] | None = None,
             index_dir: Path | str | None = None, sentence_encoder: TextEncoder | None = None,
             freeform: Sequence[FreeformQuery] = FREEFORM_QUERIES,
             hybrid: WeightChoice | None = None) -> dict[str, Any]:
    """Embed the clips of ``split`` (``all``: every clip, e.g. logs held out from training as a whole)
    with the model of ``run_dir`` and measure every figure.

    With ``index_dir`` (an index of the same model and clips) the clip embeddings are read from the
    index instead of recomputed; only the shuffled-frames baseline is embedded. ``sentence_encoder``
    (default: the frozen sentence encoder) serves the rule-caption search reference. Hybrid search takes
    the weight of ``hybrid``, else the index's, else one chosen on the clips' validation split.

    Raises:
        FileNotFoundError: no model or no clip table.
        ValueError: an unknown split, or a split without clips.
    """
    say = progress or (lambda _m: None)
    clips_dir = Path(clips_dir)
    started = time.perf_counter()
    table = read_clip_table(clips_dir)
    splits = sorted(set(table.column("split").to_pylist())) if "split" in table.column_names else []
    if split not in splits and split != ALL_SPLITS:
        raise ValueError(f"unknown split {split!r}; the clips have splits: {', '.join(splits) or '(none)'} "
                         f"(or {ALL_SPLITS!r})")
    rows = [r for r in table.to_pylist() if split in (ALL_SPLITS, r["split"])]
    if len(rows) < 2:
        raise ValueError(f"split {split!r} holds {len(rows)} clips; evaluation needs at least 2")
    embedder = embedder if embedder is not None else ModelEmbedder(run_dir)
    by_id = {r["clip_id"]: r for r in rows}

    stored, index_choice = _stored_views(index_dir, embedder.model_id, list(by_id)) if index_dir is not None \
        else ({}, None)

    def embed(view: str, shuffle: bool = False) -> np.ndarray:
        if not shuffle and view in stored:
            return stored[view]
        ids, x = embedder.embed_clips(clips_dir, view=view, split=None if split == ALL_SPLITS else split,
                                      shuffle_frames=shuffle)
        pos = {c: i for i, c in enumerate(ids)}
        missing = [c for c in by_id if c not in pos]
        if missing:
            raise ValueError(f"the model embedded no {view} vector for {len(missing)} clips, e.g. {missing[:3]}")
        return np.asarray(x, dtype=np.float32)[[pos[c] for c in by_id]]

    x = {view: embed(view) for view in ("fused", "camera", "bev")}
    x_bag = embed("fused", shuffle=True)
    say(f"eval: embedded {len(rows)} {split} clips (fused, camera, bev, shuffled frames)")
    captions = [str(r.get("canonical_caption") or r["caption"]) for r in rows]
    queries, relevant = caption_queries(captions)
    t = np.asarray(embedder.embed_texts(queries), dtype=np.float32)
    sims = {"fused": t @ x["fused"].T}
    # The camera and BEV views' figures first: their (Q, N) scores go before the others are made.
    has_camera = [bool(r.get("has_camera")) for r in rows]
    camera_view = camera_clip_figures(sims | {"camera": t @ x["camera"].T}, relevant, has_camera, seed)
    sim_bev = t @ x["bev"].T
    bev_figures, bev_curve = text_to_clip_figures(sim_bev, relevant), recall_curve(sim_bev, relevant)
    del sim_bev
    sim_bag = t @ x_bag.T
    random_figures, random_curve = random_text_to_clip(relevant, seed=seed)

    # Temporal order: each clip whose caption has ≥ 2 steps against the same steps reversed.
    pairs: list[tuple[int, str, str]] = []
    for i, (row, caption) in enumerate(zip(rows, captions)):
        generate = caption_generator(str(row.get("category", "")), list(row.get("host_tags") or []))
        rev = reverse_steps(list(row.get("tags") or []), caption, generate)
        if rev is not None:
            pairs.append((i, caption, rev))
    order: dict[str, float | int | None] = {"num_captions": len(pairs)}
    order_bag: float | None = None
    order_rule: float | None = None
    order_hybrid: float | None = None
    sentence = sentence_encoder if sentence_encoder is not None else SentenceEncoder.for_run(run_dir)
    if index_choice is not None and index_choice.split is not None and split in (index_choice.split, ALL_SPLITS):
        index_choice = None  # chosen on the clips evaluated here: no figure of a tuned weight on its own data
    choice = hybrid or index_choice or _choose_on_val(table, clips_dir, split, embedder, sentence)
    text_order = text_order_figures(np.zeros((0, 1)), np.zeros((0, 1)))
    text_order_frozen = dict(text_order)
    if pairs:
        idx = np.asarray([p[0] for p in pairs])
        t_true = np.asarray(embedder.embed_texts([p[1] for p in pairs]), dtype=np.float32)
        t_rev = np.asarray(embedder.embed_texts([p[2] for p in pairs]), dtype=np.float32)
        accuracy = temporal_order_accuracy((x["fused"][idx] * t_true).sum(1), (x["fused"][idx] * t_rev).sum(1))
        order_bag = temporal_order_accuracy((x_bag[idx] * t_true).sum(1), (x_bag[idx] * t_rev).sum(1))
        order["accuracy"] = accuracy
        text_order = text_order_figures(t_true, t_rev)
        s_true = np.asarray(sentence([p[1] for p in pairs]), dtype=np.float32)
        s_rev = np.asarray(sentence([p[2] for p in pairs]), dtype=np.float32)
        text_order_frozen = text_order_figures(s_true, s_rev)
        rule_true = rule_caption_scores(rows, [p[1] for p in pairs], sentence)  # (M, N)
        rule_rev = rule_caption_scores(rows, [p[2] for p in pairs], sentence)
        order_rule = temporal_order_accuracy(rule_true[np.arange(len(idx)), idx], rule_rev[np.arange(len(idx)), idx])
        # Hybrid: each clip's mixed score with its caption against the reversed steps, as the search would rank.
        at = np.arange(len(idx))
        order_hybrid = temporal_order_accuracy(mix(t_true @ x["fused"].T, rule_true, choice.weight)[at, idx],
                                               mix(t_rev @ x["fused"].T, rule_rev, choice.weight)[at, idx])
    else:
        order["accuracy"] = None
    say(f"eval: {len(queries)} text queries, {len(pairs)} temporal-order pairs")

    # Rule-caption search: the reference a trained model has to beat on free-form text.
    sim_rule = rule_caption_scores(rows, queries, sentence)
    free_relevant = freeform_relevance(freeform, rows)
    free_texts = [q.text for q in freeform]
    t_free = np.asarray(embedder.embed_texts(free_texts), dtype=np.float32)
    free_model, free_bag = t_free @ x["fused"].T, t_free @ x_bag.T
    free_rule = rule_caption_scores(rows, free_texts, sentence)
    free_random = np.random.default_rng(seed).random(free_relevant.shape)
    mixed = mix(sims["fused"], sim_rule, choice.weight)

    # Each half of the captions alone, as people type one ("a stopped car in the ego lane"): every view's figures.
    halves: dict[str, dict[str, Any]] = {name: {} for name in ("model", "bag_of_frames", "random", "rule_captions")}
    for name, half in (("object", OBJECT_HALF), ("ego", HOST_HALF)):
        half_texts, half_relevant = half_queries(captions, half)
        if not half_texts:
            continue
        t_half = np.asarray(embedder.embed_texts(half_texts), dtype=np.float32)
        halves["model"][name] = {**text_to_clip_figures(t_half @ x["fused"].T, half_relevant),
                                 "queries": len(half_texts)}
        halves["bag_of_frames"][name] = text_to_clip_figures(t_half @ x_bag.T, half_relevant)
        halves["random"][name] = random_text_to_clip(half_relevant, seed=seed)[0]
        halves["rule_captions"][name] = text_to_clip_figures(rule_caption_scores(rows, half_texts, sentence),
                                                             half_relevant)

    clip_facets = [facets(list(r.get("tags") or []), str(r.get("category", ""))) for r in rows]
    facets_of_caption = dict(zip(captions, clip_facets))
    by_facet = recall_by_facet({"model": sims["fused"], "bag_of_frames": sim_bag, "rule_captions": sim_rule},
                               relevant, [facets_of_caption[q] for q in queries], clip_facets)
    actions = ["|".join(r.get("tags") or []) for r in rows]
    appearance = [f"{r.get('time_of_day', 'unknown')}|{r.get('weather', 'unknown')}" for r in rows]
    logs = [str(r.get("log_id", "")) for r in rows]
    windows_ns = [(int(r["start_ns"]), int(r["end_ns"])) for r in rows]
    clip_to_clip = clip_to_clip_figures(x["fused"], actions, appearance, logs=logs, windows_ns=windows_ns)
    egos = ["|".join(r.get("host_tags") or []) for r in rows]
    clip_to_clip |= perfect_ranking_figures(actions, egos, appearance, logs=logs, windows_ns=windows_ns)
    metrics: dict[str, Any] = {
        "split": split,
        "counts": {"clips": len(rows), "queries": len(queries), "temporal_pairs": len(pairs),
                   "actions": len(set(actions))},
        "text_to_clip": text_to_clip_figures(sims["fused"], relevant),
        "temporal_order_accuracy": order,
        "text_order": text_order,
        "freeform": freeform_figures(free_model, free_relevant),
        "halves": halves["model"],
        "clip_to_clip": clip_to_clip,
        "views": {"camera": camera_view["camera"], "bev": bev_figures,
                  "camera_clips": camera_view["counts"] | {"fused": camera_view["fused"],
                                                           "random": camera_view["random"]}},
        "hybrid": {"weight": choice.weight, "chosen_on": choice.split, "given": choice.given, "origin": choice.origin,
                   "text_to_clip": text_to_clip_figures(mixed, relevant),
                   "temporal_order_accuracy": {"accuracy": order_hybrid, "num_captions": len(pairs)},
                   "freeform": freeform_figures(mix(free_model, free_rule, choice.weight), free_relevant)},
        "baselines": {
            "random": {"text_to_clip": random_figures,
                       "temporal_order_accuracy": {"accuracy": 0.5 if pairs else None, "num_captions": len(pairs)},
                       "freeform": freeform_figures(free_random, free_relevant),
                       "halves": halves["random"],
                       "clip_to_clip": random_clip_to_clip(actions, appearance, logs=logs,
                                                                 windows_ns=windows_ns)},
            "bag_of_frames": {"text_to_clip": text_to_clip_figures(sim_bag, relevant),
                              "temporal_order_accuracy": {"accuracy": order_bag, "num_captions": len(pairs)},
                              "freeform": freeform_figures(free_bag, free_relevant),
                              "halves": halves["bag_of_frames"],
                              "clip_to_clip": clip_to_clip_figures(x_bag, actions, appearance, logs=logs,
                                                                   windows_ns=windows_ns)},
            "rule_captions": {"text_to_clip": text_to_clip_figures(sim_rule, relevant),
                              # How the frozen encoder embedded a text of several sentences (SentenceEncoder).
                              "whole_text": getattr(sentence, "whole_text", None),
                              "temporal_order_accuracy": {"accuracy": order_rule, "num_captions": len(pairs)},
                              "text_order": text_order_frozen,
                              "freeform": freeform_figures(free_rule, free_relevant),
                              "halves": halves["rule_captions"],
                              # Neighbours by the clips' own captions: what a retriever by the captions'
                              # content alone does on the clip → clip figures (the bias included).
                              "clip_to_clip": clip_to_clip_figures(
                                  np.asarray(sentence(captions), dtype=np.float32), actions, appearance,
                                  logs=logs, windows_ns=windows_ns)},
        },
        "by_facet": by_facet,
        "curves": {"k": list(range(1, min(CURVE_MAX_K, len(rows)) + 1)),
                   "model": recall_curve(sims["fused"], relevant),
                   "camera": camera_view["curve"],
                   "bev": bev_curve,
                   "random": random_curve,
                   "bag_of_frames": recall_curve(sim_bag, relevant),
                   "rule_captions": recall_curve(sim_rule, relevant),
                   "hybrid": recall_curve(mixed, relevant)},
        "model_sha256": embedder.model_id,
    }
    model = getattr(embedder, "model", None)  # a trained dual encoder (ModelEmbedder); stand-ins have none
    if model is not None and getattr(model, "dense", None):
        from encoders.inference import frame_tag_figures, open_split

        dataset = open_split(clips_dir, None if split == ALL_SPLITS else split)
        if getattr(dataset, "has_frame_tags", False):
            metrics["frame_tags"] = frame_tag_figures(model, dataset)
            say("eval: per-frame tag accuracy of the dense heads")
    # The tagging head against the dataset statistics, for a run that has one; its thresholds come from the
    # validation logs, so not on those (nor on every log at once).
    if split not in (CHOICE_SPLIT, ALL_SPLITS):
        from encoders.tagging.versus_statistics import tagging_against_statistics

        tagging = tagging_against_statistics(run_dir, clips_dir, split, say)
        if tagging is not None:
            metrics["tagging"] = tagging
    metrics["wall_s"] = round(time.perf_counter() - started, 2)
    return _clean(metrics)


def _stored_views(index_dir: Path | str, model_id: str,
                  clip_ids: list[str]) -> tuple[dict[str, np.ndarray], WeightChoice | None]:
    """(N, D) embeddings of ``clip_ids`` per view from an index of the same model, and the index's hybrid
    weight; ({}, None) when it cannot serve."""
    from retrieval.scenesearch import SceneSearch

    try:
        search = SceneSearch.open(index_dir)
    except (ValueError, OSError):
        return {}, None
    if search.manifest.model_sha256 != model_id or any(c not in search.views["fused"] for c in clip_ids):
        return {}, None
    return ({view: np.asarray(index.reconstruct(clip_ids), dtype=np.float32) for view, index in search.views.items()},
            search.hybrid)


def _choose_on_val(table: Any, clips_dir: Path, split: str, embedder: Embedder, sentence: TextEncoder) -> WeightChoice:
    """The hybrid weight chosen on the validation clips (:func:`retrieval.hybrid.choose_for_rows`); the
    default when there are none, or when they are the clips evaluated."""
    rows = [r for r in table.to_pylist() if r.get("split") == CHOICE_SPLIT]
    if split in (CHOICE_SPLIT, ALL_SPLITS) or len(rows) < 2:
        return WeightChoice(DEFAULT_WEIGHT)
    ids, x = embedder.embed_clips(clips_dir, view="fused", split=CHOICE_SPLIT)
    pos = {c: i for i, c in enumerate(ids)}
    rows = [r for r in rows if r["clip_id"] in pos]
    return choose_for_rows(rows, np.asarray(x, dtype=np.float32)[[pos[r["clip_id"]] for r in rows]],
                           embedder.embed_texts, lambda texts, sample: rule_caption_scores(sample, texts, sentence))


def _clean(value: Any) -> Any:
    """NaN → None and numpy scalars → Python numbers, so the dictionary is valid JSON."""
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and math.isnan(value):
        return None
    return value
