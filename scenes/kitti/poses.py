"""KITTI poses and time: ``poses/<seq>.txt`` into the log's ego trajectory (see :mod:`scenes.kitti`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scenes.errors import ImportFormatError
from scenes.geometry import SE3, FloatArray, rotmat_to_quat
from scenes.kitti.text import parse_floats, read_lines
from scenes.tracks import EgoTrajectory

#: 2011-09-26 00:00:00 UTC in nanoseconds: the timestamp of frame 0 of every imported sequence.
KITTI_EPOCH_NS = 1_316_995_200_000_000_000
#: KITTI tracking frames are 10 Hz.
FRAME_PERIOD_NS = 100_000_000
#: A rotation matrix in a pose file whose R·Rᵀ differs from I by more than this is rejected.
POSE_ORTHONORMAL_TOLERANCE = 1e-3


def read_kitti_poses(path: Path | str) -> FloatArray:
    """Read a pose file: line i = frame i, 12 numbers of a row-major 3×4 ``world_SE3_cam``.

    Returns:
        (F, 4, 4) homogeneous ``world_SE3_cam`` per frame.
    """
    path = Path(path)
    lines = read_lines(path)
    poses = []
    for line_no, line in enumerate(lines, start=1):
        tokens = line.split()
        if not tokens and line_no == len(lines):
            continue
        if len(tokens) != 12:
            raise ImportFormatError(path, f"expected 12 numbers (a 3×4 pose), got {len(tokens)}", line=line_no)
        m = np.eye(4)
        m[:3, :] = parse_floats(path, line_no, tokens).reshape(3, 4)
        err = float(np.abs(m[:3, :3] @ m[:3, :3].T - np.eye(3)).max())
        if err > POSE_ORTHONORMAL_TOLERANCE or np.linalg.det(m[:3, :3]) <= 0:
            raise ImportFormatError(path, f"rotation is not orthonormal (|R·Rᵀ − I| = {err:.2g})", line=line_no)
        poses.append(m)
    if not poses:
        raise ImportFormatError(path, "pose file is empty")
    return np.stack(poses)


def ego_trajectory_from_kitti(world_SE3_cam: NDArray[np.floating], ego_SE3_cam: SE3) -> EgoTrajectory:
    """``city_SE3_ego`` per frame, the city frame being the ego frame at frame 0.

    Args:
        world_SE3_cam: (F, 4, 4) camera-to-world poses, one per frame.
        ego_SE3_cam: rectified camera → ego.
    """
    poses = np.asarray(world_SE3_cam, dtype=np.float64)
    ego_cam = ego_SE3_cam.matrix
    cam_ego = ego_SE3_cam.inverse().matrix
    city_world = ego_cam @ np.linalg.inv(poses[0])
    city_ego = city_world[None] @ poses @ cam_ego[None]  # (F, 4, 4)
    timestamps = KITTI_EPOCH_NS + np.arange(poses.shape[0], dtype=np.int64) * FRAME_PERIOD_NS
    return EgoTrajectory(timestamps, rotmat_to_quat(city_ego[:, :3, :3]), city_ego[:, :3, 3])
