"""Render a log's per-frame arrays once; clips are cut from them lazily.

For a log with F frames (its annotation timestamps), ``render_log`` writes into
``CLIPS_DIR/logs/<log_id>/``:

======================  =====================  ===========================================================
file                    shape, dtype           content
======================  =====================  ===========================================================
camera.npy              (F, Hc, Wc, 3) uint8   front camera RGB, resized (F = 0 when the log has no camera)
camera_instances.npy    (F, Hc, Wc) uint16     instance masks: v ≥ 1 ↔ ``track_ids[v − 1]``, 0 = none
camera_pixel_counts.npy (F, K) int32           mask pixels of every track at the camera's full resolution
bev_lidar.npy           (F, Z, Hb, Wb) uint8   occupancy per height bin (log-scaled point density)
bev_map.npy             (F, Cm, Hb, Wb) uint8  map layers (:data:`~encoders.clips.raster.MAP_CHANNELS`)
bev_instances.npy       (F, Hb, Wb) uint16     box footprints: v ≥ 1 ↔ ``track_ids[v − 1]`` (overlaps: the
                                               smaller box wins)
track_boxes.npy         (F, K, 5) float32      every track's ``x_m, y_m, length_m, width_m, yaw_rad`` in
                                               the frame's ego frame, NaN when not observed; the dataset
                                               draws the object of interest from it (never hidden by
                                               an overlapping box)
track_ids.json          list[str]              K track ids
frames.parquet          F rows                 frame_index, timestamp_ns, city_SE3_ego (qw..tz_m), x_m, y_m,
                                               yaw_rad, speed_mps, has_sweep, has_camera_frame
render.json             dict                   stats and the rendering config's fingerprint
======================  =====================  ===========================================================

Every BEV grid is in its own frame's ego frame; ego motion is recoverable from ``frames.parquet``.
The folder is written under a temporary name and renamed into place when complete, so a reader
never sees half a log.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from common.atomic import atomic_directory, atomic_write_text
from encoders.clips.config import BevSource, BevSourceChoice, ClipsConfig
from encoders.clips.raster import MAP_CHANNELS, density_uint8, render_map_frames
from scenes import av2_io
from scenes.bev import BevGrid, lidar_occupancy, rasterize_boxes
from scenes.errors import LogFormatError
from scenes.geometry import FloatArray, invert_matrices, quat_to_yaw, rotmat_to_quat
from scenes.log import INSTANCE_SUFFIX, Log
from scenes.sensorsim.instance_masks import read_instance_mask
from scenes.tracks import DenseTracks

#: Folder of rendered logs inside CLIPS_DIR.
LOGS_DIR = "logs"
#: Version of the per-log files; bump when their content changes.
RENDER_VERSION = 4


def lidar_channel_names(z_bins_m: tuple[float, ...]) -> list[str]:
    """Names of the occupancy channels, e.g. ``occupancy_z-0.5_0.3``."""
    return [f"occupancy_z{lo:g}_{hi:g}" for lo, hi in zip(z_bins_m[:-1], z_bins_m[1:])]


def bev_grid(config: ClipsConfig) -> BevGrid:
    b = config.bev
    return BevGrid(b.x_min_m, b.x_max_m, b.y_min_m, b.y_max_m, b.resolution_m)


def render_fingerprint(config: ClipsConfig) -> str:
    """Hash of everything that changes the per-log arrays (not splits, previews or clip sampling)."""
    payload = {"version": RENDER_VERSION, "camera": asdict(config.camera), "bev": config.to_dict()["bev"]}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:16]


def log_fingerprint(dense: DenseTracks) -> str:
    """Hash of a log's content as rendering sees it: frame times, track ids, boxes and ego poses.

    A log written again into the same folder (e.g. simulated anew) gets a new fingerprint, so its
    old rendering is never reused.
    """
    h = hashlib.sha256()
    for array in (dense.timestamps_ns, dense.valid, dense.center_city_xyz_m, dense.size_lwh_m, dense.city_SE3_ego):
        h.update(np.ascontiguousarray(array).tobytes())
    h.update("\0".join(map(str, dense.track_ids)).encode())
    return h.hexdigest()[:16]


@dataclass
class LogRenderStats:
    """What rendering one log did; kept in ``render.json`` and the manifest.

    Attributes:
        log_id: the log.
        frames: F.
        tracks: K.
        bev_source: ``lidar`` or ``boxes``.
        sweeps: sweeps on disk.
        sweep_coverage: fraction of frames with a usable sweep within tolerance.
        corrupt_sweeps: file names of sweeps that could not be read (skipped).
        frames_without_sweep: frames whose BEV occupancy is empty because no usable sweep was near
            (only for ``lidar`` logs).
        camera_frames: frames with a camera image.
        camera_frames_missing: frames without one (black, no masks) when the log has a camera.
        camera_mask_source: ``instance_masks``, ``projected_boxes`` or ``none``.
        corrupt_camera_frames: file names of images or masks that could not be decoded (skipped).
        bytes: disk used by the log's arrays.
        render_s: wall time.
        fingerprint: :func:`render_fingerprint` of the config used.
        log_fingerprint: :func:`log_fingerprint` of the log rendered.
    """

    log_id: str
    frames: int = 0
    tracks: int = 0
    bev_source: str = BevSource.BOXES.value
    sweeps: int = 0
    sweep_coverage: float = 0.0
    corrupt_sweeps: list[str] = field(default_factory=list)
    frames_without_sweep: int = 0
    camera_frames: int = 0
    camera_frames_missing: int = 0
    camera_mask_source: str = "none"
    corrupt_camera_frames: list[str] = field(default_factory=list)
    bytes: int = 0
    render_s: float = 0.0
    fingerprint: str = ""
    log_fingerprint: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _save_npy(folder: Path, name: str, array: NDArray[np.generic]) -> None:
    np.save(folder / name, np.ascontiguousarray(array), allow_pickle=False)


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


# ---------------------------------------------------------------------------------------------
# BEV


def _render_bev_instances(grid: BevGrid, dense: DenseTracks) -> NDArray[np.uint16]:
    """(F, Hb, Wb) footprints of every valid box; larger boxes are drawn first so small ones stay visible."""
    f = dense.valid.shape[1]
    out = np.zeros((f, *grid.shape), dtype=np.uint16)
    area = np.nan_to_num(dense.size_lwh_m[..., 0] * dense.size_lwh_m[..., 1])  # (K, F)
    for fi in range(f):
        ks = np.flatnonzero(dense.valid[:, fi])
        if ks.size == 0:
            continue
        ks = ks[np.argsort(-area[ks, fi], kind="stable")]  # later boxes win where they overlap
        out[fi] = rasterize_boxes(grid, dense.center_ego_xyz_m[ks, fi, :2], dense.size_lwh_m[ks, fi, :2],
                                  dense.yaw_ego_rad[ks, fi], values=(ks + 1).astype(np.float64))
    return out


def _track_boxes(dense: DenseTracks) -> NDArray[np.float32]:
    """(F, K, 5) ``x, y, length, width, yaw`` of every track in each frame's ego frame, NaN when unobserved."""
    boxes = np.concatenate(
        [dense.center_ego_xyz_m[..., :2], dense.size_lwh_m[..., :2], dense.yaw_ego_rad[..., None]], axis=-1
    )  # (K, F, 5)
    boxes[~dense.valid] = np.nan
    return np.ascontiguousarray(np.swapaxes(boxes, 0, 1)).astype(np.float32)


