"""Multi-positive symmetric InfoNCE against naive double-loop references."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from encoders.loss import contrastive_loss, positives_matrix


def naive_multi_positive(video: torch.Tensor, text: torch.Tensor, scale: float, keys: list[str]) -> float:
    b = len(keys)
    logits = [[scale * float(video[i] @ text[j]) for j in range(b)] for i in range(b)]
    total = 0.0
    for direction in range(2):
        for i in range(b):
            row = [logits[i][j] if direction == 0 else logits[j][i] for j in range(b)]
            denom = sum(math.exp(x) for x in row)
            mass = sum(math.exp(row[j]) for j in range(b) if keys[j] == keys[i]) / denom
            total += -math.log(mass) / b
    return total / 2


@pytest.fixture()
def data() -> tuple[torch.Tensor, torch.Tensor, list[str]]:
    g = torch.Generator().manual_seed(0)
    video = F.normalize(torch.randn(7, 16, generator=g, dtype=torch.float64), dim=-1)
    text = F.normalize(torch.randn(7, 16, generator=g, dtype=torch.float64), dim=-1)
    keys = ["a", "b", "a", "c", "b", "a", "d"]
    return video, text, keys


def test_multi_positive_matches_naive(data: tuple[torch.Tensor, torch.Tensor, list[str]]) -> None:
    video, text, keys = data
    got = contrastive_loss(video, text, torch.tensor(14.0), positives_matrix(keys))
    assert math.isclose(float(got), naive_multi_positive(video, text, 14.0, keys), rel_tol=1e-5)


def test_unique_keys_give_the_clip_loss(data: tuple[torch.Tensor, torch.Tensor, list[str]]) -> None:
    video, text, _ = data
    keys = [str(i) for i in range(7)]
    logits = 10.0 * video.float() @ text.float().T
    target = torch.arange(7)
    clip = 0.5 * (F.cross_entropy(logits, target) + F.cross_entropy(logits.T, target))
    got = contrastive_loss(video, text, torch.tensor(10.0), positives_matrix(keys))
    assert math.isclose(float(got), float(clip), rel_tol=1e-5)


def test_repeated_captions_are_not_negatives() -> None:
    # Two clips with the same caption and their (identical) caption embeddings: a perfect model.
    video = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    text = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    keys = ["x", "x", "y"]
    multi = contrastive_loss(video, text, torch.tensor(50.0), positives_matrix(keys))
    single = contrastive_loss(video, text, torch.tensor(50.0), positives_matrix(["x", "x2", "y"]))
    assert float(multi) < 1e-6
    assert float(single) > 0.4  # log(2) on 4 of 6 terms; treating the repeat as a negative penalises a correct model


def test_gradient_flows_to_scale(data: tuple[torch.Tensor, torch.Tensor, list[str]]) -> None:
    video, text, keys = data
    scale = torch.tensor(5.0, dtype=torch.float64, requires_grad=True)
    contrastive_loss(video, text, scale, positives_matrix(keys)).backward()
    assert scale.grad is not None and float(scale.grad) != 0.0
