"""The frozen sentence encoder of rule-caption search: all-MiniLM-L6-v2, packaged for offline use and
loaded by :mod:`encoders.sentence`, embedding texts directly, without a trained model
(:mod:`retrieval.captions_search`, the ``rule captions`` baseline of :mod:`retrieval.evaluation`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from encoders.config import BUNDLED_TEXT_MODEL, WHOLE_TEXT_KINDS
from encoders.sentence import cache_name, few_texts, inference_autocast, inference_dtype, shared_sentence_encoder
from encoders.text import TEXT_CACHE_FILE, TextFeatureCache, text_sentences
from retrieval.embedding import EmbeddingCache

if TYPE_CHECKING:
    import torch


class SentenceEncoder:
    """The frozen sentence encoder (all-MiniLM-L6-v2, 384-D) with a cache of the texts it has seen.

    The model is the process's shared instance (:func:`encoders.sentence.shared_sentence_encoder`),
    loaded on first use. Calls return (N, 384) L2-normalised float32 rows.

    ``whole_text``: a text of several sentences is embedded as the normalised mean of its sentences,
    each encoded alone (``sentences``, :func:`encoders.text.text_sentences`), or in one piece
    (``text``). Mean-pooled over a whole caption, the ego's sentence and the object's blur into one
    another; as sentences a caption meets a caption sentence by sentence (rule-caption search gains
    recall and order on the quality benchmark's test split: ``docs/research/rule-caption-sentences.md``),
    and the sentences are what training's text cache holds. A text of one sentence (as
    :func:`encoders.text.text_sentences` splits it: also at ``;``) is embedded the same either way.
    """

    name = "all-MiniLM-L6-v2"

    def __init__(self, cache_size: int = 100_000, known: TextFeatureCache | None = None,
                 precision: str = "auto", whole_text: str = "sentences") -> None:
        """``known``: rows already computed by the same model in the same precision (a run's text
        cache); others are encoded. ``precision``: of the encoder's matrix products
        (:func:`encoders.sentence.inference_dtype`). ``whole_text``: one of
        :data:`encoders.config.WHOLE_TEXT_KINDS`.

        Raises:
            ValueError: an unknown ``whole_text``.
        """
        if whole_text not in WHOLE_TEXT_KINDS:
            raise ValueError(f"SentenceEncoder: whole_text must be one of {list(WHOLE_TEXT_KINDS)}, got {whole_text!r}")
        self.whole_text = whole_text
        self._cache = EmbeddingCache(cache_size)
        self.dtype = inference_dtype(precision)
        name = cache_name(BUNDLED_TEXT_MODEL, self.dtype)
        self._known = known if known is not None and known.model_name == name and len(known) else None

    @classmethod
    def for_run(cls, run_dir: Path | str, precision: str = "auto", whole_text: str = "sentences") -> SentenceEncoder:
        """The encoder, seeded with the sentence embeddings a run's training computed (``RUN_DIR/text_cache.npz``).

        A run whose text tower is this frozen model has encoded its captions' sentences and their steps
        already: the rule captions of an index over its clips are then mostly known (5,066 of the 7,437
        sentences of the demo's 19,036 caption texts), and they cost the demo's index stage most of its
        time. The rows are the same up to the rounding of a different batch (≤ 1e-7 in float32, ≤ 1e-3
        in bfloat16); a cache of the other ``precision`` is not used.
        """
        known = TextFeatureCache(cache_name(BUNDLED_TEXT_MODEL, inference_dtype(precision)))
        known.load(Path(run_dir) / TEXT_CACHE_FILE)
        return cls(known=known, precision=precision, whole_text=whole_text)

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        """N texts → (N, 384)."""
        texts = list(texts)
        if not texts:
            return np.zeros((0, 384), np.float32)
        if self.whole_text == "text":
            return np.stack(self._cache.get_or_embed(texts, self._embed))
        sentences = [text_sentences(t) for t in texts]
        distinct = list(dict.fromkeys(s for parts in sentences for s in parts))
        rows = np.stack(self._cache.get_or_embed(distinct, self._embed))  # (S, 384)
        pos = {s: i for i, s in enumerate(distinct)}
        mean = np.stack([rows[[pos[s] for s in parts]].mean(axis=0) for parts in sentences])  # (N, 384)
        # Sentences that cancel out would leave no direction: a zero row, never a NaN one.
        return (mean / np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)).astype(np.float32)

    def _embed(self, texts: list[str]) -> np.ndarray:
        if self._known is None:
            return _encode_sentences(texts, self.dtype)
        rows = [self._known.get(t) for t in texts]
        missing = [t for t, row in zip(texts, rows) if row is None]
        fresh = iter(_encode_sentences(missing, self.dtype)) if missing else iter(())
        return np.stack([row if row is not None else next(fresh) for row in rows])


def _encode_sentences(texts: list[str], dtype: torch.dtype) -> np.ndarray:
    model = shared_sentence_encoder(BUNDLED_TEXT_MODEL, device="cpu")  # loaded once, under its own lock
    with few_texts(len(texts)), inference_autocast("cpu", dtype):
        emb = model.encode(texts, batch_size=64, convert_to_numpy=True, normalize_embeddings=True,
                           show_progress_bar=False)
    return np.asarray(emb, dtype=np.float32)
