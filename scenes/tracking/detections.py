"""Per-frame 3D detections, without track ids, and the generic detections table.

The generic table (Parquet or feather) has one row per detection::

    timestamp_ns int64, category str, score float in [0, 1],
    tx_m ty_m tz_m (box centre, ego frame), length_m width_m height_m, yaw_rad (ego frame)

``category`` is a raw AV2/KITTI label or a public category name.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pyarrow.parquet as pq
from numpy.typing import NDArray

from scenes.categories import Category, category_from_label
from scenes.errors import ImportFormatError
from scenes.geometry import FloatArray

DETECTION_COLUMNS = ("timestamp_ns", "category", "score", "tx_m", "ty_m", "tz_m", "length_m", "width_m", "height_m",
                     "yaw_rad")


@dataclass(frozen=True)
class Detections:
    """Detections of a whole log, one row per box, boxes in the ego frame of their timestamp.

    Attributes:
        timestamp_ns: (N,) timestamp of each detection.
        category: (N,) public category value of each detection.
        score: (N,) confidence in [0, 1].
        center_xyz_m: (N, 3) box centres in the ego frame.
        size_lwh_m: (N, 3) box sizes.
        yaw_rad: (N,) box headings in the ego frame.
        source_line: (N,) 1-based line (or row) in the source file, for error messages.
    """

    timestamp_ns: NDArray[np.int64]
    category: NDArray[np.str_]
    score: FloatArray
    center_xyz_m: FloatArray
    size_lwh_m: FloatArray
    yaw_rad: FloatArray
    source_line: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.timestamp_ns.shape[0])

    def select(self, mask: NDArray[np.bool_] | NDArray[np.integer]) -> Detections:
        """Rows where ``mask`` is true, or at the given indices."""
        return Detections(
            self.timestamp_ns[mask], self.category[mask], self.score[mask], self.center_xyz_m[mask],
            self.size_lwh_m[mask], self.yaw_rad[mask], self.source_line[mask],
        )

    @staticmethod
    def concatenate(parts: list[Detections]) -> Detections:
        """All rows of ``parts``, ordered by timestamp (stable)."""
        if not parts:
            return Detections.empty()
        ts = np.concatenate([p.timestamp_ns for p in parts])
        order = np.argsort(ts, kind="stable")
        return Detections(
            ts[order],
            np.concatenate([p.category for p in parts])[order],
            np.concatenate([p.score for p in parts])[order],
            np.concatenate([p.center_xyz_m for p in parts])[order],
            np.concatenate([p.size_lwh_m for p in parts])[order],
            np.concatenate([p.yaw_rad for p in parts])[order],
            np.concatenate([p.source_line for p in parts])[order],
        )

    @staticmethod
    def empty() -> Detections:
        return Detections(
            np.zeros(0, np.int64), np.zeros(0, np.str_), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)),
            np.zeros(0), np.zeros(0, np.int64),
        )


def validate_detections(path: Path, detections: Detections) -> None:
    """Reject non-positive sizes, scores outside [0, 1] and non-finite values, naming the line."""
    checks = [
        (~np.isfinite(detections.center_xyz_m).all(axis=1), "box centre is NaN or inf", "tx_m,ty_m,tz_m"),
        (~np.isfinite(detections.yaw_rad), "yaw is NaN or inf", "yaw_rad"),
        (~np.isfinite(detections.size_lwh_m).all(axis=1) | (detections.size_lwh_m <= 0).any(axis=1),
         "box size must be positive", "length_m,width_m,height_m"),
        (~np.isfinite(detections.score) | (detections.score < 0) | (detections.score > 1),
         "score must be in [0, 1]", "score"),
    ]
    for bad, message, field in checks:
        if bad.any():
            i = int(np.argmax(bad))
            raise ImportFormatError(path, message, line=int(detections.source_line[i]), field=field)


def read_detections_table(path: Path) -> Detections:
    """Read the generic detections table (Parquet or feather) and validate it."""
    path = Path(path)
    if not path.is_file():
        raise ImportFormatError(path, "detections file is missing")
    try:
        table = pq.read_table(path) if path.suffix in (".parquet", ".pq") else feather.read_table(path)
    except (OSError, pa.ArrowInvalid) as exc:
        raise ImportFormatError(path, f"unreadable table: {exc}") from exc
    missing = [c for c in DETECTION_COLUMNS if c not in table.column_names]
    if missing:
        raise ImportFormatError(path, f"missing columns {missing}", field=missing[0])
    labels = [str(v) for v in table.column("category").to_pylist()]
    categories = []
    for row, label in enumerate(labels):
        category = category_from_label(label)
        if category is None:
            raise ImportFormatError(path, f"unknown category {label!r}", line=row + 1, field="category")
        categories.append(category.value)

    def floats(*names: str) -> FloatArray:
        return np.stack([np.asarray(table.column(n).to_numpy(zero_copy_only=False), np.float64) for n in names], 1)

    detections = Detections(
        timestamp_ns=np.asarray(table.column("timestamp_ns").to_numpy(), np.int64),
        category=np.asarray(categories, dtype=np.str_),
        score=floats("score")[:, 0],
        center_xyz_m=floats("tx_m", "ty_m", "tz_m"),
        size_lwh_m=floats("length_m", "width_m", "height_m"),
        yaw_rad=floats("yaw_rad")[:, 0],
        source_line=np.arange(1, table.num_rows + 1, dtype=np.int64),
    )
    validate_detections(path, detections)
    order = np.argsort(detections.timestamp_ns, kind="stable")
    return detections.select(order)


def write_detections_table(path: Path, detections: Detections) -> None:
    """Write the generic detections table (Parquet), atomically."""
    from scenesearch_base.atomic import atomic_path

    table = pa.table(
        {
            "timestamp_ns": pa.array(detections.timestamp_ns, pa.int64()),
            "category": pa.array([str(c) for c in detections.category], pa.string()),
            "score": detections.score,
            "tx_m": detections.center_xyz_m[:, 0],
            "ty_m": detections.center_xyz_m[:, 1],
            "tz_m": detections.center_xyz_m[:, 2],
            "length_m": detections.size_lwh_m[:, 0],
            "width_m": detections.size_lwh_m[:, 1],
            "height_m": detections.size_lwh_m[:, 2],
            "yaw_rad": detections.yaw_rad,
        }
    )
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)


def public_category(label: str) -> str:
    """Public category value of a raw label (``other`` when unknown)."""
    return (category_from_label(label) or Category.OTHER).value
