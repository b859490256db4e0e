"""Cut one clip's views out of its log's memory-mapped arrays (numpy only; no torch).

Used by the dataset (:mod:`encoders.data`) and by the preview writer.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from numpy.typing import NDArray

from encoders.clips.raster import BevGrid, rasterize_track
from encoders.clips.render import LOGS_DIR
from scenes.geometry import wrap_angle_rad


@dataclass(frozen=True)
class LogArrays:
    """A rendered log opened with ``mmap_mode='r'``; see :mod:`encoders.clips.render` for shapes.

    Attributes:
        track_value: track id → instance value (1 + index in ``track_ids.json``).
        pose_xy_yaw: (F, 3) ego x, y (city frame, metres) and yaw (radians) per frame.
        speed_mps: (F,) ego speed per frame.
    """

    camera: NDArray[np.uint8]
    camera_instances: NDArray[np.uint16]
    bev_lidar: NDArray[np.uint8]
    bev_map: NDArray[np.uint8]
    bev_instances: NDArray[np.uint16]
    track_boxes: NDArray[np.float32]
    track_value: dict[str, int]
    pose_xy_yaw: NDArray[np.float64]
    speed_mps: NDArray[np.float64]


def open_log_arrays(clips_dir: Path, log_id: str) -> LogArrays:
    folder = Path(clips_dir) / LOGS_DIR / log_id

    def load(name: str) -> NDArray[np.generic]:
        return np.load(folder / name, mmap_mode="r")

    ids = json.loads((folder / "track_ids.json").read_text())
    frames = pq.read_table(folder / "frames.parquet", columns=["x_m", "y_m", "yaw_rad", "speed_mps"])
    pose = np.stack([frames.column(c).to_numpy() for c in ("x_m", "y_m", "yaw_rad")], axis=1).astype(np.float64)
    return LogArrays(
        camera=load("camera.npy"),  # type: ignore[arg-type]
        camera_instances=load("camera_instances.npy"),  # type: ignore[arg-type]
        bev_lidar=load("bev_lidar.npy"),  # type: ignore[arg-type]
        bev_map=load("bev_map.npy"),  # type: ignore[arg-type]
        bev_instances=load("bev_instances.npy"),  # type: ignore[arg-type]
        track_boxes=load("track_boxes.npy"),  # type: ignore[arg-type]
        track_value={str(t): i + 1 for i, t in enumerate(ids)},
        pose_xy_yaw=pose,
        speed_mps=frames.column("speed_mps").to_numpy().astype(np.float64),
    )


def object_footprint(
    arrays: LogArrays, grid: BevGrid, track_id: str, indices: NDArray[np.integer]
) -> NDArray[np.uint8]:
    """(T, Hb, Wb) uint8: the object's box footprint in each sampled frame (1 inside)."""
    k = arrays.track_value[track_id] - 1
    return rasterize_track(grid, np.asarray(arrays.track_boxes[indices, k]))


def ego_motion(pose_xy_yaw: NDArray[np.float64], speed_mps: NDArray[np.float64],
               indices: NDArray[np.integer]) -> NDArray[np.float32]:
    """Each sampled frame's ego pose in the clip's first ego frame, and its speed.

    Args:
        pose_xy_yaw: (F, 3) city-frame ego x, y, yaw.
        speed_mps: (F,) ego speeds.
        indices: (T,) sampled frames.

    Returns:
        (T, 4) ``x_m, y_m, yaw_rad, speed_mps``; row 0 is ``(0, 0, 0, speed)``.
    """
    p = pose_xy_yaw[indices]
    d = p[:, :2] - p[0, :2]
    c, s = np.cos(p[0, 2]), np.sin(p[0, 2])
    x = c * d[:, 0] + s * d[:, 1]
    y = -s * d[:, 0] + c * d[:, 1]
    yaw = wrap_angle_rad(p[:, 2] - p[0, 2])
    return np.stack([x, y, yaw, speed_mps[indices]], axis=1).astype(np.float32)


def highlight_camera(
    rgb: NDArray[np.floating], mask: NDArray[np.bool_], color_rgb: tuple[int, int, int], alpha: float, dim: float
) -> NDArray[np.float32]:
    """Highlight the object of interest: blend a colour over it, dim the rest.

    Args:
        rgb: (T, H, W, 3) colours in [0, 1].
        mask: (T, H, W) the object's pixels.
        color_rgb: overlay colour, 0–255.
        alpha: overlay opacity.
        dim: brightness kept outside the object.

    Returns:
        (T, H, W, 3) float32 in [0, 1].
    """
    color = np.asarray(color_rgb, dtype=np.float32) / 255.0
    m = mask[..., None]
    out = np.where(m, (1.0 - alpha) * rgb + alpha * color, dim * rgb)
    return out.astype(np.float32)
