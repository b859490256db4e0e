"""Contrastive loss with hard negatives: extra clip → text columns, and no change without them."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from encoders.loss import contrastive_loss, positives_matrix


def lse(*values: float) -> float:
    return math.log(sum(math.exp(v) for v in values))


def test_hand_checked_negatives() -> None:
    video = torch.tensor([[1.0, 0.0], [0.0, 1.0]])
    text = torch.tensor([[1.0, 0.0], [0.0, 1.0]])
    negatives = torch.tensor([[0.6, 0.8]])  # (M = 1, D)
    scale, positives = torch.tensor(1.0), torch.eye(2, dtype=torch.bool)
    in_batch = lse(1, 0) - 1  # every row of both sides without negatives
    got = contrastive_loss(video, text, scale, positives, negatives=negatives)
    v2t = ((lse(1, 0, 0.6) - 1) + (lse(0, 1, 0.8) - 1)) / 2
    assert float(got) == pytest.approx(0.5 * (v2t + in_batch))
    # The negative is clip 0's own caption: a second positive of clip 0, still a negative of clip 1.
    own = torch.tensor([[True], [False]])
    got = contrastive_loss(video, text, scale, positives, negatives=negatives, negative_positives=own)
    v2t = ((lse(1, 0, 0.6) - lse(1, 0.6)) + (lse(0, 1, 0.8) - 1)) / 2
    assert float(got) == pytest.approx(0.5 * (v2t + in_batch))
    # A negative closer to a clip than its caption costs more.
    near = contrastive_loss(video, text, scale, positives, negatives=torch.tensor([[1.0, 0.0]]))
    assert float(near) > float(got)


def reference_loss(video: torch.Tensor, text: torch.Tensor, scale: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
    """The loss as it is written without hard negatives."""
    logits = scale * video.float() @ text.float().T

    def side(s: torch.Tensor) -> torch.Tensor:
        return (torch.logsumexp(s, dim=1) - torch.logsumexp(s.masked_fill(~pos, float("-inf")), dim=1)).mean()
    return 0.5 * (side(logits) + side(logits.T))


def test_without_negatives_the_loss_is_unchanged() -> None:
    g = torch.Generator().manual_seed(0)
    video = F.normalize(torch.randn(6, 8, generator=g), dim=-1)
    text = F.normalize(torch.randn(6, 8, generator=g), dim=-1)
    keys = ["a", "b", "a", "c", "d", "b"]
    pos, scale = positives_matrix(keys), torch.tensor(14.3)
    expected = reference_loss(video, text, scale, pos)
    for negatives in (None, torch.zeros(0, 8)):
        got = contrastive_loss(video, text, scale, pos, negatives=negatives)
        assert torch.equal(got, expected)
