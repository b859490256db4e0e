"""The single-view losses of training (``view_weight``): the camera view over the clips with camera."""

from __future__ import annotations

import dataclasses

import pytest
import torch
import torch.nn.functional as F

from encoders.config import ConfigError
from encoders.loss import contrastive_loss, positives_matrix, view_loss
from encoders.train_config import TrainConfig

N, D, M = 8, 16, 3  # whole batch, embedding width, extra negatives


class Ranks:
    """Process ``rank`` of ``processes``: its rows of the whole batch, as :class:`encoders.distributed.Distributed`."""

    def __init__(self, rank: int, processes: int) -> None:
        self.rank, self.processes = rank, processes

    def rows(self, n: int) -> slice | None:
        return slice(self.rank * n, (self.rank + 1) * n) if self.processes > 1 else None


def batch() -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    keys = ["a", "b", "a", "c", "d", "b", "e", "f"]
    return {"view": F.normalize(torch.randn(N, D, generator=g), dim=-1),
            "text": F.normalize(torch.randn(N, D, generator=g), dim=-1),
            "negatives": F.normalize(torch.randn(M, D, generator=g), dim=-1),
            "own": torch.zeros(N, M, dtype=torch.bool), "positives": positives_matrix(keys),
            "scale": torch.tensor(10.0)}


def loss_of(dp: Ranks, keep: torch.Tensor, n_local: int) -> torch.Tensor:
    b = batch()
    return view_loss(b["view"], b["text"], b["scale"], b["positives"], keep, dp.rows(n_local), dp.processes,
                     negatives=b["negatives"], own=b["own"])


def test_one_process_takes_the_kept_clips_only() -> None:
    b = batch()
    keep = torch.tensor([1, 0, 1, 1, 0, 1, 1, 0], dtype=torch.bool)
    i = torch.nonzero(keep).reshape(-1)
    expected = contrastive_loss(b["view"][i], b["text"][i], b["scale"], b["positives"][i][:, i],
                                negatives=b["negatives"], negative_positives=b["own"][i])
    assert torch.allclose(loss_of(Ranks(0, 1), keep, N), expected)


def test_processes_average_to_the_whole_batch_loss_whatever_their_share() -> None:
    # Process 0 holds 1 kept clip of its 4, process 1 holds 3: unequal shares must not tilt the mean.
    keep = torch.tensor([1, 0, 0, 0, 1, 1, 1, 0], dtype=torch.bool)
    whole = loss_of(Ranks(0, 1), keep, N)
    parts = [loss_of(Ranks(r, 2), keep, N // 2) for r in range(2)]
    assert torch.allclose((parts[0] + parts[1]) / 2, whole, atol=1e-6)
    # A process with no kept clip adds 0, still through the view (every process's graph reaches it).
    none = torch.tensor([0, 0, 0, 0, 1, 1, 1, 0], dtype=torch.bool)
    assert float(loss_of(Ranks(0, 2), none, N // 2)) == 0.0
    assert torch.allclose(loss_of(Ranks(1, 2), none, N // 2) / 2, loss_of(Ranks(0, 1), none, N), atol=1e-6)


def test_fewer_than_two_kept_clips_give_zero_with_a_graph() -> None:
    b = batch()
    view = b["view"].clone().requires_grad_(True)
    keep = torch.zeros(N, dtype=torch.bool)
    keep[3] = True
    loss = view_loss(view, b["text"], b["scale"], b["positives"], keep, None, 1, negatives=b["negatives"],
                     own=b["own"])
    loss.backward()
    assert float(loss.detach()) == 0.0 and view.grad is not None and float(view.grad.abs().sum()) == 0.0


def test_view_weight_is_checked() -> None:
    with pytest.raises(ConfigError, match="view_weight must be >= 0"):
        dataclasses.replace(TrainConfig(), view_weight=-1.0)


@pytest.mark.parametrize("share", [-0.1, 1.5])
def test_camera_share_is_checked(share: float) -> None:
    with pytest.raises(ConfigError, match="camera_share must be in"):
        dataclasses.replace(TrainConfig(), camera_share=share)


def test_camera_apart_needs_the_view_losses() -> None:
    with pytest.raises(ConfigError, match="camera_apart needs view_weight > 0"):
        dataclasses.replace(TrainConfig(), camera_apart=True, view_weight=0.0)
    assert dataclasses.replace(TrainConfig(), camera_apart=True).camera_apart


def test_a_view_that_does_not_move_the_text_has_the_same_loss_and_view_gradient() -> None:
    b = batch()
    keep = torch.ones(N, dtype=torch.bool)
    grads = []
    for move_text in (True, False):
        view, text = b["view"].clone().requires_grad_(True), b["text"].clone().requires_grad_(True)
        negatives, scale = b["negatives"].clone().requires_grad_(True), b["scale"].clone().requires_grad_(True)
        loss = view_loss(view, text, scale, b["positives"], keep, None, 1, negatives=negatives, own=b["own"],
                         move_text=move_text)
        loss.backward()
        grads.append((float(loss.detach()), view.grad, text.grad, negatives.grad, scale.grad))
    (moved, v1, t1, n1, s1), (fixed, v2, t2, n2, s2) = grads
    assert moved == fixed and v1 is not None and v2 is not None and torch.equal(v1, v2)
    assert t1 is not None and n1 is not None and s1 is not None  # the captions' side moves ...
    assert t2 is None and n2 is None and s2 is None  # ... unless the view only meets it
