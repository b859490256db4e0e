"""LiDAR sweeps and camera frames, loaded lazily from a log folder.

A sweep is ``sensors/lidar/<timestamp_ns>.feather`` with AV2 columns ``x y z`` (float16 metres,
ego frame), ``intensity`` and ``laser_number`` (uint8), ``offset_ns`` (int32); see
:data:`scenes.schema.LIDAR_COLUMNS`. A camera frame is ``sensors/cameras/<name>/<timestamp_ns>.jpg``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from scenes import schema
from scenes.errors import LogFormatError


@dataclass(frozen=True)
class LidarSweep:
    """One LiDAR sweep in the ego frame.

    Attributes:
        timestamp_ns: sweep timestamp.
        xyz_m: (N, 3) points in the ego frame, a view of a (3, N) array: ``xyz_m.T`` is contiguous,
            as point transforms and binning read it.
        intensity: (N,) return intensity 0–255.
        laser_number: (N,) beam index.
        offset_ns: (N,) time of each point relative to the sweep timestamp.
    """

    timestamp_ns: int
    xyz_m: NDArray[np.float32]
    intensity: NDArray[np.uint8]
    laser_number: NDArray[np.uint8]
    offset_ns: NDArray[np.int32]

    def __len__(self) -> int:
        return int(self.xyz_m.shape[0])


def timestamps_in(folder: Path, suffix: str) -> NDArray[np.int64]:
    """(T,) sorted timestamps of files named ``<timestamp_ns><suffix>`` in ``folder``."""
    if not folder.is_dir():
        return np.zeros(0, dtype=np.int64)
    stamps = []
    for p in folder.iterdir():
        if p.name.endswith(suffix) and p.name[: -len(suffix)].isdigit():
            stamps.append(int(p.name[: -len(suffix)]))
    return np.array(sorted(stamps), dtype=np.int64)


#: A sweep's coordinate columns.
_XYZ = ("x", "y", "z")


def read_lidar_sweep(path: Path) -> LidarSweep:
    """Read one sweep; raises :class:`LogFormatError` naming the file and field on bad content."""
    table = schema.read_feather(path, schema.LIDAR_REQUIRED_COLUMNS, schema.LIDAR_OPTIONAL_COLUMNS)
    xyz = _points(path, table)
    n = xyz.shape[0]

    def col(name: str, dtype: type, default: int = 0) -> Any:
        if name in table.column_names:
            return np.asarray(table.column(name).to_numpy(), dtype=dtype)
        return np.full(n, default, dtype=dtype)

    return LidarSweep(
        timestamp_ns=int(path.stem),
        xyz_m=xyz,
        intensity=col("intensity", np.uint8),
        laser_number=col("laser_number", np.uint8),
        offset_ns=col("offset_ns", np.int32),
    )


def read_lidar_points(path: Path) -> NDArray[np.float32]:
    """(N, 3) one sweep's points in the ego frame (as :attr:`LidarSweep.xyz_m`), reading only the x, y
    and z columns: what a raster of the points needs, without decompressing the others. Raises
    :class:`LogFormatError` naming the file and field on bad content."""
    return _points(path, schema.read_feather(path, schema.LIDAR_REQUIRED_COLUMNS, only_required=True))


def _points(path: Path, table: pa.Table) -> NDArray[np.float32]:
    """(N, 3) the x, y, z columns of a sweep's table, finite, as a view of a (3, N) float32 array."""
    xyz_by_axis = np.empty((3, table.num_rows), dtype=np.float32)  # filled column by column, cast as copied
    for i, c in enumerate(_XYZ):
        xyz_by_axis[i] = table.column(c).to_numpy()
    problems = schema.check_finite(path, dict(zip(_XYZ, xyz_by_axis, strict=True)))
    if problems:
        raise LogFormatError(problems)
    return xyz_by_axis.T


#: A JPEG's first bytes, and its end-of-image marker, which writers may pad with a few bytes after it.
JPEG_START, JPEG_END, JPEG_TAIL_BYTES = b"\xff\xd8", b"\xff\xd9", 64


def read_camera_frame(path: Path) -> NDArray[np.uint8]:
    """(H, W, 3) BGR image; raises :class:`LogFormatError` when the file cannot be decoded."""
    import cv2

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise LogFormatError.single(path, f"unreadable image: {exc}") from None
    # libjpeg decodes a truncated file to a partly grey image with a warning on stderr only.
    if data[:2] == JPEG_START and JPEG_END not in data[-JPEG_TAIL_BYTES:]:
        raise LogFormatError.single(path, "truncated JPEG (no end-of-image marker)")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise LogFormatError.single(path, "cannot decode image")
    return np.asarray(image, dtype=np.uint8)
