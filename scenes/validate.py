"""Checks of the log contract, run on every open and by ``scenesearch validate``.

Each check returns :class:`~scenes.errors.Problem` records naming the file, the row or frame and
the field. Nothing is repaired: a reader either gets valid data or an error listing every problem.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from scenes.errors import Problem

if TYPE_CHECKING:
    from scenes.map import VectorMap

#: Columns of ``annotations.feather`` and the Arrow type family each must belong to.
ANNOTATION_COLUMNS: dict[str, str] = {
    "timestamp_ns": "int",
    "track_uuid": "str",
    "category": "str",
    "length_m": "float",
    "width_m": "float",
    "height_m": "float",
    "qw": "float",
    "qx": "float",
    "qy": "float",
    "qz": "float",
    "tx_m": "float",
    "ty_m": "float",
    "tz_m": "float",
}
OPTIONAL_ANNOTATION_COLUMNS: dict[str, str] = {"num_interior_pts": "int"}

POSE_COLUMNS: dict[str, str] = {
    "timestamp_ns": "int",
    "qw": "float",
    "qx": "float",
    "qy": "float",
    "qz": "float",
    "tx_m": "float",
    "ty_m": "float",
    "tz_m": "float",
}

#: A quaternion whose norm is further than this from 1 is not a rotation.
QUAT_NORM_TOLERANCE = 1e-2
#: Fastest believable ego speed between consecutive poses. Anything faster is a pose jump.
MAX_EGO_SPEED_MPS = 70.0


def _type_ok(arrow_type: pa.DataType, family: str) -> bool:
    if family == "int":
        return bool(pa.types.is_integer(arrow_type))
    if family == "float":
        return bool(pa.types.is_floating(arrow_type) or pa.types.is_integer(arrow_type))
    if family == "str":
        return bool(pa.types.is_string(arrow_type) or pa.types.is_large_string(arrow_type))
    raise ValueError(family)


def check_columns(
    path: Path, table: pa.Table, required: dict[str, str], optional: dict[str, str] | None = None
) -> list[Problem]:
    """Missing columns, wrong type families, and nulls."""
    problems = []
    for name, family in {**required, **(optional or {})}.items():
        if name not in table.column_names:
            if name in required:
                problems.append(Problem(path, "missing column", field=name))
            continue
        column = table.column(name)
        if not _type_ok(column.type, family):
            problems.append(Problem(path, f"wrong type {column.type}, expected {family}", field=name))
        elif column.null_count:
            first_null = int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
            problems.append(Problem(path, "null value", field=name, row=first_null))
    return problems


def check_finite(path: Path, columns: Mapping[str, NDArray[np.floating]]) -> list[Problem]:
    """NaN or inf in any float column; names the first bad row of each column."""
    problems = []
    for name, values in columns.items():
        bad = ~np.isfinite(values)
        if bad.any():
            problems.append(Problem(path, "NaN or inf value", field=name, row=int(np.argmax(bad))))
    return problems


def check_quaternions(path: Path, quat_wxyz: NDArray[np.floating]) -> list[Problem]:
    """Quaternions far from unit norm. ``quat_wxyz``: (N, 4)."""
    norm = np.linalg.norm(quat_wxyz, axis=1)
    bad = np.abs(norm - 1.0) > QUAT_NORM_TOLERANCE
    if bad.any():
        row = int(np.argmax(bad))
        return [Problem(path, f"quaternion norm {norm[row]:.4f} is not 1", field="qw..qz", row=row)]
    return []


def check_increasing(path: Path, timestamps_ns: NDArray[np.integer], strict: bool) -> list[Problem]:
    """Timestamps that go backwards (or repeat, when ``strict``). ``timestamps_ns``: (N,)."""
    if timestamps_ns.shape[0] < 2:
        return []
    step = np.diff(timestamps_ns)
    bad = step <= 0 if strict else step < 0
    if bad.any():
        row = int(np.argmax(bad)) + 1
        word = "increasing" if strict else "non-decreasing"
        return [Problem(path, f"timestamps not {word}", field="timestamp_ns", row=row)]
    return []


def check_unique_track_per_frame(
    path: Path, timestamps_ns: NDArray[np.integer], track_ids: NDArray[np.str_]
) -> list[Problem]:
    """A track id appearing twice at one timestamp."""
    if timestamps_ns.shape[0] < 2:
        return []
    order = np.lexsort((track_ids, timestamps_ns))
    ts, ids = timestamps_ns[order], track_ids[order]
    dup = (ts[1:] == ts[:-1]) & (ids[1:] == ids[:-1])
    if dup.any():
        row = int(order[int(np.argmax(dup)) + 1])
        return [
            Problem(path, f"track '{ids[int(np.argmax(dup))]}' appears twice at timestamp {ts[int(np.argmax(dup))]}",
                    field="track_uuid", row=row)
        ]
    return []


def check_positive_sizes(path: Path, size_lwh_m: NDArray[np.floating]) -> list[Problem]:
    """Box sizes that are zero or negative. ``size_lwh_m``: (N, 3)."""
    problems = []
    for axis, name in enumerate(("length_m", "width_m", "height_m")):
        bad = size_lwh_m[:, axis] <= 0
        if bad.any():
            problems.append(Problem(path, "box size must be positive", field=name, row=int(np.argmax(bad))))
    return problems


def check_pose_jumps(
    path: Path, timestamps_ns: NDArray[np.integer], translation_m: NDArray[np.floating]
) -> list[Problem]:
    """Consecutive poses further apart than :data:`MAX_EGO_SPEED_MPS` allows."""
    if timestamps_ns.shape[0] < 2:
        return []
    dt_s = np.diff(timestamps_ns).astype(np.float64) * 1e-9
    dist_m = np.linalg.norm(np.diff(translation_m, axis=0), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = np.where(dt_s > 0, dist_m / dt_s, 0.0)
    bad = speed > MAX_EGO_SPEED_MPS
    if bad.any():
        row = int(np.argmax(bad)) + 1
        return [
            Problem(path, f"pose jumps {dist_m[row - 1]:.2f} m in {dt_s[row - 1] * 1e3:.1f} ms "
                    f"({speed[row - 1]:.0f} m/s > {MAX_EGO_SPEED_MPS:.0f} m/s)", field="tx_m,ty_m,tz_m", row=row)
        ]
    return []


def format_problems(problems: Iterable[Problem]) -> str:
    return "\n".join(str(p) for p in problems)


# ---------------------------------------------------------------------------------------------
# Whole-log validation (``scenesearch validate``)

#: Columns of a LiDAR sweep file: ``x y z`` are required, the rest optional (AV2 types in
#: :data:`scenes.sensors.LIDAR_COLUMNS`).
LIDAR_REQUIRED_COLUMNS: dict[str, str] = {"x": "float", "y": "float", "z": "float"}
LIDAR_OPTIONAL_COLUMNS: dict[str, str] = {"intensity": "int", "laser_number": "int", "offset_ns": "int"}

_JPEG_MAGIC = b"\xff\xd8"


@dataclass(frozen=True)
class ValidationReport:
    """Everything ``scenesearch validate`` found out about one log.

    Attributes:
        log_dir: the log folder.
        problems: errors; a log with any problem fails validation.
        warnings: things that are allowed but worth knowing (unknown categories mapped to
            ``other``, a missing map, missing calibration).
        facts: what the log holds when it opens: ``frames``, ``tracks``, ``duration_s``,
            ``lidar_sweeps``, ``cameras``, ``camera_frames``, ``has_map``, ``source``.
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
    """Columns, types, nulls and finite coordinates of one ``sensors/lidar/<ns>.feather``."""
    import pyarrow.feather as feather

    try:
        table = feather.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        return [Problem(path, f"unreadable feather file (truncated or corrupt?): {exc}")]
    problems = check_columns(path, table, LIDAR_REQUIRED_COLUMNS, LIDAR_OPTIONAL_COLUMNS)
    if problems:
        return problems
    if table.num_rows == 0:
        return [Problem(path, "sweep has no points")]
    coords = {n: np.asarray(table.column(n).to_numpy(), dtype=np.float64) for n in ("x", "y", "z")}
    return check_finite(path, coords)


