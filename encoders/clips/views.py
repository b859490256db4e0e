"""Cut one clip's views out of its log's memory-mapped arrays (numpy only; no torch).

Used by the dataset (:mod:`encoders.data`) and by the preview writer.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
from numpy.typing import NDArray

from captioning.config import CaptioningConfig, SmoothingConfig
from captioning.host import planar_kinematics
from captioning.object_motion import TRACK_KINEMATICS_COLUMNS, track_kinematics
from encoders.clips import layout
from encoders.clips.blocks import FrameArray
from encoders.clips.raster import grid_affine_from, rasterize_track
from scenes.bev import BevGrid
from scenes.geometry import batch_matrices, wrap_angle_rad, yaw_to_rotmat


@dataclass(frozen=True)
class CropArrays:
    """A log's object crops (:mod:`encoders.clips.crops`), memory-mapped.

    Attributes:
        rgb: (N, Hc, Wc, 3) uint8 crops.
        mask: (N, Hc, Wc) uint8 the object's mask in each (1 = the object).
        index: (F, K) int32 each (frame, track)'s crop, −1 where none.
        box: (F, K, 3) float32 :data:`encoders.clips.crops.CROP_BOX_COLUMNS`.
    """

    rgb: NDArray[np.uint8]
    mask: NDArray[np.uint8]
    index: NDArray[np.int32]
    box: NDArray[np.float32]


@dataclass(frozen=True)
class LogArrays:
    """A rendered log opened with ``mmap_mode='r'``; see :mod:`encoders.clips.layout` for shapes.

    Attributes:
        track_value: track id → instance value (1 + index in ``track_ids.json``).
        pose_xy_yaw: (F, 3) ego x, y (city frame, metres) and yaw (radians) per frame.
        speed_mps: (F,) ego speed per frame.
        time_s: (F,) frame times since the log's first frame.
        accel_mps2: (F,) ego acceleration per frame, smoothed as the host rules smooth it.
        yaw_rate_rps: (F,) ego yaw rate per frame (positive = left), smoothed alike.
        crops: the object crops; None for a log rendered before crops were (no ``camera_crop_index.npy``).
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
    time_s: NDArray[np.float64]
    accel_mps2: NDArray[np.float64]
    yaw_rate_rps: NDArray[np.float64]
    crops: CropArrays | None = None


def open_log_arrays(clips_dir: Path, log_id: str) -> LogArrays:
    folder = layout.rendered_log_dir(clips_dir, log_id)

    def load(name: str) -> FrameArray:
        return layout.load_rendered_array(folder, name)

    ids = json.loads((folder / layout.TRACK_IDS_FILE).read_text())
    frames = pq.read_table(folder / layout.FRAMES_FILE, columns=["timestamp_ns", "x_m", "y_m", "yaw_rad", "speed_mps"])
    stamps_ns = frames.column("timestamp_ns").to_numpy()
    pose = np.stack([frames.column(c).to_numpy() for c in ("x_m", "y_m", "yaw_rad")], axis=1).astype(np.float64)
    time_s = ((stamps_ns - stamps_ns[0]) * 1e-9).astype(np.float64) if stamps_ns.size else np.zeros(0)
    accel_mps2, yaw_rate_rps = ego_rates(time_s, pose)
    return LogArrays(
        camera=load(layout.CAMERA_FILE),  # type: ignore[arg-type]
        camera_instances=load(layout.CAMERA_INSTANCES_FILE),  # type: ignore[arg-type]
        bev_lidar=load(layout.BEV_LIDAR_FILE),  # type: ignore[arg-type]
        bev_map=load(layout.BEV_MAP_FILE),  # type: ignore[arg-type]
        bev_instances=load(layout.BEV_INSTANCES_FILE),  # type: ignore[arg-type]
        track_boxes=load(layout.TRACK_BOXES_FILE),  # type: ignore[arg-type]
        track_value={str(t): i + 1 for i, t in enumerate(ids)},
        pose_xy_yaw=pose,
        speed_mps=frames.column("speed_mps").to_numpy().astype(np.float64),
        time_s=time_s,
        accel_mps2=accel_mps2,
        yaw_rate_rps=yaw_rate_rps,
        crops=CropArrays(load(layout.CAMERA_CROPS_FILE), load(layout.CAMERA_CROP_MASKS_FILE),  # type: ignore[arg-type]
                         load(layout.CAMERA_CROP_INDEX_FILE), load(layout.CAMERA_CROP_BOX_FILE))  # type: ignore[arg-type]
        if (folder / layout.CAMERA_CROP_INDEX_FILE).is_file() else None,
    )


