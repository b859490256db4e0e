"""Previews of clips: an animated GIF per clip (camera and BEV side by side) and a still grid.

Layout of a preview frame (pixels, at the default sizes)::

    +----------------------+----------+
    | camera, object       |  BEV,    |
    | highlighted (×2)     |  forward |
    |                      |  up (×2) |
    +----------------------+          |
    | (grey when no view)  |          |
    +----------------------+----------+

BEV colours: drivable area dark grey, lane boundaries grey, crossings olive, intersections dark
blue, LiDAR (or box) occupancy above the lowest height bin white, the object of interest magenta, the ego green.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from common.atomic import atomic_path
from encoders.clips.config import ClipsConfig
from encoders.clips.layout import read_clip_rows, read_manifest
from encoders.clips.raster import MAP_CHANNELS
from encoders.clips.render import bev_grid
from encoders.clips.views import LogArrays, highlight_camera, object_footprint, open_log_arrays

SCALE = 2
GAP_PX = 4


def _config(clips_dir: Path) -> ClipsConfig:
    """The config the clips folder was built with (its manifest's ``config`` field)."""
    return ClipsConfig.from_dict(read_manifest(clips_dir).get("config", {}))


def render_preview_frames(arrays: LogArrays, clip: Mapping[str, Any], config: ClipsConfig) -> NDArray[np.uint8]:
    """(T, H, W, 3) uint8 RGB preview frames of one clip."""
    fi = np.asarray(clip["frame_indices"], dtype=np.int64)
    value = arrays.track_value[str(clip["track_id"])]
    cam = config.camera
    hc, wc = cam.height_px * SCALE, cam.width_px * SCALE
    t = fi.shape[0]
    if bool(clip["has_camera"]) and arrays.camera.shape[0]:
        mask = np.asarray(arrays.camera_instances[fi]) == value
        camera = highlight_camera(np.asarray(arrays.camera[fi]), mask, cam.highlight_rgb, cam.highlight_alpha,
                                  cam.dim_factor)
        camera = np.repeat(np.repeat(camera, SCALE, axis=1), SCALE, axis=2)
    else:
        camera = np.full((t, hc, wc, 3), 60, np.uint8)
    bev_map = np.asarray(arrays.bev_map[fi])  # (T, Cm, H, W)
    lidar = np.asarray(arrays.bev_lidar[fi])  # (T, Z, H, W)
    occ = (lidar[:, 1:] if lidar.shape[1] > 1 else lidar).max(axis=1)  # above the ground bin: (T, H, W)
    b = config.bev
    obj = object_footprint(arrays, bev_grid(config), str(clip["track_id"]), fi) > 0
    hb, wb = occ.shape[1:]
    bev = np.zeros((t, hb, wb, 3), np.uint8)

    def paint(mask: NDArray[np.bool_], color: tuple[int, int, int]) -> None:
        bev[mask] = color

    paint(bev_map[:, MAP_CHANNELS.index("drivable_area")] > 127, (45, 45, 45))
    paint(bev_map[:, MAP_CHANNELS.index("intersection")] > 127, (25, 35, 80))
    paint(bev_map[:, MAP_CHANNELS.index("crossing")] > 127, (90, 90, 30))
    paint(bev_map[:, MAP_CHANNELS.index("lane_boundary")] > 127, (110, 110, 110))
    level = occ.astype(np.uint16)
    lit = level > 0
    grey = np.clip(80 + level * 175 // 255, 0, 255).astype(np.uint8)
    bev[lit] = np.repeat(grey[lit][:, None], 3, axis=1)
    paint(obj, (255, 0, 255))
    # The ego at the origin: 4.5 m × 2 m, rear axle at the origin.
    r0 = int((b.x_max_m - 4.0) / b.resolution_m)
    r1 = int((b.x_max_m + 0.5) / b.resolution_m)
    c0 = int((b.y_max_m - 1.0) / b.resolution_m)
    c1 = int((b.y_max_m + 1.0) / b.resolution_m)
    bev[:, max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = (0, 220, 0)
    bev = np.repeat(np.repeat(bev, SCALE, axis=1), SCALE, axis=2)
    height = max(camera.shape[1], bev.shape[1])
    width = camera.shape[2] + GAP_PX + bev.shape[2]
    canvas = np.full((t, height, width, 3), 20, np.uint8)
    canvas[:, : camera.shape[1], : camera.shape[2]] = camera
    canvas[:, : bev.shape[1], camera.shape[2] + GAP_PX :] = bev
    return canvas


def write_preview(
    clips_dir: Path | str, clip: str | Mapping[str, Any], out_path: Path | str, config: ClipsConfig | None = None,
    arrays: LogArrays | None = None,
) -> Path:
    """Write an animated GIF of one clip (by id or by its clip-table row) atomically.

    ``arrays``: the clip's log, opened once by a caller that previews many of its clips (opening it
    reads its frames table and track ids: a third of a preview's time).
    """
    from PIL import Image

    clips_dir = Path(clips_dir)
    row = read_clip_rows(clips_dir, [clip])[0] if isinstance(clip, str) else clip
    config = config or _config(clips_dir)
    arrays = arrays if arrays is not None else open_log_arrays(clips_dir, str(row["log_id"]))
    frames = render_preview_frames(arrays, row, config)
    # One palette for the whole clip, from a mosaic of a few frames: much faster than a palette per frame.
    picks = np.unique(np.linspace(0, len(frames) - 1, 4).round().astype(int))
    palette = Image.fromarray(np.concatenate(frames[picks], axis=0)).quantize(
        colors=255, method=Image.Quantize.FASTOCTREE
    )
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    out_path = Path(out_path)
    duration_ms = round(1000.0 / max(config.preview_fps, 0.1))
    with atomic_path(out_path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=duration_ms, loop=0)
    return out_path


def best_frame(arrays: LogArrays, clip: Mapping[str, Any], config: ClipsConfig) -> int:
    """Index (0 … T − 1) of the sampled frame where the object is most visible: largest camera mask
    when the clip has a camera view, else largest BEV footprint."""
    fi = np.asarray(clip["frame_indices"], dtype=np.int64)
    value = arrays.track_value[str(clip["track_id"])]
    if bool(clip["has_camera"]) and arrays.camera.shape[0]:
        area = (np.asarray(arrays.camera_instances[fi]) == value).sum(axis=(1, 2))
    else:
        area = object_footprint(arrays, bev_grid(config), str(clip["track_id"]), fi).sum(axis=(1, 2))
    return int(np.argmax(area))


def write_preview_grid(
    clips_dir: Path | str, clip_ids: Sequence[str], out_path: Path | str, columns: int = 2,
    frame_fraction: float | None = None,
) -> Path:
    """A still PNG grid: one preview frame per clip, at ``frame_fraction`` of the clip or, when None,
    where the object is most visible (:func:`best_frame`)."""
    clips_dir = Path(clips_dir)
    config = _config(clips_dir)
    tiles = []
    logs: dict[str, LogArrays] = {}
    for row in read_clip_rows(clips_dir, clip_ids):
        if row["log_id"] not in logs:  # a grid often shows several clips of one log
            logs[row["log_id"]] = open_log_arrays(clips_dir, row["log_id"])
        arrays = logs[row["log_id"]]
        frames = render_preview_frames(arrays, row, config)
        if frame_fraction is None:
            tiles.append(frames[best_frame(arrays, row, config)])
        else:
            tiles.append(frames[min(int(frame_fraction * len(frames)), len(frames) - 1)])
    if not tiles:
        raise ValueError("no clips for the preview grid")
    h, w = tiles[0].shape[:2]
    rows_n = (len(tiles) + columns - 1) // columns
    grid = np.full((rows_n * (h + GAP_PX), columns * (w + GAP_PX), 3), 255, np.uint8)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, columns)
        grid[r * (h + GAP_PX) : r * (h + GAP_PX) + h, c * (w + GAP_PX) : c * (w + GAP_PX) + w] = tile
    out_path = Path(out_path)
    with atomic_path(out_path) as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    return out_path
