"""The training step's loss as one object: named terms, each weighted, and their sum.

:class:`TrainingLoss` is built once per run from the :class:`~encoders.train_config.TrainConfig` (with the
run's processes and its tagging objective, if any). Called on a step's outputs (:func:`forward_step`,
:class:`StepOutputs`), it returns :class:`LossTerms`: every term already weighted, in the order they
add up, and their total, which the step minimises. Training logs each term (``train_terms`` of
``metrics.jsonl``), as open_clip's losses return named terms with ``output_dict``:

    contrastive   the fused view against the captions, hard negatives on the clip → text side
                  (:func:`encoders.loss.contrastive_loss`)
    partial       partial_weight × the clips against their captions' halves (:func:`~encoders.loss.partial_query_loss`)
    order         order_weight × each clip against its caption's steps reversed (:func:`~encoders.loss.order_loss`)
    dense         dense_weight × each frame's rule tags from the streams' frame tokens (:mod:`encoders.dense`)
    view_camera   view_weight × the camera view alone, over the clips with a camera (:func:`~encoders.loss.view_loss`)
    view_bev      view_weight × the BEV view alone, over every clip
    tagging       the tagging head's weight × its loss (:mod:`encoders.tagging.training`)

A term whose weight is 0, or whose part the run lacks (no tag targets), is left out.

With several processes (:mod:`encoders.distributed`) each computes its share of the whole batch's
loss: its rows of the contrastive and view terms, its pairs of the order term, its frames of the dense
term, the whole batch's partial term; gradients are averaged over processes, hence the order and dense
terms' factor ``processes``. The mean of a term over processes is the term of the whole batch.

The terms are computed, and their graph built, in the order of the table, so that the gradient sums
in one fixed order whatever the logging.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import torch

from encoders.distributed import Distributed
from encoders.loss import contrastive_loss, order_loss, partial_query_loss, positives_matrix, view_loss
from encoders.negatives import batch_negatives
from encoders.partial_queries import batch_partials
from encoders.train_config import TrainConfig

if TYPE_CHECKING:
    from encoders.model import DualEncoder
    from encoders.tagging.training import TaggingObjective

#: The name of the total among :meth:`LossTerms.values`.
TOTAL = "loss"


@dataclass(frozen=True)
class StepOutputs:
    """What a training step's forward pass gives its loss: this process's clips and texts embedded,
    and the whole batch's captions.

    Attributes:
        batch: this process's collated clips (the dense targets, ``has_camera``).
        video: (b, D) the fused vectors of this process's clips.
        text: (b, D) their captions' vectors.
        negatives: (m, D) this process's hard negatives' vectors.
        partial: (h, D) this process's caption halves' vectors.
        scale: () the logit scale.
        views: each view's (b, D) vectors (``fused``, ``camera``, ``bev``) where the view losses or the
            dense heads run; else empty.
        frames: each stream's frame tokens (b, T, W) where the dense heads run; else None.
        keys: (N,) the whole batch's canonical captions (equal ones are positives).
        clip_ids: (N,) the whole batch's clip ids.
        own: (N, M) the whole batch's clips against every process's negatives: negative j is clip i's positive.
        reversed_of: (M,) the clip whose steps negative j reverses, −1 for none.
        partial_positives: (N, H) clip i answers half h; None without partial queries.
    """

    batch: dict[str, Any]
    video: torch.Tensor
    text: torch.Tensor
    negatives: torch.Tensor
    partial: torch.Tensor
    scale: torch.Tensor
    views: dict[str, torch.Tensor]
    frames: dict[str, torch.Tensor] | None
    keys: Sequence[str]
    clip_ids: Sequence[str]
    own: list[list[bool]]
    reversed_of: list[int]
    partial_positives: list[list[bool]] | None


def forward_step(model: DualEncoder, batch: dict[str, Any], config: TrainConfig, step: int,
                 distributed: Distributed | None = None, negative_paraphrases: float = 0.0) -> StepOutputs:
    """Embed a training batch's clips, its captions and the texts its loss adds (hard negatives with
    ``negative_paraphrases`` of them paraphrased, caption halves), as ``config`` asks.

    Each tower runs once: with the view losses or the dense heads, the fused view reuses the views'
    vectors (a clip without a camera does not run the camera tower).
    """
    dp = distributed or Distributed()
    keys = batch["canonical_caption"]
    whole, all_keys = dp.whole_batch(batch, keys)  # the text fields of every process's clips
    negative_texts: list[str] = []
    own: list[list[bool]] = []
    reversed_of: list[int] = []
    if config.hard_negatives:
        negative_texts, own, reversed_of = batch_negatives(
            batch, config.hard_negatives, keys, config.seed, step, negative_paraphrases)
        if dp.active:  # the whole batch's clips against every process's negatives, in the same order
            _, own, reversed_of = batch_negatives(whole, config.hard_negatives, all_keys, config.seed, step,
                                                  negative_paraphrases)
    partials = None
    if config.partial_weight > 0:  # halves of the captions as queries of their own
        partials = batch_partials(batch, config.seed, step, config.partial_object_share,
                                  config.partial_host_share, whole if dp.active else None)
    queries = list(batch["caption"]) + negative_texts + (partials.texts if partials else [])
    views: dict[str, torch.Tensor] = {}
    frames: dict[str, torch.Tensor] | None = {} if config.dense_weight > 0 else None
    if config.view_weight > 0 or frames is not None:  # each tower once; the fused view reuses them
        views = model.encode_views(batch, camera_always=False, frames=frames,  # no camera: not run
                                   detach_camera=config.camera_apart)
        texts = model.encode_text(queries)
        video, scale = views["fused"], model.scale()
    else:
        video, texts, scale = model(batch, queries)
    split = [len(keys), len(negative_texts)]
    text, negatives, partial = texts.split([*split, len(texts) - sum(split)])  # (b, D), (m, D), (h, D)
    return StepOutputs(batch, video, text, negatives, partial, scale, views, frames, all_keys, whole["clip_id"],
                       own, reversed_of, partials.positives if partials is not None else None)


@dataclass(frozen=True)
class LossTerms:
    """A step's loss.

    Attributes:
        terms: name → () weighted term, in the order they add up (see the module's table).
        total: () their sum: what the step minimises.
    """

    terms: dict[str, torch.Tensor]
    total: torch.Tensor

    def values(self) -> dict[str, float]:
        """The total (as :data:`TOTAL`) and each term, as numbers."""
        return {TOTAL: float(self.total.detach()), **{k: float(v.detach()) for k, v in self.terms.items()}}


class TrainingLoss:
    """The loss of a training step, built from the run's config (see the module's table).

    >>> loss_fn = TrainingLoss(config, distributed, tagging)
    >>> out = loss_fn(model, forward_step(model, batch, config, step, distributed))
    >>> out.total.backward(); out.values()  # {"loss": …, "contrastive": …, "order": …, …}
    """

    def __init__(self, config: TrainConfig, distributed: Distributed | None = None,
                 tagging: TaggingObjective | None = None) -> None:
        self.config = config
        self.distributed = distributed or Distributed()
        self.tagging = tagging

    def __call__(self, model: DualEncoder, out: StepOutputs) -> LossTerms:
        """The weighted terms of the step whose forward pass gave ``out``, and their sum."""
        config, dp = self.config, self.distributed
        device, scale = out.video.device, out.scale
        rows = dp.rows(len(out.text))  # this process's rows of the whole batch
        video, text, negatives = dp.gather(out.video), dp.gather(out.text), dp.gather(out.negatives)  # whole batch
        positives = positives_matrix(out.keys, device)
        own = torch.tensor(out.own, dtype=torch.bool, device=device).reshape(len(out.keys), len(negatives))
        terms = {"contrastive": contrastive_loss(video, text, scale, positives, negatives, own, rows=rows)}
        if out.partial_positives is not None:  # the whole batch's loss on every process (see partial_query_loss)
            answers = torch.tensor(out.partial_positives, dtype=torch.bool)  # (N, H)
            terms["partial"] = config.partial_weight * partial_query_loss(video, dp.gather(out.partial), scale,
                                                                          answers)
        if config.order_weight > 0:  # each clip against its steps reversed
            terms["order"] = config.order_weight * dp.processes * order_loss(video, text, negatives, out.reversed_of,
                                                                             scale, rows)
        if out.frames:  # over the whole batch's tagged frames
            terms["dense"] = config.dense_weight * dp.processes * model.dense_loss(out.batch, out.frames, dp.total)
        if config.view_weight > 0:
            with_camera = dp.gather(torch.as_tensor(out.batch["has_camera"], dtype=torch.float32,
                                                    device=device).reshape(-1)).gt(0.5)  # (N,) whole batch
            for name, keep in (("camera", with_camera), ("bev", torch.ones_like(with_camera))):
                terms[f"view_{name}"] = config.view_weight * view_loss(
                    dp.gather(out.views[name]), text, scale, positives, keep, rows, dp.processes, negatives, own,
                    move_text=not (config.camera_apart and name == "camera"))  # apart: as the others put them
        if self.tagging is not None:
            terms["tagging"] = self.tagging.weight * self.tagging.loss(model.bev_embedding)
        parts = iter(terms.values())
        total = next(parts)
        for term in parts:
            total = total + term
        return LossTerms(terms, total)
