"""The clip dataset: (caption, camera view, BEV view) samples cut lazily from a clips folder.

>>> ds = ClipDataset("clips", split="train", augment=True, seed=0)
>>> loader = torch.utils.data.DataLoader(ds, batch_size=32, num_workers=2, collate_fn=collate_clips)

An item is a dict (with ``as_uint8=True`` the four image-like views stay uint8 0–255 — a quarter
of the bytes to move; :class:`~encoders.model.DualEncoder` converts them on its own device):

- ``clip_id``, ``log_id``, ``track_id``, ``category``: str
- ``caption``: a seeded paraphrase when augmenting, else the canonical caption; ``canonical_caption``
- ``tags``, ``host_tags``: list[str]
- ``camera``: (T, 4, Hc, Wc) float32: RGB in [0, 1] with the object highlighted (coloured overlay,
  the rest dimmed) and its binary mask as channel 3; zeros when ``has_camera`` is false
- ``has_camera``: bool
- ``camera_crop``: (T, 4, Hc, Wc) float32, only from a clips folder with object crops (its manifest's
  ``camera.object_crops``): the object's crop at full resolution (:mod:`encoders.clips.crops`), RGB in
  [0, 1] (jittered with the frames) and its mask as channel 3; zeros in frames without a crop
- ``camera_box``: (T, 4) float32 beside ``camera_crop``: the crop's centre x, y in the full image in
  [−1, 1], the object's full-resolution pixels on a log scale, and whether it was seen
- ``bev_lidar``: (T, Cl, Hb, Wb) float32 occupancy in [0, 1] per height bin
- ``bev_map``: (T, Cm, Hb, Wb) float32 map layers in [0, 1]
- ``bev_object``: (T, 1, Hb, Wb) float32, the object of interest's footprint
- ``ego_motion``: (T, 6) float32 ``x_m, y_m, yaw_rad, speed_mps, accel_mps2, yaw_rate_rps``: each
  frame's ego pose in the clip's first ego frame (every BEV grid is in its own frame's ego frame), its
  speed, and its smoothed rates (:func:`encoders.clips.views.ego_motion`)
- ``object_track``: (T, 11) float32, the object's own box through the clip relative to the ego and
  in the clip's first ego frame (:func:`encoders.clips.views.object_track`)
- ``object_velocity``: (T, 2) float32 the object's velocity relative to the ego in each frame's ego
  frame, m/s, as the motion rules compute it (:func:`encoders.clips.views.object_rates_and_velocity`)
- ``object_rates``: (T, 3) float32 the object's own ``speed_mps, accel_mps2, yaw_rate_rps`` over ground,
  as the behaviour rules compute them (the same function)
- ``frame_targets``: (T, K) int64, each frame's rule tags as class indices of the K
  :data:`encoders.dense.DENSE_TASKS`, −1 where untagged (all −1 for a clip table without frame tags)

Augmentation (seeded by ``(seed, epoch, index)``; call :meth:`ClipDataset.set_epoch`): paraphrased
captions, one small rotation and translation of the whole BEV clip about the ego (``ego_motion``
and ``object_track`` are rotated to match), colour jitter of the camera frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import torch
from numpy.typing import NDArray

from encoders.clips import layout
from encoders.clips.blocks import LOGS_KEPT
from encoders.clips.frame_tags import FRAME_TAG_COLUMNS
from encoders.clips.layout import grid_from_manifest, read_clip_table, read_manifest
from encoders.clips.views import (
    CAMERA_BOX_FEATURES,
    EGO_MOTION_FEATURES,
    OBJECT_RATES_COLUMNS,
    OBJECT_TRACK_FEATURES,
    OBJECT_VELOCITY_COLUMNS,
    LogArrays,
    ego_motion,
    gather_cells,
    highlight_camera,
    log_rates_and_velocity,
    object_crops,
    object_footprint,
    object_track,
    open_log_arrays,
    rotate_object_track,
    warp_source_cells,
)
from encoders.dense import DENSE_TASKS, frame_targets
from scenesearch_base.lru import Lru

#: The image-like views; uint8 0–255 with ``as_uint8=True``, else float32 in [0, 1].
UINT8_VIEWS = ("camera", "camera_crop", "bev_lidar", "bev_map", "bev_object")
#: The bytes of track kinematics a dataset keeps: an index build reads log after log and needs only the
#: last; training draws from every log, and those of a few thousand fit (docs/research/ingest-profile.md).
KINEMATICS_KEPT_BYTES = 512 << 20


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
    frame_targets: NDArray[np.int64]


class ClipDataset(torch.utils.data.Dataset[dict[str, Any]]):
    """Clips of one split (or all), read through memory maps; safe to use with worker processes."""

    def __init__(
        self,
        clips_dir: Path | str,
        split: str | None = None,
        augment: bool = False,
        seed: int = 0,
        augment_config: AugmentConfig | None = None,
        as_uint8: bool = False,
    ) -> None:
        self.clips_dir = Path(clips_dir)
        self.manifest = read_manifest(self.clips_dir)
        table = read_clip_table(self.clips_dir)
        if split is not None:
            if split not in ("train", "val", "test"):
                raise ValueError(f"split must be 'train', 'val', 'test' or None, got {split!r}")
            table = table.filter(pa.compute.equal(table.column("split"), split))
        cols = table.to_pydict()
        layout.check_categories(self.clips_dir, cols["clip_id"], cols["category"])
        tag_columns = [c for c in FRAME_TAG_COLUMNS if c in cols]
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
                frame_targets=frame_targets({c: cols[c][i] for c in tag_columns}, len(cols["frame_indices"][i])),
            )
            for i in range(table.num_rows)
        ]
        self.augment = augment
        self.seed = int(seed)
        self.epoch = 0
        self.augment_config = augment_config or AugmentConfig()
        self.as_uint8 = as_uint8
        cam = self.manifest["camera"]
        self._camera_shape = (int(cam["height_px"]), int(cam["width_px"]))
        #: Whether the clips hold object crops (``camera_crop`` and ``camera_box`` in every item).
        self.has_crops = bool(cam.get("object_crops", False))
        self._highlight = (
            tuple(cam.get("highlight_rgb", (255, 0, 255))),
            float(cam.get("highlight_alpha", 0.5)),
            float(cam.get("dim_factor", 0.7)),
        )
        self._grid = grid_from_manifest(self.manifest)
        self._arrays, self._kinematics = self._log_caches()

    @staticmethod
    def _log_caches() -> tuple[Lru[str, LogArrays], Lru[str, NDArray[np.float32]]]:
        """Per log: its opened arrays, and every track's kinematics (K, F, 5), least recently used going first."""
        return Lru(LOGS_KEPT), Lru(KINEMATICS_KEPT_BYTES, lambda kinematics: kinematics.nbytes)

    # Arrays are opened lazily in each process, never pickled to workers.
    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_arrays"], state["_kinematics"] = self._log_caches()
        return state

    def __len__(self) -> int:
        return len(self._rows)

    @property
    def has_frame_tags(self) -> bool:
        """Whether some clip frame has a rule tag (a dense target)."""
        return any(bool((r.frame_targets >= 0).any()) for r in self._rows)

    @property
    def clip_ids(self) -> list[str]:
        return [r.clip_id for r in self._rows]

    @property
    def camera_flags(self) -> NDArray[np.bool_]:
        """(N,) whether each clip has a camera view, from the clip table (no clip is read)."""
        return np.array([r.has_camera for r in self._rows], dtype=bool)

    def set_epoch(self, epoch: int) -> None:
        """Change the augmentation draw (before creating the epoch's DataLoader iterator)."""
        self.epoch = int(epoch)

    def _log(self, log_id: str) -> LogArrays:
        arrays = self._arrays.get(log_id)
        if arrays is None:
            arrays = open_log_arrays(self.clips_dir, log_id)
            self._arrays.put(log_id, arrays)
        return arrays

    def _track_kinematics(self, log_id: str, arrays: LogArrays, value: int) -> NDArray[np.float32]:
        """(F, 5) :func:`object_rates_and_velocity` of the track over the whole log; a log's tracks are
        computed together, once (:func:`log_rates_and_velocity`)."""
        kinematics = self._kinematics.get(log_id)
        if kinematics is None:
            kinematics = log_rates_and_velocity(arrays.track_boxes[:], arrays.pose_xy_yaw, arrays.time_s)
            self._kinematics.put(log_id, kinematics)
        return kinematics[value - 1]

    def _view_shapes(self, index: int) -> dict[str, tuple[int, ...]]:
        """Per-item shapes of the image-like views (all clips share T)."""
        t = self._rows[index].frame_indices.shape[0]
        arrays = self._log(self._rows[index].log_id)
        hb, wb = self._grid.shape
        return {
            "camera": (t, 4, *self._camera_shape),
            **({"camera_crop": (t, 4, *self._camera_shape)} if self.has_crops else {}),
            "bev_lidar": (t, arrays.bev_lidar.shape[1], hb, wb),
            "bev_map": (t, arrays.bev_map.shape[1], hb, wb),
            "bev_object": (t, 1, hb, wb),
        }

    def __getitem__(self, index: int) -> dict[str, Any]:
        batch = self.__getitems__([index])
        item = {key: value[0] for key, value in batch.items()}
        item["has_camera"] = bool(item["has_camera"])
        return item

    def __getitems__(self, indices: list[int]) -> dict[str, Any]:
        """A whole batch at once (the DataLoader calls this when it exists; :func:`collate_clips`
        passes it through). Every item is written straight into its slot of the batch's uint8
        tensors (in shared memory inside a worker, so handing the batch over copies nothing);
        float32 views, unless ``as_uint8``, are converted in one pass per view at the end."""
        indices = [int(i) for i in indices]
        shapes = self._view_shapes(indices[0])
        views = {key: _empty_batch((len(indices), *shape), torch.uint8) for key, shape in shapes.items()}
        slots = {key: tensor.numpy() for key, tensor in views.items()}
        t = shapes["camera"][0]
        motion = _empty_batch((len(indices), t, EGO_MOTION_FEATURES), torch.float32)
        box = _empty_batch((len(indices), t, CAMERA_BOX_FEATURES), torch.float32) if self.has_crops else None
        track = _empty_batch((len(indices), t, OBJECT_TRACK_FEATURES), torch.float32)
        velocity = _empty_batch((len(indices), t, len(OBJECT_VELOCITY_COLUMNS)), torch.float32)
        rates = _empty_batch((len(indices), t, len(OBJECT_RATES_COLUMNS)), torch.float32)
        targets = _empty_batch((len(indices), t, len(DENSE_TASKS)), torch.int64)
        items = [self._fill(i, {key: slot[b] for key, slot in slots.items()}, motion.numpy()[b], track.numpy()[b],
                            velocity.numpy()[b], rates.numpy()[b], targets.numpy()[b],
                            None if box is None else box.numpy()[b])
                 for b, i in enumerate(indices)]
        batch: dict[str, Any] = {key: [item[key] for item in items] for key in items[0]}
        batch["has_camera"] = torch.tensor(batch["has_camera"], dtype=torch.bool)
        for key, tensor in views.items():
            if self.as_uint8:
                batch[key] = tensor
            else:
                out = _empty_batch(tuple(tensor.shape), torch.float32)
                out.copy_(tensor).mul_(1.0 / 255.0)  # two in-place passes: faster than a promoting mul
                batch[key] = out
        batch["ego_motion"] = motion
        if box is not None:
            batch["camera_box"] = box
        batch["object_track"] = track
        batch["object_velocity"] = velocity
        batch["object_rates"] = rates
        batch["frame_targets"] = targets
        return batch

    def _fill_crop(self, log_id: str, arrays: LogArrays, value: int, indices: NDArray[np.int64],
                   factors: tuple[float, float, float] | None, crop_out: NDArray[np.uint8],
                   box_out: NDArray[np.float32]) -> None:
        """Write a clip's object crops into ``crop_out`` (T, 4, Hc, Wc), jittered by the frames' colour
        ``factors``, and their box features into ``box_out`` (T, 4)."""
        if arrays.crops is None:
            raise FileNotFoundError(f"{layout.rendered_log_dir(self.clips_dir, log_id)}: the manifest promises "
                                    f"object crops and {layout.CAMERA_CROP_INDEX_FILE} is missing; render the clips "
                                    "again (scenesearch clips)")
        t, _, h, w = crop_out.shape
        rgb = np.empty((t, h, w, 3), np.uint8)
        mask = np.empty((t, h, w), np.uint8)
        object_crops(arrays.crops, value - 1, indices, rgb, mask, box_out)
        if factors is not None:
            rgb = _colour_jitter(rgb, factors)
        crop_out[:, :3] = rgb.transpose(0, 3, 1, 2)
        np.multiply(mask, np.uint8(255), out=crop_out[:, 3], casting="unsafe")

    def _fill(self, index: int, slot: dict[str, NDArray[np.uint8]], motion_out: NDArray[np.float32],
              track_out: NDArray[np.float32], velocity_out: NDArray[np.float32], rates_out: NDArray[np.float32],
              targets_out: NDArray[np.int64], box_out: NDArray[np.float32] | None = None) -> dict[str, Any]:
        """Write item ``index``'s uint8 views into ``slot`` (contiguous (T, C, H, W) arrays), its
        ego motion into ``motion_out`` (T, 6), its track into ``track_out`` (T, 11), ``velocity_out``
        (T, 2) and ``rates_out`` (T, 3), its frames' tag classes into ``targets_out`` (T, K), and with
        crops its crop's box features into ``box_out`` (T, 4); return the item's other fields."""
        row = self._rows[index]
        arrays = self._log(row.log_id)
        fi = row.frame_indices
        value = arrays.track_value[row.track_id]
        rng = np.random.default_rng([self.seed, self.epoch, index]) if self.augment else None
        aug = self.augment_config

        caption, canonical, tags, host_tags = row.caption, row.canonical_caption, list(row.tags), list(row.host_tags)
        targets_out[:] = row.frame_targets
        if rng is not None and row.paraphrases and rng.random() < aug.paraphrase_probability:
            caption = row.paraphrases[int(rng.integers(len(row.paraphrases)))]

        has_camera = bool(row.has_camera and arrays.camera.shape[0] > 0)
        camera = slot["camera"]
        if has_camera:
            rgb = np.asarray(arrays.camera[fi])  # (T, H, W, 3) uint8
            mask = np.asarray(arrays.camera_instances[fi]) == value  # (T, H, W)
            factors = _jitter_factors(rng, aug) if rng is not None else None
            if factors is not None:
                rgb = _colour_jitter(rgb, factors)
            color, alpha, dim = self._highlight
            shown = highlight_camera(rgb, mask, color, alpha, dim)  # (T, H, W, 3)
            camera[:, :3] = shown.transpose(0, 3, 1, 2)
            np.multiply(mask, np.uint8(255), out=camera[:, 3], casting="unsafe")
            if box_out is not None:  # the folder has crops: so does the slot
                self._fill_crop(row.log_id, arrays, value, fi, factors, slot["camera_crop"], box_out)
        else:
            camera.fill(0)
            if box_out is not None:
                slot["camera_crop"].fill(0)
                box_out.fill(0.0)

        obj = object_footprint(arrays, self._grid, row.track_id, fi)[:, None]  # (T, 1, H, W), 0/1
        obj *= np.uint8(255)
        motion_out[:] = ego_motion(arrays.pose_xy_yaw, arrays.speed_mps, fi, arrays.accel_mps2, arrays.yaw_rate_rps)
        track_out[:] = object_track(arrays.track_boxes[fi, value - 1], motion_out)
        rates_and_velocity = self._track_kinematics(row.log_id, arrays, value)[fi]  # (T, 5)
        rates_out[:] = rates_and_velocity[:, : len(OBJECT_RATES_COLUMNS)]
        velocity_out[:] = rates_and_velocity[:, len(OBJECT_RATES_COLUMNS):]
        if rng is None:
            slot["bev_lidar"][:] = arrays.bev_lidar[fi]  # the frames' blocks, decompressed, into the batch
            slot["bev_map"][:] = arrays.bev_map[fi]
            slot["bev_object"][:] = obj
        else:
            theta = float(rng.uniform(-aug.max_rotation_rad, aug.max_rotation_rad))
            shift = rng.uniform(-aug.max_translation_m, aug.max_translation_m, size=2)
            source, outside = warp_source_cells(self._grid, theta, shift)  # one warp for every layer
            gather_cells(arrays.bev_lidar[fi], source, outside, slot["bev_lidar"])
            gather_cells(arrays.bev_map[fi], source, outside, slot["bev_map"])
            gather_cells(obj, source, outside, slot["bev_object"])
            c, s = np.cos(theta), np.sin(theta)
            motion_out[:, :2] = motion_out[:, :2] @ np.array([[c, s], [-s, c]], dtype=np.float32)
            rotate_object_track(track_out, theta)
            velocity_out[:] = velocity_out @ np.array([[c, s], [-s, c]], dtype=np.float32)

        return {
            "clip_id": row.clip_id,
            "log_id": row.log_id,
            "track_id": row.track_id,
            "category": row.category,
            "caption": caption,
            "canonical_caption": canonical,
            "tags": tags,
            "host_tags": host_tags,
            "has_camera": has_camera,
        }


