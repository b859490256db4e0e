from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from scenes.behavior import (
    BEHAVIOR_SCHEMA,
    BehaviorLabel,
    JunctionKind,
    read_behavior_labels,
    read_junctions,
    write_behavior_labels,
)
from scenes.errors import LogFormatError


def _table(n: int = 3) -> pa.Table:
    cols: dict[str, pa.Array] = {
        "timestamp_ns": pa.array(np.arange(n, dtype=np.int64)),
        "track_id": pa.array(["ego"] * n),
    }
    for label in BehaviorLabel:
        cols[label.value] = pa.array(np.arange(n) % 2 == 0)
    cols["speed_mps"] = pa.array(np.linspace(0, 3, n))
    cols["leader_id"] = pa.array([None, "a", None][:n], pa.string())
    cols["junction_id"] = pa.array([None] * n, pa.string())
    return pa.table(cols, schema=BEHAVIOR_SCHEMA)


def test_labels_round_trip(tmp_path: Path) -> None:
    write_behavior_labels(tmp_path, _table())
    back = read_behavior_labels(tmp_path)
    assert back is not None
    assert back.equals(_table())


def test_absent_files_read_as_none(tmp_path: Path) -> None:
    assert read_behavior_labels(tmp_path) is None
    assert read_junctions(tmp_path) is None


def test_missing_column_is_named(tmp_path: Path) -> None:
    with pytest.raises(LogFormatError, match="braking_for"):
        write_behavior_labels(tmp_path, _table().drop_columns(["braking_for"]))
    assert not (tmp_path / "behavior_labels.feather").exists()


def test_corrupt_file_is_named(tmp_path: Path) -> None:
    (tmp_path / "behavior_labels.feather").write_bytes(b"not arrow")
    with pytest.raises(LogFormatError, match="behavior_labels.feather"):
        read_behavior_labels(tmp_path)


def test_vocabulary_has_the_ten_actions() -> None:
    assert {label.value for label in BehaviorLabel} == {
        "parked", "stopped", "braking", "keeping_lane", "left_turn", "right_turn",
        "left_lane_change", "right_lane_change", "blocked_by", "braking_for",
    }


def test_junction_kind_from_arms() -> None:
    assert JunctionKind.from_arms(2) is None
    assert JunctionKind.from_arms(3) is JunctionKind.THREE_WAY
    assert JunctionKind.from_arms(4) is JunctionKind.FOUR_WAY
    assert JunctionKind.from_arms(6) is JunctionKind.MULTI_WAY
