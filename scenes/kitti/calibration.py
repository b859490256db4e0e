"""The KITTI calibration file and the sensor frames it defines (see :mod:`scenes.kitti`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenes.calibration import Calibration, CameraIntrinsics
from scenes.errors import ImportFormatError
from scenes.geometry import SE3, FloatArray
from scenes.kitti.text import parse_floats, read_lines
from scenes.schema import check_rotations

#: Height of the Velodyne above the road in the KITTI recording platform, metres.
VELODYNE_HEIGHT_M = 1.73
#: Image size of camera 2 in most KITTI tracking sequences (used for the written intrinsics).
DEFAULT_IMAGE_SIZE_PX = (1242, 375)
#: Name of camera 2 (left colour) in the written calibration.
CAMERA_NAME = "image_02"
LIDAR_NAME = "velodyne"


@dataclass(frozen=True)
class KittiCalibration:
    """The parts of a KITTI ``calib/<seq>.txt`` the importer needs.

    Attributes:
        P2: (3, 4) projection matrix of camera 2 (left colour) from the rectified reference camera.
        R0_rect: (3, 3) rectifying rotation of the reference camera.
        Tr_velo_to_cam: (3, 4) Velodyne → unrectified reference camera.
    """

    P2: FloatArray
    R0_rect: FloatArray
    Tr_velo_to_cam: FloatArray

    @property
    def cam_SE3_velo(self) -> SE3:
        """Velodyne → rectified reference camera: ``[R0_rect | 0] ∘ Tr_velo_to_cam``."""
        velo_to_cam = SE3(self.Tr_velo_to_cam[:, :3], self.Tr_velo_to_cam[:, 3])
        return SE3(self.R0_rect, np.zeros(3)).compose(velo_to_cam)

    @property
    def ego_SE3_cam(self) -> SE3:
        """Rectified reference camera → ego (Velodyne axes, origin on the road below it)."""
        return self.ego_SE3_velo.compose(self.cam_SE3_velo.inverse())

    @property
    def ego_SE3_velo(self) -> SE3:
        """Velodyne → ego: the ego origin is on the road, ``VELODYNE_HEIGHT_M`` below the Velodyne."""
        return SE3(np.eye(3), np.array([0.0, 0.0, VELODYNE_HEIGHT_M]))

    @property
    def ego_SE3_cam2(self) -> SE3:
        """Camera 2 → ego. ``P2 = K·[I | t]`` puts camera 2 at ``X_cam2 = X_cam + K⁻¹·P2[:, 3]``."""
        k = self.P2[:, :3]
        t = np.asarray(np.linalg.solve(k, self.P2[:, 3]), dtype=np.float64)
        return self.ego_SE3_cam.compose(SE3(np.eye(3), -t))


def read_kitti_calibration(path: Path | str) -> KittiCalibration:
    """Read ``calib/<seq>.txt`` (``key: v1 v2 …`` lines; tracking and object spellings accepted).

    Beyond parsing, the values must describe a camera rig: ``R0_rect`` and the rotation part of
    ``Tr_velo_to_cam`` are proper rotations (orthonormal, determinant +1) and ``P2``'s focal lengths
    are positive. A file of zeros would otherwise import, with every box mapped to one point.

    Raises:
        ImportFormatError: naming the file, the line and the entry at fault.
    """
    path = Path(path)
    entries: dict[str, tuple[int, list[str]]] = {}
    for line_no, line in enumerate(read_lines(path), start=1):
        if not line.strip():
            continue
        key, sep, rest = line.partition(":")
        if not sep:
            key, _, rest = line.strip().partition(" ")
        entries[key.strip()] = (line_no, rest.split())

    def matrix(names: tuple[str, ...], shape: tuple[int, int]) -> tuple[FloatArray, int, str]:
        """The entry as a matrix, with its line number and the spelling found."""
        for name in names:
            if name in entries:
                line_no, tokens = entries[name]
                if len(tokens) != shape[0] * shape[1]:
                    raise ImportFormatError(
                        path, f"expected {shape[0] * shape[1]} numbers, got {len(tokens)}", line=line_no, field=name
                    )
                return parse_floats(path, line_no, tokens).reshape(shape), line_no, name
        raise ImportFormatError(path, "missing calibration entry", field=" or ".join(names))

    p2, p2_line, p2_name = matrix(("P2",), (3, 4))
    r0_rect, r0_line, r0_name = matrix(("R0_rect", "R_rect"), (3, 3))
    velo_to_cam, tr_line, tr_name = matrix(("Tr_velo_to_cam", "Tr_velo_cam"), (3, 4))
    rotations = (("matrix", r0_rect, r0_line, r0_name), ("rotation part", velo_to_cam[:, :3], tr_line, tr_name))
    for what, rotation, line_no, name in rotations:
        problems = check_rotations(path, rotation[None], name)
        if problems:
            raise ImportFormatError(path, f"{what} is {problems[0].message}", line=line_no, field=name)
    for value, what in ((p2[0, 0], "fx (P2[0,0])"), (p2[1, 1], "fy (P2[1,1])")):
        if not value > 0:
            raise ImportFormatError(path, f"focal length {what} must be positive, got {value:g}", line=p2_line,
                                    field=p2_name)
    return KittiCalibration(P2=p2, R0_rect=r0_rect, Tr_velo_to_cam=velo_to_cam)


def kitti_calibration_to_av2(
    calibration: KittiCalibration, image_size_px: tuple[int, int] = DEFAULT_IMAGE_SIZE_PX
) -> Calibration:
    """Extrinsics of the Velodyne and camera 2, and camera 2's pinhole intrinsics."""
    p2 = calibration.P2
    width, height = image_size_px
    intrinsics = CameraIntrinsics(
        sensor_name=CAMERA_NAME, fx_px=float(p2[0, 0]), fy_px=float(p2[1, 1]), cx_px=float(p2[0, 2]),
        cy_px=float(p2[1, 2]), width_px=int(width), height_px=int(height),
    )
    return Calibration(
        ego_SE3_sensor={LIDAR_NAME: calibration.ego_SE3_velo, CAMERA_NAME: calibration.ego_SE3_cam2},
        intrinsics={CAMERA_NAME: intrinsics},
    )