def _jitter_factors(rng: np.random.Generator, aug: AugmentConfig) -> tuple[float, float, float]:
    """One clip's brightness, contrast and saturation factors."""
    return (float(rng.uniform(1 - aug.brightness, 1 + aug.brightness)),
            float(rng.uniform(1 - aug.contrast, 1 + aug.contrast)),
            float(rng.uniform(1 - aug.saturation, 1 + aug.saturation)))


def _colour_jitter(rgb: NDArray[np.uint8], factors: tuple[float, float, float]) -> NDArray[np.uint8]:
    """(T, H, W, 3) → the same, with one brightness / contrast / saturation draw (:func:`_jitter_factors`)
    for the whole clip.

    Brightness and contrast are one lookup table; saturation blends with the luminance image.
    """
    b, c, s = factors
    flat = np.ascontiguousarray(rgb).reshape(-1, rgb.shape[-2], 3)  # frames stacked into one image
    mean = float(flat.mean()) * b
    lut = np.clip((np.arange(256) * b - mean) * c + mean + 0.5, 0, 255).astype(np.uint8)
    out = cv2.LUT(flat, lut)
    gray = cv2.cvtColor(cv2.cvtColor(out, cv2.COLOR_RGB2GRAY), cv2.COLOR_GRAY2RGB)
    return np.asarray(cv2.addWeighted(out, s, gray, 1.0 - s, 0.0), dtype=np.uint8).reshape(rgb.shape)