def ego_rates(time_s: NDArray[np.float64], pose_xy_yaw: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                                                      NDArray[np.float64]]:
    """(F,) acceleration and (F,) yaw rate of the ego per log frame, as the host rules compute them.

    A clip's frames are too far apart, and a real log's odometry too noisy, for a model to
    difference the speed and the heading reliably: a small per-frame probe trained on simulated clips
    reads the ego's motion tag on real KITTI and AV2 logs right far more often with these than from the
    raw speed (``docs/research/ego-rates.md``). The Savitzky–Golay filter is the captioning default's
    (:class:`captioning.config.SmoothingConfig`); a log too short to differentiate gives zeros.
    """
    if time_s.shape[0] < 2:
        return np.zeros(time_s.shape[0]), np.zeros(time_s.shape[0])
    kin = planar_kinematics(time_s, pose_xy_yaw[:, :2], pose_xy_yaw[:, 2], SmoothingConfig())
    return np.nan_to_num(kin.accel_mps2), np.nan_to_num(kin.yaw_rate_rps)


#: What :func:`object_rates_and_velocity` gives per frame: the object's own motion over ground (the
#: batches' ``object_rates``), then its velocity relative to the ego in that frame's ego frame
#: (``object_velocity``).
OBJECT_RATES_COLUMNS = TRACK_KINEMATICS_COLUMNS[:3]
OBJECT_VELOCITY_COLUMNS = TRACK_KINEMATICS_COLUMNS[3:]


def object_rates_and_velocity(box_xy_lw_yaw: NDArray[np.floating], pose_xy_yaw: NDArray[np.float64],
                              time_s: NDArray[np.float64]) -> NDArray[np.float32]:
    """(F, 5) the object's own speed, acceleration and yaw rate over ground, then its velocity relative to the
    ego in each log frame's ego frame (:data:`OBJECT_RATES_COLUMNS`, :data:`OBJECT_VELOCITY_COLUMNS`), as the
    rules compute them (:func:`captioning.object_motion.track_kinematics`, the captioning default's
    filters); 0 where unknown (unobserved, or in a run too short for the rules).

    Braking, standing and turning are rates of the object's own motion: its ego-relative boxes,
    half a second apart at the clip's frames, leave the ego's motion in them to subtract and two
    differences to take. Given the rates, a temporal model trained on the demo's track inputs alone
    reads the action that the caption names right in clearly more of the test frames
    (``docs/research/object-rates.md``). Approach and away threshold the relative velocity: the rules'
    Savitzky–Golay derivative over the log's frames rather than a central difference of two
    neighbouring frames, whose noise near the threshold the model would otherwise have to learn
    (``docs/research/dense-weight.md``).

    Args:
        box_xy_lw_yaw: (F, 5) the object's box in each log frame's ego frame, NaN where unobserved.
        pose_xy_yaw: (F, 3) the ego's pose in the city frame.
        time_s: (F,) the log frames' times.
    """
    return log_rates_and_velocity(np.asarray(box_xy_lw_yaw)[:, None], pose_xy_yaw, time_s)[0]


