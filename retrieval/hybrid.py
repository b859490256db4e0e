"""Hybrid text search: the trained model's scores and rule-caption scores, mixed.

The trained dual encoder reads the clips themselves and understands everyday words; rule-caption
search (:mod:`retrieval.captions_search`) reads the captions the rules wrote from the tracks, which
name lanes, steps and own actions exactly. Each is better at part of what users type, so a hybrid
query scores every clip by both and mixes them::

    s = (1 − w) · z_model + w · z_rules

where each source's scores for the query are standardised over the indexed clips (``z``: minus their
mean, over their standard deviation; the two towers' cosines have different offsets and spreads).

The weight ``w`` is chosen on the validation clips, never on test clips or held-out queries
(:func:`choose_weight`): among :data:`WEIGHTS`, the one with the best mean of caption-query R@5 and
precision@10 on the development free-form queries (:data:`retrieval.freeform.DEV_FREEFORM_QUERIES`).
``scenesearch index`` records the choice and its curve in the index manifest (``hybrid``).

Search over an index (:class:`HybridScorer`) is exact, without scoring every clip with the model:
rule-caption scores are cheap for every clip (one dot product per distinct caption text), the model's
come from the vector index's top ``K``; a clip outside that top ``K`` scores at most
``(1 − w) · z_K + w · z_rules(clip)`` (``z_K``: the K-th model score), so only clips whose bound
reaches the k-th best mixed score are scored by the model too (the threshold algorithm of Fagin et al.).
"""

# D and I are FAISS's names for the (nq, k) score and id tables.
# ruff: noqa: E741

from __future__ import annotations

import hashlib
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from encoders.metrics import caption_queries, text_to_clip_figures
from indexes.clip_index import ClipIndex
from retrieval.captions_search import CaptionSearch
from retrieval.errors import IndexDirError, RetrievalError
from retrieval.freeform import (
    DEV_FREEFORM_QUERIES,
    FREEFORM_K,
    FreeformQuery,
    freeform_figures,
    freeform_relevance,
)
from retrieval.querying import Query

#: Weights tried on the validation clips: 0 is the model alone, 1 rule captions alone.
WEIGHTS: tuple[float, ...] = tuple(round(0.1 * i, 1) for i in range(11))
#: The weight of an index without validation clips (or built before hybrid search).
DEFAULT_WEIGHT = 0.5
#: The split the weight is chosen on.
CHOICE_SPLIT = "val"
#: The weight is chosen on at most this many clips of the split (:func:`choice_sample`): scoring every
#: caption query against every clip grows with the square of the clips (a query per distinct caption).
CHOICE_CLIPS = 2048
#: Model scores are standardised with moments from at most this many indexed clips (all of them when fewer).
MOMENT_SAMPLE = 4096
#: The model's top K before the bound is checked: ``max(CANDIDATE_FACTOR · k, MIN_CANDIDATES)``.
CANDIDATE_FACTOR = 4
MIN_CANDIDATES = 64
#: texts → (Q, D) embeddings.
Texts = Callable[[Sequence[str]], np.ndarray]


class InvalidWeightError(RetrievalError):
    """A hybrid weight outside [0, 1]."""

    def __init__(self, weight: object) -> None:
        super().__init__(f"the hybrid weight must be a number in [0, 1] (0: the model alone, 1: rule captions "
                         f"alone), got {weight!r}")


def check_weight(weight: object) -> float:
    """``weight`` as a float in [0, 1]; raises :class:`InvalidWeightError` otherwise."""
    if isinstance(weight, bool) or not isinstance(weight, int | float | np.floating | np.integer):
        raise InvalidWeightError(weight)
    if not 0.0 <= float(weight) <= 1.0:  # NaN fails too
        raise InvalidWeightError(weight)
    return float(weight)


def standardise(scores: np.ndarray) -> np.ndarray:
    """(Q, N) scores minus each row's mean, over its standard deviation (rows without spread become 0)."""
    s = np.asarray(scores, dtype=np.float64)
    std = s.std(axis=-1, keepdims=True)
    return np.asarray((s - s.mean(axis=-1, keepdims=True)) / np.where(std > 0, std, 1.0))


