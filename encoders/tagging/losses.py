"""Tagging losses and task-balanced sampling (Segal et al., Sec. 3.3).

- **Discrete** attributes: per-pixel binary cross entropy with *hard negative mining*: in each frame,
  every positive pixel and at most ``K`` (= 3) of the highest-scoring negative pixels per positive
  contribute; a frame without positives still contributes its ``min_negatives`` hardest negatives
  (otherwise nothing would ever push an empty scene down). The loss of a (frame, attribute) is the
  mean over its selected pixels; the loss is the mean over the (frame, attribute) pairs.
- **Densities learned as presence** (:data:`~encoders.tagging.attributes.FOOTPRINT_M2`): the same hard-negative
  BCE on "an object is in the cell" (target > 0), as a term of its own: averaged in with the discrete
  attributes, a presence row weighs 1/13 of the discrete term and does not learn (demo clips, tags alone:
  the row never reads p ≥ 0.5 in pedestrian cells; ``docs/research/tagging.md``).
- **Continuous** attributes: smooth L1 per pixel (mean over pixels) on V / s (the head's output
  scale); for densities also smooth L1 between the scene sums (sum over the pixels of a frame) of
  prediction and target, divided by ``scene_norm`` so that a frame's sum is near unit range.
- **Task balancing**: :class:`TaskBalancedSampler` draws an attribute uniformly, then a frame in which
  that attribute is positive somewhere.

Targets are at the grid resolution (H, W); :func:`downsample_targets` brings them to E's (H/r, W/r)
with area pooling for densities (the covered fraction stays a fraction) and max pooling for the rest
(a cell is positive when any sub-cell is).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from encoders.tagging.attributes import TagError
from scenesearch_base.config import check_at_least, check_positive


@dataclass(frozen=True)
class TagLossConfig:
    """Weights and options of the tagging loss.

    Attributes:
        hard_negatives: K, negatives kept per positive pixel in a frame.
        min_negatives: negatives kept in a frame without positives.
        smooth_l1_beta: β of the smooth L1 losses (in units of V / s).
        scene_weight: weight of the scene-sum term of continuous attributes.
        scene_norm: scene sums are divided by this before the smooth L1.
        discrete_weight: weight of the discrete term.
        continuous_weight: weight of the continuous terms.
        presence_weight: weight of the presence term (densities learned as presence); joint training
            uses ``TagTrainConfig.joint_presence_weight`` in its place.
    """

    hard_negatives: int = 3
    min_negatives: int = 16
    smooth_l1_beta: float = 0.1
    scene_weight: float = 0.1
    scene_norm: float = 100.0
    discrete_weight: float = 1.0
    continuous_weight: float = 1.0
    presence_weight: float = 1.0

    def __post_init__(self) -> None:
        check_at_least("TagLossConfig", 0, error=TagError, hard_negatives=self.hard_negatives,
                       min_negatives=self.min_negatives)
        check_positive("TagLossConfig", error=TagError, smooth_l1_beta=self.smooth_l1_beta, scene_norm=self.scene_norm)
        check_at_least("TagLossConfig", 0, error=TagError, scene_weight=self.scene_weight,
                       discrete_weight=self.discrete_weight, continuous_weight=self.continuous_weight,
                       presence_weight=self.presence_weight)


def downsample_targets(targets: torch.Tensor, factor: int, area: torch.Tensor) -> torch.Tensor:
    """targets: (N, A, H, W); area: (A,) bool (area pooling there, max pooling elsewhere) → (N, A, H/r, W/r)."""
    if factor == 1:
        return targets
    avg = F.avg_pool2d(targets, factor)  # (N, A, h, w)
    mx = F.max_pool2d(targets, factor)  # (N, A, h, w)
    return torch.where(area[None, :, None, None], avg, mx)


def hard_negative_bce(logits: torch.Tensor, targets: torch.Tensor, k: int = 3, min_negatives: int = 16) -> torch.Tensor:
    """Per-pixel BCE with hard negative mining.

    Args:
        logits: (N, P) one row per (frame, attribute), P pixels.
        targets: (N, P) 0/1.
        k: negatives kept per positive.
        min_negatives: negatives kept in a row without positives.

    Returns:
        () the mean over rows of the mean BCE over each row's selected pixels.
    """
    pos = targets >= 0.5  # (N, P)
    n_pos = pos.sum(dim=1)  # (N,)
    n_neg_avail = (~pos).sum(dim=1)
    keep = torch.where(n_pos > 0, k * n_pos, torch.full_like(n_pos, min_negatives))
    keep = torch.minimum(keep, n_neg_avail)  # (N,)
    neg_scores = logits.detach().masked_fill(pos, float("-inf"))  # (N, P)
    order = neg_scores.argsort(dim=1, descending=True)  # (N, P)
    rank = torch.empty_like(order)
    rank.scatter_(1, order, torch.arange(logits.shape[1], device=logits.device).expand_as(order))
    selected = pos | (rank < keep[:, None])  # (N, P)
    bce = F.binary_cross_entropy_with_logits(logits, pos.to(logits.dtype), reduction="none")  # (N, P)
    count = selected.sum(dim=1)  # (N,)
    rows = count > 0
    if not bool(rows.any()):
        return logits.sum() * 0.0
    per_row = (bce * selected).sum(dim=1)[rows] / count[rows]
    return per_row.mean()


def smooth_l1_pixels(pred: torch.Tensor, target: torch.Tensor, beta: float) -> torch.Tensor:
    """pred, target: (N, P) → () mean per-pixel smooth L1."""
    return F.smooth_l1_loss(pred, target, beta=beta)


def smooth_l1_scene(pred: torch.Tensor, target: torch.Tensor, beta: float, norm: float) -> torch.Tensor:
    """pred, target: (N, P) → () smooth L1 between the row sums divided by ``norm``."""
    return F.smooth_l1_loss(pred.sum(dim=1) / norm, target.sum(dim=1) / norm, beta=beta)


def tag_loss(
    v: torch.Tensor,
    targets: torch.Tensor,
    discrete: torch.Tensor,
    scale: torch.Tensor,
    config: TagLossConfig,
    valid: torch.Tensor | None = None,
    density: torch.Tensor | None = None,
    presence: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """The tagging loss of a batch.

    Args:
        v: (B, T, A, h, w) tag tensors (logits for discrete attributes, values for continuous ones).
        targets: (B, T, A, h, w) targets at E's resolution.
        discrete: (A,) bool.
        scale: (A,) the head's output scales.
        config: weights.
        valid: (A,) bool, attributes that have targets in this batch (default all).
        density: (A,) bool, the attributes whose scene sums are compared too (default: every continuous one).
        presence: (A,) bool, densities learned as presence (default none): their V is a logit trained
            like a discrete attribute's on "the target is above 0 in the cell", in a term of its own.

    Returns:
        The scalar loss and its parts as floats (``discrete``, ``presence``, ``pixel_l1``, ``scene_l1``).
    """
    a = v.shape[2]
    valid = torch.ones(a, dtype=torch.bool, device=v.device) if valid is None else valid
    vv = v.transpose(1, 2).reshape(v.shape[0], a, v.shape[1], -1)  # (B, A, T, h*w)
    tt = targets.transpose(1, 2).reshape_as(vv)
    vv = vv.transpose(0, 1).reshape(a, -1, vv.shape[-1])  # (A, B*T, P)
    tt = tt.transpose(0, 1).reshape_as(vv)
    total = v.sum() * 0.0
    parts = {"discrete": 0.0, "presence": 0.0, "pixel_l1": 0.0, "scene_l1": 0.0}
    pres = (torch.zeros_like(discrete) if presence is None else presence & ~discrete) & valid
    dis = discrete & valid
    if bool(dis.any()):
        d = hard_negative_bce(vv[dis].flatten(0, 1), tt[dis].flatten(0, 1), config.hard_negatives,
                              config.min_negatives)
        total = total + config.discrete_weight * d
        parts["discrete"] = float(d.detach())
    if bool(pres.any()):
        t_pres = (tt[pres] > 0).to(tt.dtype)  # any object in the cell
        pr = hard_negative_bce(vv[pres].flatten(0, 1), t_pres.flatten(0, 1), config.hard_negatives,
                               config.min_negatives)
        total = total + config.presence_weight * pr
        parts["presence"] = float(pr.detach())
    con = ~discrete & ~pres & valid
    if bool(con.any()):
        s = scale[con][:, None, None]
        pred, tgt = vv[con] / s, tt[con] / s  # (Ac, B*T, P)
        pix = smooth_l1_pixels(pred.flatten(0, 1), tgt.flatten(0, 1), config.smooth_l1_beta)
        total = total + config.continuous_weight * pix
        parts["pixel_l1"] = float(pix.detach())
        dens = con if density is None else con & density
        if bool(dens.any()):
            s_d = scale[dens][:, None, None]
            pd, td = (vv[dens] / s_d).flatten(0, 1), (tt[dens] / s_d).flatten(0, 1)
            scene = smooth_l1_scene(pd, td, config.smooth_l1_beta, config.scene_norm)
            total = total + config.continuous_weight * config.scene_weight * scene
            parts["scene_l1"] = float(scene.detach())
    return total, parts


class TaskBalancedSampler(torch.utils.data.Sampler[int]):
    """Draws an attribute uniformly, then an item (a (clip, frame) or (log, frame) index) where it is present.

    Attributes that are present nowhere are never drawn. Seeded and reproducible per epoch
    (:meth:`set_epoch`).
    """

    def __init__(self, present: NDArray[np.bool_], num_samples: int, seed: int = 0) -> None:
        """present: (N, A) bool, attribute a non-zero somewhere in item n."""
        p = np.asarray(present, dtype=bool)
        if p.ndim != 2:
            raise TagError(f"present must be (N, A), got shape {p.shape}")
        self.items = [np.flatnonzero(p[:, a]) for a in range(p.shape[1])]
        self.attributes = np.array([a for a, it in enumerate(self.items) if it.size > 0], dtype=np.int64)
        if self.attributes.size == 0:
            raise TagError("no attribute is present in any item: nothing to sample")
        self.num_samples = int(num_samples)
        self.seed = int(seed)
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.num_samples

    def draw(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(num_samples,) attributes drawn and (num_samples,) items drawn."""
        rng = np.random.default_rng([self.seed, self.epoch])
        attrs = self.attributes[rng.integers(0, self.attributes.size, self.num_samples)]
        u = rng.random(self.num_samples)
        sizes = np.array([self.items[a].size for a in attrs])
        pick = np.minimum((u * sizes).astype(np.int64), sizes - 1)
        items = np.array([self.items[a][i] for a, i in zip(attrs, pick)], dtype=np.int64)
        return attrs, items

    def __iter__(self) -> Iterator[int]:
        return iter(self.draw()[1].tolist())
