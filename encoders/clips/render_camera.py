"""The front camera of a log, one image per frame: resized RGB and instance masks (from the log's
masks, else from its boxes projected into the camera), every track's pixel count, and every seen
track's crop at full resolution (:mod:`encoders.clips.crops`)."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from encoders.clips.config import ClipsConfig
from encoders.clips.crops import ObjectCrops, crop_instances, crop_projected
from encoders.clips.render_stats import LogRenderStats
from scenes import av2_io
from scenes.errors import LogFormatError
from scenes.log import INSTANCE_SUFFIX, Log
from scenes.sensorsim.instance_masks import read_instance_mask, read_instance_track_ids
from scenes.tracks import DenseTracks


@dataclass(frozen=True)
class ProjectedMasks:
    """Instance masks from the boxes projected into the camera (logs with images but no masks).

    Attributes:
        masks: (F, Hc, Wc) uint16 instance values at the clips' camera size (near objects occlude far ones).
        pixels: (F, K) int32 each track's pixels in them, counted at the camera's full resolution.
        corners_uv_px: (K, F, 8, 2) each track's box corners in full-resolution pixels.
        in_front: (K, F) whether the whole box lies in front of the camera.
    """

    masks: NDArray[np.uint16]
    pixels: NDArray[np.int32]
    corners_uv_px: NDArray[np.float64]
    in_front: NDArray[np.bool_]


def project_masks(
    log: Log, config: ClipsConfig, dense: DenseTracks, frame_ok: NDArray[np.bool_]
) -> ProjectedMasks | None:
    """:class:`ProjectedMasks` of the frames ``frame_ok``, or None without calibration."""
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
        return ProjectedMasks(masks, counts, np.zeros((0, f, 8, 2)), np.zeros((0, f), bool))
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
    u = intr.fx_px * pts_cam[..., 0] / z + intr.cx_px
    v = intr.fy_px * pts_cam[..., 1] / z + intr.cy_px
    corners_uv_px = np.stack([u, v], axis=-1)  # (K, F, 8, 2) full resolution
    uv = corners_uv_px * np.array([small.width_px / intr.width_px, small.height_px / intr.height_px])
    scale_area = (intr.width_px / cam.width_px) * (intr.height_px / cam.height_px)
    mean_depth = depth.mean(axis=-1)
    for fi in np.flatnonzero(frame_ok):
        ks = np.flatnonzero(in_front[:, fi])
        for ki in ks[np.argsort(-mean_depth[ks, fi])]:  # far to near: near objects occlude
            hull = cv2.convexHull(np.round(uv[ki, fi] * 16).astype(np.int32))
            cv2.fillConvexPoly(masks[fi], hull, int(ki) + 1, lineType=cv2.LINE_8, shift=4)
        if ks.size:
            counts[fi] = np.bincount(masks[fi].ravel(), minlength=k + 1)[1:].astype(np.float64) * scale_area
    return ProjectedMasks(masks, counts, corners_uv_px, in_front)


@dataclass(frozen=True)
class RenderedCamera:
    """A log's camera arrays (:mod:`encoders.clips.layout`).

    Attributes:
        rgb: (F, Hc, Wc, 3) uint8 resized frames (F = 0 without images).
        masks: (F, Hc, Wc) uint16 instance masks (F = 0 without images).
        pixels: (F, K) int32 each track's pixels at the camera's full resolution.
        frame_ok: (F,) whether each frame has an image.
        crops: every seen track's crop (:class:`encoders.clips.crops.ObjectCrops`).
    """

    rgb: NDArray[np.uint8]
    masks: NDArray[np.uint16]
    pixels: NDArray[np.int32]
    frame_ok: NDArray[np.bool_]
    crops: ObjectCrops


def render_camera(
    log: Log, config: ClipsConfig, dense: DenseTracks, cam_ts: NDArray[np.int64], pick: NDArray[np.int64],
    stats: LogRenderStats,
) -> RenderedCamera:
    """Resize a log's camera images to the clips' size, with its instance masks and every track's crop.

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
    crops = ObjectCrops(f, k, cam.height_px, cam.width_px)
    if not (pick >= 0).any():
        return RenderedCamera(np.zeros((0, cam.height_px, cam.width_px, 3), np.uint8),
                              np.zeros((0, cam.height_px, cam.width_px), np.uint16), np.zeros((f, k), np.int32),
                              np.zeros(f, bool), crops)
    mask_dir = log.log_dir / av2_io.CAMERAS_DIR / f"{cam.camera_name}{INSTANCE_SUFFIX}"
    use_masks = mask_dir.is_dir()
    rgb = np.zeros((f, cam.height_px, cam.width_px, 3), np.uint8)
    masks = np.zeros((f, cam.height_px, cam.width_px), np.uint16)
    counts = np.zeros((f, k), np.int32)
    # Without instance masks the boxes are projected first (they need no image), so that each image is
    # cropped while it is read; a frame whose image turns out unreadable is cleared after (it has no crops).
    projected = None if use_masks else project_masks(log, config, dense, pick >= 0)
    frame_ok = np.zeros(f, dtype=bool)
    mask_track_ids: list[str] | None = None
    if use_masks:
        with contextlib.suppress(LogFormatError):  # a list that cannot be read: each frame's read names it
            mask_track_ids = read_instance_track_ids(log.log_dir)
    track_index = {str(t): i for i, t in enumerate(dense.track_ids)}
    # Mask value v ↔ mask_track_ids[v − 1] → this log's value 1 + index in track_ids (0: an id not among
    # them); the reader refuses values beyond the list, and ids listed twice.
    lut = np.array([0, *(track_index.get(t, -1) + 1 for t in mask_track_ids or ())], dtype=np.uint16)
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
        if projected is not None:
            crop_projected(crops, int(fi), bgr, projected.corners_uv_px[:, fi],
                           np.flatnonzero(projected.in_front[:, fi]), projected.pixels[fi])
        if not use_masks:
            continue
        try:
            full, _ = read_instance_mask(log.log_dir, cam.camera_name, ts, mask_track_ids)
        except LogFormatError:
            stats.corrupt_camera_frames.append(f"{cam.camera_name}{INSTANCE_SUFFIX}/{ts}.png")
            continue
        # Nearest-neighbour resizing picks pixels, so it commutes with the lookup: the small mask is remapped.
        small = np.asarray(cv2.resize(full, (cam.width_px, cam.height_px), interpolation=cv2.INTER_NEAREST),
                           dtype=np.uint16)
        masks[fi] = np.take(lut, small)  # several times faster than indexing ``lut[small]``
        counts[fi] = crop_instances(crops, int(fi), bgr, full, lut)
    stats.camera_frames = int(frame_ok.sum())
    stats.camera_frames_missing = int(f - frame_ok.sum())
    if use_masks:
        stats.camera_mask_source = "instance_masks"
    elif projected is not None:
        masks, counts = projected.masks, projected.pixels
        masks[~frame_ok] = 0
        counts[~frame_ok] = 0
        stats.camera_mask_source = "projected_boxes"
    return RenderedCamera(rgb, masks, counts, frame_ok, crops)
