"""The log contract as the readers check it: the columns of each table and the checks of their values.

The readers of :mod:`scenes.av2_io` and :mod:`scenes.sensors` run these checks on everything they
read; :func:`scenes.validate.validate_log` calls the readers. Each check returns
:class:`~scenes.errors.Problem` records naming the file, the row and the field; nothing is repaired.

A schema maps each column name to the Arrow type family its values must belong to: ``int``,
``float`` (integers accepted) or ``str``.
"""

from __future__ import annotations

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
    "timestamp_ns": "int",
    "track_uuid": "str",
    "category": "str",
    **{name: "float" for name in SIZE_COLUMNS},
    **SE3_COLUMNS,
}
OPTIONAL_ANNOTATION_COLUMNS: dict[str, str] = {"num_interior_pts": "int"}

#: ``city_SE3_egovehicle.feather``.
POSE_COLUMNS: dict[str, str] = {"timestamp_ns": "int", **SE3_COLUMNS}

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
LIDAR_COLUMNS: dict[str, str] = {
    "x": "halffloat",
    "y": "halffloat",
    "z": "halffloat",
    "intensity": "uint8",
    "laser_number": "uint8",
    "offset_ns": "int32",
}

#: A quaternion whose norm is further than this from 1 is not a rotation.
QUAT_NORM_TOLERANCE = 1e-2
#: A matrix is a rotation when ``R·Rᵀ`` is within this of the identity (entrywise) and its determinant
#: within this of +1. Calibration files print rotations to 6–7 digits (KITTI: errors about 1e-7).
ROTATION_TOLERANCE = 1e-3
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


def read_feather(path: Path, required: dict[str, str], optional: dict[str, str] | None = None) -> pa.Table:
    """Read a feather table whose columns pass :func:`check_columns`.

    Raises:
        LogFormatError: the file is missing or unreadable, or its columns are wrong (each one named).
    """
    if not path.is_file():
        raise LogFormatError.single(path, "file is missing")
    try:
        table = feather.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise LogFormatError.single(path, f"unreadable feather file (truncated or corrupt?): {exc}") from exc
    problems = check_columns(path, table, required, optional)
    if problems:
        raise LogFormatError(problems)
    return table


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
                        "timestamps must be unique", field="timestamp_ns", row=second)]
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


def check_positive_sizes(path: Path, size_lwh_m: NDArray[np.floating]) -> list[Problem]:
    """Box sizes that are zero or negative. ``size_lwh_m``: (N, 3)."""
    return check_positive(path, {name: size_lwh_m[:, axis] for axis, name in enumerate(SIZE_COLUMNS)}, "box size")


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