def _render_bev_boxes_occupancy(
    grid: BevGrid, dense: DenseTracks, z_bins_m: tuple[float, ...]
) -> NDArray[np.uint8]:
    """(F, Z, Hb, Wb) occupancy rendered from the boxes: a box fills the height bins it spans (255)."""
    k, f = dense.valid.shape
    z_edges = np.asarray(z_bins_m)
    num_z = z_edges.shape[0] - 1
    out = np.zeros((f, num_z, *grid.shape), dtype=np.uint8)
    if k == 0:
        return out
    bottom = dense.center_ego_xyz_m[..., 2] - 0.5 * dense.size_lwh_m[..., 2]  # (K, F)
    top = dense.center_ego_xyz_m[..., 2] + 0.5 * dense.size_lwh_m[..., 2]
    spans = (bottom[..., None] < z_edges[None, None, 1:]) & (top[..., None] > z_edges[None, None, :-1])  # (K,F,Z)
    spans &= dense.valid[..., None]
    for fi in range(f):
        for zi in range(num_z):
            ks = np.flatnonzero(spans[:, fi, zi])
            if ks.size:
                filled = rasterize_boxes(grid, dense.center_ego_xyz_m[ks, fi, :2], dense.size_lwh_m[ks, fi, :2],
                                         dense.yaw_ego_rad[ks, fi])
                out[fi, zi] = (filled > 0) * np.uint8(255)
    return out


