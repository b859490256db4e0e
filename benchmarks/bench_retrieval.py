"""Query latency of ``SceneSearch.search_text`` at 10k and 1M indexed clips, text encoding included,
and of ``search_hybrid`` (the model and rule captions mixed) beside it in the same run.

The text encoder is the dual encoder's real text tower (frozen all-MiniLM-L6-v2 + projection head,
``encoders.model.DualEncoder`` with its default config; latency does not depend on trained weights).
Every query is a distinct sentence (distinct across collection sizes too), so the tower's
per-caption cache never answers; a second pass over the same sentences measures the cached case.

Clip embeddings are synthetic: a mixture of Gaussian clusters on the unit sphere around the text
embeddings of 256 caption-like sentences (a trained model pulls clips towards their captions),
D = the model's width. An untrained projection head maps all caption-like sentences into one
narrow cone, where every clip is a near tie of every other and exact recall@10 can only be had by
scanning a large share of the collection; training spreads them (the demo's trained model on the same
sentences: ``TRAINED_MEAN_PAIRWISE_COS``; both cosines are in ``docs/research/benchmark-highlights.md``).
So the tower's output passes through a fixed stand-in for training, fitted once on the sentences: the
component along their mean direction is shrunk until their mean pairwise cosine matches the trained
model's (:class:`SpreadEmbedder`; one (D,) dot product per query, inside the timed call).

Reported per collection size: p50/p99 of the whole call, the share of each step (text encoding,
FAISS search, metadata rows → records), the index chosen and its recall@10 against exact search
(``faiss.knn``, the reference, also timed), and the build time. Target: p50 ≤ 20 ms at 1M.

Hybrid search (``hybrid``), at the weight 0.4 the demo's index chose, on the same queries rephrased so
that neither encoder's cache answers, with 256 distinct rule captions embedded by the frozen sentence
encoder, in two cases: ``captions_agree`` (each clip's caption is its cluster's sentence, so the model
and the rules agree, as on real captions) and ``captions_disagree`` (a random sentence per clip: the
rules' best clips lie anywhere in the model's ranking, the bound's worst case). Reported per case:
p50/p99, the ratio of its p50 to text search's, the model's mean candidate list K and the clips scored
beyond it, and the one-off cost of a view's first hybrid query (mapping clips to caption rows).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import faiss
import numpy as np
import pyarrow as pa

CATEGORIES = ("car", "truck", "bus", "pedestrian", "bicyclist")
LANES = ("left lane", "right lane", "ego lane", "oncoming lane", "crossing on the left")
MOTIONS = ("approaches", "moves away", "keeps its distance", "is stationary", "stops")


def queries(n: int, seed: int = 0) -> list[str]:
    """``n`` distinct query sentences."""
    combos = list(itertools.product(CATEGORIES, LANES, MOTIONS, MOTIONS))
    rng = np.random.default_rng(seed)
    picks = rng.choice(len(combos), size=min(n, len(combos)), replace=False)
    return [f"a {c} in the {lane} {m1}, then {m2}" for c, lane, m1, m2 in (combos[i] for i in picks)]


def clustered_vectors(n: int, centres: np.ndarray, spread: float = 0.6,
                      seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, d) unit vectors drawn around ``centres`` (C, d), and (n,) the centre of each."""
    rng = np.random.default_rng(seed)
    clusters, d = centres.shape
    out = np.empty((n, d), np.float32)
    labels = np.empty(n, np.int64)
    step = 200_000
    for s in range(0, n, step):
        m = min(step, n - s)
        labels[s:s + m] = rng.integers(clusters, size=m)
        x = centres[labels[s:s + m]] + rng.standard_normal((m, d)).astype(np.float32) * (spread / np.sqrt(d))
        out[s:s + m] = x / np.linalg.norm(x, axis=1, keepdims=True)
    return out, labels


class TowerEmbedder:
    """The dual encoder's text tower as a retrieval Embedder (text only)."""

    def __init__(self) -> None:
        import torch

        from encoders.config import DualEncoderConfig
        from encoders.model import DualEncoder

        torch.set_grad_enabled(False)
        self.model = DualEncoder(DualEncoderConfig()).eval()
        self.dim = int(self.model.config.embed_dim)

    def forget(self) -> None:
        """Empty the tower's per-caption cache."""
        cache = self.model.text.cache
        if cache is not None:
            cache.entries.clear()

    @property
    def model_id(self) -> str:
        return "bench"

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        import torch

        with torch.inference_mode():
            return np.asarray(self.model.encode_text(list(texts)).numpy(), dtype=np.float32)

    def embed_clips(self, clips_dir: Path, view: str = "fused", split: str | None = None,
                    shuffle_frames: bool = False) -> tuple[list[str], np.ndarray]:
        raise NotImplementedError

    def embed_arrays(self, clip: Mapping[str, Any], view: str = "fused") -> np.ndarray:
        raise NotImplementedError


