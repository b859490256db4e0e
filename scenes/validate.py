"""``scenesearch validate``: every check of the log contract on one log folder, as a report.

The checks themselves are the readers' (:mod:`scenes.av2_io`, :mod:`scenes.sensors`, with the
schema and plausibility bounds of :mod:`scenes.schema`): a log validates exactly when everything in
it can be read. On top of the readers, the report checks what they take on trust: the first bytes
of each camera frame, and sweeps without points. Nothing is repaired; every problem is collected,
not just the first.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from scenes import av2_io, map_schema, schema
from scenes.calibration import CameraIntrinsics
from scenes.errors import LogFormatError, Problem, collect_problems
from scenes.log import Log, log_folder_problem
from scenes.sensors import JPEG_END, JPEG_START, JPEG_TAIL_BYTES, read_camera_frame, read_lidar_sweep, timestamps_in


@dataclass(frozen=True)
class ValidationReport:
    """Everything ``scenesearch validate`` found out about one log.

    Attributes:
        log_dir: the log folder.
        problems: errors; a log with any problem fails validation.
        warnings: things that are allowed but worth knowing (unknown categories mapped to
            ``other``, a missing map, missing calibration).
        facts: what the log holds when it opens: ``frames`` (distinct annotation timestamps),
            ``tracks``, ``duration_s`` (first to last annotation timestamp), ``lidar_sweeps``,
            ``cameras``, ``camera_frames``, ``has_map``, ``source``.
    """

    log_dir: Path
    problems: list[Problem] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    facts: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.problems

    def summary(self) -> str:
        """One line: ``OK <log> (facts; warnings)`` or ``FAIL <log>: n problems``."""
        if not self.ok:
            return f"FAIL {self.log_dir}: {len(self.problems)} problem(s)"
        facts = ", ".join(f"{k}={v}" for k, v in self.facts.items())
        text = f"OK {self.log_dir} ({facts})"
        if self.warnings:
            text += "; warnings: " + "; ".join(self.warnings)
        return text

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "log_dir": str(self.log_dir),
            "ok": self.ok,
            "problems": [
                {"path": str(p.path), "row": p.row, "field": p.field, "message": p.message} for p in self.problems
            ],
            "warnings": list(self.warnings),
            "facts": dict(self.facts),
        }


def check_lidar_sweep_file(path: Path) -> list[Problem]:
    """What :func:`scenes.sensors.read_lidar_sweep` finds wrong with one sweep, and a sweep without points."""
    problems: list[Problem] = []
    sweep = collect_problems(problems, read_lidar_sweep, path)
    if sweep is not None and len(sweep) == 0:
        problems.append(Problem(path, "sweep has no points"))
    return problems


def check_camera_frame_file(path: Path) -> list[Problem]:
    """A camera frame must be a whole JPEG: its first and last bytes are checked (a truncated file loses
    its end-of-image marker), not the image between them."""
    try:
        with path.open("rb") as f:
            head = f.read(2)
            f.seek(max(0, path.stat().st_size - JPEG_TAIL_BYTES))
            tail = f.read()
    except OSError as exc:
        return [Problem(path, f"unreadable image: {exc}")]
    if head != JPEG_START:
        return [Problem(path, "not a JPEG file (empty or wrong format)")]
    if JPEG_END not in tail:
        return [Problem(path, "truncated JPEG (no end-of-image marker)")]
    return []


def check_frame_size(path: Path, intrinsics: CameraIntrinsics) -> list[Problem]:
    """A camera image of another size than its intrinsics say (another camera's, or resized): boxes would be
    projected onto the wrong pixels. The first frame of each camera is decoded for its size."""
    try:
        height_px, width_px = read_camera_frame(path).shape[:2]
    except LogFormatError:
        return []  # unreadable: check_camera_frame_file says so
    if (width_px, height_px) == (intrinsics.width_px, intrinsics.height_px):
        return []
    return [Problem(path, f"the image is {width_px}×{height_px} px, the camera's intrinsics say "
                          f"{intrinsics.width_px}×{intrinsics.height_px} px", field="width_px,height_px")]


def validate_log(log_dir: Path | str, max_pose_gap_s: float = schema.DEFAULT_MAX_POSE_GAP_S) -> ValidationReport:
    """Run every check of the log contract on one log folder, including the parts that
    :meth:`scenes.log.Log.open` reads lazily (map, calibration, LiDAR sweeps, camera frames,
    metadata). Nothing is repaired; every problem is collected, not just the first.

    Args:
        log_dir: the log folder.
        max_pose_gap_s: as for :meth:`scenes.log.Log.open`.
    """
    log_dir = Path(log_dir)
    problems: list[Problem] = []
    warnings: list[str] = []
    facts: dict[str, Any] = {}
    if not log_dir.is_dir():
        return ValidationReport(log_dir, [Problem(log_dir, log_folder_problem(log_dir))])

    log = collect_problems(problems, Log.open, log_dir, max_pose_gap_s)
    metadata = collect_problems(problems, av2_io.read_metadata, log_dir)
    map_problems: list[Problem] = []
    map_path = collect_problems(map_problems, av2_io.find_map_file, log_dir)
    problems.extend(map_problems)
    if map_path is not None:
        vector_map = collect_problems(problems, av2_io.read_map, map_path)
        if vector_map is not None and log is not None:
            problems += map_schema.check_map_covers_poses(map_path, vector_map, log.ego.translation_m[:, :2])
    elif not map_problems:
        warnings.append("no map (map/log_map_archive_*.json)")
    calibration = collect_problems(problems, av2_io.read_calibration, log_dir)

    lidar_dir = log_dir / av2_io.LIDAR_DIR
    lidar_ts = timestamps_in(lidar_dir, ".feather")
    for ts in lidar_ts:
        problems.extend(check_lidar_sweep_file(lidar_dir / f"{int(ts)}.feather"))
    if lidar_dir.is_dir():
        for p in sorted(lidar_dir.iterdir()):
            if p.suffix == ".feather" and not p.stem.isdigit():
                problems.append(Problem(p, "sweep file name is not <timestamp_ns>.feather"))

    cameras_dir = log_dir / av2_io.CAMERAS_DIR
    camera_names = sorted(p.name for p in cameras_dir.iterdir() if p.is_dir()) if cameras_dir.is_dir() else []
    camera_frames = 0
    for name in camera_names:
        stamps = timestamps_in(cameras_dir / name, ".jpg")
        camera_frames += int(stamps.shape[0])
        for ts in stamps:
            problems.extend(check_camera_frame_file(cameras_dir / name / f"{int(ts)}.jpg"))
        if calibration is not None and calibration.intrinsics and name not in calibration.intrinsics:
            warnings.append(f"camera '{name}' has no intrinsics")
        if calibration is not None and stamps.shape[0] and name not in calibration.ego_SE3_sensor:
            warnings.append(f"camera '{name}' has {stamps.shape[0]} frames but no row in "
                            f"{av2_io.EXTRINSICS_PATH}: its frames cannot be placed")
        if calibration is not None and stamps.shape[0] and name in calibration.intrinsics:
            problems.extend(check_frame_size(cameras_dir / name / f"{int(stamps[0])}.jpg",
                                             calibration.intrinsics[name]))

    if log is not None:
        # Frames are the annotated timestamps: sweeps without annotations (a log cut to a few
        # frames keeps its sweeps) neither add frames nor stretch the duration.
        ts = log.annotations.timestamps_ns
        facts["frames"] = int(ts.shape[0])
        facts["tracks"] = len(log.annotations.without_ego().track_ids)
        facts["duration_s"] = round(float(ts[-1] - ts[0]) * 1e-9, 3) if ts.shape[0] else 0.0
        if log.unknown_categories:
            listed = ", ".join(f"{k}={v}" for k, v in sorted(log.unknown_categories.items()))
            warnings.append(f"unknown categories mapped to 'other': {listed}")
        ann = log.annotations
        warnings += [str(p) for p in schema.check_one_category_per_track(
            log.log_dir / av2_io.ANNOTATIONS_FILENAME, ann.track_id, ann.category)]
    facts["lidar_sweeps"] = int(lidar_ts.shape[0])
    facts["cameras"] = len(camera_names)
    facts["camera_frames"] = camera_frames
    facts["has_map"] = map_path is not None
    if metadata is not None:
        facts["source"] = metadata.source
    return ValidationReport(log_dir, problems, warnings, facts)