def mix(model: np.ndarray, rules: np.ndarray, weight: float) -> np.ndarray:
    """(Q, N) hybrid scores of the same queries and clips: ``(1 − w)·z(model) + w·z(rules)``.

    Args:
        model: (Q, N) the trained model's scores.
        rules: (Q, N) rule-caption scores.
        weight: ``w`` in [0, 1].
    """
    model, rules = np.asarray(model), np.asarray(rules)
    if model.shape != rules.shape:
        raise ValueError(f"model scores {model.shape} and rule-caption scores {rules.shape} must both be (Q, N)")
    w = check_weight(weight)
    return (1.0 - w) * standardise(model) + w * standardise(rules)


# ---------------------------------------------------------------------- the weight


@dataclass(frozen=True)
class WeightChoice:
    """The hybrid weight of an index and how it was chosen.

    Attributes:
        weight: ``w`` in [0, 1].
        split: the clips it was chosen on; None when it was given, or is :data:`DEFAULT_WEIGHT` for want of them.
        clips: clips it was chosen on: all of the split's, or a sample of :data:`CHOICE_CLIPS` of them.
        split_clips: clips of that split (0 where not recorded).
        caption_queries: distinct captions of those clips, asked as queries.
        freeform_queries: development free-form queries with a relevant clip among them.
        curve: per weight tried: ``weight``, ``caption_R@5``, ``freeform_P@10`` and their mean ``objective``.
        given: set by whoever built the index (``scenesearch index --hybrid-weight``), not chosen.
    """

    weight: float
    split: str | None = None
    clips: int = 0
    split_clips: int = 0
    caption_queries: int = 0
    freeform_queries: int = 0
    curve: tuple[dict[str, float], ...] = ()
    given: bool = False

    @property
    def origin(self) -> str:
        """Where the weight comes from, in words."""
        if self.given:
            return "given when the index was built"
        if not self.split:
            return "the default (no validation clips)"
        sample = f" (a sample of the {self.split_clips})" if self.split_clips > self.clips else ""
        return f"chosen on {self.clips} {self.split} clips{sample}"

    def to_json(self) -> dict[str, Any]:
        """The record of a manifest (:meth:`from_json` reads it back)."""
        out = asdict(self)
        out["curve"] = [dict(point) for point in self.curve]
        return out

    @staticmethod
    def from_json(raw: object) -> WeightChoice:
        """The choice recorded in a manifest (the default for an index written before hybrid search).

        Raises:
            InvalidWeightError: a recorded weight outside [0, 1].
            ValueError: a malformed record (the message names the sub-field).
        """
        if raw is None:
            return WeightChoice(DEFAULT_WEIGHT)
        if not isinstance(raw, Mapping):
            raise ValueError(f"must be an object with 'weight', got {type(raw).__name__}")
        if not raw:
            return WeightChoice(DEFAULT_WEIGHT)
        counts = {key: raw.get(key, 0) for key in ("clips", "split_clips", "caption_queries", "freeform_queries")}
        for key, value in counts.items():
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"'{key}' must be a count, got {value!r}")
        split, given, curve = raw.get("split"), raw.get("given", False), raw.get("curve") or []
        if split is not None and not isinstance(split, str):
            raise ValueError(f"'split' must be a split name or null, got {split!r}")
        if not isinstance(given, bool):
            raise ValueError(f"'given' must be true or false, got {given!r}")
        if not isinstance(curve, list) or not all(isinstance(point, Mapping) for point in curve):
            raise ValueError("'curve' must be a list of objects")
        return WeightChoice(weight=check_weight(raw.get("weight")), split=split, curve=tuple(dict(p) for p in curve),
                            given=given, **counts)


