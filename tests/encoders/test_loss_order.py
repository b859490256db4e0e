"""The pairwise order loss: each clip against its caption's steps reversed."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from encoders.config import ConfigError
from encoders.loss import order_loss
from encoders.train_config import HardNegative, TrainConfig


def _batch(seed: int = 0, b: int = 6, m: int = 5, d: int = 8) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    video = F.normalize(torch.randn(b, d, generator=g), dim=-1).requires_grad_()
    text = F.normalize(torch.randn(b, d, generator=g), dim=-1).requires_grad_()
    negatives = F.normalize(torch.randn(m, d, generator=g), dim=-1).requires_grad_()
    return video, text, negatives


def test_the_loss_is_the_mean_softplus_of_each_pair_margin() -> None:
    video, text, negatives = _batch()
    reversed_of = torch.tensor([0, -1, 2, -1, 5])  # negatives 1 and 3 are other edits: no pair
    scale = torch.tensor(10.0)
    pairs = [(0, 0), (2, 2), (5, 4)]
    expected = sum(F.softplus(-scale * (video[i] @ text[i] - video[i] @ negatives[j])) for i, j in pairs) / len(pairs)
    assert torch.allclose(order_loss(video, text, negatives, reversed_of, scale), expected)


def test_a_clip_closer_to_its_caption_than_to_the_reversal_costs_little() -> None:
    t = torch.tensor([[1.0, 0.0]])
    n = torch.tensor([[0.0, 1.0]])
    pair = torch.tensor([0])
    scale = torch.tensor(20.0)
    right = order_loss(torch.tensor([[1.0, 0.0]]), t, n, pair, scale)
    tie = order_loss(F.normalize(torch.tensor([[1.0, 1.0]]), dim=-1), t, n, pair, scale)
    wrong = order_loss(torch.tensor([[0.0, 1.0]]), t, n, pair, scale)
    assert float(right) < 1e-6 and float(tie) == pytest.approx(math.log(2)) and float(wrong) > 19


def test_a_step_against_the_gradient_keeps_more_pairs_in_order() -> None:
    video, text, negatives = _batch(seed=1)
    reversed_of = torch.tensor([0, 1, 2, 3, 4])
    scale = torch.tensor(5.0)

    def margins(v: torch.Tensor) -> torch.Tensor:
        return (v[:5] * text[:5]).sum(-1) - (v[:5] * negatives).sum(-1)

    (grad,) = torch.autograd.grad(order_loss(video, text, negatives, reversed_of, scale), video)
    moved = video.detach() - 0.5 * grad
    assert bool((margins(moved) > margins(video.detach())).all())
    assert torch.count_nonzero(grad[5]) == 0  # clip 5 has no reversal: untouched


def test_without_pairs_the_loss_is_zero_with_a_graph() -> None:
    video, text, negatives = _batch()
    loss = order_loss(video, text, negatives, torch.full((5,), -1), torch.tensor(10.0))
    assert float(loss.detach()) == 0.0 and loss.requires_grad


def test_each_process_rows_sum_to_the_whole_batch_loss() -> None:
    video, text, negatives = _batch(seed=2)
    reversed_of = torch.tensor([0, 1, 3, 4, 5])
    scale = torch.tensor(10.0)
    whole = order_loss(video, text, negatives, reversed_of, scale)
    parts = [order_loss(video, text, negatives, reversed_of, scale, rows=rows)
             for rows in (slice(0, 3), slice(3, 6))]
    assert torch.allclose(whole, parts[0] + parts[1], atol=1e-6)
    grads = [torch.autograd.grad(loss, (video, text, negatives)) for loss in (whole, parts[0] + parts[1])]
    assert all(torch.allclose(a, b, atol=1e-6) for a, b in zip(*grads))


def test_the_weight_needs_reversed_steps_among_the_hard_negatives() -> None:
    assert TrainConfig().order_weight == 0.0
    assert TrainConfig(order_weight=1.0, hard_negatives=(HardNegative.REVERSE,)).order_weight == 1.0
    with pytest.raises(ConfigError, match="order_weight > 0 needs 'reverse'"):
        TrainConfig(order_weight=1.0)
    with pytest.raises(ConfigError, match="order_weight must be >= 0"):
        TrainConfig(order_weight=-1.0, hard_negatives=(HardNegative.REVERSE,))