def log_rates_and_velocity(track_boxes: NDArray[np.floating], pose_xy_yaw: NDArray[np.float64],
                           time_s: NDArray[np.float64]) -> NDArray[np.float32]:
    """(K, F, 5) :func:`object_rates_and_velocity` of every track of a log at once: the rules' kinematics
    run on all tracks in one vectorised pass, with the same values as track by track and at a fraction
    of the cost (a clip's loading reads them).

    Args:
        track_boxes: (F, K, 5) each track's box in each log frame's ego frame, NaN where unobserved
            (the clips folder's ``track_boxes``).
        pose_xy_yaw: (F, 3) the ego's pose in the city frame.
        time_s: (F,) the log frames' times.
    """
    boxes = np.asarray(track_boxes, dtype=np.float64).transpose(1, 0, 2)  # (K, F, 5)
    k, f = boxes.shape[:2]
    valid: NDArray[np.bool_] = np.asarray(np.isfinite(boxes).all(axis=2), dtype=bool)
    if f < 2 or not valid.any():
        return np.zeros((k, f, len(TRACK_KINEMATICS_COLUMNS)), np.float32)
    city_SE3_ego = batch_matrices(yaw_to_rotmat(pose_xy_yaw[:, 2]), np.c_[pose_xy_yaw[:, :2], np.zeros(f)])
    timestamps_ns = np.round((time_s - time_s[0]) * 1e9).astype(np.int64)
    boxes = np.nan_to_num(boxes)
    kin = track_kinematics(timestamps_ns, valid, boxes[..., :2], boxes[..., 4], city_SE3_ego, CaptioningConfig())
    return np.nan_to_num(kin).astype(np.float32)  # (K, F, 5)


def object_footprint(
    arrays: LogArrays, grid: BevGrid, track_id: str, indices: NDArray[np.integer]
) -> NDArray[np.uint8]:
    """(T, Hb, Wb) uint8: the object's box footprint in each sampled frame (1 inside)."""
    k = arrays.track_value[track_id] - 1
    return rasterize_track(grid, np.asarray(arrays.track_boxes[indices, k]))


