"""Track a log's detections into a new log folder (``scenesearch track``)."""

from __future__ import annotations

import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from scenes import av2_io
from scenes.log import Log
from scenes.metadata import LogMetadata
from scenes.sensors import timestamps_in
from scenes.tracking.config import TrackerConfig
from scenes.tracking.detections import read_detections_table
from scenes.tracking.tracker import track_detections
from scenesearch_base.folders import claimed_directory


@dataclass(frozen=True)
class TrackLogReport:
    log_dir: Path
    detections: int
    frames: int
    tracks: int
    rows: int


def track_log(
    log_dir: Path | str, detections_path: Path | str, out_dir: Path | str, config: TrackerConfig | None = None,
    overwrite: bool = False,
) -> TrackLogReport:
    """Copy a log to ``out_dir/<log_id>/`` with annotations replaced by the tracker's output.

    The source log needs ego poses; its own annotations (if any) are ignored. Frames are the
    detections' timestamps together with the LiDAR sweeps', so tracks age through sweeps where
    nothing was detected.
    """
    log_dir, detections_path = Path(log_dir), Path(detections_path)
    ego = av2_io.read_ego_poses(log_dir / av2_io.POSES_FILENAME)
    detections = read_detections_table(detections_path)
    sweeps = timestamps_in(log_dir / av2_io.LIDAR_DIR, ".feather")
    annotations = track_detections(detections, ego, config, frame_timestamps_ns=sweeps, source=detections_path)
    if len(annotations) == 0:
        raise ValueError(f"{detections_path}: the tracker confirmed no track from {len(detections)} detections")
    frames = int(np.union1d(detections.timestamp_ns, sweeps).size)
    metadata = av2_io.read_metadata(log_dir) or LogMetadata(log_id=log_dir.name)
    cfg = config or TrackerConfig()
    metadata = replace(metadata, extra={**metadata.extra, "tracked_from": str(detections_path),
                                        "tracker": cfg.to_dict()})
    target = Path(out_dir) / log_dir.name
    if target.resolve() == log_dir.resolve():
        raise ValueError(f"--out must differ from the log's own folder ({log_dir.parent})")
    with claimed_directory(target, av2_io.LOG_FOLDER, overwrite=overwrite) as tmp:
        shutil.copytree(log_dir, tmp, dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns(av2_io.ANNOTATIONS_FILENAME, ".*"))
        av2_io.write_annotations(tmp, annotations)
        av2_io.write_metadata(tmp, metadata)
        Log.open(tmp)
    return TrackLogReport(target, len(detections), frames, len(annotations.track_ids), len(annotations))
