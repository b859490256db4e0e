"""Synthetic clips whose captions depend on temporal order, for tests, benchmarks and sanity checks.

Each clip shows one object moving relative to the ego through a sequence of (lane, motion) steps,
e.g. ``left:approach`` then ``host:approach`` ("a car approaches in the left lane, then approaches in
the host lane"). Every multi-step behaviour has its time reversal among the behaviours (a cut-in
reversed is a cut-out, an approach reversed is a recede), so a bag of frames cannot tell a clip from
its reversal, while a model that reads frame order can. Distractor objects, noise and random colours
keep the task from being trivial.

Paths are centred on a random distance, so that a clip and its time reversal are equally likely to
cover the same places.

Items follow the dataset contract of :mod:`encoders.data` (``camera`` (T, 4, Hc, Wc) RGB with the
object highlighted + mask channel, ``bev_lidar`` (T, Cl, Hb, Wb), ``bev_map`` (T, Cm, Hb, Wb),
``bev_object`` (T, 1, Hb, Wb), ``ego_motion`` (T, 6), ``object_track`` (T, 11), ``object_velocity``
(T, 2), ``object_rates`` (T, 3), captions and tags).
Rendering is vectorised over frames; every item is a pure function of (seed, split, index).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from encoders.clips.layout import clip_id
from encoders.clips.views import EGO_MOTION_FEATURES, OBJECT_RATES_COLUMNS, object_rates_and_velocity, object_track

#: Seconds between a synthetic clip's frames.
FRAME_STEP_S = 0.1
LANES_Y_M = {"left": 3.5, "host": 0.0, "right": -3.5}
MOTIONS = ("approach", "recede", "constant")
CATEGORIES = {"car": (4.5, 1.9), "truck": (8.0, 2.5)}  # length_m, width_m
SPLIT_OFFSET = {"train": 0, "val": 1, "test": 2}


def behaviours() -> list[tuple[tuple[str, str], ...]]:
    """All (lane, motion) step sequences: 9 one-step, 8 lane changes, 2 motion changes."""
    one: list[tuple[tuple[str, str], ...]] = [((lane, m),) for lane in LANES_Y_M for m in MOTIONS]
    changes: list[tuple[tuple[str, str], ...]] = [
        ((a, m), (b, m))
        for a, b in (("left", "host"), ("host", "left"), ("right", "host"), ("host", "right"))
        for m in ("approach", "recede")
    ]
    motion: list[tuple[tuple[str, str], ...]] = [
        (("host", "approach"), ("host", "recede")),
        (("host", "recede"), ("host", "approach")),
    ]
    return one + changes + motion


_MOTION_WORDS = {"approach": "approaches", "recede": "moves away", "constant": "keeps its distance"}
_MOTION_ALT = {"approach": "comes closer", "recede": "drives away", "constant": "stays at the same distance"}


def caption_of(category: str, steps: tuple[tuple[str, str], ...], alt: bool = False) -> str:
    words = _MOTION_ALT if alt else _MOTION_WORDS
    noun = {"car": "vehicle", "truck": "lorry"}[category] if alt else category
    parts = [f"{words[m]} in the {lane} lane" for lane, m in steps]
    return f"a {noun} " + ", then ".join(parts)


@dataclass(frozen=True)
class SyntheticSpec:
    """Sizes of the synthetic clips (defaults: the demo's sizes).

    ``ego_speed_mps`` is the range of the ego's (constant) speed. A moving ego's odometry and the map
    passing by count time frame by frame, which lets even a bag of frames sort itself; order tests set
    it to (0, 0).
    """

    frames: int = 16
    camera_hw: tuple[int, int] = (96, 160)
    bev_hw: tuple[int, int] = (160, 80)
    lidar_channels: int = 5
    map_channels: int = 6
    x_range_m: tuple[float, float] = (-20.0, 60.0)
    y_range_m: tuple[float, float] = (-20.0, 20.0)
    distractors: int = 3
    camera_fraction: float = 0.8
    ego_speed_mps: tuple[float, float] = (0.0, 12.0)


@dataclass(frozen=True)
class ClipBoxes:
    """The boxes one synthetic clip shows, in the ego frame of each of its T frames.

    Attributes:
        x_m, y_m: (T,) centre of the object of interest.
        length_m, width_m: its size.
        distractor_x_m, distractor_y_m: (T, K) centres of the distractors (4.5 m × 1.9 m each).
    """

    x_m: np.ndarray
    y_m: np.ndarray
    length_m: float
    width_m: float
    distractor_x_m: np.ndarray
    distractor_y_m: np.ndarray

    def unpack(self) -> tuple[np.ndarray, np.ndarray, float, float, np.ndarray, np.ndarray]:
        return self.x_m, self.y_m, self.length_m, self.width_m, self.distractor_x_m, self.distractor_y_m


class SyntheticClipDataset(Dataset[dict[str, Any]]):
    """``size`` seeded synthetic clips of one split; items as :class:`encoders.data.ClipDataset` yields."""

    def __init__(
        self,
        size: int,
        split: str = "train",
        spec: SyntheticSpec | None = None,
        seed: int = 0,
        augment: bool = False,
    ) -> None:
        self.size = size
        self.split = split
        self.spec = spec or SyntheticSpec()
        self.seed = seed
        self.augment = augment
        self.behaviours = behaviours()

    def __len__(self) -> int:
        return self.size

    def _rng(self, index: int, salt: int = 0) -> np.random.Generator:
        return np.random.default_rng([self.seed, SPLIT_OFFSET.get(self.split, 3), index, salt])

    def record(self, index: int) -> dict[str, Any]:
        """The clip's table row: clip_id, category, captions, tags, has_camera."""
        rng = self._rng(index)
        steps = self.behaviours[int(rng.integers(len(self.behaviours)))]
        category = str(rng.choice(list(CATEGORIES)))
        canonical = caption_of(category, steps)
        return {
            "clip_id": clip_id(f"synthetic-{self.split}", str(index), 0),
            "category": category,
            "steps": steps,
            "canonical_caption": canonical,
            "paraphrases": [caption_of(category, steps, alt=True)],
            "tags": [f"{lane}:{m}" for lane, m in steps],
            "has_camera": bool(rng.random() < self.spec.camera_fraction),
            "split": self.split,
        }

    @property
    def camera_flags(self) -> np.ndarray:
        """(N,) whether each clip has a camera view, from the table rows (no clip is rendered)."""
        return np.array([self.record(i)["has_camera"] for i in range(self.size)], dtype=bool)

    def __getitem__(self, index: int) -> dict[str, Any]:
        if not 0 <= index < self.size:
            raise IndexError(index)
        rec = self.record(index)
        rng = self._rng(index, 1)
        s = self.spec
        t = s.frames
        x_m, y_m = trajectory(rec["steps"], t, rng)  # (T,), (T,)
        length_m, width_m = CATEGORIES[rec["category"]]
        speed = float(rng.uniform(*s.ego_speed_mps))
        ego = np.zeros((t, EGO_MOTION_FEATURES), np.float32)  # constant speed, straight: no rates
        ego[:, 0] = speed * FRAME_STEP_S * np.arange(t)
        ego[:, 3] = speed
        # Distractors: static relative to the road, so they move back by the ego's travel.
        d_x = rng.uniform(*s.x_range_m, size=s.distractors)[None, :] - ego[:, :1]  # (T, K)
        d_y = np.broadcast_to(rng.choice(list(LANES_Y_M.values()), size=s.distractors)[None, :] + 7.0, d_x.shape)
        boxes = ClipBoxes(x_m, y_m, length_m, width_m, d_x, d_y)
        lidar, obj = render_bev(s, boxes, rng)
        camera = np.zeros((t, 4, *s.camera_hw), np.float32)
        if rec["has_camera"]:
            camera = render_camera(s, boxes, rng)
        box = np.stack([x_m, y_m, np.full(t, length_m), np.full(t, width_m), np.zeros(t)], axis=1)  # (T, 5)
        # A zero pose reads the ego frame as the ground: the rates are the box's, the relative velocity
        # is the ego-frame derivative either way.
        time_s = FRAME_STEP_S * np.arange(t, dtype=np.float64)
        rates_and_velocity = object_rates_and_velocity(box, np.zeros((t, 3)), time_s)  # (T, 5)
        caption = rec["canonical_caption"]
        if self.augment:
            choices = [caption, *rec["paraphrases"]]
            caption = choices[int(self._rng(index, 2 + zlib.crc32(b"aug")).integers(len(choices)))]
        return {
            "clip_id": rec["clip_id"],
            "caption": caption,
            "canonical_caption": rec["canonical_caption"],
            "tags": list(rec["tags"]),
            "camera": torch.from_numpy(camera),
            "has_camera": rec["has_camera"],
            "bev_lidar": torch.from_numpy(lidar),
            "bev_map": torch.from_numpy(render_map(s, ego)),
            "bev_object": torch.from_numpy(obj),
            "ego_motion": torch.from_numpy(ego),
            "object_track": torch.from_numpy(object_track(box, ego)),
            "object_velocity": torch.from_numpy(rates_and_velocity[:, len(OBJECT_RATES_COLUMNS):]),
            "object_rates": torch.from_numpy(rates_and_velocity[:, : len(OBJECT_RATES_COLUMNS)]),
        }


def trajectory(
    steps: tuple[tuple[str, str], ...], frames: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The object's (T,) x_m and (T,) y_m in the ego frame for a step sequence, with smooth lane changes."""
    seg = np.minimum((np.arange(frames) * len(steps)) // frames, len(steps) - 1)  # (T,) step of each frame
    rate = {"approach": -1.0, "recede": 1.0, "constant": 0.0}
    v = np.array([rate[m] for _, m in steps])[seg] * rng.uniform(1.2, 2.0)  # (T,) metres per frame
    x = np.concatenate([[0.0], np.cumsum(v[:-1])])  # (T,)
    # Centre the path on a random distance: a path and its time reversal then cover the same places,
    # so only the order of the frames tells an approach from a recede.
    x = x - 0.5 * (x.min() + x.max()) + rng.uniform(18.0, 32.0)
    lane_y = np.array([LANES_Y_M[lane] for lane, _ in steps])[seg]  # (T,)
    kernel = np.ones(3) / 3.0
    y = np.convolve(np.pad(lane_y, 1, mode="edge"), kernel, mode="valid")  # smooth the lane change
    y = y + rng.normal(0.0, 0.15, frames)
    return x.astype(np.float32), y.astype(np.float32)


def _grid(s: SyntheticSpec) -> tuple[np.ndarray, np.ndarray]:
    h, w = s.bev_hw
    xs = np.linspace(s.x_range_m[1], s.x_range_m[0], h)  # row 0 is farthest ahead
    ys = np.linspace(s.y_range_m[1], s.y_range_m[0], w)  # column 0 is farthest left
    return xs[:, None], ys[None, :]


def _boxes(
    gx: np.ndarray, gy: np.ndarray, x: np.ndarray, y: np.ndarray, length: float, width: float
) -> np.ndarray:
    """x, y: (T, K) box centres → (T, H, W) bool union of axis-aligned boxes."""
    inside = (np.abs(gx[None, None] - x[..., None, None]) < length / 2) & (
        np.abs(gy[None, None] - y[..., None, None]) < width / 2
    )  # (T, K, H, W)
    return inside.any(axis=1)


def render_bev(s: SyntheticSpec, boxes: ClipBoxes, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """→ bev_lidar (T, Cl, H, W) and bev_object (T, 1, H, W) float32."""
    x, y, length, width, d_x, d_y = boxes.unpack()
    gx, gy = _grid(s)
    obj = _boxes(gx, gy, x[:, None], y[:, None], length, width)  # (T, H, W)
    other = _boxes(gx, gy, d_x, d_y, 4.5, 1.9)  # (T, H, W)
    occ = (obj | other).astype(np.float32)
    noise = rng.random((len(x), *s.bev_hw)) < 0.01
    lidar = np.zeros((len(x), s.lidar_channels, *s.bev_hw), np.float32)
    for c in range(s.lidar_channels):
        lidar[:, c] = np.maximum(occ * (1.0 - 0.15 * c), noise)
    return lidar, obj[:, None].astype(np.float32)


def render_map(s: SyntheticSpec, ego: np.ndarray) -> np.ndarray:
    """ego: (T, 6) → bev_map (T, Cm, H, W): drivable area, lane boundaries, dashed markings moving with the ego."""
    gx, gy = _grid(s)
    t = len(ego)
    out = np.zeros((t, s.map_channels, *s.bev_hw), np.float32)
    drivable = np.abs(gy) < 5.25  # (1, W)
    boundaries = np.min(np.abs(gy[..., None] - np.array([-5.25, -1.75, 1.75, 5.25])), axis=-1) < 0.3  # (1, W)
    dashes = (np.floor((gx[None] + ego[:, 0, None, None]) / 3.0) % 2 == 0) & boundaries[None]  # (T, H, W)
    layers = [np.broadcast_to(drivable, s.bev_hw), np.broadcast_to(boundaries, s.bev_hw)]
    for c in range(s.map_channels):
        out[:, c] = dashes if c == 2 else layers[c % 2]
    return out


def render_camera(s: SyntheticSpec, boxes: ClipBoxes, rng: np.random.Generator) -> np.ndarray:
    """A pinhole front camera → (T, 4, Hc, Wc): RGB with the object highlighted, and its mask."""
    x, y, length, width, d_x, d_y = boxes.unpack()
    h, w = s.camera_hw
    t = len(x)
    focal = 0.9 * w
    rows = np.arange(h)[None, :, None]
    cols = np.arange(w)[None, None, :]
    horizon = 0.45 * h
    img = np.empty((t, 3, h, w), np.float32)
    sky = rows < horizon
    img[:, 0] = np.where(sky, 0.55, 0.35)[0]
    img[:, 1] = np.where(sky, 0.65, 0.35)[0]
    img[:, 2] = np.where(sky, 0.85, 0.38)[0]
    img += rng.normal(0.0, 0.03, img.shape).astype(np.float32)

    def box(xc: np.ndarray, yc: np.ndarray, height_m: float, width_m: float) -> np.ndarray:
        """xc, yc: (T,) → (T, Hc, Wc) bool image footprint (empty behind the camera)."""
        depth = np.maximum(xc, 1e-3)[:, None, None]
        u = w / 2 - focal * yc[:, None, None] / depth
        v_bottom = horizon + focal * 1.6 / depth
        half_w = focal * width_m / 2 / depth
        top = v_bottom - focal * height_m / depth
        return (xc[:, None, None] > 3.0) & (np.abs(cols - u) < half_w) & (rows < v_bottom) & (rows > top)

    for k in range(d_x.shape[1]):
        m = box(d_x[:, k], d_y[:, k], 1.5, 1.9)
        img[:, 1] = np.where(m, 0.2, img[:, 1])
    colour = rng.uniform(0.0, 1.0, 3)
    mask = box(x, y, 1.5 if length < 6 else 3.0, width)  # (T, Hc, Wc)
    for c in range(3):
        img[:, c] = np.where(mask, 0.5 * colour[c] + 0.5 * (1.0, 0.2, 0.2)[c], img[:, c])
    return np.concatenate([np.clip(img, 0.0, 1.0), mask[:, None].astype(np.float32)], axis=1)


def collate_clips(items: list[dict[str, Any]]) -> dict[str, Any]:
    """Items → a batch as :func:`encoders.data.collate_clips` makes it: tensors stacked to (B, T, C, H, W),
    ``has_camera`` (B,) bool, lists for strings."""
    out: dict[str, Any] = {}
    for key, value in items[0].items():
        values = [it[key] for it in items]
        if isinstance(value, torch.Tensor):
            out[key] = torch.stack(values)
        elif isinstance(value, bool):
            out[key] = torch.tensor(values, dtype=torch.bool)
        else:
            out[key] = values
    return out


#: Small clips for the training tests: 4 frames, small views, no distractors.
SMALL_SPEC = SyntheticSpec(frames=4, camera_hw=(16, 16), bev_hw=(16, 8), distractors=0)
HOST_TAGS = ["cruising:heading_straight"]


class CaptionedClips(Dataset[dict[str, Any]]):
    """Synthetic clips (:data:`SMALL_SPEC`) captioned as a clips folder's: tags, host tags and captions,
    frame tags on some frames only (the dense targets), and a camera only where ``has_camera(index)``."""

    def __init__(self, size: int, has_camera: Callable[[int], bool], augment: bool = False) -> None:
        self.base = SyntheticClipDataset(size, "train", SMALL_SPEC, seed=1, augment=augment)
        self.has_camera = has_camera

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, index: int) -> dict[str, Any]:
        from encoders.dense import DENSE_TASKS
        from encoders.negatives import render_caption

        item, record = self.base[index], self.base.record(index)
        tags = [f"{lane}:{'away' if motion == 'recede' else motion}" for lane, motion in record["steps"]]
        caption = render_caption(record["category"], tags, HOST_TAGS)
        has_camera = self.has_camera(index)
        rng = np.random.default_rng([2, index])
        targets = np.stack([rng.integers(-1, len(c), SMALL_SPEC.frames) for c in DENSE_TASKS.values()], axis=1)
        return {**item, "category": record["category"], "tags": tags, "host_tags": HOST_TAGS,
                "canonical_caption": caption, "caption": caption, "has_camera": has_camera,
                "camera": item["camera"] if has_camera else torch.zeros_like(item["camera"]),
                "frame_targets": torch.as_tensor(targets, dtype=torch.int64)}