def _render_bev_lidar(
    log: Log, grid: BevGrid, config: ClipsConfig, frame_ts: NDArray[np.int64], city_SE3_ego: FloatArray,
    sweep_index: NDArray[np.int64], stats: LogRenderStats,
) -> NDArray[np.uint8]:
    """(F, Z, Hb, Wb) occupancy from the nearest sweep and the previous ones, motion-compensated.

    Each sweep is read once; sweep points are moved into the frame's ego frame by
    ``ego_SE3_city(frame) · city_SE3_ego(sweep)`` (ego poses interpolated at the sweep times).
    """
    b = config.bev
    sweep_ts = log.lidar_timestamps_ns
    num_z = len(b.z_bins_m) - 1
    out = np.zeros((frame_ts.shape[0], num_z, *grid.shape), dtype=np.uint8)
    if sweep_ts.shape[0] == 0:
        return out
    city_SE3_sweep = log.ego.interpolate(sweep_ts).matrices  # (S, 4, 4)
    ego_SE3_city = invert_matrices(city_SE3_ego)  # (F, 4, 4)
    reach = max(abs(b.x_min_m), abs(b.x_max_m), abs(b.y_min_m), abs(b.y_max_m)) + 30.0
    cache: dict[int, NDArray[np.float32] | None] = {}

    def points(j: int) -> NDArray[np.float32] | None:
        if j not in cache:
            try:
                xyz = log.lidar_sweep(int(sweep_ts[j])).xyz_m
            except LogFormatError as exc:
                stats.corrupt_sweeps.append(f"{int(sweep_ts[j])}.feather: {exc.problems[0].message}")
                cache[j] = None
                return None
            keep = (np.abs(xyz[:, 0]) < reach) & (np.abs(xyz[:, 1]) < reach)
            keep &= (xyz[:, 2] >= b.z_bins_m[0]) & (xyz[:, 2] < b.z_bins_m[-1] + 5.0)
            cache[j] = xyz[keep]
        return cache[j]

    for fi in range(frame_ts.shape[0]):
        j = int(sweep_index[fi])
        if j < 0:
            continue
        if points(j) is None:  # the frame's own sweep is corrupt: skip the frame
            sweep_index[fi] = -1
            continue
        parts = []
        for jj in range(j, max(j - b.num_sweeps, -1), -1):
            pts = points(jj)
            if pts is None:
                continue
            m = ego_SE3_city[fi] @ city_SE3_sweep[jj]
            parts.append(pts @ m[:3, :3].T.astype(np.float32) + m[:3, 3].astype(np.float32))
        for stale in [key for key in cache if key < j - b.num_sweeps]:
            del cache[stale]
        counts = lidar_occupancy(grid, np.concatenate(parts, axis=0), np.asarray(b.z_bins_m))
        out[fi] = density_uint8(counts, b.density_saturation_points)
    return out


def _render_map(log: Log, grid: BevGrid, city_SE3_ego: FloatArray) -> NDArray[np.uint8]:
    vector_map = log.map
    if vector_map is None or city_SE3_ego.shape[0] == 0:
        return np.zeros((city_SE3_ego.shape[0], len(MAP_CHANNELS), *grid.shape), dtype=np.uint8)
    return render_map_frames(vector_map, grid, city_SE3_ego)


# ---------------------------------------------------------------------------------------------
# Camera


