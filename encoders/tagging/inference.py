"""Query-time use of a trained tagging model: load a run folder's :class:`Tagger` and tag whole logs.

A run folder that answers tag queries holds ``tagging.json`` (the :class:`TagTrainConfig`, the head's
attribute names, the clips grid and rendering config) and ``tag_head.safetensors``; a run trained
``alone`` also holds ``tag_backbone.safetensors`` (the BEV tower), a joint run takes the tower from
the dual encoder's ``model.safetensors``. :mod:`encoders.tagging.training` writes these files.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from safetensors.torch import load_file

from encoders.bev import BevTower
from encoders.clips.blocks import FrameArray
from encoders.clips.layout import grid_from_manifest
from encoders.config import BevConfig
from encoders.inference import load_model, resolve_device
from encoders.tagging.ablation import Inputs, mask_inputs, parse_inputs
from encoders.tagging.config import TagTrainConfig
from encoders.tagging.head import TagHead, TagHeadConfig
from scenes.bev import BevGrid

TAGGING_FILE = "tagging.json"
HEAD_FILE = "tag_head.safetensors"
BACKBONE_FILE = "tag_backbone.safetensors"
#: Parameters of the BEV tower that compute E (what tagging needs); the rest pools E into clip embeddings.
EMBEDDING_PREFIXES = BevTower.EMBEDDING_PREFIXES


class Tagger:
    """A trained tagging model: BEV tower + attribute head, and the grid and inputs it was trained on."""

    def __init__(self, bev: BevTower, head: TagHead, config: TagTrainConfig, meta: dict[str, Any],
                 device: torch.device) -> None:
        self.bev = bev.eval().to(device)
        self.head = head.eval().to(device)
        self.config = config
        self.meta = meta
        self.device = device
        self.grid: BevGrid = grid_from_manifest({"bev": meta["grid"]})
        self.map_channels: list[str] = list(meta["grid"].get("map_channels", []))
        self.downsample = int(self.bev.config.downsample)

    @property
    def bev_config(self) -> BevConfig:
        return self.bev.config

    @property
    def names(self) -> tuple[str, ...]:
        return self.head.names

    @property
    def inputs(self) -> Inputs:
        return parse_inputs(self.config.inputs)

    @torch.no_grad()
    def tag_frames(self, bev_lidar: FrameArray, bev_map: FrameArray, chunk: int = 32,
                   attributes: list[int] | None = None) -> NDArray[np.float32]:
        """Tag tensors of consecutive frames of one log.

        E is computed over the frames at the training spacing (``frame_stride``: one pass per phase,
        in chunks with temporal context), so each frame sees neighbours as in training.

        Args:
            bev_lidar: (F, Cl, H, W) uint8 (the clip stage's ``bev_lidar.npy``).
            bev_map: (F, Cm, H, W) uint8.
            chunk: frames per forward pass.
            attributes: rows of A to return (default all).

        Returns:
            (F, A', H/r, W/r) float32 V (logits for discrete attributes).
        """
        f = int(bev_lidar.shape[0])
        sel = list(range(len(self.names))) if attributes is None else list(attributes)
        h, w = self.grid.height // self.downsample, self.grid.width // self.downsample
        out = np.zeros((f, len(sel), h, w), np.float32)
        ctx = self.bev.config.temporal_kernel // 2
        stride = self.config.frame_stride
        for phase in range(min(stride, f)):
            idx = np.arange(phase, f, stride)
            for lo in range(0, idx.shape[0], chunk):
                a, b = max(0, lo - ctx), min(idx.shape[0], lo + chunk + ctx)
                fr = idx[a:b]
                batch = {
                    "bev_lidar": torch.from_numpy(np.asarray(bev_lidar[fr])).float().div_(255.0)[None],
                    "bev_map": torch.from_numpy(np.asarray(bev_map[fr])).float().div_(255.0)[None],
                }
                batch = mask_inputs(batch, self.inputs)
                e = self.bev.embed_map(batch["bev_lidar"].to(self.device), batch["bev_map"].to(self.device))
                v = self.head(e)[0, :, sel]  # (n, A', h, w)
                keep = slice(lo - a, lo - a + min(chunk, idx.shape[0] - lo))
                out[idx[lo : lo + chunk]] = v[keep].float().cpu().numpy()
        return out


def load_embedding_weights(bev: BevTower, state: dict[str, torch.Tensor], source: Path) -> None:
    """Load a saved tower; only the parameters behind E must match (the clip-embedding part may differ)."""
    result = bev.load_state_dict({k: v for k, v in state.items() if k.startswith(EMBEDDING_PREFIXES)}, strict=False)
    missing = [k for k in result.missing_keys if k.startswith(EMBEDDING_PREFIXES)]
    if missing:
        raise ValueError(f"{source}: the BEV embedding weights do not match the model: missing {missing}")


def load_tagger(run_dir: Path | str, device: str = "cpu") -> Tagger:
    """The tagging model of a run folder (trained ``alone`` or jointly).

    Raises:
        FileNotFoundError: the run has no ``tagging.json`` (it was trained without tagging).
    """
    run = Path(run_dir)
    path = run / TAGGING_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the run has no tagging model (train with tagging, or "
                                "`scenesearch eval-tags --train`)")
    meta = json.loads(path.read_text())
    config = TagTrainConfig.from_dict(meta["config"], source=f"{path}: config")
    head = TagHead(TagHeadConfig.from_dict(meta["head"]))
    head.load_state_dict(load_file(str(run / HEAD_FILE)))
    dev = resolve_device(device)
    if meta.get("backbone") == BACKBONE_FILE:
        bev = BevTower(config.bev, 32)
        load_embedding_weights(bev, load_file(str(run / BACKBONE_FILE)), run / BACKBONE_FILE)
    else:
        bev = load_model(run, device="cpu", text=False).bev  # the BEV tower alone: no sentence encoder
    return Tagger(bev, head, config, meta, dev)
