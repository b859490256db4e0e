"""Development AV2 logs of ../shared/realdata for the reader tests, and rewritten copies of them.

A rewritten log is a fixture with one table (``annotations.feather`` unless named) replaced (in a
temporary folder; every other entry links to the fixture, nothing is copied into the repository). The
variants are the row orders real releases use.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pytest

from scenes import av2_io
from scenes.categories import EGO_VEHICLE_LABEL
from tests.realdata import REALDATA

DEV_LOGS = {
    "7fab2350": REALDATA / "av2" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede",
    "adcf7d18": REALDATA / "av2" / "adcf7d18-0510-35b0-a2fa-b4cea13a6d76",
}
EGO_UUID = "5b8e6f3a-ego-vehicle"


def require(path: Path) -> Path:
    if not path.is_dir():
        pytest.skip(f"real AV2 data not found at {path} (the shared realdata folder is absent)")
    return path


def rewritten_log(
    source: Path, dest: Path, change: Callable[[pa.Table], pa.Table], filename: str = av2_io.ANNOTATIONS_FILENAME
) -> Path:
    """A copy of ``source`` whose table ``filename`` (``annotations.feather`` unless named) is
    ``change(original)``; every other entry is a link to the fixture (read-only, nothing copied)."""
    dest.mkdir(parents=True)
    for entry in source.iterdir():
        if entry.name != filename:
            (dest / entry.name).symlink_to(entry, target_is_directory=entry.is_dir())
    table = feather.read_table(source / filename)
    feather.write_feather(change(table), dest / filename)
    return dest


def shuffled(table: pa.Table) -> pa.Table:
    return table.take(pa.array(np.random.default_rng(20).permutation(table.num_rows)))


def grouped_by_track(table: pa.Table) -> pa.Table:
    """Rows grouped by track (tracks in reverse id order), each track's rows newest first."""
    ids = np.asarray(table.column("track_uuid").to_pylist())
    ts = table.column("timestamp_ns").to_numpy()
    rank = np.unique(ids, return_inverse=True)[1]
    return table.take(pa.array(np.lexsort((-ts, -rank))))


def with_ego_rows(table: pa.Table) -> pa.Table:
    """The table with an ``EGO_VEHICLE`` box (at the ego origin) at every annotated timestamp, appended."""
    ts = np.unique(table.column("timestamp_ns").to_numpy())
    n = ts.shape[0]
    values = {"timestamp_ns": ts, "track_uuid": [EGO_UUID] * n, "category": [EGO_VEHICLE_LABEL] * n,
              "length_m": np.full(n, 4.9), "width_m": np.full(n, 2.0), "height_m": np.full(n, 1.7),
              "qw": np.ones(n), "qx": np.zeros(n), "qy": np.zeros(n), "qz": np.zeros(n),
              "tx_m": np.full(n, 1.4), "ty_m": np.zeros(n), "tz_m": np.full(n, 0.85),
              "num_interior_pts": np.zeros(n, np.int64)}
    ego = pa.table({name: pa.array(values[name], table.schema.field(name).type) for name in table.column_names})
    return pa.concat_tables([table, ego])


def grouped_with_ego_rows(table: pa.Table) -> pa.Table:
    return with_ego_rows(grouped_by_track(table))


VARIANTS = {"shuffled": shuffled, "grouped-by-track": grouped_by_track, "ego-rows-appended": with_ego_rows,
            "grouped-then-ego-rows": grouped_with_ego_rows}