def _project_masks(
    log: Log, config: ClipsConfig, dense: DenseTracks, frame_ok: NDArray[np.bool_]
) -> tuple[NDArray[np.uint16], NDArray[np.int32]] | None:
    """Instance masks from the boxes projected into the camera (logs with images but no masks).

    Returns (F, Hc, Wc) masks and (F, K) full-resolution pixel counts, or None without calibration.
    """
    cam = config.camera
    calib = log.calibration
    if cam.camera_name not in calib.intrinsics or cam.camera_name not in calib.ego_SE3_sensor:
        return None
    intr = calib.intrinsics[cam.camera_name]
    small = intr.scaled(cam.width_px, cam.height_px)
    cam_SE3_ego = calib.ego_SE3_sensor[cam.camera_name].inverse()
    k, f = dense.valid.shape
    masks = np.zeros((f, cam.height_px, cam.width_px), dtype=np.uint16)
    counts = np.zeros((f, k), dtype=np.int32)
    if k == 0:
        return masks, counts
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    half = 0.5 * np.nan_to_num(dense.size_lwh_m)  # (K, F, 3)
    yaw = np.nan_to_num(dense.yaw_ego_rad)
    local = signs[None, None] * half[:, :, None, :]  # (K, F, 8, 3)
    cos, sin = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    ego = np.stack(
        [cos * local[..., 0] - sin * local[..., 1], sin * local[..., 0] + cos * local[..., 1], local[..., 2]], axis=-1
    ) + np.nan_to_num(dense.center_ego_xyz_m)[:, :, None, :]
    pts_cam = ego @ cam_SE3_ego.rotation.T + cam_SE3_ego.translation  # (K, F, 8, 3)
    depth = pts_cam[..., 2]
    in_front = (depth > 0.5).all(axis=-1) & dense.valid  # (K, F)
    z = np.where(depth > 0.5, depth, 1.0)
    u = small.fx_px * pts_cam[..., 0] / z + small.cx_px
    v = small.fy_px * pts_cam[..., 1] / z + small.cy_px
    uv = np.stack([u, v], axis=-1)
    scale_area = (intr.width_px / cam.width_px) * (intr.height_px / cam.height_px)
    mean_depth = depth.mean(axis=-1)
    for fi in np.flatnonzero(frame_ok):
        ks = np.flatnonzero(in_front[:, fi])
        for ki in ks[np.argsort(-mean_depth[ks, fi])]:  # far to near: near objects occlude
            hull = cv2.convexHull(np.round(uv[ki, fi] * 16).astype(np.int32))
            cv2.fillConvexPoly(masks[fi], hull, int(ki) + 1, lineType=cv2.LINE_8, shift=4)
        if ks.size:
            counts[fi] = np.bincount(masks[fi].ravel(), minlength=k + 1)[1:].astype(np.float64) * scale_area
    return masks, counts


def _render_camera(
    log: Log, config: ClipsConfig, dense: DenseTracks, stats: LogRenderStats
) -> tuple[NDArray[np.uint8], NDArray[np.uint16], NDArray[np.int32], NDArray[np.bool_]]:
    """Resized RGB frames (F or 0 of them), instance masks, full-resolution pixel counts (F, K), and
    (F,) whether each frame has an image."""
    cam = config.camera
    frame_ts = dense.timestamps_ns
    k, f = dense.valid.shape
    empty = (
        np.zeros((0, cam.height_px, cam.width_px, 3), np.uint8),
        np.zeros((0, cam.height_px, cam.width_px), np.uint16),
        np.zeros((f, k), np.int32),
        np.zeros(f, bool),
    )
    if cam.camera_name not in log.camera_names():
        return empty
    cam_ts = log.camera_timestamps_ns(cam.camera_name)
    pick = nearest_within(cam_ts, frame_ts, cam.frame_tolerance_ns)
    if not (pick >= 0).any():
        return empty
    mask_dir = log.log_dir / av2_io.CAMERAS_DIR / f"{cam.camera_name}{INSTANCE_SUFFIX}"
    use_masks = mask_dir.is_dir()
    rgb = np.zeros((f, cam.height_px, cam.width_px, 3), np.uint8)
    masks = np.zeros((f, cam.height_px, cam.width_px), np.uint16)
    counts = np.zeros((f, k), np.int32)
    frame_ok = np.zeros(f, dtype=bool)
    track_index = {str(t): i for i, t in enumerate(dense.track_ids)}
    lut: NDArray[np.uint16] | None = None
    lut_ids: list[str] | None = None
    for fi in np.flatnonzero(pick >= 0):
        ts = int(cam_ts[pick[fi]])
        try:
            bgr = log.camera_frame(cam.camera_name, ts)
        except LogFormatError:
            stats.corrupt_camera_frames.append(f"{cam.camera_name}/{ts}.jpg")
            continue
        rgb[fi] = cv2.cvtColor(cv2.resize(bgr, (cam.width_px, cam.height_px), interpolation=cv2.INTER_AREA),
                               cv2.COLOR_BGR2RGB)
        frame_ok[fi] = True
        if not use_masks:
            continue
        try:
            full, ids = read_instance_mask(log.log_dir, cam.camera_name, ts)
        except LogFormatError:
            stats.corrupt_camera_frames.append(f"{cam.camera_name}{INSTANCE_SUFFIX}/{ts}.png")
            continue
        if lut is None or ids != lut_ids:
            # Mask value v ↔ ids[v − 1] → this log's value 1 + index in track_ids (0 = unknown id).
            lut = np.zeros(max(int(full.max()), len(ids)) + 1, dtype=np.uint16)
            lut[1 : len(ids) + 1] = [track_index.get(t, -1) + 1 for t in ids]
            lut_ids = ids
        if full.max() >= lut.shape[0]:
            lut = np.concatenate([lut, np.zeros(int(full.max()) + 1 - lut.shape[0], np.uint16)])
        remapped = lut[full]
        counts[fi] = np.bincount(remapped.ravel(), minlength=k + 1)[1 : k + 1]
        masks[fi] = cv2.resize(remapped, (cam.width_px, cam.height_px), interpolation=cv2.INTER_NEAREST)
    stats.camera_frames = int(frame_ok.sum())
    stats.camera_frames_missing = int(f - frame_ok.sum())
    if use_masks:
        stats.camera_mask_source = "instance_masks"
    else:
        projected = _project_masks(log, config, dense, frame_ok)
        if projected is not None:
            masks, counts = projected
            stats.camera_mask_source = "projected_boxes"
    return rgb, masks, counts, frame_ok