#: Mean pairwise cosine of the text embeddings of ``queries(200)`` under the demo's trained model
#: (``scenesearch demo``): ``x = ModelEmbedder(run).embed_texts(queries(200))``, mean of the off-diagonal
#: ``x @ x.T``.
TRAINED_MEAN_PAIRWISE_COS = 0.59


class SpreadEmbedder(TowerEmbedder):
    """The text tower, with the common direction of caption-like sentences shrunk as training does.

    ``y → normalize(y − β (y · u) u)``, ``u`` the unit mean of the fitting sentences' embeddings and
    ``β`` in [0, 1] chosen by bisection so that their mean pairwise cosine is ``target_cos``.
    """

    def __init__(self, fit_texts: list[str], target_cos: float = TRAINED_MEAN_PAIRWISE_COS) -> None:
        super().__init__()
        y = super().embed_texts(fit_texts)
        mean = y.mean(axis=0)
        self.u = (mean / np.linalg.norm(mean)).astype(np.float32)
        self.beta = 0.0
        lo, hi = 0.0, 1.0
        for _ in range(30):
            self.beta = 0.5 * (lo + hi)
            z = self._spread(y)
            cos = (z @ z.T)[np.triu_indices(len(z), 1)].mean()
            lo, hi = (self.beta, hi) if cos > target_cos else (lo, self.beta)
        self.mean_pairwise_cos = float(cos)

    def _spread(self, y: np.ndarray) -> np.ndarray:
        z = y - self.beta * (y @ self.u)[:, None] * self.u[None]
        return np.asarray(z / np.linalg.norm(z, axis=1, keepdims=True), dtype=np.float32)

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        return self._spread(super().embed_texts(texts))


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values) * 1e3, q))


def measure(n: int, embedder: TowerEmbedder, texts: list[str], seed: int = 0) -> dict[str, Any]:
    from indexes.clip_index import ClipIndex
    from retrieval.querying import Query, hits_to_results
    from retrieval.scenesearch import SceneSearch

    d = embedder.dim
    # Clip embeddings cluster around the embeddings of the captions that describe them.
    centre_texts = queries(256, seed=seed + 1)
    centres = embedder.embed_texts(centre_texts)
    xb, labels = clustered_vectors(n, centres, seed=seed)
    embedder.forget()  # the centres' sentences must not answer timed queries from the cache
    meta = pa.table({
        "clip_id": pa.array([f"log{i // 1000:05d}:t{i % 1000:03d}:0" for i in range(n)]),
        "category": pa.array(np.asarray(CATEGORIES)[np.arange(n) % len(CATEGORIES)].tolist()),
        "caption": pa.array(["a car in the left lane approaches"] * n),
    })
    t0 = time.perf_counter()
    index = ClipIndex.build(xb, meta, metric="cosine")
    build_s = time.perf_counter() - t0
    search = SceneSearch.__new__(SceneSearch)
    search.views = {"fused": index}
    search._embedder = embedder
    search.clips_dir = Path(".")
    search.last_timings_s = {}
    for q in texts[:5]:  # warm-up (also loads lazily initialised pieces)
        search.search_text(q + " warm", k=10)
    total, enc, fais, rec = [], [], [], []
    for q in texts:
        t0 = time.perf_counter()
        search.search_text(q, k=10)
        total.append(time.perf_counter() - t0)
    cached = []
    for q in texts:
        t0 = time.perf_counter()
        search.search_text(q, k=10)
        cached.append(time.perf_counter() - t0)
    # The steps one by one, on fresh sentences (so encoding is not cached).
    xq_all = []
    for q in texts:
        q2 = q.replace("a ", "one ", 1)
        t0 = time.perf_counter()
        xq = embedder.embed_texts([q2])
        t1 = time.perf_counter()
        index.vectors.search(xq, 10)
        t2 = time.perf_counter()
        hits_to_results(index, xq, Query(10, None), "fused", None)
        t3 = time.perf_counter()
        enc.append(t1 - t0)
        fais.append(t2 - t1)
        rec.append(max(0.0, (t3 - t2) - (t2 - t1)))
        xq_all.append(xq[0])
    xq_arr = np.asarray(xq_all, np.float32)
    t0 = time.perf_counter()
    _, i_exact = faiss.knn(xq_arr, xb, 10, metric=faiss.METRIC_INNER_PRODUCT)
    exact_ms = (time.perf_counter() - t0) / len(xq_arr) * 1e3
    _, i_found = index.vectors.search(xq_arr, 10)
    recall = float(np.mean([len(set(a) & set(b)) / 10 for a, b in zip(i_exact, i_found)]))
    step_ms = {"encode_text": float(np.mean(enc)) * 1e3, "faiss_search": float(np.mean(fais)) * 1e3,
               "metadata_records": float(np.mean(rec)) * 1e3}
    step_total = sum(step_ms.values())
    knob, value = index.vectors.search_knob
    hybrid = measure_hybrid(search, labels, centre_texts, texts, text_p50_ms=_pct(total, 50))
    return {
        "n": n, "dim": d, "factory": index.vectors.factory, "knob": f"{knob}={value}", "build_s": round(build_s, 1),
        "queries": len(texts),
        "p50_ms": round(_pct(total, 50), 2), "p99_ms": round(_pct(total, 99), 2),
        "p50_ms_cached_text": round(_pct(cached, 50), 2),
        "step_mean_ms": {k: round(v, 3) for k, v in step_ms.items()},
        "step_share": {k: round(v / step_total, 3) for k, v in step_ms.items()},
        "recall_at_10_vs_exact": round(recall, 4),
        "exact_search_ms_per_query_batched": round(exact_ms, 3),
        "meets_target_p50_20ms": bool(_pct(total, 50) <= 20.0),
        "hybrid": hybrid,
    }


