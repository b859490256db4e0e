"""Temporal hard negatives: each edit of a clip's steps, captions rendered by captioning, self-equal ones dropped."""

from __future__ import annotations

import random
from typing import Any

import pytest

from encoders.config import ConfigError
from encoders.negatives import batch_negatives, edited_steps, hard_negatives, render_caption, reversed_steps
from encoders.train_config import HardNegative, TrainConfig

HOST = ["cruising:heading_straight"]
ALL = list(HardNegative)


def test_reverse_edit() -> None:
    assert reversed_steps(["left:approach", "host:away"]) == ["host:away", "left:approach"]
    assert reversed_steps(["left:approach"]) is None
    assert reversed_steps(["left:approach", "host:away", "left:approach"]) is None  # a palindrome
    assert edited_steps(["a:b", "c:d"], "reverse") == ["c:d", "a:b"]


def test_hard_negatives_render_with_captioning_and_drop_the_own_caption() -> None:
    tags = ["left:approach", "host:away"]
    own = render_caption("car", tags, HOST)
    negatives = hard_negatives("car", tags, HOST, ALL)
    assert [n.kind for n in negatives] == ALL
    assert all(n.text == n.canonical != own for n in negatives)
    assert negatives[0].canonical == render_caption("car", ["host:away", "left:approach"], HOST)
    # An edit that renders as the clip's caption is no negative: here the stored caption is the edited one.
    stored = negatives[0].canonical
    assert hard_negatives("car", tags, HOST, ALL, caption=stored) == []
    # One step, nothing to reverse: nothing.
    assert hard_negatives("car", ["host:constant"], HOST, ALL) == []


def test_ego_clips_reverse_their_host_steps() -> None:
    tags = ["cruising:heading_straight", "decelerating:steering_left"]
    negatives = hard_negatives("ego", tags, [], ALL)
    assert [n.kind for n in negatives] == [HardNegative.REVERSE]
    assert negatives[0].canonical.startswith("The ego vehicle is decelerating")


def test_paraphrased_negatives_are_seeded() -> None:
    tags = ["left:approach", "host:away"]

    def texts(seed: str) -> list[str]:
        return [n.text for n in hard_negatives("car", tags, HOST, ALL, rng=random.Random(seed),
                                               paraphrase_probability=1.0)]

    assert texts("a") == texts("a")
    assert any(texts(str(s)) != [n.canonical for n in hard_negatives("car", tags, HOST, ALL)] for s in range(5))


def test_batch_negatives_mark_a_negative_equal_to_a_batch_caption_as_its_positive() -> None:
    a, b = ["left:approach", "host:away"], ["host:away", "left:approach"]  # b is a reversed
    batch: dict[str, Any] = {
        "clip_id": ["a", "b"], "category": ["car", "car"], "tags": [a, b], "host_tags": [HOST, HOST],
        "canonical_caption": [render_caption("car", a, HOST), render_caption("car", b, HOST)]}
    texts, own, reversed_of = batch_negatives(batch, [HardNegative.REVERSE], batch["canonical_caption"])
    assert texts == batch["canonical_caption"][::-1]
    assert own == [[False, True], [True, False]]  # a's negative is b's caption: b's positive, and vice versa
    assert reversed_of == [0, 1]
    first = batch_negatives(batch, ALL, batch["canonical_caption"], seed=3, step=7, paraphrase_probability=0.8)
    assert first == batch_negatives(batch, ALL, batch["canonical_caption"], seed=3, step=7, paraphrase_probability=0.8)
    with pytest.raises(KeyError, match="host_tags"):
        batch_negatives({k: v for k, v in batch.items() if k != "host_tags"}, ALL, batch["canonical_caption"])


def test_batch_negatives_say_which_clip_each_reversal_belongs_to() -> None:
    a, b = ["left:approach", "host:away"], ["left:approach"]  # b has one step: nothing to reverse
    batch: dict[str, Any] = {"clip_id": ["a", "b"], "category": ["car", "car"], "tags": [a, b],
                             "host_tags": [HOST, HOST]}
    got = batch_negatives(batch, ALL, [render_caption("car", t, HOST) for t in (a, b)])
    kinds = [n.kind for t in (a, b) for n in hard_negatives("car", t, HOST, ALL)]
    assert len(got.reversed_of) == len(got.texts) == len(kinds)
    assert got.reversed_of == [0 if k == HardNegative.REVERSE else -1 for k in kinds]
    assert got.reversed_of.count(0) == 1 and 1 not in got.reversed_of


def test_config_key() -> None:
    assert TrainConfig().hard_negatives == ()
    config = TrainConfig.from_yaml_text("hard_negatives: [reverse, reverse]")
    assert config.hard_negatives == (HardNegative.REVERSE,)
    assert TrainConfig.from_dict(config.to_dict()) == config
    for removed in ("backwards", "motion", "mirror"):
        with pytest.raises(ConfigError, match="hard_negatives"):
            TrainConfig.from_yaml_text(f"hard_negatives: [{removed}]")
