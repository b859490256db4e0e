"""The per-log feature cache: :class:`~scenarios.features.LogFeatures` built once, kept small, read fast.

``CACHE_DIR/<log_id>.features`` holds one log's features, only for the (object, frame) cells where the
object is observed, in compact integer encodings, each along its track as differences from the frame
before (so that zlib compresses them well):

=================  ============================================================
position           centimetres from the log's first ego position, differences of
                   differences (a steady motion is a run of zeros)
height             decimetres (deltas)
heading            1e-4 rad, differences (wrapped) of differences
speed              cm/s (deltas)
frame of a cell    deltas along the track (mostly 1)
flags, lanes       as they are (uint16, int8), lane ids renumbered from 0
to the junction    0.5 m steps, 255 beyond 127 m (deltas)
timestamps         the first, then deltas
ids and labels     one UTF-8 JSON list each
=================  ============================================================

Integers are stored in the narrowest type that holds them (int8 … int64).

Velocities and accelerations are derived again from positions and speeds when a file is read. A file
records what it was built from (the log's files' sizes and modification times, the captioning
config, :data:`CACHE_VERSION`); a file that no longer matches, or whose bytes fail zlib's checksums,
is built again, never used.
"""

from __future__ import annotations

import hashlib
import json
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from captioning.config import CaptioningConfig
from scenarios.features import LogFeatures, build_features, time_derivative
from scenes.log import Log
from scenesearch_base.atomic import atomic_write_bytes
from scenesearch_base.folders import FolderClaimError, FolderKind, claim_folder, mark_folder

#: Version of the encoding; files of another are built again.
CACHE_VERSION = 6
#: The cache folder (:mod:`scenesearch_base.folders`).
#: The suffix of a log's file.
FEATURES_SUFFIX = ".features"
FEATURES_FOLDER = FolderKind("scenario features", signature="", entries=(f"*{FEATURES_SUFFIX}",))
#: The file's first bytes; then the length of its header (4 bytes, little-endian) and one zlib stream of
#: the header (JSON: each array's name, dtype and shape) followed by the arrays' bytes. One stream, not a
#: zip of arrays: a log's file is about 10 kB, and an archive's headers would be a third of it.
_MAGIC = b"SSFEAT"
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


def _second_starts(starts: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The cells kept as they are when deltas are taken again: each track's first two (its position and
    its first step)."""
    second = starts.copy()
    second[1:] |= starts[:-1]
    return second


def _undeltas(deltas: NDArray[np.int64], starts: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Inverse of :func:`_deltas` (a cumulative sum restarted at each track's first cell)."""
    total = np.cumsum(deltas, axis=0)
    first = np.maximum.accumulate(np.where(starts, np.arange(starts.shape[0]), 0))  # each cell's track start
    return total - (total[first] - deltas[first])


def _narrow(values: NDArray[np.integer]) -> NDArray[np.integer]:
    """``values`` in the narrowest signed integer type that holds them (zlib packs the small ones best)."""
    if values.size == 0:
        return values.astype(np.int8)
    lo, hi = int(values.min()), int(values.max())
    for dtype in (np.int8, np.int16, np.int32):
        info = np.iinfo(dtype)
        if info.min <= lo and hi <= info.max:
            return values.astype(dtype)
    return values.astype(np.int64)


def _strings(values: NDArray[np.str_]) -> NDArray[np.uint8]:
    """(N,) strings as the UTF-8 bytes of their JSON list (a fixed-width array spends 4 bytes a character)."""
    return np.frombuffer(json.dumps(values.tolist()).encode("utf-8"), dtype=np.uint8)


def _unstrings(data: NDArray[np.uint8]) -> NDArray[np.str_]:
    values = json.loads(data.tobytes().decode("utf-8"))
    if not isinstance(values, list) or not all(isinstance(v, str) for v in values):
        raise ValueError("a string list that is not one")
    return np.asarray(values, dtype=np.str_)


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
    xy_deltas = _deltas(xy, starts)
    first_frame = np.arange(x.num_frames) == 0
    arrays = {
        "timestamps_ns": _narrow(_deltas(np.asarray(x.timestamps_ns, dtype=np.int64), first_frame)),
        "track_ids": _strings(x.track_ids), "labels": _strings(x.labels), "categories": _strings(x.categories),
        "size_lwh_m": x.size_lwh_m, "k": _narrow(np.diff(k_idx, prepend=0)), "f": _narrow(_deltas(f_idx, starts)),
        "origin": origin, "xy": _narrow(_deltas(xy_deltas, _second_starts(starts))),
        "z": _narrow(_deltas(z, starts)), "yaw": _narrow(_deltas(dyaw, _second_starts(starts))),
        "speed": _narrow(_deltas(speed, starts)),
        "flags": x.flags[k_idx, f_idx], "ego_lane": x.ego_lane[k_idx, f_idx],
        "lanes": lanes.astype(np.int32), "lane": lane_code.astype(np.int16),
        "to_junction": _narrow(_deltas(junction.astype(np.int64), starts)),
        "meta": np.frombuffer(json.dumps({"log_id": x.log_id, "has_map": x.has_map, "time_of_day": x.time_of_day,
                                          "weather": x.weather, "stamp": stamp, "version": CACHE_VERSION}).encode(),
                              dtype=np.uint8),
    }
    header = json.dumps([[name, value.dtype.str, list(value.shape)] for name, value in arrays.items()]).encode()
    body = b"".join(np.ascontiguousarray(value).tobytes() for value in arrays.values())
    return _MAGIC + len(header).to_bytes(4, "little") + zlib.compress(header + body, 9)