def choose_weight(captions: tuple[np.ndarray, np.ndarray, np.ndarray],
                  freeform: tuple[np.ndarray, np.ndarray, np.ndarray],
                  weights: Sequence[float] = WEIGHTS, split: str = CHOICE_SPLIT) -> WeightChoice:
    """The weight with the best mean of caption R@5 and free-form precision@10 (ties: the smaller weight).

    Args:
        captions: (model, rules, relevant), each (Qc, N): the caption queries' scores and relevance.
        freeform: (model, rules, relevant), each (Qf, N): the development free-form queries'.
        weights: the weights to try.
        split: the name of the clips scored, recorded in the choice.
    """
    cap_model, cap_rules, cap_relevant = captions
    free_model, free_rules, free_relevant = freeform
    answered = np.asarray(free_relevant, dtype=bool).any(axis=1)
    curve: list[dict[str, float]] = []
    for w in weights:
        r5 = text_to_clip_figures(mix(cap_model, cap_rules, w), cap_relevant)["R@5"] if len(cap_model) else 0.0
        p10 = freeform_figures(mix(free_model, free_rules, w), free_relevant)[f"precision@{FREEFORM_K}"] \
            if answered.any() else None
        parts = [r5] if len(cap_model) else []
        parts += [float(p10)] if p10 is not None else []
        curve.append({"weight": float(w), "caption_R@5": float(r5), f"freeform_P@{FREEFORM_K}": float(p10 or 0.0),
                      "objective": float(np.mean(parts)) if parts else 0.0})
    best = max(curve, key=lambda p: (p["objective"], -p["weight"]))
    clips = int(np.asarray(cap_relevant).shape[1])
    return WeightChoice(best["weight"], split, clips, clips, len(cap_model), int(answered.sum()), tuple(curve))


def choice_sample(clip_ids: Sequence[str], limit: int | None = None) -> np.ndarray:
    """(n,) ascending positions of the clips the weight is chosen on: all of them up to ``limit``
    (:data:`CHOICE_CLIPS` when None), else the ``limit`` whose ids hash lowest (BLAKE2b), so that the
    sample does not depend on the clips' order and mostly stays when clips are added."""
    limit = CHOICE_CLIPS if limit is None else limit
    if len(clip_ids) <= limit:
        return np.arange(len(clip_ids), dtype=np.int64)
    keys = np.array([int.from_bytes(hashlib.blake2b(str(c).encode(), digest_size=8).digest(), "little")
                     for c in clip_ids], dtype=np.uint64)
    return np.sort(np.argsort(keys, kind="stable")[:limit]).astype(np.int64)


def choose_for_rows(rows: Sequence[Mapping[str, Any]], x_model: np.ndarray, embed_texts: Texts,
                    rule_scores: Callable[[Sequence[str], Sequence[Mapping[str, Any]]], np.ndarray],
                    freeform: Sequence[FreeformQuery] = DEV_FREEFORM_QUERIES,
                    split: str = CHOICE_SPLIT) -> WeightChoice:
    """:func:`choose_weight` over clips ``rows`` (their :func:`choice_sample`): their caption queries and
    the development free-form queries.

    Args:
        rows: clip-table rows (clip_id, caption, canonical_caption, category, tags, host_tags).
        x_model: (N, D) the model's clip embeddings of ``rows``, L2-normalised.
        embed_texts: texts → (Q, D) the model's normalised text embeddings.
        rule_scores: (texts, rows) → (Q, n) rule-caption scores of those rows.
        freeform: the development free-form queries (never the held-out ones).
        split: the name of ``rows``' split, recorded in the choice.
    """
    if len(rows) < 2:
        return WeightChoice(DEFAULT_WEIGHT)
    keep = choice_sample([str(r["clip_id"]) for r in rows])
    sample = [rows[i] for i in keep]
    captions = [str(r.get("canonical_caption") or r.get("caption")) for r in sample]
    queries, relevant = caption_queries(captions)
    free_texts = [q.text for q in freeform]
    x = np.asarray(x_model, dtype=np.float32)[keep]
    cap_model = np.asarray(embed_texts(queries), dtype=np.float32) @ x.T
    free_model = np.asarray(embed_texts(free_texts), dtype=np.float32) @ x.T if free_texts else np.zeros((0, len(x)))
    free_rules = np.asarray(rule_scores(free_texts, sample)).reshape(len(free_texts), len(x))
    choice = choose_weight((cap_model, np.asarray(rule_scores(queries, sample)), relevant),
                           (free_model, free_rules, freeform_relevance(freeform, sample)), split=split)
    return replace(choice, split_clips=len(rows))


# ---------------------------------------------------------------------- search over an index


