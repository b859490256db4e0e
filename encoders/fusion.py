"""Fusion over time (per-frame vectors → one clip vector) and over views (camera + BEV → one embedding).

:class:`TemporalEncoder` is shared by the camera and BEV towers: a temporal convolution, learned time
positions and a small transformer read out by a learned query token, so its output depends on frame
order (a mean over frames would not). :class:`ViewFusion` merges the two views' normalised embeddings and drops one view
at random in training, so that camera-only and BEV-only inputs embed well too; with
``FusionConfig.object_category`` it also reads the clip's object category (:func:`category_indices`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch
import torch.nn.functional as F
from torch import nn

from encoders.config import FusionConfig, TemporalConfig
from scenes.categories import CATEGORY_NAMES

#: The fusion's category table has a row per :data:`scenes.categories.CATEGORY_NAMES`, in order, and one
#: more, this one, for "not told" (withheld in training, or absent from a batch).
UNKNOWN_CATEGORY = len(CATEGORY_NAMES)


def category_indices(categories: Iterable[str], batch_size: int, device: torch.device) -> torch.Tensor:
    """Object categories (the clip table's ``category`` strings) → (B,) rows of the fusion's category table.

    Raises:
        ValueError: a category outside :data:`scenes.categories.CATEGORY_NAMES`, or not one per clip.
    """
    names = [str(c) for c in categories]
    unknown = sorted({c for c in names if c not in CATEGORY_NAMES})
    if unknown:
        raise ValueError(f"batch 'category': {unknown} not among the object categories {list(CATEGORY_NAMES)}")
    if len(names) != batch_size:
        raise ValueError(f"batch 'category': {len(names)} categories for {batch_size} clips")
    return torch.tensor([CATEGORY_NAMES.index(c) for c in names], dtype=torch.long, device=device)


def sinusoids(length: int, width: int) -> torch.Tensor:
    """(length, width) sinusoidal position codes (sin on even, cos on odd channels)."""
    pos = torch.arange(length, dtype=torch.float32)[:, None]  # (L, 1)
    freq = torch.exp(-math.log(1000.0) * torch.arange(0, width, 2, dtype=torch.float32) / width)  # (W/2,)
    out = torch.zeros(length, width)
    out[:, 0::2] = torch.sin(pos * freq)
    out[:, 1::2] = torch.cos(pos * freq)[:, : width // 2]
    return out


class TemporalEncoder(nn.Module):
    """(B, T, C_in) per-frame vectors → (B, width) clip vector; order-aware, any T ≤ max_frames."""

    def __init__(self, config: TemporalConfig, in_features: int) -> None:
        super().__init__()
        self.config = config
        self.proj = nn.Linear(in_features, config.width)
        # A temporal convolution gives each frame its neighbours (local motion: how the object moved
        # since the last frame); learned time positions, initialised sinusoidal, give the transformer
        # where each frame sits in the clip.
        self.motion = nn.Conv1d(config.width, config.width, kernel_size=3, padding=1)
        self.time = nn.Parameter(sinusoids(config.max_frames, config.width))
        self.query = nn.Parameter(torch.randn(1, 1, config.width) * 0.02)
        layer = nn.TransformerEncoderLayer(
            d_model=config.width,
            nhead=config.heads,
            dim_feedforward=2 * config.width,
            dropout=config.dropout,
            batch_first=True,
            norm_first=True,
        )
        self.transformer = nn.TransformerEncoder(layer, config.layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(config.width)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """frames: (B, T, C_in) → (B, width)."""
        return self.encode(frames)[0]

    def encode(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """frames: (B, T, C_in) → the clip vector (B, width) and the frame tokens (B, T, width)."""
        b, t, _ = frames.shape
        if t > self.config.max_frames:
            raise ValueError(f"clip has {t} frames, the temporal model takes at most {self.config.max_frames}")
        x = self.proj(frames)  # (B, T, W)
        x = x + self.motion(x.transpose(1, 2)).transpose(1, 2) + self.time[:t]  # (B, T, W)
        x = torch.cat([self.query.expand(b, 1, -1), x], dim=1)  # (B, 1 + T, W)
        x = self.norm(self.transformer(x))  # (B, 1 + T, W)
        return x[:, 0], x[:, 1:]  # (B, W), (B, T, W)


class ViewFusion(nn.Module):
    """Camera and BEV clip embeddings (B, D) each → fused (B, D), with modality dropout in training."""

    camera_weight: torch.Tensor  # () buffer

    def __init__(self, config: FusionConfig, dim: int, slot_dims: int = 0) -> None:
        super().__init__()
        self.config = config
        # With time slots (encoders.timeline) the MLP writes the global part only: mixing the slots'
        # dimensions with each other would undo what each slot stands for.
        self.slot_dims = slot_dims
        self.mlp = nn.Sequential(nn.Linear(dim, config.hidden), nn.GELU(), nn.Linear(config.hidden, dim - slot_dims))
        # The category joins the MLP's input as a learned vector, zero at first so that training starts
        # from the fusion without it; the last row ("not told") is never trained away from zero unless
        # training withholds categories (category_drop_p).
        self.category = nn.Embedding(len(CATEGORY_NAMES) + 1, dim) if config.object_category else None
        if self.category is not None:
            nn.init.zeros_(self.category.weight)
        # The camera view's weight against BEV's 1 in the mean: 1 in training, then set from the
        # validation split (encoders.calibration). A buffer, so it travels with the weights.
        self.register_buffer("camera_weight", torch.ones(()))

    def set_camera_weight(self, weight: float) -> None:
        """Weigh the camera view by ``weight`` (≥ 0) against the BEV view's 1; 0 fuses BEV alone."""
        if not weight >= 0.0:
            raise ValueError(f"the camera weight must be >= 0, got {weight}")
        self.camera_weight.fill_(float(weight))

    def forward(self, camera: torch.Tensor, bev: torch.Tensor, has_camera: torch.Tensor,
                category: torch.Tensor | None = None) -> torch.Tensor:
        """camera: (B, D); bev: (B, D); has_camera: (B,) bool; category: (B,) rows of the category table
        (:func:`category_indices`; read with ``object_category``; None: not told) → (B, D).

        Clips without camera use BEV only; with camera, the mean weighs the camera view by
        ``camera_weight`` (see :meth:`set_camera_weight`). In training, when both views are present,
        the camera view is dropped with ``drop_camera_p`` and otherwise the BEV view with ``drop_bev_p``;
        a category is withheld with ``category_drop_p``.
        """
        cam_w = has_camera.to(camera.dtype) * self.camera_weight.to(camera.dtype)  # (B,)
        bev_w = torch.ones_like(cam_w)
        if self.training:
            u = torch.rand(cam_w.shape, device=cam_w.device)  # (B,)
            drop_cam = (u < self.config.drop_camera_p) & has_camera
            drop_bev = (u >= 1.0 - self.config.drop_bev_p) & has_camera & (cam_w > 0)  # one view is always kept
            cam_w = cam_w * (~drop_cam).to(cam_w.dtype)
            bev_w = bev_w * (~drop_bev).to(bev_w.dtype)
        mixed = (cam_w[:, None] * F.normalize(camera, dim=-1) + bev_w[:, None] * F.normalize(bev, dim=-1)) / (
            cam_w + bev_w
        )[:, None]  # (B, D)
        told = mixed
        if self.category is not None:
            if category is None:
                category = torch.full(cam_w.shape, UNKNOWN_CATEGORY, dtype=torch.long, device=mixed.device)
            if self.training and self.config.category_drop_p > 0:
                withheld = torch.rand(category.shape, device=category.device) < self.config.category_drop_p
                category = torch.where(withheld, torch.full_like(category, UNKNOWN_CATEGORY), category)
            told = mixed + self.category(category).to(mixed.dtype)  # (B, D)
        return mixed + F.pad(self.mlp(told), (0, self.slot_dims))  # the slots' dimensions pass as they are
