"""Training windows for tagging: a few consecutive BEV frames of a rendered log and their targets.

An item centred on frame f of a log holds the frames ``f + stride·(i − T//2)`` for i < T (clamped to
the log), read through memory maps:

- ``bev_lidar``: (T, Cl, H, W) float32 in [0, 1]
- ``bev_map``: (T, Cm, H, W) float32 in [0, 1]
- ``targets``: (T, A, H, W) float32, the attributes of :attr:`TagWindowDataset.names`
- ``log_id``: str, ``frame``: int (f)

Items are all (log, frame) pairs of the logs of a split (the clip table's split of each log);
:attr:`TagWindowDataset.present` (N, A) feeds the task-balanced sampler.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from encoders.clips.blocks import LOGS_KEPT, FrameArray
from encoders.clips.layout import BEV_LIDAR_FILE, BEV_MAP_FILE, load_rendered_array, read_manifest, rendered_log_dir
from encoders.tagging.attributes import TagError
from encoders.tagging.targets import LogTargets, open_targets
from scenesearch_base.lru import Lru

TargetSource = Callable[[str], LogTargets]


def split_logs(manifest: dict[str, Any], split: str | None) -> list[str]:
    """Log ids of a split (``train``, ``val``, ``test``; None = all) from a clips manifest."""
    logs = manifest.get("logs", {})
    return sorted(lid for lid, info in logs.items() if split is None or info.get("split") == split)


def window_indices(center: int, num_frames: int, window: int, stride: int) -> NDArray[np.int64]:
    """(T,) frame indices of the window centred on ``center``, clamped to [0, num_frames)."""
    offsets = stride * (np.arange(window) - window // 2)
    return np.clip(center + offsets, 0, num_frames - 1).astype(np.int64)


class TagWindowDataset(torch.utils.data.Dataset[dict[str, Any]]):
    """(log, frame) windows of the logs of a split that have tag targets."""

    def __init__(
        self,
        clips_dir: Path | str,
        split: str | None = "train",
        window_frames: int = 5,
        frame_stride: int = 2,
        targets: TargetSource | None = None,
        log_ids: Sequence[str] | None = None,
    ) -> None:
        self.clips_dir = Path(clips_dir)
        self.manifest = read_manifest(self.clips_dir)
        self.window_frames = int(window_frames)
        self.frame_stride = int(frame_stride)
        self._source: TargetSource = targets or (lambda lid: open_targets(self.clips_dir, lid))
        ids = list(log_ids) if log_ids is not None else split_logs(self.manifest, split)
        if not ids:
            raise TagError(f"{self.clips_dir}: no logs in split {split!r}")
        self.log_ids: list[str] = []
        self._targets: dict[str, LogTargets] = {}
        log_index, frame_index, present = [], [], []
        names: tuple[str, ...] | None = None
        for lid in ids:
            t = self._source(lid)
            if names is None:
                names = t.names
            elif t.names != names:
                raise TagError(f"log {lid}: target attributes {list(t.names)} differ from {list(names)}")
            self._targets[lid] = t
            f = t.targets.shape[0]
            log_index.append(np.full(f, len(self.log_ids)))
            frame_index.append(np.arange(f))
            present.append(t.present)
            self.log_ids.append(lid)
        self.names: tuple[str, ...] = names or ()
        self.log_index = np.concatenate(log_index).astype(np.int64)
        self.frame_index = np.concatenate(frame_index).astype(np.int64)
        self.present: NDArray[np.bool_] = np.concatenate(present).astype(bool)
        self._arrays: Lru[str, tuple[FrameArray, FrameArray]] = Lru(LOGS_KEPT)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_arrays"] = Lru(LOGS_KEPT)
        return state

    def __len__(self) -> int:
        return int(self.log_index.shape[0])

    def _bev(self, log_id: str) -> tuple[FrameArray, FrameArray]:
        arrays = self._arrays.get(log_id)
        if arrays is None:
            folder = rendered_log_dir(self.clips_dir, log_id)
            arrays = (load_rendered_array(folder, BEV_LIDAR_FILE), load_rendered_array(folder, BEV_MAP_FILE))
            self._arrays.put(log_id, arrays)
        return arrays

    def __getitem__(self, index: int) -> dict[str, Any]:
        lid = self.log_ids[int(self.log_index[index])]
        f = int(self.frame_index[index])
        lidar, bev_map = self._bev(lid)
        tg = self._targets[lid].targets
        idx = window_indices(f, tg.shape[0], self.window_frames, self.frame_stride)
        return {
            "bev_lidar": torch.from_numpy(np.asarray(lidar[idx])).float().div_(255.0),  # (T, Cl, H, W)
            "bev_map": torch.from_numpy(np.asarray(bev_map[idx])).float().div_(255.0),  # (T, Cm, H, W)
            "targets": torch.from_numpy(np.asarray(tg[idx], dtype=np.float32)),  # (T, A, H, W)
            "log_id": lid,
            "frame": f,
        }


def collate_windows(items: list[dict[str, Any]]) -> dict[str, Any]:
    """Stack tensors to (B, T, C, H, W); strings and ints to lists."""
    out: dict[str, Any] = {}
    for key in items[0]:
        values = [it[key] for it in items]
        out[key] = torch.stack(values) if isinstance(values[0], torch.Tensor) else values
    return out
