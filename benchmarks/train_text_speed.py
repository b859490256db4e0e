"""The text side of a training step, timed for :mod:`benchmarks.bench_train`: the sentence-embedding cache,
grouped encoding, bfloat16 matrix products and the whole text as the mean of its sentences, each as a
ratio against its baseline in the same run (see that module's docstring).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from encoders.text import ENCODE_GROUP, TextTower


def text_cache_speedup(batch_size: int, steps: int) -> dict[str, float]:
    """Text side of a training step (encoder + head, forward and backward) with and without the cache."""
    from encoders.config import TextConfig
    from tests.encoders.synthetic import behaviours, caption_of

    captions = [caption_of(c, b) for c in ("car", "truck") for b in behaviours()]
    rng = np.random.default_rng(0)
    batches = [[captions[i] for i in rng.integers(len(captions), size=batch_size)] for _ in range(steps)]
    dev = torch.device("cpu")
    figures: dict[str, float] = {}
    for name, cache in (("cached", True), ("reencoded", False)):
        tower = TextTower(TextConfig(cache=cache), 256).train()
        tower(captions, dev)  # warm-up; fills the cache with every caption, as the first epoch does
        cpu0 = time.process_time()
        for texts in batches:
            tower(texts, dev).sum().backward()
        figures[f"{name}_ms_per_batch"] = round(1000 * (time.process_time() - cpu0) / steps, 3)
    figures["speedup"] = round(figures["reencoded_ms_per_batch"] / figures["cached_ms_per_batch"], 1)
    figures["batch_size"] = batch_size
    return figures


def _step_strings(captions_per_step: int, steps: int) -> list[list[str]]:
    """The distinct strings the slot text tower encodes in each of ``steps`` training steps: each
    caption whole and each of its steps (an ego sentence and an object sentence of one to three
    steps, 3 to 30 words a string)."""
    import encoders.text as text_module
    from tests.encoders.synthetic import behaviours, caption_of

    hosts = ("stationary", "cruising straight", "accelerating while steering left", "decelerating straight")
    captions = [f"The ego vehicle is {h}. {caption_of(c, b).capitalize()}."
                for h in hosts for c in ("car", "truck", "pedestrian") for b in behaviours()]
    rng = np.random.default_rng(0)
    batches = []
    for _ in range(steps):
        picked = [captions[i] for i in rng.choice(len(captions), captions_per_step, replace=False)]
        batches.append(list(dict.fromkeys(s for c in picked for s in (c, *(x for sentence in
                                          text_module.sentence_steps(c) for x in sentence)))))
    return batches


def grouped_encoding_speedup(captions_per_step: int, steps: int) -> dict[str, float]:
    """The sentence encoder on the strings of a training step's captions, by length in groups of
    :data:`encoders.text.ENCODE_GROUP` against one call (every string padded to the longest), in float32.
    """
    import encoders.text as text_module
    from encoders.config import TextConfig

    batches = _step_strings(captions_per_step, steps)
    backbone = text_module.PretrainedText(TextConfig(cache=False, precision="float32")).eval()
    dev, group = torch.device("cpu"), text_module.ENCODE_GROUP
    figures: dict[str, float] = {}
    for name, size in (("one_call", max(map(len, batches))), ("grouped", group)):
        with torch.no_grad():
            backbone._run(batches[0], dev, size)  # warm-up
            cpu0 = time.process_time()
            for texts in batches:
                backbone._run(texts, dev, size)
        figures[f"{name}_ms_per_step"] = round(1000 * (time.process_time() - cpu0) / steps, 1)
    figures["speedup"] = round(figures["one_call_ms_per_step"] / figures["grouped_ms_per_step"], 2)
    figures.update(strings_per_step=round(float(np.mean([len(b) for b in batches])), 1), group=group)
    return figures


def text_precision_speedup(captions_per_step: int, steps: int) -> dict[str, Any]:
    """The frozen sentence encoder on a training step's strings (grouped, as training runs it) with its
    matrix products in bfloat16 against float32, and the cosine of the two embeddings of each string.

    ``TextConfig.precision: auto`` takes bfloat16 only where ``native_bfloat16`` (AVX512-BF16 or AMX);
    elsewhere the CPU emulates it and the ratio says how much slower that would be.
    """
    import encoders.text as text_module
    from encoders.config import TextConfig
    from encoders.sentence import inference_autocast, native_bfloat16

    batches = _step_strings(captions_per_step, steps)
    backbone = text_module.PretrainedText(TextConfig(cache=False, precision="float32")).eval()
    dev = torch.device("cpu")
    figures: dict[str, Any] = {}
    rows: dict[str, list[torch.Tensor]] = {}
    for name, dtype in (("float32", torch.float32), ("bfloat16", torch.bfloat16)):
        with torch.no_grad(), inference_autocast(dev, dtype):
            backbone._run(batches[0], dev)  # warm-up
            cpu0 = time.process_time()
            rows[name] = [backbone._run(texts, dev) for texts in batches]
        figures[f"{name}_ms_per_step"] = round(1000 * (time.process_time() - cpu0) / steps, 1)
    cosine = torch.nn.functional.cosine_similarity(torch.cat(rows["float32"]), torch.cat(rows["bfloat16"]))
    figures["speedup"] = round(figures["float32_ms_per_step"] / figures["bfloat16_ms_per_step"], 2)
    figures.update(min_cosine=round(float(cosine.min()), 6), mean_cosine=round(float(cosine.mean()), 6),
                   strings_per_step=round(float(np.mean([len(b) for b in batches])), 1),
                   native_bfloat16=native_bfloat16())
    return figures


def training_texts(clips_per_step: int, steps: int, clips: int = 400, seed: int = 0) -> list[list[str]]:
    """The caption texts of ``steps`` training steps of the demo's recipe over ``clips`` clips: per clip
    drawn, its caption (one of its 3 paraphrases 80 % of the time, as captioning stores them) and the
    caption of its steps reversed (a hard negative, paraphrased as often). Clips take their steps from
    :func:`tests.encoders.synthetic.behaviours` and an ego tag of a few: sentences recur, captions hardly."""
    import random

    from captioning.text import caption_text, paraphrases
    from encoders.negatives import hard_negatives
    from tests.encoders.synthetic import behaviours

    rng = random.Random(seed)
    hosts = ("stationary:heading_straight", "cruising:heading_straight", "accelerating:steering_left",
             "decelerating:heading_straight")
    motion = {"recede": "away"}
    pool = []
    for key in range(clips):
        host, category = [rng.choice(hosts)], rng.choice(("car", "truck", "pedestrian"))
        tags = [f"{lane}:{motion.get(m, m)}" for lane, m in rng.choice(behaviours())]
        pool.append((category, tags, host, [caption_text(category, tags, host),
                                            *paraphrases(category, tags, host, 3, seed, (key,))]))

    def texts(category: str, tags: list[str], host: list[str], captions: list[str]) -> list[str]:
        caption = rng.choice(captions[1:]) if len(captions) > 1 and rng.random() < 0.8 else captions[0]
        negatives = hard_negatives(category, tags, host, ["reverse"], rng=rng, paraphrase_probability=0.8)
        return [caption, *(n.text for n in negatives)]

    return [[t for clip in rng.sample(pool, clips_per_step) for t in texts(*clip)] for _ in range(steps)]


class _CountedRun:
    """Stands in for a sentence encoder's ``_run`` and keeps the strings it encodes."""

    def __init__(self, backbone: Any) -> None:
        self.run = backbone._run
        self.strings: list[str] = []
        backbone._run = self

    def __call__(self, texts: list[str], device: torch.device, group: int = ENCODE_GROUP) -> torch.Tensor:
        self.strings.extend(texts)
        return self.run(texts, device, group)


