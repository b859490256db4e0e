"""The clip dataset: (caption, camera view, BEV view) samples cut lazily from a clips folder.

>>> ds = ClipDataset("clips", split="train", augment=True, seed=0)
>>> loader = torch.utils.data.DataLoader(ds, batch_size=32, num_workers=2, collate_fn=collate_clips)

An item is a dict:

- ``clip_id``, ``log_id``, ``track_id``, ``category``: str
- ``caption``: a seeded paraphrase when augmenting, else the canonical caption; ``canonical_caption``
- ``tags``, ``host_tags``: list[str]
- ``camera``: (T, 4, Hc, Wc) float32: RGB in [0, 1] with the object highlighted (coloured overlay,
  the rest dimmed) and its binary mask as channel 3; zeros when ``has_camera`` is false
- ``has_camera``: bool
- ``bev_lidar``: (T, Cl, Hb, Wb) float32 occupancy in [0, 1] per height bin
- ``bev_map``: (T, Cm, Hb, Wb) float32 map layers in [0, 1]
- ``bev_object``: (T, 1, Hb, Wb) float32, the object of interest's footprint
- ``ego_motion``: (T, 4) float32 ``x_m, y_m, yaw_rad, speed_mps`` of each frame's ego pose in the
  clip's first ego frame (every BEV grid is in its own frame's ego frame)

Augmentation (seeded by ``(seed, epoch, index)``; call :meth:`ClipDataset.set_epoch`): paraphrased
captions, one small rotation and translation of the whole BEV clip about the ego (``ego_motion`` is
rotated to match), and colour jitter of the camera frames.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from encoders.clips.raster import BevGrid
from encoders.clips.views import LogArrays, ego_motion, highlight_camera, object_footprint, open_log_arrays

CLIPS_FILE = "clips.parquet"
MANIFEST_FILE = "manifest.json"


def read_clip_table(clips_dir: Path | str) -> pa.Table:
    """``CLIPS_DIR/clips.parquet``."""
    path = Path(clips_dir) / CLIPS_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: clip table not found (run `scenesearch clips` first)")
    return pq.read_table(path)


def read_manifest(clips_dir: Path | str) -> dict[str, Any]:
    """``CLIPS_DIR/manifest.json``."""
    path = Path(clips_dir) / MANIFEST_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: clips manifest not found (run `scenesearch clips` first)")
    data: dict[str, Any] = json.loads(path.read_text())
    return data


@dataclass(frozen=True)
class AugmentConfig:
    """Strength of the augmentations.

    Attributes:
        max_rotation_rad: BEV rotation drawn from U(−max, max).
        max_translation_m: BEV shift along x and y drawn from U(−max, max).
        brightness, contrast, saturation: camera jitter factors drawn from U(1 − v, 1 + v).
        paraphrase_probability: chance to use a paraphrase instead of the canonical caption.
    """

    max_rotation_rad: float = 0.1
    max_translation_m: float = 1.0
    brightness: float = 0.2
    contrast: float = 0.2
    saturation: float = 0.2
    paraphrase_probability: float = 0.8


@dataclass(frozen=True)
class _Row:
    clip_id: str
    log_id: str
    track_id: str
    category: str
    caption: str
    canonical_caption: str
    paraphrases: tuple[str, ...]
    tags: tuple[str, ...]
    host_tags: tuple[str, ...]
    has_camera: bool
    frame_indices: NDArray[np.int64]


class ClipDataset(torch.utils.data.Dataset[dict[str, Any]]):
    """Clips of one split (or all), read through memory maps; safe to use with worker processes."""

    def __init__(
        self,
        clips_dir: Path | str,
        split: str | None = None,
        augment: bool = False,
        seed: int = 0,
        augment_config: AugmentConfig | None = None,
    ) -> None:
        self.clips_dir = Path(clips_dir)
        self.manifest = read_manifest(self.clips_dir)
        table = read_clip_table(self.clips_dir)
        if split is not None:
            if split not in ("train", "val", "test"):
                raise ValueError(f"split must be 'train', 'val', 'test' or None, got {split!r}")
            table = table.filter(pa.compute.equal(table.column("split"), split))
        cols = table.to_pydict()
        self._rows = [
            _Row(
                clip_id=cols["clip_id"][i],
                log_id=cols["log_id"][i],
                track_id=cols["track_id"][i],
                category=cols["category"][i],
                caption=cols["caption"][i],
                canonical_caption=cols["canonical_caption"][i],
                paraphrases=tuple(cols["paraphrases"][i] or ()),
                tags=tuple(cols["tags"][i] or ()),
                host_tags=tuple(cols["host_tags"][i] or ()),
                has_camera=bool(cols["has_camera"][i]),
                frame_indices=np.asarray(cols["frame_indices"][i], dtype=np.int64),
            )
            for i in range(table.num_rows)
        ]
        self.augment = augment
        self.seed = int(seed)
        self.epoch = 0
        self.augment_config = augment_config or AugmentConfig()
        cam = self.manifest["camera"]
        self._camera_shape = (int(cam["height_px"]), int(cam["width_px"]))
        self._highlight = (
            tuple(cam.get("highlight_rgb", (255, 0, 255))),
            float(cam.get("highlight_alpha", 0.5)),
            float(cam.get("dim_factor", 0.7)),
        )
        bev = self.manifest["bev"]
        self._bev = (float(bev["x_min_m"]), float(bev["x_max_m"]), float(bev["y_min_m"]), float(bev["y_max_m"]),
                     float(bev["resolution_m"]))
        self._grid = BevGrid(*self._bev)
        self._arrays: dict[str, LogArrays] = {}

    # Memory maps are opened lazily in each process, never pickled to workers.
    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_arrays"] = {}
        return state

    def __len__(self) -> int:
        return len(self._rows)

    @property
    def clip_ids(self) -> list[str]:
        return [r.clip_id for r in self._rows]

    def set_epoch(self, epoch: int) -> None:
        """Change the augmentation draw (before creating the epoch's DataLoader iterator)."""
        self.epoch = int(epoch)

    def _log(self, log_id: str) -> LogArrays:
        arrays = self._arrays.get(log_id)
        if arrays is None:
            arrays = open_log_arrays(self.clips_dir, log_id)
            self._arrays[log_id] = arrays
        return arrays

    def __getitem__(self, index: int) -> dict[str, Any]:
        row = self._rows[index]
        arrays = self._log(row.log_id)
        fi = row.frame_indices
        t = fi.shape[0]
        value = arrays.track_value[row.track_id]
        rng = np.random.default_rng([self.seed, self.epoch, index]) if self.augment else None
        aug = self.augment_config

        caption = row.caption
        if rng is not None and row.paraphrases and rng.random() < aug.paraphrase_probability:
            caption = row.paraphrases[int(rng.integers(len(row.paraphrases)))]

        hc, wc = self._camera_shape
        if row.has_camera and arrays.camera.shape[0]:
            rgb = np.asarray(arrays.camera[fi], dtype=np.float32) * np.float32(1.0 / 255.0)  # (T, H, W, 3)
            mask = np.asarray(arrays.camera_instances[fi]) == value  # (T, H, W)
            if rng is not None:
                rgb = _colour_jitter(rgb, rng, aug)
            color, alpha, dim = self._highlight
            shown = highlight_camera(rgb, mask, color, alpha, dim)
            camera = np.concatenate([shown, mask[..., None].astype(np.float32)], axis=-1)
            camera_t = torch.from_numpy(camera).permute(0, 3, 1, 2).contiguous()  # (T, 4, H, W)
        else:
            camera_t = torch.zeros((t, 4, hc, wc), dtype=torch.float32)

        lidar = torch.from_numpy(np.asarray(arrays.bev_lidar[fi])).float().div_(255.0)  # (T, Cl, H, W)
        bev_map = torch.from_numpy(np.asarray(arrays.bev_map[fi])).float().div_(255.0)  # (T, Cm, H, W)
        footprint = object_footprint(arrays, self._grid, row.track_id, fi)
        obj = torch.from_numpy(footprint).float().unsqueeze(1)  # (T, 1, H, W)
        motion = ego_motion(arrays.pose_xy_yaw, arrays.speed_mps, fi)
        if rng is not None:
            theta = float(rng.uniform(-aug.max_rotation_rad, aug.max_rotation_rad))
            shift = rng.uniform(-aug.max_translation_m, aug.max_translation_m, size=2)
            cl, cm = lidar.shape[1], bev_map.shape[1]
            stacked = _warp_bev(torch.cat([lidar, bev_map, obj], dim=1), theta, shift, self._bev)
            lidar, bev_map = stacked[:, :cl], stacked[:, cl : cl + cm]
            obj = (stacked[:, cl + cm :] > 0.5).float()
            c, s = np.cos(theta), np.sin(theta)
            motion[:, :2] = motion[:, :2] @ np.array([[c, s], [-s, c]], dtype=np.float32)

        return {
            "clip_id": row.clip_id,
            "log_id": row.log_id,
            "track_id": row.track_id,
            "category": row.category,
            "caption": caption,
            "canonical_caption": row.canonical_caption,
            "tags": list(row.tags),
            "host_tags": list(row.host_tags),
            "camera": camera_t,
            "has_camera": bool(row.has_camera and arrays.camera.shape[0] > 0),
            "bev_lidar": lidar,
            "bev_map": bev_map,
            "bev_object": obj,
            "ego_motion": torch.from_numpy(motion),
        }


def _colour_jitter(rgb: NDArray[np.float32], rng: np.random.Generator, aug: AugmentConfig) -> NDArray[np.float32]:
    """(T, H, W, 3) → the same, with one brightness / contrast / saturation draw for the whole clip."""
    b = rng.uniform(1 - aug.brightness, 1 + aug.brightness)
    c = rng.uniform(1 - aug.contrast, 1 + aug.contrast)
    s = rng.uniform(1 - aug.saturation, 1 + aug.saturation)
    out = rgb * np.float32(b)
    mean = out.mean(dtype=np.float32)
    out = (out - mean) * np.float32(c) + mean
    gray = out.mean(axis=-1, keepdims=True)
    out = (out - gray) * np.float32(s) + gray
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def _warp_bev(
    bev: torch.Tensor, theta_rad: float, shift_xy_m: NDArray[np.float64], grid: tuple[float, float, float, float, float]
) -> torch.Tensor:
    """Rotate every frame by ``theta_rad`` about the ego origin and shift it by ``shift_xy_m``.

    A point at ego ``p`` moves to ``R(θ)·p + shift``. ``bev``: (T, C, H, W).
    """
    x_min, x_max, y_min, y_max, _res = grid
    hh, hw = 0.5 * (x_max - x_min), 0.5 * (y_max - y_min)
    centre = np.array([0.5 * (x_min + x_max), 0.5 * (y_min + y_max)])
    # Normalised (u → columns, v → rows) to ego metres: x = cx − v·hh, y = cy − u·hw.
    a = np.array([[0.0, -hh], [-hw, 0.0]])
    a_inv = np.linalg.inv(a)
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    rot_inv = np.array([[c, s], [-s, c]])
    # Output q' → input q: p = R⁻¹(A q' + centre − shift); q = A⁻¹(p − centre).
    m = a_inv @ rot_inv @ a
    b = a_inv @ (rot_inv @ (centre - shift_xy_m) - centre)
    affine = torch.tensor(np.concatenate([m, b[:, None]], axis=1), dtype=bev.dtype).unsqueeze(0)
    affine = affine.expand(bev.shape[0], 2, 3)
    sample_grid = F.affine_grid(affine, list(bev.shape), align_corners=False)
    return F.grid_sample(bev, sample_grid, mode="bilinear", padding_mode="zeros", align_corners=False)


def collate_clips(items: list[dict[str, Any]]) -> dict[str, Any]:
    """Stack items into a batch: tensors → (B, T, C, H, W) / (B, T, 4), ``has_camera`` → (B,) bool,
    strings and tag lists → lists. The camera tensor holds zeros where ``has_camera`` is false."""
    out: dict[str, Any] = {}
    for key in items[0]:
        values = [item[key] for item in items]
        if isinstance(values[0], torch.Tensor):
            out[key] = torch.stack(values)
        elif key == "has_camera":
            out[key] = torch.tensor(values, dtype=torch.bool)
        else:
            out[key] = values
    return out
