"""The log contract as the readers check it: the columns of each table and the checks of their values.

The readers of :mod:`scenes.av2_io` and :mod:`scenes.sensors` run these checks on everything they
read; :func:`scenes.validate.validate_log` calls the readers. Each check returns
:class:`~scenes.errors.Problem` records naming the file, the row and the field; nothing is repaired.

A schema maps each column name to the Arrow type family its values must belong to: ``int``,
``int64_ns`` (a timestamp: int64 nanoseconds), ``float`` (integers accepted) or ``str``.

Beyond types, values must be physically plausible; the bounds live here, in one place:

- city-frame coordinates (ego poses, map points): every coordinate within
  :data:`MAX_CITY_COORDINATE_M` of the city origin, which holds any projected frame in use (UTM
  northings stay below 1e7 m);
- ego-frame annotation centres: every coordinate within :data:`MAX_EGO_FRAME_COORDINATE_M` of the
  ego (LiDAR labels reach about 250 m, imported WOMD tracks about 300 m);
- box sizes: positive and at most :data:`MAX_BOX_SIZE_M` (an articulated truck is about 25 m);
- timestamps: int64 nanoseconds, consecutive distinct ones a median of at least
  :data:`MIN_TIMESTAMP_STEP_NS` apart (no sensor of a log runs faster), which tells seconds,
  milliseconds and microseconds apart from nanoseconds whatever the epoch (WOMD logs start at 0);
- ego poses around an annotation timestamp at most ``max_pose_gap_s`` apart
  (:data:`DEFAULT_MAX_POSE_GAP_S` unless the caller raises it), so that poses are interpolated over
  short spans only.

A violation is a :class:`~scenes.errors.Problem` naming the file, the row, the field, the value and
the bound.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
from numpy.typing import NDArray

from scenes.errors import LogFormatError, Problem

#: The rotation (unit quaternion, w first) and translation of a pose: shared by the ego poses,
#: the annotation boxes and the sensor extrinsics.
QUAT_COLUMNS: tuple[str, ...] = ("qw", "qx", "qy", "qz")
TRANSLATION_COLUMNS: tuple[str, ...] = ("tx_m", "ty_m", "tz_m")
SIZE_COLUMNS: tuple[str, ...] = ("length_m", "width_m", "height_m")
SE3_COLUMNS: dict[str, str] = {name: "float" for name in (*QUAT_COLUMNS, *TRANSLATION_COLUMNS)}

#: ``annotations.feather``.
ANNOTATION_COLUMNS: dict[str, str] = {
    "timestamp_ns": "int64_ns",
    "track_uuid": "str",
    "category": "str",
    **{name: "float" for name in SIZE_COLUMNS},
    **SE3_COLUMNS,
}
OPTIONAL_ANNOTATION_COLUMNS: dict[str, str] = {"num_interior_pts": "int"}

#: ``city_SE3_egovehicle.feather``.
POSE_COLUMNS: dict[str, str] = {"timestamp_ns": "int64_ns", **SE3_COLUMNS}

#: ``calibration/egovehicle_SE3_sensor.feather``.
EXTRINSICS_COLUMNS: dict[str, str] = {"sensor_name": "str", **SE3_COLUMNS}

#: ``calibration/intrinsics.feather`` (the distortion terms ``k1 k2 k3`` are optional, 0 when absent).
INTRINSICS_COLUMNS: dict[str, str] = {
    "sensor_name": "str",
    "fx_px": "float",
    "fy_px": "float",
    "cx_px": "float",
    "cy_px": "float",
    "height_px": "int",
    "width_px": "int",
}
OPTIONAL_INTRINSICS_COLUMNS: dict[str, str] = {"k1": "float", "k2": "float", "k3": "float"}

#: ``sensors/lidar/<timestamp_ns>.feather``: ``x y z`` are required, the rest optional.
LIDAR_REQUIRED_COLUMNS: dict[str, str] = {"x": "float", "y": "float", "z": "float"}
LIDAR_OPTIONAL_COLUMNS: dict[str, str] = {"intensity": "int", "laser_number": "int", "offset_ns": "int"}
#: The Arrow types AV2 stores a sweep in, and the writer keeps (float16 metres in the ego frame).
LIDAR_COLUMNS: dict[str, str] = {"x": "halffloat", "y": "halffloat", "z": "halffloat", "intensity": "uint8",
                                 "laser_number": "uint8", "offset_ns": "int32"}

#: A quaternion whose norm is further than this from 1 is not a rotation.
QUAT_NORM_TOLERANCE = 1e-2
#: A matrix is a rotation when ``R·Rᵀ`` is within this of the identity (entrywise) and its determinant
#: within this of +1. Calibration files print rotations to 6–7 digits (KITTI: errors about 1e-7).
ROTATION_TOLERANCE = 1e-3
#: Fastest believable ego speed between consecutive poses. Anything faster is a pose jump.
MAX_EGO_SPEED_MPS = 70.0
#: Largest absolute city-frame coordinate (ego poses, map points), in metres.
MAX_CITY_COORDINATE_M = 1e7
#: Largest absolute ego-frame coordinate of an annotation's box centre, in metres.
MAX_EGO_FRAME_COORDINATE_M = 1000.0
#: Largest box length, width or height, in metres.
MAX_BOX_SIZE_M = 60.0
#: Smallest believable median step between consecutive distinct timestamps of a table, in
#: nanoseconds (0.5 ms: 2 kHz). Poses run at about 200 Hz (5 ms), annotations at 10 Hz (100 ms); the
#: same streams in microseconds step 5 µs and 100 µs, below it.
MIN_TIMESTAMP_STEP_NS = 500_000
#: Default largest gap, in seconds, between the two ego poses an annotation timestamp is
#: interpolated between. AV2 poses are about 5 ms apart, KITTI and WOMD poses 100 ms.
DEFAULT_MAX_POSE_GAP_S = 1.0


def _type_ok(arrow_type: pa.DataType, family: str) -> bool:
    if family == "int64_ns":
        return bool(pa.types.is_int64(arrow_type))
    if family == "int":
        return bool(pa.types.is_integer(arrow_type))
    if family == "float":
        return bool(pa.types.is_floating(arrow_type) or pa.types.is_integer(arrow_type))
    if family == "str":
        if pa.types.is_dictionary(arrow_type):  # categorical columns (pandas Categorical) hold strings too
            arrow_type = arrow_type.value_type
        return bool(pa.types.is_string(arrow_type) or pa.types.is_large_string(arrow_type))
    raise ValueError(family)


def check_columns(
    path: Path, table: pa.Table, required: dict[str, str], optional: dict[str, str] | None = None
) -> list[Problem]:
    """Columns named twice, missing columns, wrong type families, and nulls."""
    problems = []
    names = table.column_names
    for name in sorted({n for n in names if names.count(n) > 1}):
        problems.append(Problem(path, f"column appears {names.count(name)} times", field=name))
    if problems:
        return problems
    for name, family in {**required, **(optional or {})}.items():
        if name not in table.column_names:
            if name in required:
                problems.append(Problem(path, "missing column", field=name))
            continue
        column = table.column(name)
        if not _type_ok(column.type, family):
            if family == "int64_ns":
                message = (f"wrong type {column.type}: the column must hold int64 nanoseconds "
                           "(seconds or milliseconds must be converted)")
            else:
                message = f"wrong type {column.type}, expected {family}"
            problems.append(Problem(path, message, field=name))
        elif column.null_count:
            first_null = int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
            problems.append(Problem(path, "null value", field=name, row=first_null))
    return problems


def read_feather(path: Path, required: dict[str, str], optional: dict[str, str] | None = None,
                 only_required: bool = False) -> pa.Table:
    """Read a feather table whose columns pass :func:`check_columns`; with ``only_required``, only the
    required columns are read and checked (the others are neither decompressed nor converted).

    Raises:
        LogFormatError: the file is missing or unreadable, or its columns are wrong (each one named).
    """
    if not path.is_file():
        raise LogFormatError.single(path, why_not_a_file(path))
    # Stages run in parallel across logs (a task per log), and a log's files are small (a LiDAR sweep, a
    # log's annotations or poses): pyarrow's own threads would only add CPU time (a sweep reads in 0.5
    # CPU-ms without them, 0.9 with them). A read of some columns fails on a column missing or named
    # twice: the whole table is read then, so that the check below names it.
    try:
        table = feather.read_table(path, columns=list(required), use_threads=False) if only_required else None
    except (OSError, pa.ArrowException):
        table = None
    try:
        table = feather.read_table(path, use_threads=False) if table is None else table
    except (OSError, pa.ArrowException) as exc:
        raise LogFormatError.single(path, f"unreadable feather file (truncated or corrupt?): {exc}") from exc
    optional = None if only_required else optional
    problems = check_columns(path, table, required, optional)
    if problems:
        raise LogFormatError(problems)
    for i, field in enumerate(table.schema):  # categorical columns as the plain strings they hold
        if pa.types.is_dictionary(field.type):
            column = table.column(i)
            plain = pa.chunked_array([chunk.dictionary_decode() for chunk in column.chunks], field.type.value_type)
            table = table.set_column(i, field.name, plain)
    return table


def why_not_a_file(path: Path) -> str:
    """Why ``path`` cannot be opened as a file, in words: a symbolic-link loop, a link to nothing,
    a folder, or no entry at all ("file is missing")."""
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return f"symbolic-link loop: {path} never resolves to a file"
        if os.path.islink(path):
            return f"broken symbolic link to {os.readlink(path)}"
        if exc.errno == errno.ENOENT:
            return "file is missing"
        return f"cannot read: {exc.strerror}"
    return "is a folder, not a file" if path.is_dir() else "not a regular file"


def check_finite(path: Path, columns: Mapping[str, NDArray[np.floating]]) -> list[Problem]:
    """NaN or inf in any float column (each (N,)); names the first bad row of each column."""
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


def check_rotations(path: Path, rotation: NDArray[np.floating], field: str) -> list[Problem]:
    """Matrices that are not proper rotations: not orthonormal, or a reflection (determinant −1).

    ``rotation``: (N, 3, 3). An all-zero or scaled matrix fails, which would otherwise collapse or
    stretch every point it maps.
    """
    rot = np.asarray(rotation, dtype=np.float64).reshape(-1, 3, 3)
    if rot.shape[0] == 0:
        return []
    gram_error = np.abs(rot @ np.swapaxes(rot, 1, 2) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot)
    bad = ~((gram_error <= ROTATION_TOLERANCE) & (np.abs(det - 1.0) <= ROTATION_TOLERANCE))
    if not bad.any():
        return []
    row = int(np.argmax(bad))
    return [
        Problem(path, f"not a proper rotation: max |R·Rᵀ − I| = {gram_error[row]:.3g}, det = {det[row]:.3g} "
                "(expected orthonormal, determinant +1)", field=field, row=row)
    ]


def check_positive(path: Path, columns: Mapping[str, NDArray[np.number]], what: str) -> list[Problem]:
    """Values that are zero or negative in any column (each (N,)); names the first bad row of each.

    NaN fails too (it is not positive), so a missing value cannot slip through a ``<= 0`` test.
    """
    problems = []
    for name, values in columns.items():
        bad = ~(np.asarray(values, dtype=np.float64) > 0)
        if bad.any():
            problems.append(Problem(path, f"{what} must be positive", field=name, row=int(np.argmax(bad))))
    return problems


def check_unique_timestamps(path: Path, timestamps_ns: NDArray[np.integer]) -> list[Problem]:
    """A timestamp that appears on more than one row (in any order). ``timestamps_ns``: (N,).

    Names the later of the first two rows that share a timestamp.
    """
    if timestamps_ns.shape[0] < 2:
        return []
    order = np.argsort(timestamps_ns, kind="stable")
    ts = timestamps_ns[order]
    dup = ts[1:] == ts[:-1]
    if dup.any():
        i = int(np.argmax(dup))
        first, second = sorted((int(order[i]), int(order[i + 1])))
        return [Problem(path, f"timestamp {int(ts[i])} appears twice (rows {first} and {second}); "
                        "timestamps must be unique int64 nanoseconds (seconds or milliseconds repeat)",
                        field="timestamp_ns", row=second)]
    return []


def check_unique_track_per_frame(
    path: Path, timestamps_ns: NDArray[np.integer], track_ids: NDArray[np.str_]
) -> list[Problem]:
    """A track id appearing twice at one timestamp. ``timestamps_ns``, ``track_ids``: (N,)."""
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


def check_one_category_per_track(
    path: Path, track_ids: NDArray[np.str_], categories: NDArray[np.str_]
) -> list[Problem]:
    """A track whose rows name more than one category; ``track_ids``, ``categories``: (N,)."""
    if track_ids.shape[0] < 2:
        return []
    pairs = np.unique(np.stack([track_ids, categories], axis=1), axis=0)
    tracks, counts = np.unique(pairs[:, 0], return_counts=True)
    mixed = tracks[counts > 1]
    if mixed.size == 0:
        return []
    track = str(mixed[0])
    rows = np.flatnonzero(track_ids == track)
    first = categories[rows[0]]
    other = int(rows[np.argmax(categories[rows] != first)])
    names = sorted({str(c) for c in categories[rows]})
    more = f" ({mixed.size - 1} more tracks likewise)" if mixed.size > 1 else ""
    return [Problem(path, f"track '{track}' is labelled {' and '.join(names)}: a track keeps one category{more}",
                    field="category", row=other)]


def check_pose_jumps(
    path: Path, timestamps_ns: NDArray[np.integer], translation_m: NDArray[np.floating]
) -> list[Problem]:
    """Consecutive poses further apart than :data:`MAX_EGO_SPEED_MPS` allows.

    ``timestamps_ns``: (N,); ``translation_m``: (N, 3).
    """
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


def check_bounds(path: Path, columns: Mapping[str, NDArray[np.floating]], bound_m: float, what: str) -> list[Problem]:
    """Values whose magnitude exceeds ``bound_m`` in any column (each (N,)); names the first bad row
    of each column, its value and the bound. NaN is left to :func:`check_finite`."""
    problems = []
    for name, values in columns.items():
        bad = np.abs(np.asarray(values, dtype=np.float64)) > bound_m
        if bad.any():
            row = int(np.argmax(bad))
            problems.append(Problem(path, f"{what} {float(values[row]):.6g} m is beyond the bound of "
                                    f"±{bound_m:g} m", field=name, row=row))
    return problems


#: Largest roll or pitch of a believable ego pose, in degrees (the steepest streets tilt a car by about 20°).
MAX_EGO_TILT_DEG = 45.0


def check_upright(path: Path, quat_wxyz: NDArray[np.floating]) -> list[Problem]:
    """Ego poses that roll or pitch the vehicle beyond :data:`MAX_EGO_TILT_DEG`: most often quaternions
    written scalar-last (x, y, z, w) into the (qw, qx, qy, qz) columns, which turns the car on its side.
    ``quat_wxyz``: (N, 4) unit quaternions; names the first row."""
    w, x, y, z = (np.asarray(quat_wxyz, dtype=np.float64)[:, i] for i in range(4))
    roll_deg = np.degrees(np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)))
    pitch_deg = np.degrees(np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0)))
    tilted = (np.abs(roll_deg) > MAX_EGO_TILT_DEG) | (np.abs(pitch_deg) > MAX_EGO_TILT_DEG)
    if not tilted.any():
        return []
    row = int(np.argmax(tilted))
    return [Problem(path, f"the ego is rolled {roll_deg[row]:.0f}° and pitched {pitch_deg[row]:.0f}° "
                          f"({int(tilted.sum())} of {tilted.shape[0]} poses beyond ±{MAX_EGO_TILT_DEG:g}°): are the "
                          "quaternions in (qw, qx, qy, qz) order?", field="qw,qx,qy,qz", row=row)]


def check_box_sizes(path: Path, size_lwh_m: NDArray[np.floating]) -> list[Problem]:
    """Box sizes that are not positive or exceed :data:`MAX_BOX_SIZE_M`. ``size_lwh_m``: (N, 3)."""
    columns = {name: size_lwh_m[:, axis] for axis, name in enumerate(SIZE_COLUMNS)}
    problems = check_positive(path, columns, "box size")
    for name, values in columns.items():
        bad = values > MAX_BOX_SIZE_M
        if bad.any() and not any(p.field == name for p in problems):
            row = int(np.argmax(bad))
            problems.append(Problem(path, f"box size {float(values[row]):.6g} m exceeds the bound of "
                                    f"{MAX_BOX_SIZE_M:g} m", field=name, row=row))
    return problems


def check_unique_names(path: Path, names: list[str], field: str) -> list[Problem]:
    """A name on more than one row (``sensor_name`` of a calibration file): which row holds it is
    ambiguous, so the file is refused. Names each repeated name with its rows."""
    rows: dict[str, list[int]] = {}
    for row, name in enumerate(names):
        rows.setdefault(name, []).append(row)
    return [
        Problem(path, f"'{name}' appears on rows {', '.join(map(str, where))}; each must appear once",
                field=field, row=where[1])
        for name, where in rows.items()
        if len(where) > 1
    ]


def check_timestamp_unit(path: Path, timestamps_ns: NDArray[np.integer]) -> list[Problem]:
    """Timestamps that are not nanoseconds: consecutive distinct values a median of fewer than
    :data:`MIN_TIMESTAMP_STEP_NS` apart (seconds, milliseconds or microseconds). ``timestamps_ns``: (N,)."""
    distinct = np.unique(timestamps_ns)
    if distinct.shape[0] < 2:
        return []
    step = float(np.median(np.diff(distinct)))
    if step >= MIN_TIMESTAMP_STEP_NS:
        return []
    return [
        Problem(path, f"consecutive timestamps are a median of {step:g} apart, closer than "
                f"{MIN_TIMESTAMP_STEP_NS} ns: these are not nanoseconds (seconds, milliseconds or "
                "microseconds?); the column must hold int64 nanoseconds", field="timestamp_ns")
    ]


def check_pose_gaps(
    path: Path, pose_timestamps_ns: NDArray[np.integer], query_timestamps_ns: NDArray[np.integer], max_gap_s: float
) -> list[Problem]:
    """Gaps longer than ``max_gap_s`` between the two poses a query timestamp is interpolated between.

    One problem per such gap, naming both poses' rows as they are in the file, their timestamps and
    the first query timestamp inside the gap. Queries on a pose's own timestamp, or outside the pose
    stream, are not interpolated and never fail here.

    Args:
        path: the poses file.
        pose_timestamps_ns: (N,) unique pose timestamps, in file order.
        query_timestamps_ns: (Q,) timestamps that poses are interpolated to (annotation timestamps).
        max_gap_s: the largest gap allowed.
    """
    if pose_timestamps_ns.shape[0] < 2 or query_timestamps_ns.shape[0] == 0:
        return []
    order = np.argsort(pose_timestamps_ns, kind="stable")
    ts = np.asarray(pose_timestamps_ns, dtype=np.int64)[order]
    queries = np.unique(np.asarray(query_timestamps_ns, dtype=np.int64))
    after = np.searchsorted(ts, queries, side="right")  # first pose later than the query
    inside = (after > 0) & (after < ts.shape[0])
    after_in = np.clip(after, 1, ts.shape[0] - 1)
    interpolated = inside & (ts[after_in - 1] != queries)
    gap_ns = ts[after_in] - ts[after_in - 1]
    bad = interpolated & (gap_ns > max_gap_s * 1e9)
    problems = []
    for gap_index in np.unique(after_in[bad]):
        first_query = int(queries[bad & (after_in == gap_index)][0])
        t0, t1 = int(ts[gap_index - 1]), int(ts[gap_index])
        r0, r1 = int(order[gap_index - 1]), int(order[gap_index])
        problems.append(Problem(
            path, f"ego poses at {t0} (row {r0}) and {t1} (row {r1}) are {(t1 - t0) * 1e-9:.3f} s apart, more "
            f"than the limit of {max_gap_s:g} s; annotation timestamp {first_query} lies in the gap and its "
            "pose would be interpolated across it (if the poses really are this sparse, raise the limit: "
            "max_pose_gap_s of Log.open and validate_log, --max-pose-gap-s of scenesearch validate)",
            field="timestamp_ns", row=r1))
    return problems