#: The weight the demo's index chose on its validation clips (`scenesearch index` on the demo's clips).
HYBRID_WEIGHT = 0.4


def measure_hybrid(search: Any, labels: np.ndarray, centre_texts: list[str], texts: list[str],
                   text_p50_ms: float) -> dict[str, Any]:
    """Latency of ``search_hybrid`` over ``search``'s fused view, with rule captions that agree with the
    clips' vectors (each clip captioned by its cluster's sentence) and that do not (a random sentence)."""
    from indexes.metadata import MetadataStore
    from retrieval.captions_search import CaptionSearch, _Groups
    from retrieval.hybrid import Scorers, WeightChoice
    from retrieval.sentence_encoder import SentenceEncoder

    index = search.views["fused"]
    n = len(index)
    encoder = SentenceEncoder()
    embedded = encoder(centre_texts)
    meta = index.metadata.table.select(["clip_id", "category", "caption"])
    store = MetadataStore.from_rows(meta, np.arange(n, dtype=np.int64))
    search.hybrid = WeightChoice(HYBRID_WEIGHT)
    out: dict[str, Any] = {"weight": HYBRID_WEIGHT, "captions": len(centre_texts)}
    shuffled = np.random.default_rng(5).integers(len(centre_texts), size=n)
    for case, caption_of in (("captions_agree", labels), ("captions_disagree", shuffled)):
        groups = _Groups(np.arange(n + 1, dtype=np.int64), caption_of)  # one caption text per clip
        search.captions = CaptionSearch(store, centre_texts, embedded, groups, groups, encoder)
        search._scorers = Scorers()
        t0 = time.perf_counter()
        scorer = search._scorers.get("fused", index, search.captions)  # what the first hybrid query builds
        setup_s = time.perf_counter() - t0
        for q in texts[:5]:
            search.search_hybrid(q + " warm", k=10)
        total, extra, candidates = [], [], []
        for q in texts:
            q2 = q.replace("a ", f"one single {case[9:]} ", 1)  # neither encoder has seen it
            t0 = time.perf_counter()
            search.search_hybrid(q2, k=10)
            total.append(time.perf_counter() - t0)
            extra.append(scorer.last_extra)
            candidates.append(scorer.last_candidates)
        out[case] = {"first_query_setup_s": round(setup_s, 2), "p50_ms": round(_pct(total, 50), 2),
                     "p99_ms": round(_pct(total, 99), 2),
                     "p50_over_text_search": round(_pct(total, 50) / text_p50_ms, 2),
                     "mean_model_candidates": round(float(np.mean(candidates)), 1),
                     "mean_clips_scored_beyond_candidates": round(float(np.mean(extra)), 1)}
    return out


def run(quick: bool) -> dict[str, Any]:
    import torch

    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
    sizes = (10_000, 100_000) if quick else (10_000, 1_000_000)
    per_size = 40 if quick else 200
    # Distinct sentences for every size (and for the step-by-step pass), so no size meets a cached text.
    pool = queries(len(sizes) * per_size, seed=7)
    embedder = SpreadEmbedder(queries(200, seed=3))
    out: dict[str, Any] = {
        "text_tower": "all-MiniLM-L6-v2 (frozen) + projection head + fixed spread (stand-in for training)",
        "fit_mean_pairwise_cos": round(embedder.mean_pairwise_cos, 3),
        "sizes": {},
    }
    for i, n in enumerate(sizes):
        texts = pool[i * per_size : (i + 1) * per_size]
        out["sizes"][str(n)] = measure(n, embedder, texts)
        print(out["sizes"][str(n)], flush=True)
    return out


if __name__ == "__main__":
    import json
    import sys

    print(json.dumps(run(quick="--quick" in sys.argv), indent=2))
