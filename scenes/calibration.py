"""Sensor calibration: extrinsics ``ego_SE3_sensor`` and pinhole camera intrinsics.

Camera frames follow the AV2 / OpenCV convention: x right, y down, z forward (optical axis).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from scenes.geometry import SE3, FloatArray


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics with radial distortion coefficients (AV2 ``intrinsics.feather`` row)."""

    sensor_name: str
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    width_px: int
    height_px: int
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0

    @property
    def K(self) -> FloatArray:
        """(3, 3) camera matrix."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    def scaled(self, width_px: int, height_px: int) -> CameraIntrinsics:
        """The same camera for an image resized to ``width_px`` × ``height_px``."""
        sx, sy = width_px / self.width_px, height_px / self.height_px
        return CameraIntrinsics(
            self.sensor_name, self.fx_px * sx, self.fy_px * sy, self.cx_px * sx, self.cy_px * sy,
            width_px, height_px, self.k1, self.k2, self.k3,
        )

    def project(self, points_cam_xyz: NDArray[np.floating]) -> tuple[FloatArray, NDArray[np.bool_]]:
        """Project camera-frame points to pixels (distortion ignored).

        Args:
            points_cam_xyz: (N, 3) points in the camera frame.

        Returns:
            (N, 2) pixel coordinates (u right, v down) and (N,) whether each point is in front of
            the camera (z > 0.1 m) and inside the image.
        """
        pts = np.asarray(points_cam_xyz, dtype=np.float64)
        z = pts[:, 2]
        safe_z = np.where(np.abs(z) < 1e-9, 1e-9, z)
        u = self.fx_px * pts[:, 0] / safe_z + self.cx_px
        v = self.fy_px * pts[:, 1] / safe_z + self.cy_px
        ok = (z > 0.1) & (u >= 0) & (u < self.width_px) & (v >= 0) & (v < self.height_px)
        return np.stack([u, v], axis=1), ok


@dataclass(frozen=True)
class Calibration:
    """Extrinsics of every sensor and intrinsics of every camera of a log."""

    ego_SE3_sensor: Mapping[str, SE3] = field(default_factory=dict)
    intrinsics: Mapping[str, CameraIntrinsics] = field(default_factory=dict)

    def camera_names(self) -> list[str]:
        return sorted(self.intrinsics)
