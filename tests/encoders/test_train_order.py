"""Training for order: the slots text tower with reversed-step negatives keeps a caption apart from its
reversed steps, the pooled tower does not; hard negatives keep resume exact."""

from __future__ import annotations

import dataclasses
import json
import random
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from safetensors.torch import load_file
from torch.utils.data import Dataset

from encoders.config import TextConfig
from encoders.inference import embed_texts, load_model
from encoders.negatives import render_caption, reversed_steps
from encoders.presets import preset
from encoders.sentence import TextModelUnavailableError
from encoders.text import text_sentences
from encoders.train import TrainingError, train
from encoders.train_config import HardNegative, TrainConfig
from retrieval.evaluation import ORDER_COSINE_MAX, text_order_figures
from tests.encoders.synthetic import SyntheticClipDataset, SyntheticSpec

SPEC = SyntheticSpec(frames=4, camera_hw=(16, 16), bev_hw=(16, 8), distractors=0, camera_fraction=0.0)
HOST = ["cruising:heading_straight"]
MOTION = {"approach": "approach", "recede": "away", "constant": "constant"}


def shown(steps: tuple[tuple[str, str], ...]) -> bool:
    """One of each pair of time-reversed behaviours: as in real data, a caption's reversed steps are
    (almost) never another training caption, so only hard negatives show them."""
    return len(steps) < 2 or steps < steps[::-1]


def tags_of(steps: tuple[tuple[str, str], ...]) -> list[str]:
    return [f"{lane}:{MOTION[motion]}" for lane, motion in steps]


class CaptionedClips(Dataset[dict[str, Any]]):
    """Synthetic clips captioned as a clips folder's are (captioning's generator, a host cruising straight)."""

    def __init__(self, size: int, augment: bool = False) -> None:
        self.base = SyntheticClipDataset(10 * size, "train", SPEC, seed=1)
        self.index = [i for i in range(10 * size) if shown(self.base.record(i)["steps"])][:size]
        self.augment = augment
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, index: int) -> dict[str, Any]:
        item, record = self.base[self.index[index]], self.base.record(self.index[index])
        tags = tags_of(record["steps"])
        canonical = render_caption(record["category"], tags, HOST)
        rng = random.Random(f"{self.epoch}/{index}") if self.augment else None
        return {**item, "category": record["category"], "tags": tags, "host_tags": HOST,
                "canonical_caption": canonical, "caption": render_caption(record["category"], tags, HOST, rng)}


def config(text: TextConfig, **changes: Any) -> TrainConfig:
    tiny = preset("tiny").train
    slots = {"time_slots": 4, "slot_dim": 4} if text.kind == "slots" else {}
    changes = {"batch_size": 8, "augment": False, "device": "cpu", **changes}
    return dataclasses.replace(tiny, model=dataclasses.replace(tiny.model, text=text, **slots), **changes)


def run(out: Path, cfg: TrainConfig, dataset: Dataset[dict[str, Any]], **kwargs: Any) -> None:
    torch.set_num_threads(1)
    try:
        train("unused", out, cfg, datasets={"train": dataset}, progress=False, log=lambda _m: None, **kwargs)
    except TextModelUnavailableError as exc:
        pytest.skip(f"the pretrained sentence encoder is not installed: {exc}")


def test_slots_tower_with_reversed_negatives_keeps_reversed_steps_apart(tmp_path: Path) -> None:
    clips = CaptionedClips(32)
    shapes = {(r["category"], r["steps"]) for r in map(clips.base.record, clips.index)}
    pairs = [(render_caption(category, tags_of(steps), HOST), render_caption(category, rev, HOST))
             for category, steps in sorted(shapes) if (rev := reversed_steps(tags_of(steps)))]
    assert len(pairs) >= 6
    figures: dict[str, dict[str, Any]] = {}
    for name, text, negatives in (("slots", TextConfig(kind="slots"), (HardNegative.REVERSE,)),
                                  ("pooled", TextConfig(), ())):
        out = tmp_path / name
        run(out, config(text, epochs=10, hard_negatives=negatives), clips)
        model = load_model(out)
        assert model.text.cache is not None
        # The reversed captions never were training captions; the slots run met them as negatives.
        cached = [text_sentences(rev)[-1] if name == "slots" else rev for _, rev in pairs]  # what the tower encodes
        assert all((model.text.cache.get(c) is not None) == bool(negatives) for c in cached)
        figures[name] = text_order_figures(embed_texts(model, [p[0] for p in pairs]),
                                           embed_texts(model, [p[1] for p in pairs]))
    assert ORDER_COSINE_MAX == 0.95
    assert figures["slots"]["kept_apart"] >= 0.75, figures
    assert figures["pooled"]["kept_apart"] <= 0.25 and figures["pooled"]["mean_cosine"] > 0.95, figures


def metrics(run_dir: Path) -> list[dict[str, Any]]:
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in ("samples_per_s", "epoch_s")} for r in rows]


class Killed(Exception):
    pass


def test_resume_with_paraphrased_hard_negatives_is_exact(tmp_path: Path) -> None:
    cfg = config(preset("tiny").train.model.text, epochs=2, augment=True, hard_negatives=tuple(HardNegative))
    run(tmp_path / "straight", cfg, CaptionedClips(16, augment=True))

    def kill(epoch: int) -> None:
        if epoch == 1:
            raise Killed

    with pytest.raises(Killed):
        run(tmp_path / "resumed", cfg, CaptionedClips(16, augment=True), on_epoch_end=kill)
    run(tmp_path / "resumed", cfg, CaptionedClips(16, augment=True), resume=True)
    assert metrics(tmp_path / "resumed") == metrics(tmp_path / "straight")
    a, b = (load_file(str(tmp_path / d / "model.safetensors")) for d in ("resumed", "straight"))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    # The negatives are in the loss: without them the same run trains differently.
    run(tmp_path / "plain", dataclasses.replace(cfg, hard_negatives=()), CaptionedClips(16, augment=True))
    losses = [[r["train_loss"] for r in metrics(tmp_path / d)] for d in ("straight", "plain")]
    assert not np.allclose(losses[0], losses[1])


def test_hard_negatives_need_the_clips_tags() -> None:
    cfg = config(preset("tiny").train.model.text, hard_negatives=(HardNegative.REVERSE,))
    with pytest.raises(TrainingError, match="category, host_tags"):
        train("unused", "/nonexistent/run", cfg, datasets={"train": SyntheticClipDataset(4, "train", SPEC)},
              progress=False, log=lambda _m: None)
