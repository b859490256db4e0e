"""Temporal hard negatives: each edit of a clip's steps, captions rendered by captioning, self-equal ones dropped."""

from __future__ import annotations

import random
from typing import Any

import pytest

from encoders.config import ConfigError, HardNegative, TrainConfig
from encoders.negatives import batch_negatives, edited_steps, hard_negatives, render_caption, reversed_steps

HOST = ["cruising:heading_straight"]
ALL = list(HardNegative)


def test_reverse_edit() -> None:
    assert reversed_steps(["left:approach", "host:away"]) == ["host:away", "left:approach"]
    assert reversed_steps(["left:approach"]) is None
    assert reversed_steps(["left:approach", "host:away", "left:approach"]) is None  # a palindrome
    assert edited_steps(["a:b", "c:d"], "reverse") == ["c:d", "a:b"]


def test_motion_edit_flips_one_step_and_merges_repeats() -> None:
    tags = ["left:approach", "host:away"]
    flipped = {tuple(edited_steps(tags, HardNegative.MOTION, key=f"clip{i}") or ()) for i in range(20)}
    # Either step may be the one flipped; flipping the second makes two equal steps that merge into one.
    assert flipped == {("left:away", "host:away"), ("left:approach", "host:approach")}
    assert edited_steps(tags, "motion", key="x") == edited_steps(tags, "motion", key="x")  # stable per clip
    assert edited_steps(["host:approach", "host:away"], "motion", key="") in (["host:away"], ["host:approach"])
    assert edited_steps(["left:approach:braking"], "motion") == ["left:away:braking"]  # action and context kept
    assert edited_steps(["left:constant", "host:stationary"], "motion") is None


def test_mirror_edit_swaps_left_and_right_lanes() -> None:
    assert edited_steps(["left:approach", "host:away", "right_lateral:constant"], "mirror") == [
        "right:approach", "host:away", "left_lateral:constant"]
    assert edited_steps(["host:approach", "oncoming:approach"], "mirror") is None


def test_hard_negatives_render_with_captioning_and_drop_the_own_caption() -> None:
    tags = ["left:approach", "host:away"]
    own = render_caption("car", tags, HOST)
    negatives = hard_negatives("car", tags, HOST, ALL, key="c")
    assert [n.kind for n in negatives] == ALL
    assert all(n.text == n.canonical != own for n in negatives)
    assert negatives[0].canonical == render_caption("car", ["host:away", "left:approach"], HOST)
    assert "right lane" in negatives[2].canonical and "left lane" in own
    # An edit that renders as the clip's caption is no negative: here the stored caption is the edited one.
    stored = negatives[0].canonical
    assert [n.kind for n in hard_negatives("car", tags, HOST, ALL, key="c", caption=stored)] == ALL[1:]
    # One step that neither flips nor mirrors: nothing.
    assert hard_negatives("car", ["host:constant"], HOST, ALL) == []


def test_ego_clips_only_reverse() -> None:
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
    _, own_by_tags, _ = batch_negatives(batch, [HardNegative.REVERSE], [tuple(a), tuple(b)], by="tags")
    assert own_by_tags == own
    first = batch_negatives(batch, ALL, batch["canonical_caption"], seed=3, step=7, paraphrase_probability=0.8)
    assert first == batch_negatives(batch, ALL, batch["canonical_caption"], seed=3, step=7, paraphrase_probability=0.8)
    with pytest.raises(KeyError, match="host_tags"):
        batch_negatives({k: v for k, v in batch.items() if k != "host_tags"}, ALL, batch["canonical_caption"])


def test_batch_negatives_say_which_clip_each_reversal_belongs_to() -> None:
    a, b = ["left:approach", "host:away"], ["left:approach"]  # b has one step: nothing to reverse
    batch: dict[str, Any] = {"clip_id": ["a", "b"], "category": ["car", "car"], "tags": [a, b],
                             "host_tags": [HOST, HOST]}
    got = batch_negatives(batch, ALL, [render_caption("car", t, HOST) for t in (a, b)])
    kinds = [n.kind for key, t in (("a", a), ("b", b)) for n in hard_negatives("car", t, HOST, ALL, key=key)]
    assert len(got.reversed_of) == len(got.texts) == len(kinds)
    assert got.reversed_of == [0 if k == HardNegative.REVERSE else -1 for k in kinds]
    assert got.reversed_of.count(0) == 1 and 1 not in got.reversed_of


def test_config_key() -> None:
    assert TrainConfig().hard_negatives == ()
    config = TrainConfig.from_yaml_text("hard_negatives: [mirror, reverse, mirror]")
    assert config.hard_negatives == (HardNegative.REVERSE, HardNegative.MIRROR)
    assert TrainConfig.from_dict(config.to_dict()) == config
    with pytest.raises(ConfigError, match="hard_negatives"):
        TrainConfig.from_yaml_text("hard_negatives: [backwards]")
