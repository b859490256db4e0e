"""The training step's loss as one object: its total is the sum the training loop built term by term,
to the bit, with the same gradients; each term is named and logged."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
import torch

from encoders.distributed import Distributed
from encoders.inference import collate
from encoders.loss import contrastive_loss, order_loss, partial_query_loss, positives_matrix, view_loss
from encoders.model import DualEncoder
from encoders.negatives import batch_negatives
from encoders.partial_queries import batch_partials
from encoders.presets import preset
from encoders.train import train
from encoders.train_config import HardNegative, TrainConfig
from encoders.training_loss import TOTAL, LossTerms, TrainingLoss, forward_step
from tests.encoders.synthetic import CaptionedClips


def Clips(size: int = 8) -> CaptionedClips:
    """Synthetic clips captioned as a clips folder's, with frame tags on some frames and a camera on some clips."""
    return CaptionedClips(size, lambda index: index % 3 != 0)


class Tagging:
    """A stand-in for the tagging objective: a weight and a loss over the BEV embedding of one batch."""

    def __init__(self, batch: dict[str, Any]) -> None:
        self.weight = 0.7
        self.batch = batch

    def loss(self, embed: Any) -> torch.Tensor:
        return embed(self.batch).square().mean()


def every_term() -> TrainConfig:
    tiny = dataclasses.replace(preset("tiny").train, device="cpu")
    model = dataclasses.replace(tiny.model, dense_streams=("camera", "track"),
                                bev=dataclasses.replace(tiny.model.bev, track_velocity=True))
    return dataclasses.replace(tiny, model=model, hard_negatives=(HardNegative.REVERSE,), view_weight=0.5,
                               dense_weight=0.5, order_weight=0.5, partial_weight=0.5, camera_apart=True)


def reference_loss(model: DualEncoder, batch: dict[str, Any], config: TrainConfig, step: int,
                   tag_objective: Tagging | None) -> torch.Tensor:
    """The step's loss as the training loop summed it, one term after the other (one process)."""
    dp, device = Distributed(), torch.device("cpu")
    keys = batch["canonical_caption"]
    _, all_keys = dp.whole_batch(batch, keys)
    negative_texts: list[str] = []
    own: list[list[bool]] = []
    reversed_of: list[int] = []
    if config.hard_negatives:
        negative_texts, own, reversed_of = batch_negatives(batch, config.hard_negatives, keys, config.seed, step, 0.8)
    partials = None
    if config.partial_weight > 0:
        partials = batch_partials(batch, config.seed, step, config.partial_object_share, config.partial_host_share,
                                  None)
    queries = list(batch["caption"]) + negative_texts + (partials.texts if partials else [])
    views: dict[str, torch.Tensor] = {}
    frames: dict[str, torch.Tensor] | None = {} if config.dense_weight > 0 else None
    if config.view_weight > 0 or frames is not None:
        views = model.encode_views(batch, camera_always=False, frames=frames, detach_camera=config.camera_apart)
        texts = model.encode_text(queries)
        video, scale = views["fused"], model.scale()
    else:
        video, texts, scale = model(batch, queries)
    split = [len(keys), len(negative_texts)]
    text, negatives, partial = texts.split([*split, len(texts) - sum(split)])
    video, text, negatives = dp.gather(video), dp.gather(text), dp.gather(negatives)
    positives = positives_matrix(all_keys, device)
    own_mask = torch.tensor(own, dtype=torch.bool, device=device).reshape(len(all_keys), len(negatives))
    loss = contrastive_loss(video, text, scale, positives, negatives, own_mask, rows=dp.rows(len(keys)))
    if partials is not None:
        partial_positives = torch.tensor(partials.positives, dtype=torch.bool)
        loss = loss + config.partial_weight * partial_query_loss(video, dp.gather(partial), scale, partial_positives)
    if config.order_weight > 0:
        loss = loss + config.order_weight * dp.processes * order_loss(video, text, negatives, reversed_of, scale,
                                                                      dp.rows(len(keys)))
    if frames:
        loss = loss + config.dense_weight * dp.processes * model.dense_loss(batch, frames, dp.total)
    if config.view_weight > 0:
        with_camera = dp.gather(torch.as_tensor(batch["has_camera"], dtype=torch.float32,
                                                device=device).reshape(-1)).gt(0.5)
        for name, keep in (("camera", with_camera), ("bev", torch.ones_like(with_camera))):
            loss = loss + config.view_weight * view_loss(
                dp.gather(views[name]), text, scale, positives, keep, dp.rows(len(keys)), dp.processes,
                negatives, own_mask, move_text=not (config.camera_apart and name == "camera"))
    if tag_objective is not None:
        loss = loss + tag_objective.weight * tag_objective.loss(model.bev_embedding)
    return loss


def _step(config: TrainConfig, new: bool, with_tagging: bool) -> tuple[torch.Tensor, dict[str, torch.Tensor],
                                                                        LossTerms | None]:
    torch.set_num_threads(1)
    batch = collate([Clips()[i] for i in range(8)])
    torch.manual_seed(0)
    model = DualEncoder(config.model).train()
    tagging = Tagging(batch) if with_tagging else None
    torch.manual_seed(1)  # the step's draws (modality dropout): the same for both
    terms = None
    if new:
        loss_fn = TrainingLoss(config, Distributed(), tagging)  # type: ignore[arg-type]
        terms = loss_fn(model, forward_step(model, batch, config, 3, None, 0.8))
        loss = terms.total
    else:
        loss = reference_loss(model, batch, config, 3, tagging)
    loss.backward()
    return loss.detach(), {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}, terms


@pytest.mark.parametrize(("config", "with_tagging"), [
    (every_term(), True),
    (dataclasses.replace(every_term(), camera_apart=False), False),
    (dataclasses.replace(preset("tiny").train, device="cpu", view_weight=0.0), False),  # one forward
])
def test_the_total_and_its_gradients_are_the_terms_summed_as_the_loop_did(config: TrainConfig,
                                                                          with_tagging: bool) -> None:
    old_loss, old_grads, _ = _step(config, new=False, with_tagging=with_tagging)
    new_loss, new_grads, terms = _step(config, new=True, with_tagging=with_tagging)
    assert torch.equal(new_loss, old_loss)
    assert new_grads.keys() == old_grads.keys() and all(torch.equal(new_grads[k], old_grads[k]) for k in old_grads)
    assert terms is not None
    values = terms.values()
    assert values[TOTAL] == float(old_loss) and sum(terms.terms.values()).item() == pytest.approx(values[TOTAL])
    every = config.partial_weight > 0
    expected = ["contrastive", *(["partial", "order", "dense", "view_camera", "view_bev"] if every else []),
                *(["tagging"] if with_tagging else [])]
    assert list(terms.terms) == expected and list(values) == [TOTAL, *expected]


def test_every_term_is_logged_per_epoch(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    config = dataclasses.replace(every_term(), batch_size=4, epochs=1)
    train("unused", tmp_path / "run", config, datasets={"train": Clips()}, progress=False, log=lambda _m: None)
    row = json.loads((tmp_path / "run" / "metrics.jsonl").read_text().splitlines()[0])
    assert set(row["train_terms"]) == {"contrastive", "partial", "order", "dense", "view_camera", "view_bev"}
    # Each is the epoch's mean of the step's weighted terms, which add up to the step's loss.
    assert sum(row["train_terms"].values()) == pytest.approx(row["train_loss"], rel=1e-5)
