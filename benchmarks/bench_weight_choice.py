"""The hybrid weight's choice (:func:`retrieval.hybrid.choose_for_rows`, run by ``scenesearch index``) as
the validation split grows: on a sample of at most :data:`retrieval.hybrid.CHOICE_CLIPS` clips, against
every clip of the split (the baseline, in the same run).

The choice asks each distinct caption of its clips as a query and scores it against every one of them,
so over the whole split its time and memory grow with the square of the clips (about one distinct
caption per two clips on the demo's validation split: 368 of 622). The clips are synthetic, with
captions drawn so that half of them are distinct, and the two encoders are stand-ins (a seeded
random unit vector per text, of the model's width): what is measured is the choice's own scoring,
which grows with queries × clips; the real encoders add a cost per query, which the sample bounds too.

Figures per split size: wall and CPU seconds and the peak of traced memory (``tracemalloc``, which
numpy reports to), for the sample and, up to :data:`WHOLE_MAX` clips, for the whole split;
``whole_over_sample``: their ratio of CPU seconds.
"""

from __future__ import annotations

import hashlib
import time
import tracemalloc
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from retrieval import hybrid

#: Validation split sizes (``quick``: a smoke run).
SIZES, QUICK_SIZES = (1_000, 4_000, 16_000), (500, 2_500)
#: The largest split also chosen on whole: beyond it the baseline takes minutes and gigabytes.
WHOLE_MAX = 4_000
DIM = 256
CATEGORIES = ("car", "truck", "bus", "pedestrian", "cyclist")
STEPS = ("left:approaching", "right:moving_away", "host:following", "host_lateral:crossing", "oncoming:passing",
         "right:approaching", "left:moving_away", "host:stationary")
HOST = ("cruising:heading_straight", "decelerating:steering_left", "accelerating:steering_right", "stationary:*")


def _unit(text: str) -> np.ndarray:
    seed = int.from_bytes(hashlib.blake2b(text.encode(), digest_size=8).digest(), "little")
    v = np.random.default_rng(seed).standard_normal(DIM).astype(np.float32)
    return v / np.linalg.norm(v)


def embed(texts: Sequence[str]) -> np.ndarray:
    """texts → (Q, DIM) seeded unit vectors (the encoders' stand-in)."""
    return np.stack([_unit(t) for t in texts]) if len(texts) else np.zeros((0, DIM), np.float32)


def split_rows(n: int, seed: int = 0) -> tuple[list[dict[str, Any]], np.ndarray]:
    """``n`` clip rows of one split, each with one of n / 2 captions (about 0.43 n of them distinct, as
    0.59 n on the demo's validation split), and their (n, DIM) model vectors."""
    rng = np.random.default_rng(seed)
    pool = []
    for variant in range(max(n // 2, 1)):
        category = CATEGORIES[int(rng.integers(len(CATEGORIES)))]
        tags = [STEPS[int(j)] for j in rng.integers(len(STEPS), size=int(rng.integers(1, 4)))]
        host = [HOST[int(rng.integers(len(HOST)))]]
        pool.append((category, tags, host, f"A {category}: {' then '.join(tags)}; the ego vehicle is {host[0]} "
                                           f"({variant})."))
    rows = []
    for i in range(n):
        category, tags, host, caption = pool[int(rng.integers(len(pool)))]
        rows.append({"clip_id": f"log{i // 50}:{i}", "caption": caption, "canonical_caption": caption,
                     "category": category, "tags": tags, "host_tags": host})
    x = embed([r["caption"] for r in rows]) + 0.5 * rng.standard_normal((n, DIM)).astype(np.float32)
    return rows, x / np.linalg.norm(x, axis=1, keepdims=True)


def _rule_scores(texts: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> np.ndarray:
    return embed(texts) @ embed([str(r["caption"]) for r in rows]).T


def _timed_choice(rows: list[dict[str, Any]], x: np.ndarray) -> dict[str, Any]:
    tracemalloc.start()
    wall, cpu = time.perf_counter(), time.process_time()
    choice = hybrid.choose_for_rows(rows, x, embed, _rule_scores)
    out = {"wall_s": round(time.perf_counter() - wall, 3), "cpu_s": round(time.process_time() - cpu, 3),
           "peak_traced_mb": round(tracemalloc.get_traced_memory()[1] / 1e6, 1), "clips": choice.clips,
           "caption_queries": choice.caption_queries}
    tracemalloc.stop()
    return out


def run(quick: bool = False) -> dict[str, Any]:
    sizes = QUICK_SIZES if quick else SIZES
    limit = hybrid.CHOICE_CLIPS
    figures: dict[str, Any] = {}
    for n in sizes:
        rows, x = split_rows(n)
        entry = {"sample": _timed_choice(rows, x)}
        if n <= WHOLE_MAX:
            hybrid.CHOICE_CLIPS = n  # the baseline: every clip of the split
            try:
                entry["whole"] = _timed_choice(rows, x)
            finally:
                hybrid.CHOICE_CLIPS = limit
            entry["whole_over_sample"] = round(entry["whole"]["cpu_s"] / max(entry["sample"]["cpu_s"], 1e-9), 2)
        figures[str(n)] = entry
    return {"choice_clips": limit, "sizes": figures}