# ---------------------------------------------------------------------------------------------
# Frames table and the whole log


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


def rendered_log_ok(folder: Path, config: ClipsConfig, dense: DenseTracks) -> bool:
    """Whether ``folder`` holds a complete rendering of this log's content (``dense``) made with an
    equivalent config."""
    path = folder / "render.json"
    if not path.is_file():
        return False
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return False
    return bool(data.get("fingerprint") == render_fingerprint(config)
                and data.get("log_fingerprint") == log_fingerprint(dense))


def read_render_stats(folder: Path) -> LogRenderStats:
    data = json.loads((folder / "render.json").read_text())
    return LogRenderStats(**{k: v for k, v in data.items() if k in LogRenderStats.__dataclass_fields__})


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
        bev_occ = _render_bev_lidar(log, grid, config, frame_ts, city_SE3_ego, sweep_index, stats)
        stats.bev_source = BevSource.LIDAR.value
        stats.frames_without_sweep = int((sweep_index < 0).sum())
    else:
        bev_occ = _render_bev_boxes_occupancy(grid, dense, config.bev.z_bins_m)
        stats.bev_source = BevSource.BOXES.value
    stats.sweep_coverage = float((sweep_index >= 0).mean()) if f else 0.0
    bev_inst = _render_bev_instances(grid, dense)
    bev_map = _render_map(log, grid, city_SE3_ego)
    camera, camera_inst, pixel_counts, has_cam_frame = _render_camera(log, config, dense, stats)

    target = clips_dir / LOGS_DIR / log.log_id
    with atomic_directory(target, overwrite=True) as tmp:
        _save_npy(tmp, "camera.npy", camera)
        _save_npy(tmp, "camera_instances.npy", camera_inst)
        _save_npy(tmp, "camera_pixel_counts.npy", pixel_counts)
        _save_npy(tmp, "bev_lidar.npy", bev_occ)
        _save_npy(tmp, "bev_map.npy", bev_map)
        _save_npy(tmp, "bev_instances.npy", bev_inst)
        _save_npy(tmp, "track_boxes.npy", _track_boxes(dense))
        atomic_write_text(tmp / "track_ids.json", json.dumps([str(t) for t in dense.track_ids]))
        pq.write_table(_frames_table(frame_ts, city_SE3_ego, speed, sweep_index >= 0, has_cam_frame),
                       tmp / "frames.parquet")
        stats.bytes = int(sum(p.stat().st_size for p in tmp.iterdir()))
        stats.render_s = round(time.perf_counter() - start, 3)
        atomic_write_text(tmp / "render.json", json.dumps(stats.to_dict(), indent=2))
    return stats
