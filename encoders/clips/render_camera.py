"""The front camera of a log, one image per frame: resized RGB and instance masks (from the log's
masks, else from its boxes projected into the camera), and every track's pixel count."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from encoders.clips.config import ClipsConfig
from encoders.clips.render_stats import LogRenderStats
from scenes import av2_io
from scenes.errors import LogFormatError
from scenes.log import INSTANCE_SUFFIX, Log
from scenes.sensorsim.instance_masks import read_instance_mask
from scenes.tracks import DenseTracks


def project_masks(
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


def render_camera(
    log: Log, config: ClipsConfig, dense: DenseTracks, cam_ts: NDArray[np.int64], pick: NDArray[np.int64],
    stats: LogRenderStats,
) -> tuple[NDArray[np.uint8], NDArray[np.uint16], NDArray[np.int32], NDArray[np.bool_]]:
    """Resized RGB frames (F or 0 of them), instance masks, full-resolution pixel counts (F, K), and
    (F,) whether each frame has an image.

    Args:
        log: the log.
        config: the clips config (camera name and sizes).
        dense: the log's tracks on its F frames.
        cam_ts: (S,) the configured camera's image timestamps (empty without that camera).
        pick: (F,) each frame's image, an index into ``cam_ts``, or −1 when none is near enough.
        stats: receives the image counts and the names of corrupt files.
    """
    cam = config.camera
    k, f = dense.valid.shape
    empty = (
        np.zeros((0, cam.height_px, cam.width_px, 3), np.uint8),
        np.zeros((0, cam.height_px, cam.width_px), np.uint16),
        np.zeros((f, k), np.int32),
        np.zeros(f, bool),
    )
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
        projected = project_masks(log, config, dense, frame_ok)
        if projected is not None:
            masks, counts = projected
            stats.camera_mask_source = "projected_boxes"
    return rgb, masks, counts, frame_ok