def warp_source_cells(
    grid: BevGrid, theta_rad: float, shift_xy_m: NDArray[np.floating]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Where each cell of a BEV layer rotated by ``theta_rad`` about the ego origin, then shifted by
    ``shift_xy_m``, comes from: computed once per clip, applied to every layer by :func:`gather_cells`.

    A point at ego ``p`` moves to ``R(θ)·p + shift``; the nearest source cell is taken.

    Returns:
        ``source`` (H·W,) flat source cell of each destination cell (0 where it lies outside the
        grid), and ``outside`` (n,) the flat destination cells whose source lies outside (they get 0).
    """
    h, w = grid.shape
    # Destination cell at p' comes from p = R(−θ)(p' − shift): the source-from-destination pose.
    cos, sin = np.cos(theta_rad), np.sin(theta_rad)
    rot_inv = np.array([[cos, sin], [-sin, cos]])
    source_SE3_grid = np.eye(3)
    source_SE3_grid[:2, :2] = rot_inv
    source_SE3_grid[:2, 2] = -rot_inv @ np.asarray(shift_xy_m, dtype=np.float64)
    affine = grid_affine_from(grid, grid, source_SE3_grid)
    cols, rows = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    src_col = np.rint(affine[0, 0] * cols + affine[0, 1] * rows + affine[0, 2]).astype(np.int64)
    src_row = np.rint(affine[1, 0] * cols + affine[1, 1] * rows + affine[1, 2]).astype(np.int64)
    inside = (src_col >= 0) & (src_col < w) & (src_row >= 0) & (src_row < h)
    source = np.where(inside, src_row * w + src_col, 0).ravel()
    return source, np.flatnonzero(~inside.ravel())


def gather_cells(
    layers: NDArray[np.uint8], source: NDArray[np.int64], outside: NDArray[np.int64], out: NDArray[np.uint8]
) -> None:
    """Write ``layers`` (T, C, H, W) warped by :func:`warp_source_cells` into ``out`` (same shape,
    C-contiguous, e.g. a slot of a batch tensor): one gather for all planes, then the few cells
    that come from outside the grid are cleared."""
    t, c, h, w = layers.shape
    flat_out = out.reshape(t * c, h * w)  # a view: ``out`` is contiguous
    # mode="clip" skips the bounds check and lets numpy write straight into ``out`` (no buffer).
    np.take(np.ascontiguousarray(layers).reshape(t * c, h * w), source, axis=1, out=flat_out, mode="clip")
    if outside.size:
        flat_out[:, outside] = 0


#: The columns of :func:`ego_motion`, per frame.
EGO_MOTION_COLUMNS = ("x_m", "y_m", "yaw_rad", "speed_mps", "accel_mps2", "yaw_rate_rps")
EGO_MOTION_FEATURES = len(EGO_MOTION_COLUMNS)


def ego_motion(pose_xy_yaw: NDArray[np.float64], speed_mps: NDArray[np.float64], indices: NDArray[np.integer],
               accel_mps2: NDArray[np.float64], yaw_rate_rps: NDArray[np.float64]) -> NDArray[np.float32]:
    """Each sampled frame's ego pose in the clip's first ego frame, its speed, acceleration and yaw rate.

    Args:
        pose_xy_yaw: (F, 3) city-frame ego x, y, yaw.
        speed_mps: (F,) ego speeds.
        indices: (T,) sampled frames.
        accel_mps2, yaw_rate_rps: (F,) the smoothed rates of :func:`ego_rates`.

    Returns:
        (T, 6) ``x_m, y_m, yaw_rad, speed_mps, accel_mps2, yaw_rate_rps``; row 0 is ``(0, 0, 0, speed, …)``.
    """
    p = pose_xy_yaw[indices]
    d = p[:, :2] - p[0, :2]
    c, s = np.cos(p[0, 2]), np.sin(p[0, 2])
    x = c * d[:, 0] + s * d[:, 1]
    y = -s * d[:, 0] + c * d[:, 1]
    yaw = wrap_angle_rad(p[:, 2] - p[0, 2])
    return np.stack([x, y, yaw, speed_mps[indices], accel_mps2[indices], yaw_rate_rps[indices]],
                    axis=1).astype(np.float32)


#: Per-frame features of the object's own track (:func:`object_track`).
OBJECT_TRACK_FEATURES = 11
#: Metres and sizes brought to about unit range.
_TRACK_POSITION_SCALE_M = 50.0
_TRACK_SIZE_SCALE_M = 10.0


def object_track(box_xy_lw_yaw: NDArray[np.floating], ego: NDArray[np.floating]) -> NDArray[np.float32]:
    """The object's own track through a clip, as the temporal models read it.

    What an object does (approaches, moves away, changes lane, stands, brakes, turns) is a function of
    its box over time and of the ego's motion; the box is known for every clip (it is what the clip
    is cut around), so the track is given directly instead of being recovered from rasterised masks.

    Args:
        box_xy_lw_yaw: (T, 5) ``x_m, y_m, length_m, width_m, yaw_rad`` in each frame's ego frame, NaN
            where the object is unobserved.
        ego: (T, 6) :func:`ego_motion` of the same frames (pose in the clip's first ego frame first).

    Returns:
        (T, 11) float32: position and heading (cos, sin) relative to the ego, then position and heading
        in the clip's first ego frame (ground-fixed: the object's own motion), length, width, and an
        observed flag; zeros where unobserved. Positions / 50 m, sizes / 10 m.
    """
    box = np.asarray(box_xy_lw_yaw, dtype=np.float64)
    seen = np.asarray(np.isfinite(box).all(axis=1), dtype=bool)  # (T,)
    box = np.where(seen[:, None], box, 0.0)
    x, y, length, width, yaw = box.T
    ex, ey, eyaw = (np.asarray(ego, dtype=np.float64)[:, i] for i in range(3))
    c, s = np.cos(eyaw), np.sin(eyaw)
    fixed_x, fixed_y, fixed_yaw = ex + c * x - s * y, ey + s * x + c * y, eyaw + yaw  # first_ego_SE2_object
    p, z = _TRACK_POSITION_SCALE_M, _TRACK_SIZE_SCALE_M
    out = np.stack([x / p, y / p, np.cos(yaw), np.sin(yaw), fixed_x / p, fixed_y / p, np.cos(fixed_yaw),
                    np.sin(fixed_yaw), length / z, width / z, np.ones_like(x)], axis=1)
    return (out * seen[:, None]).astype(np.float32)


def rotate_object_track(track: NDArray[np.float32], theta_rad: float) -> None:
    """Rotate :func:`object_track` features in place by ``theta_rad`` about the ego, as the BEV
    augmentation rotates the rasters and the ego motion (positions and heading vectors alike)."""
    c, s = np.float32(np.cos(theta_rad)), np.float32(np.sin(theta_rad))
    rotation = np.array([[c, s], [-s, c]], dtype=np.float32)  # row vectors: (x, y) @ R turns by +theta
    for first in (0, 2, 4, 6):
        track[:, first:first + 2] = track[:, first:first + 2] @ rotation


#: Per frame of a clip, what the camera tower reads beside the crop: the crop's
#: :data:`encoders.clips.crops.CROP_BOX_COLUMNS`, then whether the object was seen.
CAMERA_BOX_FEATURES = 4


def object_crops(crops: CropArrays, track: int, indices: NDArray[np.integer], rgb_out: NDArray[np.uint8],
                 mask_out: NDArray[np.uint8], box_out: NDArray[np.float32]) -> None:
    """Write a clip's crops of one track: (T, Hc, Wc, 3) RGB and (T, Hc, Wc) masks (0 or 1), and its
    (T, :data:`CAMERA_BOX_FEATURES`) box features; zeros in the frames without a crop.

    Args:
        crops: the log's crops.
        track: the track's index (instance value − 1).
        indices: (T,) the clip's frames.
    """
    rows = np.asarray(crops.index[indices, track])  # (T,)
    seen = rows >= 0
    rgb_out.fill(0)
    mask_out.fill(0)
    box_out.fill(0.0)
    if not seen.any():
        return
    rgb_out[seen] = crops.rgb[rows[seen]]
    mask_out[seen] = crops.mask[rows[seen]]
    box_out[:, :-1] = crops.box[indices, track]
    box_out[:, -1] = seen


def highlight_camera(
    rgb: NDArray[np.uint8], mask: NDArray[np.bool_], color_rgb: tuple[int, int, int], alpha: float, dim: float
) -> NDArray[np.uint8]:
    """Highlight the object of interest: blend a colour over it, dim the rest.

    Args:
        rgb: (T, H, W, 3) uint8 colours.
        mask: (T, H, W) the object's pixels.
        color_rgb: overlay colour, 0–255.
        alpha: overlay opacity.
        dim: brightness kept outside the object.

    Returns:
        (T, H, W, 3) uint8.
    """
    t, h, w, _ = rgb.shape
    flat = np.ascontiguousarray(rgb).reshape(t * h, w, 3)  # frames stacked into one image for OpenCV
    color = np.empty_like(flat)
    color[:] = np.asarray(color_rgb, dtype=np.uint8)
    blended = cv2.addWeighted(flat, 1.0 - alpha, color, alpha, 0.0)
    out = cv2.convertScaleAbs(flat, alpha=dim)
    cv2.copyTo(blended, np.ascontiguousarray(mask, dtype=np.uint8).reshape(t * h, w), out)
    return np.asarray(out, dtype=np.uint8).reshape(t, h, w, 3)
