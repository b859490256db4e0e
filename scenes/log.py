"""A drive log on disk, in the Argoverse 2 sensor layout.

>>> log = Log.open("path/to/<log_id>")           # validates annotations and poses
>>> tracks = log.tracks()                         # per-track, ego and city frames
>>> sweep = log.lidar_sweep(log.lidar_timestamps_ns[0])   # loaded on demand

The map, calibration, sensor files and metadata are validated when first read; to check all of a
log at once (what ``scenesearch validate`` does) use :func:`scenes.validate.validate_log`.
"""

from __future__ import annotations

import errno
import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scenes import av2_io, map_schema, schema
from scenes.calibration import Calibration
from scenes.errors import LogFormatError, Problem, collect_problems
from scenes.map import VectorMap
from scenes.metadata import LogMetadata
from scenes.sensors import LidarSweep, read_camera_frame, read_lidar_points, read_lidar_sweep, timestamps_in
from scenes.tracks import Annotations, DenseTracks, EgoTrajectory, ObjectTrack, dense_tracks, tracks_from_annotations


@dataclass
class Log:
    """One log folder. Annotations and poses are read (and validated) on open; the map,
    calibration and sensor data are read when first used."""

    log_dir: Path
    annotations: Annotations
    ego: EgoTrajectory
    #: Raw labels not in the public vocabulary, mapped to ``other``, with row counts.
    unknown_categories: dict[str, int] = field(default_factory=dict)

    @staticmethod
    def open(log_dir: Path | str, max_pose_gap_s: float = schema.DEFAULT_MAX_POSE_GAP_S) -> Log:
        """Open and validate a log folder.

        Args:
            log_dir: the log folder.
            max_pose_gap_s: the largest gap between the two ego poses that an annotation timestamp
                is interpolated between; a log with a longer gap is refused rather than given made-up
                poses. Raise it only for logs whose poses really are this sparse.

        Raises:
            LogFormatError: naming every file, row and field at fault.
        """
        log_dir = Path(log_dir)
        if not log_dir.is_dir():
            raise LogFormatError.single(log_dir, log_folder_problem(log_dir))
        problems: list[Problem] = []
        annotations: Annotations | None = None
        ann_path = log_dir / av2_io.ANNOTATIONS_FILENAME
        if not os.path.lexists(ann_path):
            problems.append(Problem(ann_path, "log has no annotations (file is missing)"))
        else:
            annotations = collect_problems(problems, av2_io.read_annotations, ann_path)
        ego = collect_problems(
            problems, av2_io.read_ego_poses, log_dir / av2_io.POSES_FILENAME,
            None if annotations is None else annotations.timestamps_ns, max_pose_gap_s,
        )
        if annotations is not None and ego is not None:
            problems.extend(_check_pose_coverage(log_dir, annotations, ego))
            problems.extend(_check_sweep_times(log_dir, ego))
        if problems or annotations is None or ego is None:
            raise LogFormatError(problems)
        return Log(log_dir, annotations, ego, annotations.unknown_labels())

    @property
    def log_id(self) -> str:
        return self.log_dir.name

    @cached_property
    def metadata(self) -> LogMetadata:
        """The log's metadata; for logs without ``log_metadata.json`` a default naming the log."""
        meta = av2_io.read_metadata(self.log_dir)
        if meta is not None:
            return meta
        map_path = self.map_path
        city = "UNKNOWN"
        if map_path is not None and "____" in map_path.stem:
            city = map_path.stem.split("____")[-1].split("_")[0]
        return LogMetadata(log_id=self.log_id, source="av2", city_name=city)

    @property
    def map_path(self) -> Path | None:
        return av2_io.find_map_file(self.log_dir)

    @cached_property
    def map(self) -> VectorMap | None:
        """The vector map, or None when the log has none."""
        path = self.map_path
        if path is None:
            return None
        vector_map = av2_io.read_map(path)
        problems = map_schema.check_map_covers_poses(path, vector_map, self.ego.translation_m[:, :2])
        if problems:
            raise LogFormatError(problems)
        return vector_map

    @cached_property
    def calibration(self) -> Calibration:
        return av2_io.read_calibration(self.log_dir)

    @cached_property
    def timestamps_ns(self) -> NDArray[np.int64]:
        """(T,) the log's frame grid: annotation timestamps and LiDAR sweep timestamps together.

        In the AV2 layout a sweep with nothing around the ego has no annotation rows; its frame
        still belongs to the log (time keeps running for the ego's own motion).
        """
        return np.union1d(self.annotations.timestamps_ns, self.lidar_timestamps_ns).astype(np.int64)

    @cached_property
    def lidar_timestamps_ns(self) -> NDArray[np.int64]:
        """(S,) timestamps of the LiDAR sweeps on disk."""
        return timestamps_in(self.log_dir / av2_io.LIDAR_DIR, ".feather")

    def camera_names(self) -> list[str]:
        folder = self.log_dir / av2_io.CAMERAS_DIR
        if not folder.is_dir():
            return []
        # Instance-mask folders (``<camera>_instance``) sit beside the cameras but are not cameras.
        return sorted(p.name for p in folder.iterdir() if p.is_dir() and not p.name.endswith(INSTANCE_SUFFIX))

    def camera_timestamps_ns(self, camera_name: str) -> NDArray[np.int64]:
        """(F,) timestamps of the frames of one camera."""
        return timestamps_in(self.log_dir / av2_io.CAMERAS_DIR / camera_name, ".jpg")

    def lidar_sweep(self, timestamp_ns: int) -> LidarSweep:
        return read_lidar_sweep(self.log_dir / av2_io.LIDAR_DIR / f"{int(timestamp_ns)}.feather")

    def lidar_points(self, timestamp_ns: int) -> NDArray[np.float32]:
        """(N, 3) the sweep's points in the ego frame, its other columns left unread."""
        return read_lidar_points(self.log_dir / av2_io.LIDAR_DIR / f"{int(timestamp_ns)}.feather")

    def camera_frame(self, camera_name: str, timestamp_ns: int) -> NDArray[np.uint8]:
        """(H, W, 3) BGR image."""
        return read_camera_frame(self.log_dir / av2_io.CAMERAS_DIR / camera_name / f"{int(timestamp_ns)}.jpg")

    def tracks(self) -> dict[str, ObjectTrack]:
        """Every track (the ego's own box excluded), in the ego and the city frame."""
        return tracks_from_annotations(self.annotations, self.ego)

    def dense_tracks(self) -> DenseTracks:
        """All tracks on the frame grid (:attr:`timestamps_ns`), (K, T) arrays."""
        return dense_tracks(self.annotations, self.ego, self.timestamps_ns)

    def ego_at_frames(self) -> EgoTrajectory:
        """Ego poses interpolated to the annotation timestamps."""
        return self.ego.interpolate(self.timestamps_ns)


