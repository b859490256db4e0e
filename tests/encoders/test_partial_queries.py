"""Partial queries: the halves of a batch's captions, who answers each, drawn alike on every process."""

from __future__ import annotations

from typing import Any

import pytest
import torch

from captioning.text import HOST_HALF, OBJECT_HALF, caption_halves, caption_text
from encoders.loss import partial_query_loss, row_losses
from encoders.partial_queries import batch_partials, chosen_halves

STOPPED = ["decelerating:heading_straight", "stationary:heading_straight"]
CRUISING = ["cruising:heading_straight"]


def clip(clip_id: str, category: str, tags: list[str], host: list[str], paraphrase: bool = False) -> dict[str, Any]:
    import random

    canonical = caption_text(None if category == "ego" else category, tags, host)
    caption = caption_text(None if category == "ego" else category, tags, host, random.Random(clip_id)) \
        if paraphrase else canonical
    return {"clip_id": clip_id, "category": category, "caption": caption, "canonical_caption": canonical}


def batch_of(*clips: dict[str, Any]) -> dict[str, list[Any]]:
    return {k: [c[k] for c in clips] for k in clips[0]}


BATCH = batch_of(
    clip("a", "car", ["host:approach"], CRUISING, paraphrase=True),
    clip("b", "car", ["host:approach"], STOPPED),  # the same object sentence as a, another ego sentence
    clip("c", "car", ["left:approach", "host:constant"], CRUISING),  # the same ego sentence as a
    clip("d", "ego", STOPPED, STOPPED),  # an ego clip: one sentence, no halves
)


def test_every_clip_with_two_sentences_asks_its_object_sentence_and_the_draw_is_stable() -> None:
    assert chosen_halves("a", "car", BATCH["canonical_caption"][0], 0, 3, 1.0, 0.0) == [OBJECT_HALF]
    assert chosen_halves("a", "car", BATCH["canonical_caption"][0], 0, 3, 1.0, 1.0) == [OBJECT_HALF, HOST_HALF]
    assert chosen_halves("d", "ego", BATCH["canonical_caption"][3], 0, 3, 1.0, 1.0) == []
    draws = [chosen_halves(c, "car", BATCH["canonical_caption"][0], 0, s, 0.5, 0.5) for c in "abc" for s in range(20)]
    assert draws == [chosen_halves(c, "car", BATCH["canonical_caption"][0], 0, s, 0.5, 0.5)
                     for c in "abc" for s in range(20)]
    assert len({tuple(d) for d in draws}) == 4  # none, object, host, both


def test_halves_are_cut_from_the_trained_caption_and_answered_by_the_canonical_halves() -> None:
    partials = batch_partials(BATCH, seed=0, step=1, object_share=1.0, host_share=1.0)
    halves_a = caption_halves(BATCH["caption"][0])
    assert BATCH["caption"][0] != BATCH["canonical_caption"][0]  # a trains on a paraphrase
    assert partials.texts[:2] == [halves_a[1], halves_a[0]]  # a's object sentence, then its ego sentence
    assert len(partials.texts) == 6 and len(partials.positives) == 4
    # Columns: a object, a ego, b object, b ego, c object, c ego; rows: the clips a, b, c, d.
    assert partials.positives == [
        [True, True, True, False, False, True],
        [True, False, True, True, False, False],
        [False, True, False, False, True, True],
        [False, False, False, True, False, False],  # the ego clip answers b's ego sentence: its caption
    ]


def test_the_whole_batch_gives_every_process_the_positives_of_all_halves_in_rank_order() -> None:
    whole = {k: v for k, v in BATCH.items() if k != "caption"}  # what Distributed.whole_batch gathers
    first = batch_of(*[{k: BATCH[k][i] for k in BATCH} for i in (0, 1)])
    second = batch_of(*[{k: BATCH[k][i] for k in BATCH} for i in (2, 3)])
    one = batch_partials(BATCH, 0, 5, 1.0, 0.5)
    parts = [batch_partials(p, 0, 5, 1.0, 0.5, whole=whole) for p in (first, second)]
    assert parts[0].texts + parts[1].texts == one.texts
    assert parts[0].positives == parts[1].positives == one.positives


def test_a_batch_without_the_fields_is_refused() -> None:
    with pytest.raises(KeyError, match="canonical_caption"):
        batch_partials({"clip_id": ["a"], "category": ["car"], "caption": ["x"]}, 0, 0, 1.0, 0.0)


def test_partial_query_loss_is_symmetric_infonce_over_the_clips_that_answer_a_half() -> None:
    torch.manual_seed(0)
    video = torch.nn.functional.normalize(torch.randn(4, 8), dim=-1)
    partial = torch.nn.functional.normalize(torch.randn(3, 8), dim=-1)
    positives = torch.tensor([[True, False, True], [False, True, False], [False, False, True], [False, False, False]])
    scale = torch.tensor(5.0)
    logits = scale * video @ partial.T
    by_hand = 0.5 * (row_losses(logits[:3], positives[:3]).mean() + row_losses(logits.T, positives.T).mean())
    loss = partial_query_loss(video, partial, scale, positives)
    assert torch.isfinite(loss) and torch.allclose(loss, by_hand)  # clip 3 answers no half: left out, not infinite
    # Each half's positive clips closer than the others: lower loss.
    aligned = torch.nn.functional.normalize(positives.T.float() @ video + 0.01 * partial, dim=-1)
    assert partial_query_loss(video, aligned, scale, positives) < loss


def test_partial_query_loss_without_halves_is_zero_with_a_graph() -> None:
    video = torch.randn(3, 4, requires_grad=True)
    loss = partial_query_loss(video, torch.zeros(0, 4), torch.tensor(1.0), torch.zeros(3, 0, dtype=torch.bool))
    loss.backward()
    assert float(loss.detach()) == 0.0 and video.grad is not None
