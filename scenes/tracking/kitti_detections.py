"""KITTI-style 3D detections (PointRCNN output as distributed with AB3DMOT) → a tracked log.

Each file ``<Class>/<seq>.txt`` holds comma-separated rows::

    frame, type, x1, y1, x2, y2, score, h, w, l, x, y, z, rot_y, alpha

with ``type`` 1 = Pedestrian, 2 = Car, 3 = Cyclist, boxes in the rectified camera frame (bottom
centre, as in KITTI labels) and ``score`` a raw detector logit. Scores are mapped to [0, 1] with the
logistic function, which keeps their order (so any threshold on raw scores has an equivalent).
The frame conversion is :func:`scenes.kitti.boxes.kitti_boxes_to_ego`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenes.categories import KITTI_TO_CATEGORY
from scenes.errors import ImportFormatError
from scenes.geometry import SE3, quat_to_yaw
from scenes.kitti.boxes import kitti_boxes_to_ego
from scenes.kitti.calibration import read_kitti_calibration
from scenes.kitti.importer import sequence_name, write_kitti_log
from scenes.kitti.poses import FRAME_PERIOD_NS, KITTI_EPOCH_NS, ego_trajectory_from_kitti, read_kitti_poses
from scenes.metadata import LogMetadata
from scenes.tracking.config import TrackerConfig
from scenes.tracking.detections import Detections
from scenes.tracking.tracker import track_detections

POINTRCNN_TYPES = {1: "Pedestrian", 2: "Car", 3: "Cyclist"}
POINTRCNN_FIELDS = ("frame", "type", "x1", "y1", "x2", "y2", "score", "h", "w", "l", "x", "y", "z", "rot_y", "alpha")


def read_pointrcnn_detections(path: Path | str, ego_SE3_cam: SE3) -> Detections:
    """Read one PointRCNN detection file into ego-frame detections.

    Args:
        path: the CSV file.
        ego_SE3_cam: rectified camera → ego (from the calibration).

    Raises:
        ImportFormatError: wrong column count, a non-number, an unknown type code, a non-positive
            size (each names the line and field).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: detections file is missing")
    rows = []
    lines = []
    for line_no, raw in enumerate(path.read_text().splitlines(), start=1):
        if not raw.strip():
            continue
        tokens = [t.strip() for t in raw.split(",")]
        if len(tokens) != len(POINTRCNN_FIELDS):
            raise ImportFormatError(path, f"expected {len(POINTRCNN_FIELDS)} comma-separated values, got {len(tokens)}",
                                    line=line_no)
        values = []
        for name, token in zip(POINTRCNN_FIELDS, tokens):
            try:
                values.append(float(token))
            except ValueError:
                raise ImportFormatError(path, f"not a number: {token!r}", line=line_no, field=name) from None
        if int(values[1]) not in POINTRCNN_TYPES:
            raise ImportFormatError(path, f"unknown type code {tokens[1]}", line=line_no, field="type")
        if min(values[7], values[8], values[9]) <= 0:
            raise ImportFormatError(path, "box size must be positive", line=line_no, field="h,w,l")
        if not np.isfinite(values).all():
            raise ImportFormatError(path, "NaN or inf value", line=line_no)
        rows.append(values)
        lines.append(line_no)
    if not rows:
        return Detections.empty()
    a = np.asarray(rows)
    frame = a[:, 0].astype(np.int64)
    if (frame < 0).any():
        i = int(np.argmax(frame < 0))
        raise ImportFormatError(path, "negative frame", line=lines[i], field="frame")
    center_ego, quat = kitti_boxes_to_ego(a[:, 10:13], a[:, 7], a[:, 13], ego_SE3_cam)
    categories = [KITTI_TO_CATEGORY[POINTRCNN_TYPES[int(t)]].value for t in a[:, 1]]
    return Detections(
        timestamp_ns=KITTI_EPOCH_NS + frame * FRAME_PERIOD_NS,
        category=np.asarray(categories, dtype=np.str_),
        score=1.0 / (1.0 + np.exp(-a[:, 6])),
        center_xyz_m=center_ego,
        size_lwh_m=a[:, [9, 8, 7]],  # h w l → l w h
        yaw_rad=quat_to_yaw(quat),
        source_line=np.asarray(lines, dtype=np.int64),
    )


@dataclass(frozen=True)
class TrackingImportReport:
    """What an import from detections produced."""

    log_dir: Path
    sequence: str
    frames: int
    detections: int
    tracks: int
    rows: int


def import_kitti_detections(
    detection_paths: list[Path] | list[str],
    poses_path: Path | str,
    calib_path: Path | str,
    out_dir: Path | str,
    config: TrackerConfig | None = None,
    overwrite: bool = False,
) -> TrackingImportReport:
    """Track KITTI detections of one sequence and write ``<out_dir>/kitti_<seq>/`` atomically.

    Args:
        detection_paths: one file per class (``Car/0001.txt``, ``Pedestrian/0001.txt``, …), all of
            the same sequence.
        poses_path: ``<seq>.txt`` camera-to-world poses, one line per frame.
        calib_path: ``<seq>.txt`` KITTI calibration.
        out_dir: folder that receives the log.
        config: tracker parameters.
        overwrite: replace an existing log of the same name.
    """
    paths = [Path(p) for p in detection_paths]
    if not paths:
        raise ValueError("no detection files given")
    sequences = {sequence_name(p) for p in paths}
    if len(sequences) != 1:
        raise ValueError(f"detection files belong to different sequences: {sorted(sequences)}")
    seq = sequences.pop()
    calibration = read_kitti_calibration(calib_path)
    world_SE3_cam = read_kitti_poses(poses_path)
    ego = ego_trajectory_from_kitti(world_SE3_cam, calibration.ego_SE3_cam)
    parts = [read_pointrcnn_detections(p, calibration.ego_SE3_cam) for p in paths]
    for path, part in zip(paths, parts):
        frames = (part.timestamp_ns - KITTI_EPOCH_NS) // FRAME_PERIOD_NS
        beyond = frames >= world_SE3_cam.shape[0]
        if beyond.any():
            i = int(np.argmax(beyond))
            raise ImportFormatError(path, f"frame {int(frames[i])} has no pose ({world_SE3_cam.shape[0]} poses in "
                                    f"{poses_path})", line=int(part.source_line[i]), field="frame")
    detections = Detections.concatenate(parts)
    annotations = track_detections(detections, ego, config, frame_timestamps_ns=ego.timestamps_ns,
                                   source=paths[0], pose_tolerance_ns=0)
    if len(annotations) == 0:
        raise ValueError(f"the tracker confirmed no track from {len(detections)} detections of sequence {seq}")
    log_id = f"kitti_{seq}"
    cfg = config or TrackerConfig()
    metadata = LogMetadata(
        log_id=log_id, source="kitti-tracker", city_name="KITTI",
        extra={"sequence": seq, "frames": int(world_SE3_cam.shape[0]), "detections": len(detections),
               "detection_files": [str(p) for p in paths], "tracker": cfg.to_dict()},
    )
    target = write_kitti_log(out_dir, annotations, ego, calibration, metadata, overwrite)
    return TrackingImportReport(target, seq, int(world_SE3_cam.shape[0]), len(detections),
                                len(annotations.track_ids), len(annotations))