def check_map_finite(path: Path, vector_map: VectorMap) -> list[Problem]:
    """NaN or inf coordinates in map polylines; names the element and the polyline."""
    polylines: list[tuple[str, NDArray[np.float64]]] = []
    for lane in vector_map.lane_segments.values():
        polylines.append((f"lane_segments[{lane.id}].left_lane_boundary", lane.left_lane_boundary))
        polylines.append((f"lane_segments[{lane.id}].right_lane_boundary", lane.right_lane_boundary))
    for crossing in vector_map.pedestrian_crossings.values():
        polylines.append((f"pedestrian_crossings[{crossing.id}].edge1", crossing.edge1))
        polylines.append((f"pedestrian_crossings[{crossing.id}].edge2", crossing.edge2))
    for area in vector_map.drivable_areas.values():
        polylines.append((f"drivable_areas[{area.id}].area_boundary", area.area_boundary))
    problems = []
    for name, points in polylines:
        bad = ~np.isfinite(points).all(axis=1)
        if bad.any():
            problems.append(Problem(path, "NaN or inf coordinate", field=name, row=int(np.argmax(bad))))
    return problems


def check_camera_frame_file(path: Path) -> list[Problem]:
    """A camera frame must be a non-empty JPEG (its first bytes are checked, not the whole image)."""
    try:
        with path.open("rb") as f:
            head = f.read(2)
    except OSError as exc:
        return [Problem(path, f"unreadable image: {exc}")]
    if head != _JPEG_MAGIC:
        return [Problem(path, "not a JPEG file (empty or wrong format)")]
    return []


