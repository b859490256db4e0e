"""Read and write logs in the Argoverse 2 sensor layout.

Every reader checks what it reads against :mod:`scenes.schema` and raises
:class:`~scenes.errors.LogFormatError` listing each problem with its file, row and field. Every
writer writes atomically (temp name, then rename), so a reader never sees a half file.

Layout::

    <log_id>/annotations.feather
    <log_id>/city_SE3_egovehicle.feather
    <log_id>/map/log_map_archive_<log_id>____<CITY>_city_0.json
    <log_id>/calibration/egovehicle_SE3_sensor.feather, intrinsics.feather
    <log_id>/sensors/lidar/<timestamp_ns>.feather
    <log_id>/sensors/cameras/<camera>/<timestamp_ns>.jpg
    <log_id>/log_metadata.json                      (beyond AV2; optional)
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
from numpy.typing import NDArray

from scenes import map_schema, schema
from scenes.calibration import Calibration, CameraIntrinsics
from scenes.errors import LogFormatError, MapFormatError, Problem, collect_problems
from scenes.geometry import SE3, quat_to_rotmat
from scenes.map import VectorMap
from scenes.metadata import METADATA_FILENAME, LogMetadata
from scenes.sensors import LidarSweep
from scenes.tracks import Annotations, EgoTrajectory
from scenesearch_base.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from scenesearch_base.folders import FolderKind
from scenesearch_base.lru import Lru

ANNOTATIONS_FILENAME = "annotations.feather"
POSES_FILENAME = "city_SE3_egovehicle.feather"
EXTRINSICS_PATH = Path("calibration") / "egovehicle_SE3_sensor.feather"
INTRINSICS_PATH = Path("calibration") / "intrinsics.feather"
LIDAR_DIR = Path("sensors") / "lidar"
CAMERAS_DIR = Path("sensors") / "cameras"
#: A log folder that scenesearch writes (simulated, imported, tracked; :mod:`scenesearch_base.folders`): the AV2
#: layout and the files beside it. An unmarked folder counts as one when it holds ``log_metadata.json``,
#: which real AV2 logs lack: a user's own log is never replaced.
LOG_FOLDER = FolderKind("log", signature=METADATA_FILENAME, entries=(
    ANNOTATIONS_FILENAME, POSES_FILENAME, "calibration", "map", "sensors", METADATA_FILENAME, "*.feather", "*.json"))


def _write_table(path: Path, table: pa.Table) -> None:
    with atomic_path(path) as tmp:
        feather.write_feather(table, tmp, compression="lz4")


def _float_columns(table: pa.Table, names: tuple[str, ...]) -> dict[str, NDArray[np.float64]]:
    """Each named column as a (N,) float64 array."""
    return {n: np.asarray(table.column(n).to_numpy(), dtype=np.float64) for n in names}


def _stack(columns: dict[str, NDArray[np.float64]], names: tuple[str, ...]) -> NDArray[np.float64]:
    """(N, len(names)) the named columns side by side."""
    return np.stack([columns[n] for n in names], axis=1)


def _read_se3(table: pa.Table) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.float64], NDArray[np.float64]]:
    """The pose columns of a table: by name (each (N,)), the (N, 4) quaternions and the (N, 3) translations."""
    floats = _float_columns(table, (*schema.QUAT_COLUMNS, *schema.TRANSLATION_COLUMNS))
    return floats, _stack(floats, schema.QUAT_COLUMNS), _stack(floats, schema.TRANSLATION_COLUMNS)


def _se3_columns(quat_wxyz: NDArray[np.floating], translation_m: NDArray[np.floating]) -> dict[str, NDArray]:
    """The pose columns ``qw qx qy qz tx_m ty_m tz_m`` of a table. ``quat_wxyz``: (N, 4); ``translation_m``: (N, 3)."""
    return {
        **{n: quat_wxyz[:, i] for i, n in enumerate(schema.QUAT_COLUMNS)},
        **{n: translation_m[:, i] for i, n in enumerate(schema.TRANSLATION_COLUMNS)},
    }


# ---------------------------------------------------------------------------------------------
# Annotations


def read_annotations(path: Path) -> Annotations:
    """Read and validate ``annotations.feather``; rows come back ordered by (timestamp, track id).

    Beyond the columns, values must be plausible (:mod:`scenes.schema`): int64 nanosecond
    timestamps, box centres within :data:`~scenes.schema.MAX_EGO_FRAME_COORDINATE_M` of the ego,
    box sizes positive and at most :data:`~scenes.schema.MAX_BOX_SIZE_M`.

    The file may hold its rows in any order, as av2-api accepts: real logs keep ``EGO_VEHICLE`` rows
    at the end or group rows by track. Problems name the row as it is in the file.
    """
    table = schema.read_feather(path, schema.ANNOTATION_COLUMNS, schema.OPTIONAL_ANNOTATION_COLUMNS)
    if table.num_rows == 0:
        raise LogFormatError.single(path, "table has no rows")
    timestamps = np.asarray(table.column("timestamp_ns").to_numpy(), dtype=np.int64)
    track_ids = np.asarray(table.column("track_uuid").to_pylist(), dtype=np.str_)
    categories = np.asarray(table.column("category").to_pylist(), dtype=np.str_)
    floats = _float_columns(table, (*schema.SIZE_COLUMNS, *schema.QUAT_COLUMNS, *schema.TRANSLATION_COLUMNS))
    size = _stack(floats, schema.SIZE_COLUMNS)
    quat = _stack(floats, schema.QUAT_COLUMNS)
    center = _stack(floats, schema.TRANSLATION_COLUMNS)
    # Timestamps in another unit make frames collide: that is said once, not as repeated tracks.
    unit = schema.check_timestamp_unit(path, timestamps)
    problems = unit + schema.check_finite(path, floats)
    if not problems:
        problems += schema.check_quaternions(path, quat)
        problems += schema.check_box_sizes(path, size)
        problems += schema.check_bounds(path, {n: floats[n] for n in schema.TRANSLATION_COLUMNS},
                                        schema.MAX_EGO_FRAME_COORDINATE_M, "ego-frame coordinate")
    if not unit:
        problems += schema.check_unique_track_per_frame(path, timestamps, track_ids)
    if problems:
        raise LogFormatError(problems)
    if "num_interior_pts" in table.column_names:
        points = np.asarray(table.column("num_interior_pts").to_numpy(), dtype=np.int64)
    else:
        points = np.full(table.num_rows, -1, dtype=np.int64)
    annotations = Annotations(timestamps, track_ids, categories, center, size, quat, points)
    return annotations if _in_canonical_order(timestamps, track_ids) else annotations.sorted()


def _in_canonical_order(timestamps_ns: NDArray[np.int64], track_ids: NDArray[np.str_]) -> bool:
    """Whether rows are already ordered by (timestamp, track id), so that sorting can be skipped.

    ``timestamps_ns``, ``track_ids``: (N,).
    """
    same = timestamps_ns[1:] == timestamps_ns[:-1]
    return bool(np.all((timestamps_ns[1:] > timestamps_ns[:-1]) | (same & (track_ids[1:] > track_ids[:-1]))))


def write_annotations(log_dir: Path, annotations: Annotations) -> Path:
    """Write ``annotations.feather`` sorted by (timestamp, track id)."""
    ann = annotations.sorted()
    table = pa.table(
        {
            "timestamp_ns": pa.array(ann.timestamp_ns, pa.int64()),
            "track_uuid": pa.array(ann.track_id.tolist(), pa.string()),
            "category": pa.array(ann.category.tolist(), pa.string()),
            **{n: ann.size_lwh_m[:, i] for i, n in enumerate(schema.SIZE_COLUMNS)},
            **_se3_columns(ann.quat_wxyz, ann.center_xyz_m),
            "num_interior_pts": pa.array(ann.num_interior_pts, pa.int64()),
        }
    )
    path = Path(log_dir) / ANNOTATIONS_FILENAME
    _write_table(path, table)
    return path


# ---------------------------------------------------------------------------------------------
# Ego poses


def read_ego_poses(
    path: Path,
    interpolated_at_ns: NDArray[np.integer] | None = None,
    max_pose_gap_s: float = schema.DEFAULT_MAX_POSE_GAP_S,
) -> EgoTrajectory:
    """Read and validate ``city_SE3_egovehicle.feather``; poses come back in time order.

    Rows may be in any order (av2-api reads them into a mapping keyed by timestamp); a timestamp
    on two rows is refused, as are timestamps that are not nanoseconds and coordinates beyond
    :data:`scenes.schema.MAX_CITY_COORDINATE_M`. Problems name the row as it is in the file.

    Args:
        path: the poses file.
        interpolated_at_ns: (Q,) timestamps the poses will be interpolated to (the annotation
            timestamps), or None. A query between two poses more than ``max_pose_gap_s`` apart
            is refused: its pose would be made up across the gap.
        max_pose_gap_s: the largest gap between poses that a query may be interpolated across.
    """
    table = schema.read_feather(path, schema.POSE_COLUMNS)
    if table.num_rows == 0:
        raise LogFormatError.single(path, "table has no rows")
    timestamps = np.asarray(table.column("timestamp_ns").to_numpy(), dtype=np.int64)
    floats, quat, trans = _read_se3(table)
    unit = schema.check_timestamp_unit(path, timestamps)
    problems = unit + schema.check_finite(path, floats)
    if not unit:
        problems += schema.check_unique_timestamps(path, timestamps)
    if not problems:
        problems += schema.check_quaternions(path, quat)
        problems += schema.check_upright(path, quat)
        problems += schema.check_bounds(path, {n: floats[n] for n in schema.TRANSLATION_COLUMNS},
                                        schema.MAX_CITY_COORDINATE_M, "city-frame coordinate")
    order = np.argsort(timestamps, kind="stable")
    if not problems:
        # Jumps are between poses neighbouring in time; their rows are mapped back to the file's.
        jumps = schema.check_pose_jumps(path, timestamps[order], trans[order])
        problems += [replace(p, row=None if p.row is None else int(order[p.row])) for p in jumps]
    if not problems and interpolated_at_ns is not None:
        problems += schema.check_pose_gaps(path, timestamps, np.asarray(interpolated_at_ns), max_pose_gap_s)
    if problems:
        raise LogFormatError(problems)
    return EgoTrajectory(timestamps[order], quat[order], trans[order])


def write_ego_poses(log_dir: Path, ego: EgoTrajectory) -> Path:
    table = pa.table(
        {"timestamp_ns": pa.array(ego.timestamps_ns, pa.int64()), **_se3_columns(ego.quat_wxyz, ego.translation_m)}
    )
    path = Path(log_dir) / POSES_FILENAME
    _write_table(path, table)
    return path


# ---------------------------------------------------------------------------------------------
# Map


#: The log's map folder (``log_map_archive_*.json`` inside).
MAP_DIRNAME = "map"


def find_map_file(log_dir: Path) -> Path | None:
    """The log's ``map/log_map_archive_*.json``, or None when the log has no map.

    Raises:
        LogFormatError: the log holds more than one archive (naming each): which one is the log's
            map is ambiguous, and av2-api refuses such a log too.
    """
    folder = Path(log_dir) / MAP_DIRNAME
    candidates = sorted(folder.glob("log_map_archive_*.json"))
    if len(candidates) > 1:
        names = ", ".join(p.name for p in candidates)
        raise LogFormatError.single(
            folder, f"{len(candidates)} map archives ({names}); a log holds exactly one log_map_archive_*.json")
    return candidates[0] if candidates else None


#: Maps parsed lately, by content digest: the logs of one fleet area (every simulated log of a city)
#: carry the same map file, and parsing it costs more than captioning a short log. Map elements hold
#: read-only arrays, so one parsed map can be shared.
_PARSED_MAPS: Lru[bytes, VectorMap] = Lru(8)


def forget_parsed_maps() -> None:
    """Empty the cache of parsed maps (timing a cold read, or after rewriting a map in place)."""
    _PARSED_MAPS.clear()


def read_map(path: Path) -> VectorMap:
    """Read a map JSON file; :class:`LogFormatError` names the file and the key of every bad part,
    including NaN, inf and implausible (:data:`scenes.schema.MAX_CITY_COORDINATE_M`) coordinates.

    Files with the same bytes as one read lately give the same (immutable) :class:`VectorMap`.
    """
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise LogFormatError.single(path, f"unreadable map JSON: {exc}") from exc
    digest = hashlib.blake2b(raw, digest_size=16).digest()
    if (cached := _PARSED_MAPS.get(digest)) is not None:
        return cached
    try:
        data = json.loads(raw.decode("utf-8"), object_pairs_hook=map_schema.unique_keys)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise LogFormatError.single(path, f"unreadable map JSON: {exc}") from exc
    try:
        vector_map = VectorMap.from_json_dict(data)
    except MapFormatError as exc:
        raise LogFormatError(exc.problems(path)) from exc
    problems = map_schema.check_map_coordinates(path, vector_map)
    if problems:
        raise LogFormatError(problems)
    _PARSED_MAPS.put(digest, vector_map)
    return vector_map


def write_map(log_dir: Path, vector_map: VectorMap, log_id: str, city_name: str = "SIM") -> Path:
    path = Path(log_dir) / MAP_DIRNAME / f"log_map_archive_{log_id}____{city_name}_city_0.json"
    atomic_write_text(path, json.dumps(vector_map.to_json_dict()))
    return path


# ---------------------------------------------------------------------------------------------
# Calibration


def read_calibration(log_dir: Path) -> Calibration:
    """Extrinsics and intrinsics; an empty :class:`Calibration` when the log has none.

    Beyond the columns, the values must make sense: each sensor has one row per file (a repeated
    ``sensor_name`` is refused, not resolved by row order), every extrinsic rotation is a proper rotation,
    focal lengths and image sizes are finite and positive, principal points and distortion finite.
    Every problem of both files is reported.
    """
    log_dir = Path(log_dir)
    problems: list[Problem] = []
    extrinsics = collect_problems(problems, _read_extrinsics, log_dir / EXTRINSICS_PATH)
    intrinsics = collect_problems(problems, _read_intrinsics, log_dir / INTRINSICS_PATH)
    if problems:
        raise LogFormatError(problems)
    return Calibration(extrinsics or {}, intrinsics or {})


def _read_extrinsics(path: Path) -> dict[str, SE3]:
    if not path.is_file():
        return {}
    table = schema.read_feather(path, schema.EXTRINSICS_COLUMNS)
    floats, quat, trans = _read_se3(table)
    names = [str(name) for name in table.column("sensor_name").to_pylist()]
    problems = schema.check_unique_names(path, names, "sensor_name")
    problems += schema.check_finite(path, floats) or schema.check_quaternions(path, quat)
    if problems:
        raise LogFormatError(problems)
    # The norm check already implies a rotation; checking the matrices actually used keeps every
    # calibration file (AV2, KITTI) to the one rule of :func:`scenes.schema.check_rotations`.
    rotation = quat_to_rotmat(quat)
    problems = schema.check_rotations(path, rotation, "qw..qz")
    if problems:
        raise LogFormatError(problems)
    return {name: SE3(rotation[i], trans[i]) for i, name in enumerate(names)}


def _read_intrinsics(path: Path) -> dict[str, CameraIntrinsics]:
    if not path.is_file():
        return {}
    distortion = schema.OPTIONAL_INTRINSICS_COLUMNS
    table = schema.read_feather(path, schema.INTRINSICS_COLUMNS, distortion)
    present = tuple(c for c in ("fx_px", "fy_px", "cx_px", "cy_px", *distortion) if c in table.column_names)
    floats = _float_columns(table, present)
    sizes = {c: np.asarray(table.column(c).to_numpy(), dtype=np.int64) for c in ("width_px", "height_px")}
    names = [str(name) for name in table.column("sensor_name").to_pylist()]
    problems = schema.check_unique_names(path, names, "sensor_name")
    problems += schema.check_finite(path, floats)
    not_finite = {p.field for p in problems}  # a NaN is named once, as NaN, not again as not positive
    focal = {c: floats[c] for c in ("fx_px", "fy_px") if c not in not_finite}
    problems += schema.check_positive(path, focal, "focal length")
    problems += schema.check_positive(path, sizes, "image size")
    if problems:
        raise LogFormatError(problems)
    zeros = np.zeros(table.num_rows)
    out: dict[str, CameraIntrinsics] = {}
    for i, name in enumerate(names):
        out[name] = CameraIntrinsics(
            sensor_name=name,
            fx_px=float(floats["fx_px"][i]),
            fy_px=float(floats["fy_px"][i]),
            cx_px=float(floats["cx_px"][i]),
            cy_px=float(floats["cy_px"][i]),
            width_px=int(sizes["width_px"][i]),
            height_px=int(sizes["height_px"][i]),
            k1=float(floats.get("k1", zeros)[i]),
            k2=float(floats.get("k2", zeros)[i]),
            k3=float(floats.get("k3", zeros)[i]),
        )
    return out


def write_calibration(log_dir: Path, calibration: Calibration) -> None:
    log_dir = Path(log_dir)
    if calibration.ego_SE3_sensor:
        names = sorted(calibration.ego_SE3_sensor)
        quat = np.stack([calibration.ego_SE3_sensor[n].quat_wxyz for n in names])
        trans = np.stack([calibration.ego_SE3_sensor[n].translation for n in names])
        table = pa.table({"sensor_name": names, **_se3_columns(quat, trans)})
        _write_table(log_dir / EXTRINSICS_PATH, table)
    if calibration.intrinsics:
        cams = [calibration.intrinsics[n] for n in sorted(calibration.intrinsics)]
        table = pa.table(
            {
                "sensor_name": [c.sensor_name for c in cams],
                "fx_px": [c.fx_px for c in cams],
                "fy_px": [c.fy_px for c in cams],
                "cx_px": [c.cx_px for c in cams],
                "cy_px": [c.cy_px for c in cams],
                "k1": [c.k1 for c in cams],
                "k2": [c.k2 for c in cams],
                "k3": [c.k3 for c in cams],
                "height_px": pa.array([c.height_px for c in cams], pa.uint16()),
                "width_px": pa.array([c.width_px for c in cams], pa.uint16()),
            }
        )
        _write_table(log_dir / INTRINSICS_PATH, table)


# ---------------------------------------------------------------------------------------------
# Sensors


def write_lidar_sweep(log_dir: Path, sweep: LidarSweep) -> Path:
    """Write one sweep in the AV2 columns (float16 coordinates, as AV2 stores them)."""
    xyz = np.asarray(sweep.xyz_m, dtype=np.float16)
    table = pa.table(
        {
            "x": pa.array(xyz[:, 0], pa.float16()),
            "y": pa.array(xyz[:, 1], pa.float16()),
            "z": pa.array(xyz[:, 2], pa.float16()),
            "intensity": pa.array(np.asarray(sweep.intensity, np.uint8), pa.uint8()),
            "laser_number": pa.array(np.asarray(sweep.laser_number, np.uint8), pa.uint8()),
            "offset_ns": pa.array(np.asarray(sweep.offset_ns, np.int32), pa.int32()),
        }
    )
    path = Path(log_dir) / LIDAR_DIR / f"{int(sweep.timestamp_ns)}.feather"
    _write_table(path, table)
    return path


def write_camera_frame(
    log_dir: Path, camera_name: str, timestamp_ns: int, image_bgr: NDArray[np.uint8], jpeg_quality: int = 90
) -> Path:
    """Write one camera frame as JPEG. ``image_bgr``: (H, W, 3) uint8."""
    import cv2

    ok, encoded = cv2.imencode(".jpg", image_bgr, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    if not ok:
        raise ValueError(f"cannot encode camera frame {camera_name}/{timestamp_ns} as JPEG")
    path = Path(log_dir) / CAMERAS_DIR / camera_name / f"{int(timestamp_ns)}.jpg"
    atomic_write_bytes(path, encoded.tobytes())
    return path


# ---------------------------------------------------------------------------------------------
# Metadata


def read_metadata(log_dir: Path) -> LogMetadata | None:
    path = Path(log_dir) / METADATA_FILENAME
    if not path.is_file():
        return None
    try:
        return LogMetadata.from_json_dict(json.loads(path.read_text()))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise LogFormatError(Problem(path, f"unreadable log metadata: {exc!r}")) from exc


def write_metadata(log_dir: Path, metadata: LogMetadata) -> Path:
    path = Path(log_dir) / METADATA_FILENAME
    atomic_write_text(path, json.dumps(metadata.to_json_dict(), indent=2, sort_keys=True))
    return path
