"""Small synthetic stand-ins for retrieval tests: a clips directory, a hashing text encoder and a model.

The stand-in model embeds a clip as its caption's embedding plus seeded noise, so retrieval has a
right answer; its text encoder hashes words and word pairs, so the order of steps matters, and
"shuffled frames" embed the caption's words sorted, which loses that order.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

DIM = 64
STEPS = {
    "left:approach": "a car in the left lane approaches",
    "left:cut_in": "moves into the host lane",
    "host:stop": "stops ahead of the host",
    "host:constant": "keeps its distance ahead",
    "right:overtake": "overtakes on the right",
}
SEQUENCES = [
    ["left:approach", "left:cut_in"],
    ["left:cut_in", "left:approach"],
    ["host:constant", "host:stop"],
    ["host:stop", "host:constant"],
    ["right:overtake"],
    ["host:constant"],
    ["left:approach", "host:stop"],
]


def caption_of(tags: Sequence[str]) -> str:
    return ", then ".join(STEPS[t] for t in tags)


def hash_embed(texts: Sequence[str], dim: int = DIM) -> np.ndarray:
    """(N, dim) normalised hashed unigrams + bigrams of each text."""
    out = np.zeros((len(texts), dim), np.float32)
    for i, text in enumerate(texts):
        words = text.lower().replace(",", " ,").split()
        grams = words + [f"{a}_{b}" for a, b in zip(words, words[1:])]
        for g in grams:
            h = int.from_bytes(hashlib.blake2b(g.encode(), digest_size=8).digest(), "little")
            out[i, h % dim] += 1.0 if (h >> 32) & 1 else -1.0
        if not grams:
            out[i, 0] = 1.0
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-9)
    return out


class HashTextEncoder:
    name = "hash-test"

    def __init__(self, whole_text: str = "text") -> None:
        self.calls = 0
        self.whole_text = whole_text  # recorded by the caption index, as SentenceEncoder's

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        self.calls += 1
        return hash_embed(list(texts))


class FakeEmbedder:
    """Implements retrieval.embedding.Embedder without a trained model."""

    def __init__(self, model_id: str, noise: float = 0.3, seed: int = 0) -> None:
        self._model_id = model_id
        self.noise = noise
        self.seed = seed

    @property
    def model_id(self) -> str:
        return self._model_id

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        return hash_embed(list(texts))

    def embed_clips(self, clips_dir: Path, view: str = "fused", split: str | None = None,
                    shuffle_frames: bool = False) -> tuple[list[str], np.ndarray]:
        table = pq.read_table(Path(clips_dir) / "clips.parquet").to_pylist()
        if split is not None:
            table = [r for r in table if r["split"] == split]
        texts = [r["canonical_caption"] for r in table]
        if shuffle_frames:
            texts = [" ".join(sorted(t.replace(",", "").split())) for t in texts]
        x = hash_embed(texts)
        scale = {"fused": 1.0, "camera": 2.0, "bev": 1.5}[view]
        for i, r in enumerate(table):
            seed = int.from_bytes(hashlib.blake2b(f"{r['clip_id']}:{view}:{self.seed}".encode(),
                                                  digest_size=4).digest(), "little")
            x[i] += np.random.default_rng(seed).normal(0, self.noise * scale / np.sqrt(DIM), DIM)
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        return [r["clip_id"] for r in table], x

    def embed_arrays(self, clip: Mapping[str, Any], view: str = "fused") -> np.ndarray:
        return hash_embed([str(clip["caption"])])


#: Tag sequences in captioning's own vocabulary (lane:motion), captioned by captioning's text generator.
CAPTIONING_SEQUENCES = [
    ["left:approach", "host:approach"],
    ["host:approach", "left:approach"],
    ["host:constant", "host:stationary"],
    ["host:stationary", "host:constant"],
    ["right:away"],
    ["oncoming:approach", "oncoming:away"],
    ["oncoming:away", "oncoming:approach"],
]
HOST_TAGS = ["cruising:heading_straight"]


def captioning_caption(tags: Sequence[str], category: str) -> str:
    from captioning.text import caption_text

    return caption_text(category, list(tags), HOST_TAGS)


def make_clips_dir(root: Path, n_logs: int = 6, clips_per_log: int = 14, seed: int = 0,
                   sequences: Sequence[list[str]] | None = None,
                   caption: Callable[[Sequence[str], str], str] | None = None) -> Path:
    """A clips directory holding only ``clips.parquet`` (enough for stand-in models).

    ``sequences`` and ``caption`` (tags, category → text) default to this module's small vocabulary.
    """
    sequences = SEQUENCES if sequences is None else sequences
    caption = caption or (lambda tags, _category: caption_of(tags))
    rng = np.random.default_rng(seed)
    rows = []
    for li in range(n_logs):
        log_id = f"log{li:02d}"
        split = "test" if li < 3 else ("val" if li == 3 else "train")
        tod, weather = ["day", "night"][li % 2], ["clear", "rain"][(li // 2) % 2]
        for ci in range(clips_per_log):
            tags = sequences[int(rng.integers(len(sequences)))]
            track = f"t{ci:03d}"
            start = 1_000_000_000 * (ci + 1)
            cat = ["car", "truck", "pedestrian"][ci % 3]
            text = caption(tags, cat)
            rows.append({
                "clip_id": f"{log_id}:{track}:{start}", "log_id": log_id, "track_id": track, "category": cat,
                "start_ns": start, "end_ns": start + 1_500_000_000, "caption": text,
                "canonical_caption": text, "paraphrases": [text], "tags": tags,
                "host_tags": HOST_TAGS, "split": split, "has_camera": True, "bev_source": "lidar",
                "time_of_day": tod, "weather": weather, "frame_indices": list(range(ci, ci + 16)),
                "preview_path": f"previews/{log_id}_{track}.gif",
            })
    root.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(rows), root / "clips.parquet")
    (root / "manifest.json").write_text('{"format_version": 2, "frames_per_clip": 16}')
    return root


def make_run_dir(root: Path, payload: bytes = b"weights-v1") -> Path:
    root.mkdir(parents=True, exist_ok=True)
    (root / "model.safetensors").write_bytes(payload)
    (root / "config.json").write_text('{"embed_dim": 64}')
    return root
