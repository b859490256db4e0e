"""The camera view's weight in the fusion, chosen on the validation split after training.

The camera tower learns the look of the training logs far better than it generalises (camera-only
R@5 on held-out logs is a third of the BEV tower's), so an equal mean of the two views lets the
camera's errors into every fused ranking. How much weight the camera deserves depends on the data
(real cameras with more variety, or more camera clips, may earn more), so it is measured rather than
fixed: every clip of the validation split is embedded once per view, the fusion is replayed for each
weight of a small grid, and the weight with the best text → clip mAP is kept in the model.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from encoders.inference import batches, clip_autocast, embed_texts
from encoders.metrics import caption_queries, text_to_clip_metrics
from encoders.model import DualEncoder
from encoders.sentence import evaluating

#: Weights tried, camera against BEV's 1; 1 is what training used (an equal mean).
CAMERA_WEIGHTS: tuple[float, ...] = (0.0, 0.125, 0.25, 0.375, 0.5, 0.75, 1.0)


@dataclass(frozen=True)
class CameraWeightChoice:
    """The outcome of :func:`calibrate_camera_weight`.

    Attributes:
        weight: the weight kept in the model.
        map_by_weight: validation mAP of each weight tried (empty when nothing was measured).
        reason: why the weight was not calibrated ("" when it was).
    """

    weight: float
    map_by_weight: dict[float, float]
    reason: str = ""

    def describe(self) -> str:
        """One line for the training log and the model card."""
        if self.reason:
            return f"camera weight {self.weight:g} in the fusion (not calibrated: {self.reason})"
        tried = ", ".join(f"{w:g}: {m:.3f}" for w, m in self.map_by_weight.items())
        return f"camera weight {self.weight:g} in the fusion, chosen by validation mAP ({tried})"


@torch.no_grad()
def calibrate_camera_weight(model: DualEncoder, val_set: Dataset[dict[str, Any]] | None, batch_size: int = 32,
                            weights: Sequence[float] = CAMERA_WEIGHTS) -> CameraWeightChoice:
    """Set ``model.fusion``'s camera weight to the one of ``weights`` with the best validation mAP.

    Ties go to the larger weight (the one closer to what training used). Without a validation set,
    or without a camera clip in it, the weight is left as it is.
    """
    current = float(model.fusion.camera_weight)
    if val_set is None or len(val_set) == 0:  # type: ignore[arg-type]
        return CameraWeightChoice(current, {}, "no validation split")
    with evaluating(model):
        camera, bev, has_camera, category, captions = _views(model, val_set, batch_size)
        if not bool(has_camera.any()):
            return CameraWeightChoice(current, {}, "no camera clip in the validation split")
        queries, relevant = caption_queries(captions)
        text = embed_texts(model, queries)  # (Q, D)
        map_by_weight: dict[float, float] = {}
        for weight in sorted(weights):
            model.fusion.set_camera_weight(weight)
            with clip_autocast(model.device):  # the precision embedding the clips runs in: the same figures
                fused_raw = model.fusion(camera, bev, has_camera, category)
            fused = F.normalize(fused_raw.float(), dim=-1).cpu().numpy()  # (N, D)
            map_by_weight[weight] = float(text_to_clip_metrics(text @ fused.T, relevant)["mAP"])
        best = max(map_by_weight, key=lambda w: (round(map_by_weight[w], 6), w))
        model.fusion.set_camera_weight(best)
        return CameraWeightChoice(best, map_by_weight)


def _views(model: DualEncoder, dataset: Dataset[dict[str, Any]],
           batch_size: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None, list[str]]:
    """What the fusion reads, once for the whole split: camera (N, D), BEV (N, D), ``has_camera`` (N,),
    the object categories (N,) (None for a fusion without them, or clips without any), and the clips'
    canonical captions."""
    cameras, bevs, flags, captions = [], [], [], []
    categories: list[torch.Tensor] = []
    for batch in batches(dataset, batch_size):
        # A batch without camera clips skips the camera tower: the fusion reads BEV alone for them.
        with clip_autocast(model.device):
            views = model.encode_views(batch, normalize=False, camera_always=False)
        cameras.append(views["camera"])  # (B, D)
        bevs.append(views["bev"])  # (B, D)
        flags.append(torch.as_tensor(batch["has_camera"], dtype=torch.bool, device=model.device).reshape(-1))
        captions += list(batch["canonical_caption"])
        category = model.category(batch)
        if category is not None:
            categories.append(category)
    category_rows = torch.cat(categories) if categories else None
    return torch.cat(cameras), torch.cat(bevs), torch.cat(flags), category_rows, captions