class HybridScorer:
    """Top-k hybrid search over one view of an index and its rule captions.

    Exact on an exact (``Flat``) vector index. On an approximate one (HNSW, IVF, PQ) the model's candidates
    come from the index's own approximate search, as :meth:`SceneSearch.search_text`'s results do, so a clip
    the index misses and the rule captions do not lift can be missed here too.

    Args:
        index: the view's clip index (cosine).
        caption_clip_ids: (Nc,) the clip ids of the rule-caption rows, in row order.

    Raises:
        IndexDirError: an indexed clip without a rule caption.
    """

    def __init__(self, index: ClipIndex, caption_clip_ids: Sequence[str]) -> None:
        self.index = index
        table = index.metadata.table
        self.ids = np.asarray(table.column("id").to_numpy(), dtype=np.int64)  # (N,) view ids, row order
        row_of_caption = {c: i for i, c in enumerate(caption_clip_ids)}
        clip_ids = table.column("clip_id").to_pylist()
        missing = [c for c in clip_ids if c not in row_of_caption]
        if missing:
            raise IndexDirError(f"{len(missing)} indexed clips have no rule caption in the caption index, e.g. "
                                f"{missing[:3]}: rebuild the index (`scenesearch index`)")
        self.caption_rows = np.asarray([row_of_caption[c] for c in clip_ids], dtype=np.int64)  # (N,)
        # As `scenesearch index` writes them, caption rows and view rows are the same clips in the same order.
        self._same_rows = len(caption_clip_ids) == len(clip_ids) and \
            bool(np.array_equal(self.caption_rows, np.arange(len(clip_ids))))
        # id → row position, as an array: a filter can pass a million ids.
        self._position = np.full(int(self.ids.max(initial=-1)) + 1, -1, dtype=np.int64)
        self._position[self.ids] = np.arange(len(self.ids))
        step = -(-len(self.ids) // MOMENT_SAMPLE)  # rounded up: the sample spreads over every log and split
        self._sample = index.vectors.reconstruct(self.ids[::step])  # (S, D), S ≤ MOMENT_SAMPLE
        #: Clips the model scored beyond its top K in the last call (what the bound let through), and that K.
        self.last_extra = 0
        self.last_candidates = 0

    def _model_z(self, positions: np.ndarray, xq: np.ndarray, mean: float, std: float) -> np.ndarray:
        """(M,) standardised model scores of the clips at ``positions``, all computed alike (so ties stay ties).

        einsum, not @: a BLAS product wakes OpenBLAS's threads, whose spinning afterwards halves the speed
        of the next query's text encoders on a small machine (bench_retrieval's hybrid figures).
        """
        x = self.index.vectors.reconstruct(self.ids[positions])  # (M, D)
        return np.asarray((np.einsum("md,d->m", x, xq).astype(np.float64) - mean) / std)

    def top_k(self, xq: np.ndarray, rule_scores: np.ndarray, query: Query,
              weight: float) -> tuple[np.ndarray, np.ndarray]:
        """The k best clips by hybrid score.

        Args:
            xq: (D,) the model's text embedding of the query.
            rule_scores: (Nc,) the query's rule-caption score of every caption row.
            query: the checked k and filter (:func:`retrieval.querying.build_query`).
            weight: ``w`` in [0, 1].
        Returns:
            ids: (M,) view ids, best first, ties by id (M ≤ k: fewer when the filter passes fewer).
            scores: (M,) their hybrid scores.
        """
        w = check_weight(weight)
        xq = np.asarray(xq, dtype=np.float32).reshape(-1)
        xq = xq / max(float(np.linalg.norm(xq)), 1e-12)  # the index compares normalised vectors
        rules = np.asarray(rule_scores, dtype=np.float32)
        rules = rules if self._same_rows else rules[self.caption_rows]  # (N,) in view row order
        r_mean, r_std = float(rules.mean(dtype=np.float64)), float(rules.std(dtype=np.float64)) or 1.0
        sample = np.einsum("sd,d->s", self._sample, xq)
        m_mean, m_std = float(sample.mean()), float(sample.std()) or 1.0
        allowed_ids = None if query.filters is None else self.index.select(query.filters)
        allowed = None if allowed_ids is None else self._position[allowed_ids]  # their row positions
        n_allowed = len(self.ids) if allowed is None else len(allowed)
        if query.k == 0 or n_allowed == 0:
            return np.zeros(0, np.int64), np.zeros(0)

        def z_rules(at: np.ndarray) -> np.ndarray:
            return np.asarray((rules[at].astype(np.float64) - r_mean) / r_std)

        K = min(n_allowed, max(CANDIDATE_FACTOR * query.k, MIN_CANDIDATES))
        while True:
            _, I = self.index.vectors.search(xq[None], K, allowed_ids)
            pos = self._position[I[0][I[0] >= 0]]
            z_model = self._model_z(pos, xq, m_mean, m_std)
            mixed = (1 - w) * z_model + w * z_rules(pos)
            if len(pos) == 0:  # an approximate filtered search found nothing: score what the filter passes
                rest = np.arange(len(self.ids)) if allowed is None else allowed
                break
            if len(pos) >= n_allowed:
                rest = pos[:0]
                break
            # A clip outside the model's top K scores at most (1 − w)·z_K + w·z(its rules) (z_K a hair higher,
            # as the index's scores and ours may differ in the last bits): only clips whose bound reaches the
            # k-th best mixed score can enter. In raw rule scores that bound is a threshold.
            kth = np.sort(mixed)[-query.k] if len(mixed) >= query.k else -np.inf
            floor = (1 - w) * (z_model.min() + 1e-5)
            if w > 0:
                cut = r_mean + r_std * ((kth - floor) / w - 1e-6)
                rest = np.flatnonzero(rules >= cut) if allowed is None else allowed[rules[allowed] >= cut]
            elif floor >= kth:  # the model alone: only a tie with the K-th score could still enter
                rest = np.arange(len(self.ids)) if allowed is None else allowed
            else:
                rest = pos[:0]
            rest = rest[~np.isin(rest, pos)]
            if len(rest) <= len(pos) or n_allowed <= K:
                break
            # The sources disagree: a deeper model list lowers the bound for less than scoring every clip let in.
            K = min(n_allowed, CANDIDATE_FACTOR * K)
        self.last_candidates, self.last_extra = K, len(rest)
        if len(rest):
            pos = np.concatenate([pos, rest])
            mixed = np.concatenate([mixed, (1 - w) * self._model_z(rest, xq, m_mean, m_std) + w * z_rules(rest)])
        ids = self.ids[pos]
        order = np.lexsort((ids, -mixed))[: query.k]  # best first, ties by id
        return ids[order], mixed[order]


class Scorers:
    """One :class:`HybridScorer` per view, built on first use (once, whatever the concurrent requests)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._by_view: dict[str, HybridScorer] = {}

    def get(self, view: str, index: ClipIndex, captions: CaptionSearch) -> HybridScorer:
        with self._lock:
            if view not in self._by_view:
                self._by_view[view] = HybridScorer(index, captions.metadata.table.column("clip_id").to_pylist())
            return self._by_view[view]


def choose_for_index(rows: pa.Table, index: ClipIndex, captions: CaptionSearch, embed_texts: Texts,
                     split: str = CHOICE_SPLIT, given: float | None = None) -> WeightChoice:
    """The weight of an index: ``given``, else :func:`choose_for_rows` over its clips of ``split`` (the
    default without any).

    Args:
        rows: the indexed clip rows (:func:`retrieval.captions_search.caption_rows`: with ``split`` and
            ``canonical_caption``).
        index: the fused view's clip index (the clips' model embeddings).
        captions: the rule-caption index of the same rows.
        embed_texts: the model's text embedder.
        given: a weight set by the user (``InvalidWeightError`` outside [0, 1]).
    """
    if given is not None:
        return WeightChoice(check_weight(given), given=True)
    if "split" not in rows.column_names:
        return WeightChoice(DEFAULT_WEIGHT)
    chosen = [r for r in rows.filter(pc.equal(rows.column("split"), split)).to_pylist() if r["clip_id"] in index]
    if len(chosen) < 2:
        return WeightChoice(DEFAULT_WEIGHT)
    sample = [chosen[i] for i in choice_sample([r["clip_id"] for r in chosen])]
    clip_ids = [r["clip_id"] for r in sample]
    caption_pos = captions.metadata.positions(captions.metadata.ids_of(clip_ids))  # (n,) their caption rows

    def rule_scores(texts: Sequence[str], _rows: Sequence[Mapping[str, Any]]) -> np.ndarray:
        if not texts:
            return np.zeros((0, len(sample)))
        return captions.scores_of(np.asarray(captions.encoder(list(texts)), dtype=np.float32), caption_pos)

    choice = choose_for_rows(sample, index.reconstruct(clip_ids), embed_texts, rule_scores, split=split)
    return replace(choice, split_clips=len(chosen))
