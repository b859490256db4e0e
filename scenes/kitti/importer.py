"""One KITTI tracking sequence into a log folder in the AV2 layout (see :mod:`scenes.kitti`)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scenes import av2_io, schema
from scenes.categories import CATEGORY_TO_AV2, KITTI_TO_CATEGORY, Category
from scenes.errors import ImportFormatError
from scenes.kitti.boxes import kitti_boxes_to_ego
from scenes.kitti.calibration import (
    DEFAULT_IMAGE_SIZE_PX,
    KittiCalibration,
    kitti_calibration_to_av2,
    read_kitti_calibration,
)
from scenes.kitti.labels import KittiLabels, read_kitti_labels
from scenes.kitti.poses import FRAME_PERIOD_NS, KITTI_EPOCH_NS, ego_trajectory_from_kitti, read_kitti_poses
from scenes.log import Log
from scenes.metadata import LogMetadata
from scenes.tracks import Annotations, EgoTrajectory
from scenesearch_base.folders import claimed_directory


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


def write_kitti_log(
    out_dir: Path | str,
    annotations: Annotations,
    ego: EgoTrajectory,
    calibration: KittiCalibration,
    metadata: LogMetadata,
    overwrite: bool = False,
    image_size_px: tuple[int, int] = DEFAULT_IMAGE_SIZE_PX,
) -> Path:
    """Write ``<out_dir>/<metadata.log_id>/`` atomically; it is opened (and so validated) before it
    replaces anything at the target. Returns the log folder.

    Raises:
        FileExistsError: the log folder exists and ``overwrite`` is false.
    """
    target = Path(out_dir) / metadata.log_id
    with claimed_directory(target, av2_io.LOG_FOLDER, overwrite=overwrite) as tmp:
        av2_io.write_annotations(tmp, annotations)
        av2_io.write_ego_poses(tmp, ego)
        av2_io.write_calibration(tmp, kitti_calibration_to_av2(calibration, image_size_px))
        av2_io.write_metadata(tmp, metadata)
        Log.open(tmp)
    return target


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
    track_ids = np.array([str(t) for t in labels.track_id], dtype=np.str_)
    size_lwh = labels.size_hwl_m[:, [2, 1, 0]]
    annotations = Annotations(
        timestamp_ns=KITTI_EPOCH_NS + labels.frame * FRAME_PERIOD_NS,
        track_id=track_ids,
        category=categories,
        center_xyz_m=center_ego,
        size_lwh_m=size_lwh,
        quat_wxyz=quat,
        num_interior_pts=np.full(len(labels), -1, dtype=np.int64),
    )
    return annotations, type_counts, unknown


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
    mixed = schema.check_one_category_per_track(Path(labels_path), labels.track_id.astype(str), labels.kitti_type)
    if mixed:  # KITTI's ground truth keeps each track's type: a file that does not is damaged
        raise ImportFormatError(labels_path, mixed[0].message, field="type")
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
            # Absolute, so that commands run from any folder (eval-tracking reads the labels back) find them.
            "sources": {"labels": str(Path(labels_path).resolve()), "poses": str(Path(poses_path).resolve()),
                        "calib": str(Path(calib_path).resolve())},
        },
    )
    target = write_kitti_log(out_dir, annotations, ego, calibration, metadata, overwrite, image_size_px)
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
