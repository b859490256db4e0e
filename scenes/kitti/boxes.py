"""KITTI boxes (rectified camera frame, bottom centre, ``rotation_y``) to AV2 ego-frame boxes and back.

The derivation is in :mod:`scenes.kitti`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from scenes.geometry import SE3, FloatArray, quat_to_rotmat, rotmat_to_quat, wrap_angle_rad

# Columns of the AV2 object frame (x length, y left, z up) written in KITTI object axes.
_KOBJ_R_OBJ = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _rot_y(angle_rad: FloatArray) -> FloatArray:
    """(N, 3, 3) the KITTI devkit's rotations about the camera y axis. ``angle_rad``: (N,)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    rot = np.zeros((angle_rad.shape[0], 3, 3))
    rot[:, 0, 0] = c
    rot[:, 0, 2] = s
    rot[:, 1, 1] = 1.0
    rot[:, 2, 0] = -s
    rot[:, 2, 2] = c
    return rot


def _center_to_bottom_cam(height_m: NDArray[np.floating]) -> FloatArray:
    """(N, 3) from a box's centre to its bottom centre in the camera frame: half the height along +y,
    because the camera's y axis points down. ``height_m``: (N,)."""
    h = np.asarray(height_m, dtype=np.float64).reshape(-1)
    return np.stack([np.zeros_like(h), h / 2.0, np.zeros_like(h)], axis=1)


def kitti_boxes_to_ego(
    bottom_center_cam_xyz_m: NDArray[np.floating],
    height_m: NDArray[np.floating],
    rotation_y_rad: NDArray[np.floating],
    ego_SE3_cam: SE3,
) -> tuple[FloatArray, FloatArray]:
    """KITTI camera-frame boxes → AV2 ego-frame box poses (see the module docstring).

    Args:
        bottom_center_cam_xyz_m: (N, 3) bottom centres in the rectified camera frame.
        height_m: (N,) box heights.
        rotation_y_rad: (N,) KITTI ``rotation_y``.
        ego_SE3_cam: rectified camera → ego.

    Returns:
        (N, 3) box centres and (N, 4) orientations ``ego_SE3_object`` (scalar-first quaternions).
    """
    bottom = np.asarray(bottom_center_cam_xyz_m, dtype=np.float64).reshape(-1, 3)
    ry = np.asarray(rotation_y_rad, dtype=np.float64).reshape(-1)
    center_cam = bottom - _center_to_bottom_cam(height_m)
    center_ego = ego_SE3_cam.transform_points(center_cam)
    ego_R_obj = np.einsum("ij,njk,kl->nil", ego_SE3_cam.rotation, _rot_y(ry), _KOBJ_R_OBJ)
    return center_ego, rotmat_to_quat(ego_R_obj)


def ego_boxes_to_kitti(
    center_ego_xyz_m: NDArray[np.floating],
    height_m: NDArray[np.floating],
    quat_wxyz: NDArray[np.floating],
    ego_SE3_cam: SE3,
) -> tuple[FloatArray, FloatArray]:
    """Inverse of :func:`kitti_boxes_to_ego` for boxes upright in the camera frame.

    Args:
        center_ego_xyz_m: (N, 3) box centres in the ego frame.
        height_m: (N,) box heights.
        quat_wxyz: (N, 4) orientations ``ego_SE3_object``.
        ego_SE3_cam: rectified camera → ego.

    Returns:
        (N, 3) bottom centres in the rectified camera frame and (N,) ``rotation_y`` in (−π, π].
    """
    cam_SE3_ego = ego_SE3_cam.inverse()
    center_cam = cam_SE3_ego.transform_points(np.asarray(center_ego_xyz_m, dtype=np.float64).reshape(-1, 3))
    bottom = center_cam + _center_to_bottom_cam(height_m)
    cam_R_obj = np.einsum("ij,njk->nik", cam_SE3_ego.rotation, quat_to_rotmat(quat_wxyz))
    heading_cam = cam_R_obj[:, :, 0]  # the object's x axis = (cos ry, 0, −sin ry)
    ry = wrap_angle_rad(np.arctan2(-heading_cam[:, 2], heading_cam[:, 0]))
    return bottom, ry
