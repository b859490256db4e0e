"""The per-log feature cache: :class:`~scenarios.features.LogFeatures` built once, kept small, read fast.

``CACHE_DIR/<log_id>.npz`` holds one log's features, only for the (object, frame) cells where the
object is observed, in compact integer encodings, each along its track as differences from the frame
before (so that zlib compresses them well):

=================  ============================================================
position           centimetres from the log's first ego position (int32 deltas)
height             decimetres (int16 deltas)
heading            1e-4 rad (int16 deltas, wrapped)
speed              cm/s (int16 deltas)
flags, lanes       as they are (uint16, int8), lane ids renumbered from 0
to the junction    0.5 m steps, 255 beyond 127 m
=================  ============================================================

Velocities and accelerations are derived again from positions and speeds when a file is read. A file
records what it was built from (the log's files' sizes and modification times, the captioning
config, :data:`CACHE_VERSION`); a file that no longer matches, or whose bytes fail zlib's checksums,
is built again, never used.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from captioning.config import CaptioningConfig
from common.atomic import atomic_write_bytes
from common.folders import FolderClaimError, FolderKind, claim_folder, mark_folder
from scenarios.features import LogFeatures, build_features, time_derivative
from scenes.log import Log

#: Version of the encoding; files of another are built again.
CACHE_VERSION = 1
#: The cache folder (:mod:`common.folders`).
FEATURES_FOLDER = FolderKind("scenario features", signature="", entries=("*.npz",))
_CM = 100.0  # centimetres per metre
_DM = 10.0
_YAW = 1e4  # 1e-4 rad
_CMS = 100.0
_JUNCTION_STEP_M = 0.5


def source_stamp(log_dir: Path, config: CaptioningConfig) -> str:
    """What a log's features depend on: its files' sizes and modification times, and the config."""
    parts = [f"v{CACHE_VERSION}", json.dumps(config.to_dict(), sort_keys=True, default=str)]
    for path in sorted([*log_dir.glob("*.feather"), *log_dir.glob("*.json"), *(log_dir / "map").glob("*.json")]):
        st = path.stat()
        parts.append(f"{path.name}:{st.st_size}:{st.st_mtime_ns}")
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:20]


def _deltas(values: NDArray[np.int64], starts: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Differences from the cell before, the first cell of each track kept as it is."""
    out = np.diff(values, axis=0, prepend=np.zeros_like(values[:1]))
    out[starts] = values[starts]
    return out