def validate_log(log_dir: Path | str) -> ValidationReport:
    """Run every check of the log contract on one log folder, including the parts that
    :meth:`scenes.log.Log.open` reads lazily (map, calibration, LiDAR sweeps, camera frames,
    metadata). Nothing is repaired; every problem is collected, not just the first.
    """
    from scenes import av2_io
    from scenes.errors import LogFormatError
    from scenes.log import Log
    from scenes.sensors import timestamps_in

    log_dir = Path(log_dir)
    problems: list[Problem] = []
    warnings: list[str] = []
    facts: dict[str, Any] = {}
    if not log_dir.is_dir():
        return ValidationReport(log_dir, [Problem(log_dir, "log folder does not exist")])

    log: Log | None = None
    try:
        log = Log.open(log_dir)
    except LogFormatError as exc:
        problems.extend(exc.problems)

    try:
        metadata = av2_io.read_metadata(log_dir)
    except LogFormatError as exc:
        problems.extend(exc.problems)
        metadata = None

    map_path = av2_io.find_map_file(log_dir)
    if map_path is None:
        warnings.append("no map (map/log_map_archive_*.json)")
    else:
        try:
            vector_map = av2_io.read_map(map_path)
        except LogFormatError as exc:
            problems.extend(exc.problems)
        else:
            problems.extend(check_map_finite(map_path, vector_map))

    calibration = None
    try:
        calibration = av2_io.read_calibration(log_dir)
    except LogFormatError as exc:
        problems.extend(exc.problems)

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

    if log is not None:
        ts = log.timestamps_ns
        facts["frames"] = int(ts.shape[0])
        facts["tracks"] = len(log.annotations.without_ego().track_ids)
        facts["duration_s"] = round(float(ts[-1] - ts[0]) * 1e-9, 3) if ts.shape[0] else 0.0
        if log.unknown_categories:
            listed = ", ".join(f"{k}={v}" for k, v in sorted(log.unknown_categories.items()))
            warnings.append(f"unknown categories mapped to 'other': {listed}")
    facts["lidar_sweeps"] = int(lidar_ts.shape[0])
    facts["cameras"] = len(camera_names)
    facts["camera_frames"] = camera_frames
    facts["has_map"] = map_path is not None
    if metadata is not None:
        facts["source"] = metadata.source
    return ValidationReport(log_dir, problems, warnings, facts)