def log_folder_problem(log_dir: Path) -> str:
    """Why ``log_dir`` is not a log folder, in words: it does not exist, is a symbolic-link loop, or is a file."""
    try:
        os.stat(log_dir)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return f"symbolic-link loop: {log_dir} never resolves to a folder"
        return "log folder does not exist"
    return "not a folder"


#: Suffix of the folders holding per-frame instance masks beside a camera's frames.
INSTANCE_SUFFIX = "_instance"

#: Annotation timestamps may lie this far outside the pose stream (AV2 sweeps start slightly
#: before the first pose); beyond it, poses would be extrapolated and are refused.
POSE_COVERAGE_TOLERANCE_NS = 200_000_000


def _outside_poses(ts: NDArray[np.int64], ego: EgoTrajectory) -> tuple[NDArray[np.bool_], int, int]:
    """(T,) which of ``ts`` lie beyond the poses' span and its tolerance; the span's first and last time."""
    lo, hi = int(ego.timestamps_ns[0]), int(ego.timestamps_ns[-1])
    return (ts < lo - POSE_COVERAGE_TOLERANCE_NS) | (ts > hi + POSE_COVERAGE_TOLERANCE_NS), lo, hi


def _check_pose_coverage(log_dir: Path, annotations: Annotations, ego: EgoTrajectory) -> list[Problem]:
    ts = annotations.timestamps_ns
    outside, lo, hi = _outside_poses(ts, ego)
    if outside.any():
        first = int(ts[np.argmax(outside)])
        return [
            Problem(log_dir / av2_io.ANNOTATIONS_FILENAME,
                    f"timestamp {first} has no ego pose (poses cover {lo}..{hi})", field="timestamp_ns")
        ]
    return []


def _check_sweep_times(log_dir: Path, ego: EgoTrajectory) -> list[Problem]:
    """A LiDAR sweep named at a time the ego poses do not cover (``1.feather``, a sweep of another log):
    its name is its timestamp, so it would add a frame outside the log and stretch its time grid."""
    lidar_dir = log_dir / av2_io.LIDAR_DIR
    ts = timestamps_in(lidar_dir, ".feather")
    outside, lo, hi = _outside_poses(ts, ego)
    if not outside.any():
        return []
    first = int(ts[np.argmax(outside)])
    return [Problem(lidar_dir / f"{first}.feather",
                    f"the sweep's name gives the time {first} ns, outside the ego poses ({lo}..{hi} ns); "
                    f"{int(outside.sum())} sweep(s) of {ts.shape[0]} lie outside the log",
                    field="timestamp_ns (file name)")]

