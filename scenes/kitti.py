"""Import KITTI tracking sequences into the Argoverse 2 log layout.

Inputs (one sequence ``<seq>``, e.g. ``0001``):

- ``label_02/<seq>.txt``: one object per line,
  ``frame track_id type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y [score]``.
- ``poses/<seq>.txt``: line i = frame i, a row-major 3×4 camera-to-world pose ``world_SE3_cam_i``.
- ``calib/<seq>.txt``: ``P0``–``P3``, ``R0_rect`` (or ``R_rect``), ``Tr_velo_to_cam`` (or ``Tr_velo_cam``).

Output: ``<out>/kitti_<seq>/`` with ``annotations.feather``, ``city_SE3_egovehicle.feather``,
``calibration/`` and ``log_metadata.json``.

Frames and the conversion
=========================

``cam``: the rectified reference camera of KITTI, in which labels and poses are given::

    cam:  x right, y down, z forward (optical axis)

``velo``: the Velodyne frame, x forward, y left, z up, mounted 1.73 m above the road (KITTI set-up).
A Velodyne point maps into the unrectified camera by ``Tr_velo_to_cam`` and then into the
rectified camera by ``R0_rect``, so::

    cam_SE3_velo = [R0_rect | 0] ∘ Tr_velo_to_cam

``ego``: the log's ego frame (x forward, y left, z up, as everywhere in :mod:`scenes`). Its axes are
the Velodyne's; its origin is the road point straight below the Velodyne, so that box centres sit at
about half their height, as in AV2 (whose origin is on the ground too)::

    ego_SE3_velo = translation (0, 0, +VELODYNE_HEIGHT_M)
    ego_SE3_cam  = ego_SE3_velo ∘ cam_SE3_velo⁻¹

Boxes. A KITTI label gives the *bottom* centre ``(x, y, z)`` in ``cam``, the size ``h w l`` and
``rotation_y``, the rotation about the camera's y axis. The KITTI devkit builds the box corners as
``R_y(ry) · corner + (x, y, z)`` with ``R_y(ry) = [[cos ry, 0, sin ry], [0, 1, 0], [−sin ry, 0, cos ry]]``,
the length along the object's own x axis, the height along −y (up) and the width along z. So the
object's heading (its length axis) in ``cam`` is ``R_y(ry)·(1, 0, 0) = (cos ry, 0, −sin ry)``: ry = 0
faces camera-right, ry = −π/2 faces forward (+z). The box centre is half a height above the bottom
centre, i.e. ``(x, y − h/2, z)`` because y points down.

The AV2 object frame (x along the length, y left, z up) written in KITTI object axes is
``x_obj = x_k``, ``z_obj = −y_k`` and ``y_obj = z_obj × x_obj = z_k``, i.e.::

    kobj_R_obj = [[1, 0, 0], [0, 0, −1], [0, 1, 0]]     (columns: obj x, y, z in KITTI object axes)
    ego_R_obj  = ego_R_cam · R_y(ry) · kobj_R_obj
    centre_ego = ego_SE3_cam · (x, y − h/2, z)
    size_lwh   = (l, w, h)

With the nominal calibration (``ego_R_cam`` maps cam z → ego x, cam x → −ego y, cam y → −ego z) the
heading ``(cos ry, 0, −sin ry)`` becomes ``(−sin ry, −cos ry, 0)`` in ``ego``, so
``yaw_ego = −ry − π/2``, the well-known KITTI camera → LiDAR yaw relation. The importer uses the
full rotation above (the real calibration tilts the camera by about a degree), which
:func:`ego_boxes_to_kitti` inverts exactly.

Ego poses. The pose file gives ``world_SE3_cam_i`` with ``world`` = the camera frame of some
reference frame (the first, as identity). The city frame is chosen as the ego frame at frame 0, so
that it is z up, x forward at the start::

    city_SE3_world = ego_SE3_cam ∘ world_SE3_cam_0⁻¹
    city_SE3_ego_i = city_SE3_world ∘ world_SE3_cam_i ∘ ego_SE3_cam⁻¹

Timestamps. KITTI tracking has no absolute times; frames are 10 Hz. Frame i gets
``KITTI_EPOCH_NS + i × FRAME_PERIOD_NS`` with ``KITTI_EPOCH_NS`` = 2011-09-26 00:00:00 UTC (the
first KITTI recording day), so timestamps look like real ones and never start at zero.

Categories. KITTI types map through :data:`scenes.categories.KITTI_TO_CATEGORY`; the file's
``category`` column holds the AV2 label of the mapped category (:data:`CATEGORY_TO_AV2`). Unknown
types map to ``other`` and are counted; ``DontCare`` rows are dropped and counted. Both counts and
the per-type row counts are kept in ``log_metadata.json``.

Line numbers in errors are 1-based, as in an editor.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from common.atomic import atomic_directory
from scenes import av2_io
from scenes.calibration import Calibration, CameraIntrinsics
from scenes.categories import CATEGORY_TO_AV2, KITTI_TO_CATEGORY, Category
from scenes.errors import ImportFormatError
from scenes.geometry import SE3, FloatArray, quat_to_rotmat, rotmat_to_quat, wrap_angle_rad
from scenes.log import Log
from scenes.metadata import LogMetadata
from scenes.tracks import Annotations, EgoTrajectory

#: Height of the Velodyne above the road in the KITTI recording platform, metres.
VELODYNE_HEIGHT_M = 1.73
#: 2011-09-26 00:00:00 UTC in nanoseconds: the timestamp of frame 0 of every imported sequence.
KITTI_EPOCH_NS = 1_316_995_200_000_000_000
#: KITTI tracking frames are 10 Hz.
FRAME_PERIOD_NS = 100_000_000
#: Image size of camera 2 in most KITTI tracking sequences (used for the written intrinsics).
DEFAULT_IMAGE_SIZE_PX = (1242, 375)
#: Name of camera 2 (left colour) in the written calibration.
CAMERA_NAME = "image_02"
LIDAR_NAME = "velodyne"
DONTCARE = "DontCare"

LABEL_FIELDS = (
    "frame", "track_id", "type", "truncated", "occluded", "alpha",
    "x1", "y1", "x2", "y2", "h", "w", "l", "x", "y", "z", "rotation_y",
)
#: A rotation matrix in a pose file whose R·Rᵀ differs from I by more than this is rejected.
POSE_ORTHONORMAL_TOLERANCE = 1e-3

# Columns of the AV2 object frame (x length, y left, z up) written in KITTI object axes.
_KOBJ_R_OBJ = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


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


@dataclass(frozen=True)
class KittiLabels:
    """Labelled boxes of one sequence, ``DontCare`` rows removed.

    Attributes:
        frame: (N,) frame index of each box.
        track_id: (N,) KITTI track id.
        kitti_type: (N,) KITTI type (``Car``, ``Pedestrian``, …).
        size_hwl_m: (N, 3) height, width, length.
        bottom_center_cam_xyz_m: (N, 3) bottom centre of the box in the rectified camera frame.
        rotation_y_rad: (N,) rotation about the camera's y axis.
        dropped_dontcare: number of ``DontCare`` rows removed.
        num_label_frames: number of distinct frames in the file (``DontCare``-only frames included).
    """

    frame: NDArray[np.int64]
    track_id: NDArray[np.int64]
    kitti_type: NDArray[np.str_]
    size_hwl_m: FloatArray
    bottom_center_cam_xyz_m: FloatArray
    rotation_y_rad: FloatArray
    dropped_dontcare: int
    num_label_frames: int

    def __len__(self) -> int:
        return int(self.frame.shape[0])


@dataclass(frozen=True)
class KittiImportReport:
    """What an import wrote and what it dropped."""

    log_dir: Path
    sequence: str
    frames: int
    rows: int
    tracks: int
    dropped_dontcare: int
    unknown_types: dict[str, int] = field(default_factory=dict)
    type_counts: dict[str, int] = field(default_factory=dict)

    def summary(self) -> str:
        unknown = ", ".join(f"{k}={v}" for k, v in sorted(self.unknown_types.items())) or "none"
        return (
            f"{self.log_dir}: {self.frames} frames, {self.tracks} tracks, {self.rows} boxes; "
            f"skipped {self.dropped_dontcare} DontCare rows; unknown types mapped to 'other': {unknown}"
        )


# ---------------------------------------------------------------------------------------------
# Readers


def _read_lines(path: Path) -> list[str]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file is missing")
    try:
        return path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ImportFormatError(path, f"unreadable text file: {exc}") from exc


def _floats(path: Path, line_no: int, tokens: list[str], names: list[str] | None = None) -> FloatArray:
    try:
        values = np.array([float(t) for t in tokens], dtype=np.float64)
    except ValueError as exc:
        bad = next(i for i, t in enumerate(tokens) if not _is_float(t))
        name = names[bad] if names else f"value {bad + 1}"
        raise ImportFormatError(path, f"not a number: {tokens[bad]!r}", line=line_no, field=name) from exc
    if not np.isfinite(values).all():
        bad = int(np.argmax(~np.isfinite(values)))
        name = names[bad] if names else f"value {bad + 1}"
        raise ImportFormatError(path, "NaN or inf value", line=line_no, field=name)
    return values


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def read_kitti_calibration(path: Path | str) -> KittiCalibration:
    """Read ``calib/<seq>.txt`` (``key: v1 v2 …`` lines; tracking and object spellings accepted)."""
    path = Path(path)
    entries: dict[str, tuple[int, list[str]]] = {}
    for line_no, line in enumerate(_read_lines(path), start=1):
        if not line.strip():
            continue
        key, sep, rest = line.partition(":")
        if not sep:
            key, _, rest = line.strip().partition(" ")
        entries[key.strip()] = (line_no, rest.split())

    def matrix(names: tuple[str, ...], shape: tuple[int, int]) -> FloatArray:
        for name in names:
            if name in entries:
                line_no, tokens = entries[name]
                if len(tokens) != shape[0] * shape[1]:
                    raise ImportFormatError(
                        path, f"expected {shape[0] * shape[1]} numbers, got {len(tokens)}", line=line_no, field=name
                    )
                return _floats(path, line_no, tokens).reshape(shape)
        raise ImportFormatError(path, "missing calibration entry", field=" or ".join(names))

    return KittiCalibration(
        P2=matrix(("P2",), (3, 4)),
        R0_rect=matrix(("R0_rect", "R_rect"), (3, 3)),
        Tr_velo_to_cam=matrix(("Tr_velo_to_cam", "Tr_velo_cam"), (3, 4)),
    )


def read_kitti_poses(path: Path | str) -> FloatArray:
    """Read a pose file: line i = frame i, 12 numbers of a row-major 3×4 ``world_SE3_cam``.

    Returns:
        (F, 4, 4) homogeneous ``world_SE3_cam`` per frame.
    """
    path = Path(path)
    lines = _read_lines(path)
    poses = []
    for line_no, line in enumerate(lines, start=1):
        tokens = line.split()
        if not tokens and line_no == len(lines):
            continue
        if len(tokens) != 12:
            raise ImportFormatError(path, f"expected 12 numbers (a 3×4 pose), got {len(tokens)}", line=line_no)
        m = np.eye(4)
        m[:3, :] = _floats(path, line_no, tokens).reshape(3, 4)
        err = float(np.abs(m[:3, :3] @ m[:3, :3].T - np.eye(3)).max())
        if err > POSE_ORTHONORMAL_TOLERANCE or np.linalg.det(m[:3, :3]) <= 0:
            raise ImportFormatError(path, f"rotation is not orthonormal (|R·Rᵀ − I| = {err:.2g})", line=line_no)
        poses.append(m)
    if not poses:
        raise ImportFormatError(path, "pose file is empty")
    return np.stack(poses)


def read_kitti_labels(path: Path | str) -> KittiLabels:
    """Read ``label_02/<seq>.txt``; ``DontCare`` rows are dropped and counted.

    Raises:
        ImportFormatError: naming the (1-based) line and field of a wrong column count, a value that
            is not a number, a non-positive box size, frames out of order, or a track id twice in
            one frame.
    """
    path = Path(path)
    frames: list[int] = []
    track_ids: list[int] = []
    types: list[str] = []
    values: list[FloatArray] = []
    dropped = 0
    all_frames: set[int] = set()
    seen: dict[tuple[int, int], int] = {}
    last_frame = -1
    float_names = list(LABEL_FIELDS[10:17])
    for line_no, line in enumerate(_read_lines(path), start=1):
        tokens = line.split()
        if not tokens:
            continue
        if len(tokens) not in (17, 18):
            raise ImportFormatError(
                path, f"expected 17 columns ({' '.join(LABEL_FIELDS)}), got {len(tokens)}", line=line_no
            )
        try:
            frame = int(tokens[0])
        except ValueError as exc:
            raise ImportFormatError(path, f"not an integer: {tokens[0]!r}", line=line_no, field="frame") from exc
        try:
            track = int(tokens[1])
        except ValueError as exc:
            raise ImportFormatError(path, f"not an integer: {tokens[1]!r}", line=line_no, field="track_id") from exc
        if frame < 0:
            raise ImportFormatError(path, f"negative frame {frame}", line=line_no, field="frame")
        if frame < last_frame:
            raise ImportFormatError(path, f"frame {frame} after frame {last_frame}: not in order", line=line_no,
                                    field="frame")
        last_frame = frame
        all_frames.add(frame)
        kitti_type = tokens[2]
        if kitti_type == DONTCARE:
            dropped += 1
            continue
        if track < 0:
            raise ImportFormatError(path, f"negative track id {track} on a {kitti_type} row", line=line_no,
                                    field="track_id")
        if (frame, track) in seen:
            raise ImportFormatError(
                path, f"track {track} appears twice in frame {frame} (first on line {seen[(frame, track)]})",
                line=line_no, field="track_id",
            )
        seen[(frame, track)] = line_no
        box = _floats(path, line_no, tokens[10:17], float_names)
        for i, name in enumerate(("h", "w", "l")):
            if box[i] <= 0:
                raise ImportFormatError(path, f"box size must be positive, got {box[i]}", line=line_no, field=name)
        frames.append(frame)
        track_ids.append(track)
        types.append(kitti_type)
        values.append(box)
    if not all_frames:
        raise ImportFormatError(path, "label file has no rows")
    box_array = np.stack(values) if values else np.zeros((0, 7))
    return KittiLabels(
        frame=np.asarray(frames, dtype=np.int64),
        track_id=np.asarray(track_ids, dtype=np.int64),
        kitti_type=np.asarray(types, dtype=np.str_),
        size_hwl_m=box_array[:, 0:3],
        bottom_center_cam_xyz_m=box_array[:, 3:6],
        rotation_y_rad=box_array[:, 6],
        dropped_dontcare=dropped,
        num_label_frames=len(all_frames),
    )


# ---------------------------------------------------------------------------------------------
# Frame conversion


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
    h = np.asarray(height_m, dtype=np.float64).reshape(-1)
    ry = np.asarray(rotation_y_rad, dtype=np.float64).reshape(-1)
    center_cam = bottom - np.stack([np.zeros_like(h), h / 2.0, np.zeros_like(h)], axis=1)  # y points down
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
    h = np.asarray(height_m, dtype=np.float64).reshape(-1)
    bottom = center_cam + np.stack([np.zeros_like(h), h / 2.0, np.zeros_like(h)], axis=1)
    cam_R_obj = np.einsum("ij,njk->nik", cam_SE3_ego.rotation, quat_to_rotmat(quat_wxyz))
    heading_cam = cam_R_obj[:, :, 0]  # the object's x axis = (cos ry, 0, −sin ry)
    ry = wrap_angle_rad(np.arctan2(-heading_cam[:, 2], heading_cam[:, 0]))
    return bottom, ry


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


# ---------------------------------------------------------------------------------------------
# Import


def sequence_name(labels_path: Path | str) -> str:
    """The sequence of a label file: its stem (``0001.txt`` → ``0001``)."""
    stem = Path(labels_path).stem
    if not stem or not re.fullmatch(r"[A-Za-z0-9_.-]+", stem):
        raise ValueError(f"{labels_path}: cannot name a sequence after this file")
    return stem


def kitti_labels_to_annotations(
    labels: KittiLabels, calibration: KittiCalibration
) -> tuple[Annotations, dict[str, int], dict[str, int]]:
    """Labels → AV2 annotations in the ego frame.

    Returns:
        The annotations, the row count of each KITTI type, and the unknown types (mapped to
        ``other``) with their row counts.
    """
    center_ego, quat = kitti_boxes_to_ego(
        labels.bottom_center_cam_xyz_m, labels.size_hwl_m[:, 0], labels.rotation_y_rad, calibration.ego_SE3_cam
    )
    types, counts = np.unique(labels.kitti_type, return_counts=True)
    type_counts = {str(t): int(c) for t, c in zip(types, counts)}
    unknown = {t: c for t, c in type_counts.items() if t not in KITTI_TO_CATEGORY}
    av2_label = {t: CATEGORY_TO_AV2[KITTI_TO_CATEGORY.get(t, Category.OTHER)] for t in type_counts}
    categories = np.array([av2_label[str(t)] for t in labels.kitti_type], dtype=np.str_)
    size_lwh = labels.size_hwl_m[:, [2, 1, 0]]
    annotations = Annotations(
        timestamp_ns=KITTI_EPOCH_NS + labels.frame * FRAME_PERIOD_NS,
        track_id=np.array([str(t) for t in labels.track_id], dtype=np.str_),
        category=categories,
        center_xyz_m=center_ego,
        size_lwh_m=size_lwh,
        quat_wxyz=quat,
        num_interior_pts=np.full(len(labels), -1, dtype=np.int64),
    )
    return annotations, type_counts, unknown


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


def import_kitti_sequence(
    labels_path: Path | str,
    poses_path: Path | str,
    calib_path: Path | str,
    out_dir: Path | str,
    overwrite: bool = False,
    image_size_px: tuple[int, int] = DEFAULT_IMAGE_SIZE_PX,
) -> KittiImportReport:
    """Convert one KITTI tracking sequence into ``<out_dir>/kitti_<seq>/`` (written atomically).

    The written log is opened (and so validated) before it replaces anything at the target.

    Raises:
        FileNotFoundError: an input file is missing.
        ImportFormatError: an input file is malformed (names the line and field), the pose file
            has fewer frames than the labels, or the pose or calibration file is named after another
            sequence (``0002.txt`` beside labels ``0001.txt``).
        FileExistsError: the log folder exists and ``overwrite`` is false.
    """
    labels_path, poses_path, calib_path = Path(labels_path), Path(poses_path), Path(calib_path)
    seq = sequence_name(labels_path)
    for other in (poses_path, calib_path):
        if seq.isdigit() and other.stem.isdigit() and other.stem != seq:
            raise ImportFormatError(other, f"belongs to sequence {other.stem}, but the labels are sequence {seq}")
    labels = read_kitti_labels(labels_path)
    world_SE3_cam = read_kitti_poses(poses_path)
    calibration = read_kitti_calibration(calib_path)
    max_frame = int(labels.frame.max()) if len(labels) else -1
    if max_frame >= world_SE3_cam.shape[0]:
        raise ImportFormatError(
            poses_path,
            f"pose file has {world_SE3_cam.shape[0]} frames but {labels_path} labels frame {max_frame}",
            line=world_SE3_cam.shape[0] + 1,
        )
    if len(labels) == 0:
        raise ImportFormatError(labels_path, "no boxes besides DontCare rows: the log would have no annotations")
    annotations, type_counts, unknown = kitti_labels_to_annotations(labels, calibration)
    ego = ego_trajectory_from_kitti(world_SE3_cam, calibration.ego_SE3_cam)
    log_id = f"kitti_{seq}"
    metadata = LogMetadata(
        log_id=log_id,
        source="kitti",
        city_name="KITTI",
        extra={
            "sequence": seq,
            "frames": int(world_SE3_cam.shape[0]),
            "label_frames": labels.num_label_frames,
            "dropped_dontcare": labels.dropped_dontcare,
            "kitti_type_counts": type_counts,
            "unknown_types": unknown,
            "frame_period_ns": FRAME_PERIOD_NS,
            "epoch_ns": KITTI_EPOCH_NS,
            "sources": {"labels": str(labels_path), "poses": str(poses_path), "calib": str(calib_path)},
        },
    )
    target = Path(out_dir) / log_id
    with atomic_directory(target, overwrite=overwrite) as tmp:
        av2_io.write_annotations(tmp, annotations)
        av2_io.write_ego_poses(tmp, ego)
        av2_io.write_calibration(tmp, kitti_calibration_to_av2(calibration, image_size_px))
        av2_io.write_metadata(tmp, metadata)
        Log.open(tmp)
    return KittiImportReport(
        log_dir=target,
        sequence=seq,
        frames=int(world_SE3_cam.shape[0]),
        rows=len(annotations),
        tracks=len(annotations.track_ids),
        dropped_dontcare=labels.dropped_dontcare,
        unknown_types=unknown,
        type_counts=type_counts,
    )