def _undeltas(deltas: NDArray[np.int64], starts: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Inverse of :func:`_deltas` (a cumulative sum restarted at each track's first cell)."""
    total = np.cumsum(deltas, axis=0)
    first = np.maximum.accumulate(np.where(starts, np.arange(starts.shape[0]), 0))  # each cell's track start
    return total - (total[first] - deltas[first])


def encode(x: LogFeatures, stamp: str) -> bytes:
    """The compressed file of ``x`` (see the module docstring)."""
    k_idx, f_idx = np.nonzero(x.valid)  # cells in (track, frame) order
    starts = np.ones(k_idx.shape[0], dtype=bool)
    starts[1:] = k_idx[1:] != k_idx[:-1]
    origin = np.nan_to_num(x.xy_m[x.ego_index, 0]).astype(np.float64) if x.num_frames else np.zeros(2)
    xy = np.round((x.xy_m[k_idx, f_idx] - origin) * _CM).astype(np.int64)
    z = np.round(np.nan_to_num(x.z_m[k_idx, f_idx]) * _DM).astype(np.int64)
    yaw = np.round(np.nan_to_num(x.yaw_rad[k_idx, f_idx]) * _YAW).astype(np.int64)
    dyaw = _deltas(yaw, starts)
    dyaw = np.where(starts, dyaw, (dyaw + 31416) % 62832 - 31416)  # wrapped around ±π
    speed = np.round(x.speed_mps[k_idx, f_idx] * _CMS).astype(np.int64)
    lanes, lane_code = np.unique(x.lane[k_idx, f_idx], return_inverse=True)
    junction = np.minimum(np.round(x.to_junction_m[k_idx, f_idx] / _JUNCTION_STEP_M), 255).astype(np.uint8)
    arrays = {
        "timestamps_ns": x.timestamps_ns, "track_ids": x.track_ids, "labels": x.labels, "categories": x.categories,
        "size_lwh_m": x.size_lwh_m, "k": k_idx.astype(np.int32), "f": f_idx.astype(np.int32),
        "origin": origin, "xy": _deltas(xy, starts).astype(np.int32), "z": _deltas(z, starts).astype(np.int32),
        "yaw": dyaw.astype(np.int16), "speed": _deltas(speed, starts).astype(np.int32),
        "flags": x.flags[k_idx, f_idx], "ego_lane": x.ego_lane[k_idx, f_idx], "ego_motion": x.ego_motion[k_idx, f_idx],
        "lanes": lanes.astype(np.int32), "lane": lane_code.astype(np.int16), "to_junction": junction,
        "meta": np.asarray(json.dumps({"log_id": x.log_id, "has_map": x.has_map, "time_of_day": x.time_of_day,
                                       "weather": x.weather, "stamp": stamp, "version": CACHE_VERSION})),
    }
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)  # type: ignore[arg-type]
    return buffer.getvalue()


def decode(data: bytes) -> tuple[LogFeatures, str]:
    """The features in a file written by :func:`encode`, and the stamp it records.

    Raises:
        ValueError: the bytes are not such a file (or fail their checksums).
    """
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            a = {name: z[name] for name in z.files}
    except (zipfile.BadZipFile, OSError, EOFError, KeyError, ValueError) as exc:
        raise ValueError(f"not a feature file ({exc})") from None
    meta = json.loads(str(a["meta"]))
    if meta.get("version") != CACHE_VERSION:
        raise ValueError(f"feature file of version {meta.get('version')}, expected {CACHE_VERSION}")
    ts, k_idx, f_idx = a["timestamps_ns"].astype(np.int64), a["k"].astype(np.int64), a["f"].astype(np.int64)
    n_obj, n_frames = a["track_ids"].shape[0], ts.shape[0]
    starts = np.ones(k_idx.shape[0], dtype=bool)
    starts[1:] = k_idx[1:] != k_idx[:-1]
    valid = np.zeros((n_obj, n_frames), dtype=bool)
    valid[k_idx, f_idx] = True

    def dense(values: NDArray[Any], fill: float | int, dtype: type, extra: tuple[int, ...] = ()) -> NDArray[Any]:
        out = np.full((n_obj, n_frames, *extra), fill, dtype=dtype)
        out[k_idx, f_idx] = values
        return out

    xy = _undeltas(a["xy"].astype(np.int64), starts) / _CM + a["origin"]
    yaw = _undeltas(a["yaw"].astype(np.int64), starts) / _YAW
    speed = _undeltas(a["speed"].astype(np.int64), starts) / _CMS
    t_s = (ts - ts[0]).astype(np.float64) * 1e-9 if n_frames else np.zeros(0)
    xy_dense = dense(xy, np.nan, np.float64, (2,))
    speed_dense = dense(speed, 0.0, np.float64)
    junction = a["to_junction"].astype(np.float64) * _JUNCTION_STEP_M
    junction[a["to_junction"] == 255] = np.inf
    features = LogFeatures(
        log_id=str(meta["log_id"]), timestamps_ns=ts, track_ids=a["track_ids"], labels=a["labels"],
        categories=a["categories"], valid=valid, xy_m=xy_dense.astype(np.float32),
        z_m=dense(_undeltas(a["z"].astype(np.int64), starts) / _DM, np.nan, np.float32),
        yaw_rad=dense((yaw + np.pi) % (2 * np.pi) - np.pi, np.nan, np.float32),
        size_lwh_m=a["size_lwh_m"].astype(np.float32),
        velocity_mps=time_derivative(np.nan_to_num(xy_dense), valid, t_s).astype(np.float32),
        speed_mps=speed_dense.astype(np.float32),
        accel_mps2=time_derivative(speed_dense, valid, t_s).astype(np.float32),
        flags=dense(a["flags"], 0, np.uint16), ego_lane=dense(a["ego_lane"], -1, np.int8),
        ego_motion=dense(a["ego_motion"], -1, np.int8),
        lane=dense(a["lanes"][a["lane"]], -1, np.int32).astype(np.int32),
        to_junction_m=dense(junction, np.inf, np.float32).astype(np.float32), has_map=bool(meta["has_map"]),
        time_of_day=str(meta["time_of_day"]), weather=str(meta["weather"]),
    )
    return features, str(meta["stamp"])


def cached_features(log_dir: Path | str, cache_dir: Path | str | None, config: CaptioningConfig | None = None
                    ) -> tuple[LogFeatures, bool]:
    """The features of the log at ``log_dir``: read from ``cache_dir`` when a file there still matches
    the log, else built (and written there when ``cache_dir`` is given).

    Returns:
        (features, whether they came from the cache).

    Raises:
        ScenesError, ValueError, OSError: the log cannot be read.
    """
    log_dir = Path(log_dir)
    config = config or CaptioningConfig()
    stamp = source_stamp(log_dir, config)
    path = Path(cache_dir) / f"{log_dir.name}.npz" if cache_dir is not None else None
    if path is not None and path.is_file():
        try:
            features, found = decode(path.read_bytes())
            if found == stamp:
                return features, True
        except ValueError:
            pass  # damaged or of another version: built again below
    features = build_features(Log.open(log_dir), config)
    if path is not None:
        atomic_write_bytes(path, encode(features, stamp))
    return features, False


def claim_cache(cache_dir: Path | str, inputs: list[Path]) -> None:
    """Take ``cache_dir`` as a feature cache: new, empty or one already (:mod:`common.folders`)."""
    try:
        claim_folder(cache_dir, FEATURES_FOLDER, inputs)
    except FolderClaimError as exc:  # the folder is the cache's: say so rather than "--out"
        raise FolderClaimError(str(exc).replace("--out ", "--cache ", 1)) from None
    mark_folder(cache_dir, FEATURES_FOLDER, FEATURES_FOLDER.entries)
