"""DualEncoder: captions and clips in one embedding space.

    texts ─────────────── TextTower ─────────────── (B, D)  encode_text
    camera (B,T,4,Hc,Wc) ─ CameraTower ─┐
                                        ├ ViewFusion ─ (B, D)  encode_video(view="fused")
    bev_* (B,T,C,Hb,Wb) ── BevTower ────┘          camera / bev alone: view="camera" / "bev"
    category (B,) ────────────────────── into ViewFusion (the fused view only; ``fusion.object_category``)

A learnable ``logit_scale`` (log of the inverse temperature, initialised to log(1/0.07), clamped to
ln 100) scales the cosine similarities in the contrastive loss. ``bev_embedding`` exposes the BEV
tower's universal embedding E. With ``time_slots`` K > 0 the last K · ``slot_dim`` dimensions of
every embedding, text and video alike, are K stretches of the clip in order (:mod:`encoders.timeline`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from encoders.bev import BevTower
from encoders.camera import CameraTower, unit_pixels
from encoders.config import DualEncoderConfig
from encoders.dense import DenseHeads, stream_dense_loss
from encoders.fusion import ViewFusion, category_indices
from encoders.text import TextTower, UnloadedText

VIEWS = ("fused", "camera", "bev")


class DualEncoder(nn.Module):
    """Text tower + camera and BEV towers fused into one clip embedding."""

    def __init__(self, config: DualEncoderConfig, text: bool = True) -> None:
        """``text=False``: the text tower is not built (:class:`encoders.text.UnloadedText`); the model
        embeds clips only, as a process that never encodes text needs it."""
        super().__init__()
        self.config = config
        d = config.embed_dim
        slots = (config.time_slots, config.slot_dim)
        self.text = TextTower(config.text, d, *slots) if text else UnloadedText(config.text)
        self.camera = CameraTower(config.camera, d, *slots)
        self.bev = BevTower(config.bev, d, *slots)
        self.fusion = ViewFusion(config.fusion, d, config.time_slots * config.slot_dim)
        widths = {"camera": config.camera.temporal.width, "bev": config.bev.temporal.width,
                  "track": config.bev.track.width}
        self.dense = nn.ModuleDict({s: DenseHeads(widths[s], config.dense_tasks) for s in config.dense_streams})
        self.logit_scale = nn.Parameter(torch.tensor(config.logit_scale_init))

    @property
    def device(self) -> torch.device:
        return self.logit_scale.device

    def scale(self) -> torch.Tensor:
        """exp(logit_scale) with the log clamped to ``logit_scale_max``."""
        return self.logit_scale.clamp(max=self.config.logit_scale_max).exp()

    def encode_text(self, texts: list[str], normalize: bool = True) -> torch.Tensor:
        """texts: B strings → (B, D)."""
        x = self.text(list(texts), self.device)
        return F.normalize(x, dim=-1) if normalize else x

    def encode_video(self, batch: dict[str, Any], view: str = "fused", normalize: bool = True) -> torch.Tensor:
        """batch: collated clips (tensors (B, T, C, H, W), ``has_camera`` (B,)) → (B, D).

        ``view``: ``camera`` (camera tower only), ``bev`` (BEV tower only) or ``fused`` (both; clips
        without camera use BEV only).
        """
        if view not in VIEWS:
            raise ValueError(f"view must be one of {VIEWS}, got {view!r}")
        if view == "camera":
            x = self.camera(self._get(batch, "camera", as_bytes=True), ego_motion=self._camera_ego(batch),
                            **self._camera_crop(batch))
        elif view == "bev":
            x = self._bev(batch)
        else:
            x = self.fusion(*self._towers(batch, camera_always=False), self.category(batch))
        return F.normalize(x, dim=-1) if normalize else x

    def encode_views(self, batch: dict[str, Any], normalize: bool = True, camera_always: bool = True,
                     frames: dict[str, torch.Tensor] | None = None,
                     detach_camera: bool = False) -> dict[str, torch.Tensor]:
        """All three views of a batch at the cost of one: each tower runs once, fusion reuses them.

        Returns ``{"camera": (B, D), "bev": (B, D), "fused": (B, D)}``, equal to
        :meth:`encode_video` with each view. ``camera_always=False`` skips the camera tower when no
        clip of the batch has camera (training: the camera view then has nothing to learn from);
        the camera vectors are then zero and the fused ones are still :meth:`encode_video`'s.
        With a ``frames`` dict, each temporal stream that ran leaves its frame tokens there (see
        :meth:`dense_logits`). ``detach_camera``: the fused view reads the camera vectors without their
        gradient (training with ``TrainConfig.camera_apart``); the camera view keeps it.
        """
        camera, bev, has_camera = self._towers(batch, camera_always, frames)
        fused = self.fusion(camera.detach() if detach_camera else camera, bev, has_camera, self.category(batch))
        out = {"camera": camera, "bev": bev, "fused": fused}
        return {k: F.normalize(v, dim=-1) for k, v in out.items()} if normalize else out

    def _towers(self, batch: dict[str, Any], camera_always: bool,
                frames: dict[str, torch.Tensor] | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """→ camera (B, D), BEV (B, D) and ``has_camera`` (B,) bool, what the fusion reads.

        The camera tower runs when ``camera_always``, or when some clip has camera, or when the batch
        says ``run_camera``: in data-parallel training another process's clips may have camera; every
        process then runs the tower, whose batch norms share the whole batch's statistics
        (encoders.distributed). Otherwise the camera vectors are zero (the fusion uses BEV alone).
        """
        has_camera = torch.as_tensor(batch["has_camera"], dtype=torch.bool, device=self.device).reshape(-1)
        bev = self._bev(batch, frames)  # (B, D)
        camera = torch.zeros_like(bev)
        if camera_always or bool(has_camera.any()) or bool(batch.get("run_camera", False)):
            camera = self.camera(self._get(batch, "camera", as_bytes=True), frames, self._camera_ego(batch),
                                 **self._camera_crop(batch))  # (B, D)
        return camera, bev, has_camera

    def dense_logits(self, frames: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Frame tokens that :meth:`encode_views` left → stream → per-frame tag logits (B, T, ΣC) of
        each stream with dense heads (``config.dense_streams``) that ran."""
        return {name: head(frames[name]) for name, head in self.dense.items() if name in frames}

    def dense_loss(self, batch: dict[str, Any], frames: dict[str, torch.Tensor],
                   whole: Callable[[torch.Tensor], torch.Tensor] | None = None) -> torch.Tensor:
        """The dense loss of ``batch``'s frame tags (``frame_targets`` (B, T, K)) over the frame tokens
        that :meth:`encode_views` left in ``frames`` (:func:`encoders.dense.stream_dense_loss`; ``whole``
        sums frame counts over data-parallel processes)."""
        has_camera = self._get(batch, "has_camera").reshape(-1).bool()
        return stream_dense_loss(self.dense_logits(frames), self._get(batch, "frame_targets"), has_camera, whole,
                                 self.config.dense_tasks)

    def bev_embedding(self, batch: dict[str, Any]) -> torch.Tensor:
        """batch: collated clips → E (B, T, D_e, Hb/r, Wb/r), the universal BEV embedding."""
        return self.bev.embed_map(self._get(batch, "bev_lidar"), self._get(batch, "bev_map"))

    def forward(self, batch: dict[str, Any], texts: list[str]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """→ normalised video (B, D), normalised text (B, D) and the clamped scale exp(logit_scale)."""
        return self.encode_video(batch), self.encode_text(texts), self.scale()

    def _bev(self, batch: dict[str, Any], frames: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        # The rasters stay bytes: in eval mode the tower finds the frames that clips share on them and
        # converts only those (encoders.bev.BevTower.embed_distinct).
        return self.bev(
            self._get(batch, "bev_lidar", as_bytes=True),
            self._get(batch, "bev_map", as_bytes=True),
            self._get(batch, "bev_object"),
            self._get(batch, "ego_motion"),
            self._get(batch, "object_track") if self.config.bev.track_features else None,
            frames,
            self._get(batch, "object_velocity") if self.config.bev.track_velocity else None,
            self._get(batch, "object_rates") if self.config.bev.track_features and self.config.bev.track_rates
            else None,
        )

    def category(self, batch: dict[str, Any]) -> torch.Tensor | None:
        """(B,) the batch's object categories as the fusion reads them; None for a model without
        ``fusion.object_category``, or a batch without ``category`` (the fusion then is "not told")."""
        if self.fusion.category is None or "category" not in batch:
            return None
        size = int(torch.as_tensor(batch["has_camera"]).reshape(-1).shape[0])
        return category_indices(batch["category"], size, self.device)

    def _camera_crop(self, batch: dict[str, Any]) -> dict[str, torch.Tensor]:
        """The object crops the camera tower reads with ``camera.object_crop`` (none without)."""
        if not self.config.camera.object_crop:
            return {}
        if "camera_crop" not in batch or "camera_box" not in batch:
            raise ValueError("this model reads object crops (model.camera.object_crop) and the clips have none: "
                             "render them again with `scenesearch clips` (clips folders from before crops lack "
                             "camera_crops.npy)")
        return {"crop": self._get(batch, "camera_crop", as_bytes=True), "box": self._get(batch, "camera_box")}

    def _camera_ego(self, batch: dict[str, Any]) -> torch.Tensor | None:
        return self._get(batch, "ego_motion") if self.config.camera.ego_features else None

    def _get(self, batch: dict[str, Any], key: str, as_bytes: bool = False) -> torch.Tensor:
        """The batch's ``key`` on the model's device; a uint8 view (a batch loaded with ``as_uint8``,
        moved as bytes) converted to float unless ``as_bytes`` (the tower converts what it reads)."""
        if key not in batch:
            raise KeyError(f"batch has no {key!r} (keys: {sorted(batch)})")
        x = torch.as_tensor(batch[key]).to(self.device, non_blocking=True)
        return x if as_bytes else unit_pixels(x)

    def saved_state_dict(self) -> dict[str, torch.Tensor]:
        """state_dict without frozen pretrained text weights (they are loaded from ``text.model``)."""
        skip = [f"text.{p}" for p in self.text.frozen_prefixes()]
        return {k: v for k, v in self.state_dict().items() if not any(k.startswith(s) for s in skip)}

    def load_saved_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Load what :meth:`saved_state_dict` wrote; any other missing or extra key is an error."""
        if isinstance(self.text, UnloadedText):  # built without its text tower: the text weights stay unread
            state = {k: v for k, v in state.items() if not k.startswith("text.")}
        result = self.load_state_dict(state, strict=False)
        skip = [f"text.{p}" for p in self.text.frozen_prefixes()]
        missing = [k for k in result.missing_keys if not any(k.startswith(s) for s in skip)]
        if missing or result.unexpected_keys:
            raise ValueError(f"weights do not match the model: missing {missing}, unexpected {result.unexpected_keys}")
