"""Render a log's per-frame arrays once; clips are cut from them lazily.

:func:`render_log` matches the log's sweeps and camera images to its frames (annotation
timestamps), renders the BEV (:mod:`encoders.clips.render_bev`) and camera
(:mod:`encoders.clips.render_camera`) arrays, and writes them with the frames table and the render
stats (:mod:`encoders.clips.render_stats`) into ``CLIPS_DIR/logs/<log_id>/`` (the files are listed
in :mod:`encoders.clips.layout`). The folder is written under a temporary name and renamed into
place when complete, so a reader never sees half a log.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from encoders.clips import layout
from encoders.clips.blocks import write_blocks
from encoders.clips.config import BevSource, BevSourceChoice, ClipsConfig
from encoders.clips.raster import MAP_CHANNELS
from encoders.clips.render_bev import (
    render_bev_instances,
    render_boxes_occupancy,
    render_lidar_occupancy,
    render_map,
    track_boxes,
)
from encoders.clips.render_camera import render_camera
from encoders.clips.render_stats import LogRenderStats, log_fingerprint, render_fingerprint
from scenes.bev import BevGrid
from scenes.geometry import FloatArray, quat_to_yaw, rotmat_to_quat
from scenes.log import Log
from scenes.tracks import DenseTracks
from scenesearch_base.atomic import atomic_directory, atomic_write_text
from scenesearch_base.checksums import file_checksums
from scenesearch_base.memory import check_memory


def lidar_channel_names(z_bins_m: tuple[float, ...]) -> list[str]:
    """Names of the occupancy channels, e.g. ``occupancy_z-0.5_0.3``."""
    return [f"occupancy_z{lo:g}_{hi:g}" for lo, hi in zip(z_bins_m[:-1], z_bins_m[1:])]


def bev_grid(config: ClipsConfig) -> BevGrid:
    b = config.bev
    return BevGrid(b.x_min_m, b.x_max_m, b.y_min_m, b.y_max_m, b.resolution_m)


def _save_blocks(folder: Path, name: str, array: NDArray[np.generic], image: bool = False) -> None:
    write_blocks(folder / name, array, image=image)  # by frames: a clips folder is mostly zeros and static map


def nearest_within(
    source_ns: NDArray[np.int64], query_ns: NDArray[np.int64], tolerance_ns: int
) -> NDArray[np.int64]:
    """For each query time, the index of the nearest source time within tolerance, else −1.

    Args:
        source_ns: (S,) increasing timestamps.
        query_ns: (Q,) timestamps.
        tolerance_ns: the largest allowed difference.

    Returns:
        (Q,) indices into ``source_ns`` or −1.
    """
    if source_ns.shape[0] == 0:
        return np.full(query_ns.shape[0], -1, dtype=np.int64)
    right = np.clip(np.searchsorted(source_ns, query_ns), 0, source_ns.shape[0] - 1)
    left = np.clip(right - 1, 0, source_ns.shape[0] - 1)
    pick = np.where(np.abs(source_ns[left] - query_ns) <= np.abs(source_ns[right] - query_ns), left, right)
    ok = np.abs(source_ns[pick] - query_ns) <= tolerance_ns
    return np.where(ok, pick, -1).astype(np.int64)


def _frames_table(
    frame_ts: NDArray[np.int64], city_SE3_ego: FloatArray, speed_mps: FloatArray,
    has_sweep: NDArray[np.bool_], has_camera_frame: NDArray[np.bool_],
) -> pa.Table:
    quat = rotmat_to_quat(city_SE3_ego[:, :3, :3]) if frame_ts.shape[0] else np.zeros((0, 4))
    trans = city_SE3_ego[:, :3, 3]
    return pa.table(
        {
            "frame_index": pa.array(np.arange(frame_ts.shape[0], dtype=np.int32)),
            "timestamp_ns": pa.array(frame_ts.astype(np.int64)),
            "qw": quat[:, 0], "qx": quat[:, 1], "qy": quat[:, 2], "qz": quat[:, 3],
            "tx_m": trans[:, 0], "ty_m": trans[:, 1], "tz_m": trans[:, 2],
            "x_m": trans[:, 0], "y_m": trans[:, 1],
            "yaw_rad": quat_to_yaw(quat) if frame_ts.shape[0] else np.zeros(0),
            "speed_mps": np.asarray(speed_mps, dtype=np.float64),
            "has_sweep": pa.array(has_sweep.astype(bool)),
            "has_camera_frame": pa.array(has_camera_frame.astype(bool)),
        }
    )


def render_bytes(config: ClipsConfig, frames: int, tracks: int) -> int:
    """About the memory rendering a log of ``frames`` frames and ``tracks`` tracks holds at its peak:
    every per-frame array at once (the table in :mod:`encoders.clips.layout`), crops counted for 16
    tracks in view per frame at most (a camera rarely sees more)."""
    grid = bev_grid(config)
    cam_px = config.camera.height_px * config.camera.width_px
    bev_px = grid.height * grid.width
    channels = len(config.bev.z_bins_m) - 1 + len(MAP_CHANNELS)
    per_frame = cam_px * (3 + 2) + bev_px * (channels + 2) + tracks * (4 + 4 + 12 + 20)
    crops = frames * min(tracks, 16) * cam_px * 4
    return int(frames * per_frame * 2 + crops)  # ×2: arrays are built, then copied into their files


def render_log(log: Log, config: ClipsConfig, clips_dir: Path, dense: DenseTracks | None = None) -> LogRenderStats:
    """Render one log's per-frame arrays into ``clips_dir/logs/<log_id>/`` (atomically).

    Corrupt sweeps and camera frames are skipped, counted and named in the returned stats.
    """
    start = time.perf_counter()
    dense = log.dense_tracks() if dense is None else dense
    grid = bev_grid(config)
    stats = LogRenderStats(log_id=log.log_id, fingerprint=render_fingerprint(config),
                           log_fingerprint=log_fingerprint(dense))
    frame_ts = dense.timestamps_ns
    f = frame_ts.shape[0]
    stats.frames, stats.tracks = f, int(dense.track_ids.shape[0])
    check_memory(render_bytes(config, f, stats.tracks), f"rendering log {log.log_id} ({f} frames, {stats.tracks} "
                 "tracks)", "camera.width_px / height_px or the BEV grid (bev.resolution_m, its extent, bev.z_bins_m)")
    city_SE3_ego = dense.city_SE3_ego
    speed = log.ego.interpolate(frame_ts).speed_mps() if f else np.zeros(0)

    # BEV occupancy: LiDAR when sweeps cover enough frames (or when asked), else from boxes.
    sweep_ts = log.lidar_timestamps_ns
    stats.sweeps = int(sweep_ts.shape[0])
    sweep_index = nearest_within(sweep_ts, frame_ts, config.bev.sweep_tolerance_ns)
    choice = config.bev.source
    coverage = float((sweep_index >= 0).mean()) if f else 0.0
    use_lidar = stats.sweeps > 0 and (
        choice == BevSourceChoice.LIDAR
        or (choice == BevSourceChoice.AUTO and coverage >= config.bev.lidar_min_coverage)
    )
    if use_lidar:
        bev_occ = render_lidar_occupancy(log, grid, config, frame_ts, city_SE3_ego, sweep_index, stats)
        stats.bev_source = BevSource.LIDAR.value
        stats.frames_without_sweep = int((sweep_index < 0).sum())
    else:
        bev_occ = render_boxes_occupancy(grid, dense, config.bev.z_bins_m)
        stats.bev_source = BevSource.BOXES.value
    stats.sweep_coverage = float((sweep_index >= 0).mean()) if f else 0.0
    bev_inst = render_bev_instances(grid, dense)
    bev_map = render_map(log, grid, city_SE3_ego)
    # Camera images matched to the frames like the sweeps; a log without the configured camera has none.
    cam = config.camera
    has_camera = cam.camera_name in log.camera_names()
    cam_ts = log.camera_timestamps_ns(cam.camera_name) if has_camera else np.zeros(0, np.int64)
    cam_index = nearest_within(cam_ts, frame_ts, cam.frame_tolerance_ns)
    camera = render_camera(log, config, dense, cam_ts, cam_index, stats)
    crop_rgb, crop_masks, crop_index, crop_box = camera.crops.arrays()

    target = layout.rendered_log_dir(clips_dir, log.log_id)
    with atomic_directory(target, overwrite=True) as tmp:
        _save_blocks(tmp, layout.CAMERA_FILE, camera.rgb, image=True)
        _save_blocks(tmp, layout.CAMERA_INSTANCES_FILE, camera.masks)
        _save_blocks(tmp, layout.CAMERA_PIXEL_COUNTS_FILE, camera.pixels)
        _save_blocks(tmp, layout.CAMERA_CROPS_FILE, crop_rgb, image=True)
        _save_blocks(tmp, layout.CAMERA_CROP_MASKS_FILE, crop_masks)
        _save_blocks(tmp, layout.CAMERA_CROP_INDEX_FILE, crop_index)
        _save_blocks(tmp, layout.CAMERA_CROP_BOX_FILE, crop_box)
        _save_blocks(tmp, layout.BEV_LIDAR_FILE, bev_occ)
        _save_blocks(tmp, layout.BEV_MAP_FILE, bev_map)
        _save_blocks(tmp, layout.BEV_INSTANCES_FILE, bev_inst)
        _save_blocks(tmp, layout.TRACK_BOXES_FILE, track_boxes(dense))
        atomic_write_text(tmp / layout.TRACK_IDS_FILE, json.dumps([str(t) for t in dense.track_ids]))
        pq.write_table(_frames_table(frame_ts, city_SE3_ego, speed, sweep_index >= 0, camera.frame_ok),
                       tmp / layout.FRAMES_FILE)
        stats.files = file_checksums(tmp, sorted(p.name for p in tmp.iterdir()))
        stats.bytes = int(sum(entry["size_bytes"] for entry in stats.files.values()))
        stats.render_s = round(time.perf_counter() - start, 3)
        atomic_write_text(tmp / layout.RENDER_FILE, json.dumps(stats.to_dict(), indent=2))
    return stats