def _unpack(data: bytes) -> dict[str, NDArray[Any]]:
    """The arrays of a file written by :func:`encode`.

    Raises:
        ValueError: not such a file, or its bytes fail zlib's checksum.
    """
    if not data.startswith(_MAGIC) or len(data) < len(_MAGIC) + 4:
        raise ValueError("not a feature file (it does not start as one)")
    header_length = int.from_bytes(data[len(_MAGIC):len(_MAGIC) + 4], "little")
    try:
        raw = zlib.decompress(data[len(_MAGIC) + 4:])
        entries = json.loads(raw[:header_length].decode())
        arrays, offset = {}, header_length
        for name, dtype_str, shape in entries:
            dtype = np.dtype(dtype_str)
            if dtype.hasobject:
                raise ValueError(f"array {name!r} of objects")
            count = int(np.prod(shape, dtype=np.int64))
            arrays[str(name)] = np.frombuffer(raw, dtype, count, offset).reshape(shape)
            offset += count * dtype.itemsize
    except (zlib.error, UnicodeDecodeError, TypeError, ValueError) as exc:
        raise ValueError(f"not a feature file ({exc})") from None
    return arrays


def decode(data: bytes) -> tuple[LogFeatures, str]:
    """The features in a file written by :func:`encode`, and the stamp it records.

    Raises:
        ValueError: the bytes are not such a file (or fail their checksums).
    """
    a = _unpack(data)
    try:
        meta = json.loads(a["meta"].tobytes().decode())
    except (KeyError, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"not a feature file (its record: {exc})") from None
    if meta.get("version") != CACHE_VERSION:
        raise ValueError(f"feature file of version {meta.get('version')}, expected {CACHE_VERSION}")
    ts, k_idx = np.cumsum(a["timestamps_ns"].astype(np.int64)), np.cumsum(a["k"].astype(np.int64))
    track_ids, labels, categories = (_unstrings(a[name]) for name in ("track_ids", "labels", "categories"))
    n_obj, n_frames = track_ids.shape[0], ts.shape[0]
    starts = np.ones(k_idx.shape[0], dtype=bool)
    starts[1:] = k_idx[1:] != k_idx[:-1]
    f_idx = _undeltas(a["f"].astype(np.int64), starts)
    valid = np.zeros((n_obj, n_frames), dtype=bool)
    valid[k_idx, f_idx] = True

    def dense(values: NDArray[Any], fill: float | int, dtype: type, extra: tuple[int, ...] = ()) -> NDArray[Any]:
        out = np.full((n_obj, n_frames, *extra), fill, dtype=dtype)
        out[k_idx, f_idx] = values
        return out

    xy = _undeltas(_undeltas(a["xy"].astype(np.int64), _second_starts(starts)), starts) / _CM + a["origin"]
    yaw = _undeltas(_undeltas(a["yaw"].astype(np.int64), _second_starts(starts)), starts) / _YAW
    speed = _undeltas(a["speed"].astype(np.int64), starts) / _CMS
    t_s = (ts - ts[0]).astype(np.float64) * 1e-9 if n_frames else np.zeros(0)
    xy_dense = dense(xy, np.nan, np.float64, (2,))
    speed_dense = dense(speed, 0.0, np.float64)
    junction_steps = _undeltas(a["to_junction"].astype(np.int64), starts)
    junction = junction_steps.astype(np.float64) * _JUNCTION_STEP_M
    junction[junction_steps == 255] = np.inf
    features = LogFeatures(
        log_id=str(meta["log_id"]), timestamps_ns=ts, track_ids=track_ids, labels=labels,
        categories=categories, valid=valid, xy_m=xy_dense.astype(np.float32),
        z_m=dense(_undeltas(a["z"].astype(np.int64), starts) / _DM, np.nan, np.float32),
        yaw_rad=dense((yaw + np.pi) % (2 * np.pi) - np.pi, np.nan, np.float32),
        size_lwh_m=a["size_lwh_m"].astype(np.float32),
        velocity_mps=time_derivative(np.nan_to_num(xy_dense), valid, t_s).astype(np.float32),
        speed_mps=speed_dense.astype(np.float32),
        accel_mps2=time_derivative(speed_dense, valid, t_s).astype(np.float32),
        flags=dense(a["flags"], 0, np.uint16), ego_lane=dense(a["ego_lane"], -1, np.int8),
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
    path = Path(cache_dir) / f"{log_dir.name}{FEATURES_SUFFIX}" if cache_dir is not None else None
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
    """Take ``cache_dir`` as a feature cache: new, empty or one already (:mod:`scenesearch_base.folders`)."""
    try:
        claim_folder(cache_dir, FEATURES_FOLDER, inputs)
    except FolderClaimError as exc:  # the folder is the cache's: say so rather than "--out"
        raise FolderClaimError(str(exc).replace("--out ", "--cache ", 1)) from None
    mark_folder(cache_dir, FEATURES_FOLDER, FEATURES_FOLDER.entries)