def whole_text_speedup(clips_per_step: int, steps: int) -> dict[str, Any]:
    """The slots text tower (4 time slots, cache on, cold) over the caption texts of a run of training
    steps, with the whole text as the mean of its sentences against in one piece
    (``TextConfig.whole_text``; ``speedup``: the seconds in one piece over those as sentences): the
    distinct strings the sentence encoder ran, their characters and its CPU seconds. Each caption is
    nearly a string of its own, whereas its sentences recur across captions.
    """
    import encoders.text as text_module
    from encoders.config import TextConfig

    batches = training_texts(clips_per_step, steps)
    dev = torch.device("cpu")
    figures: dict[str, Any] = {}
    for whole in ("text", "sentences"):
        tower = TextTower(TextConfig(kind="slots", precision="float32", whole_text=whole), 256, 4, 32)
        backbone = tower.backbone
        assert isinstance(backbone, text_module.SlotText)
        with torch.no_grad():
            backbone.sentence._run(["The ego vehicle is stationary."], dev)  # warm-up, outside the cache
        counted = _CountedRun(backbone.sentence)
        cpu0 = time.process_time()
        with torch.no_grad():
            for texts in batches:
                tower(texts, dev)
        figures[whole] = {"cpu_s": round(time.process_time() - cpu0, 2), "strings": len(counted.strings),
                          "characters": sum(map(len, counted.strings))}
    figures["speedup"] = round(figures["text"]["cpu_s"] / max(figures["sentences"]["cpu_s"], 0.01), 2)
    for what in ("strings", "characters"):
        figures[f"{what}_ratio"] = round(figures["text"][what] / figures["sentences"][what], 2)
    figures.update(clips_per_step=clips_per_step, steps=steps,
                   texts=sum(map(len, batches)), distinct_texts=len({t for b in batches for t in b}))
    return figures