def _empty_batch(shape: tuple[int, ...], dtype: torch.dtype) -> torch.Tensor:
    """An uninitialised tensor, allocated in shared memory inside a DataLoader worker (as
    ``default_collate`` does) so that handing it to the main process copies nothing."""
    if torch.utils.data.get_worker_info() is None:
        return torch.empty(shape, dtype=dtype)
    numel = int(np.prod(shape))
    storage = torch.empty(0, dtype=dtype)._typed_storage()._new_shared(numel, device="cpu")
    return torch.empty(0, dtype=dtype).new(storage).resize_(*shape)


def collate_clips(items: list[dict[str, Any]] | dict[str, Any]) -> dict[str, Any]:
    """Stack items into a batch: tensors → (B, T, C, H, W) / (B, T, 4), ``has_camera`` → (B,) bool,
    strings and tag lists → lists. The camera tensor holds zeros where ``has_camera`` is false.

    In a DataLoader worker the stacked tensors are written straight into shared memory (as
    ``default_collate`` does), saving a copy per batch. A batch already built by
    :meth:`ClipDataset.__getitems__` passes through unchanged."""
    if isinstance(items, dict):
        return items
    out: dict[str, Any] = {}
    for key in items[0]:
        values = [item[key] for item in items]
        if isinstance(values[0], torch.Tensor):
            out[key] = torch.utils.data.default_collate(values)
        elif key == "has_camera":
            out[key] = torch.tensor(values, dtype=torch.bool)
        else:
            out[key] = values
    return out
