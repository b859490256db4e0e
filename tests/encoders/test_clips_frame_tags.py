"""The rules' tags at each clip frame, read from frame_tags.parquet."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from encoders.clips.frame_tags import (
    FRAME_TAG_COLUMNS,
    LogFrameTagsRef,
    empty_clip_columns,
    frame_tags_by_log,
    frame_tags_of,
    read_frame_tags,
)


def _write(path: Path, actions: bool = False) -> None:
    rows = [
        {"log_id": "a", "timestamp_ns": 10, "track_id": "ego", "lane": None, "motion": None,
         "host_motion": "accelerating", "host_direction": "steering_left"},
        {"log_id": "a", "timestamp_ns": 10, "track_id": "car", "lane": "left", "motion": "approach",
         "host_motion": None, "host_direction": None},
        {"log_id": "a", "timestamp_ns": 20, "track_id": "car", "lane": "host", "motion": "away",
         "host_motion": None, "host_direction": None},
        {"log_id": "b", "timestamp_ns": 10, "track_id": "car", "lane": "right", "motion": "constant",
         "host_motion": None, "host_direction": None},
    ]
    if actions:
        actions_contexts = [(None, None), ("braking", "none"), ("none", "on_crosswalk"), ("parked", "none")]
        for row, (action, context) in zip(rows, actions_contexts):
            row.update(action=action, context=context)
    pq.write_table(pa.Table.from_pylist(rows), path)


def test_clip_columns_give_the_tags_at_each_sampled_frame(tmp_path: Path) -> None:
    path = tmp_path / "frame_tags.parquet"
    _write(path)
    tags = read_frame_tags(path)
    assert sorted(tags) == ["a", "b"]
    cols = tags["a"].clip_columns("car", np.array([10, 10, 20, 30]))
    assert list(cols) == list(FRAME_TAG_COLUMNS)
    assert cols["frame_lane"] == ["left", "left", "host", None]  # 30: no row, untagged
    assert cols["frame_motion"] == ["approach", "approach", "away", None]
    assert cols["frame_host_motion"] == ["accelerating", "accelerating", None, None]
    assert cols["frame_host_direction"] == ["steering_left", "steering_left", None, None]
    # A file from before the action and context columns (or under rules: paper): null there.
    assert cols["frame_action"] == cols["frame_context"] == [None] * 4
    assert tags["a"].clip_columns("bus", np.array([10]))["frame_lane"] == [None]
    assert list(read_frame_tags(path, log_ids=["b"])) == ["b"] and read_frame_tags(path, log_ids=[]) == {}
    assert empty_clip_columns(2) == {name: [None, None] for name in FRAME_TAG_COLUMNS}


def test_a_file_of_one_log_per_row_group_is_read_log_by_log(tmp_path: Path) -> None:
    """As ``caption`` writes it: each log's task reads its own row groups, to the tags of a whole read."""
    whole = tmp_path / "whole.parquet"
    _write(whole, actions=True)
    table = pq.read_table(whole)
    grouped = tmp_path / "grouped.parquet"
    with pq.ParquetWriter(grouped, table.schema) as writer:
        for part in (table.slice(0, 2), table.slice(3, 1), table.slice(2, 1)):  # a's rows in two row groups
            writer.write_table(part)
    expected = read_frame_tags(whole)
    refs = frame_tags_by_log(grouped, ["a", "b", "c"])
    assert sorted(refs) == ["a", "b"] and all(isinstance(r, LogFrameTagsRef) for r in refs.values())
    assert refs["a"].row_groups == (0, 2)  # type: ignore[union-attr]
    for log_id, ref in refs.items():
        assert isinstance(ref, LogFrameTagsRef) and ref.load() == expected[log_id]
    # Row groups holding several logs (a file written at once): the tags, read at once.
    assert frame_tags_by_log(whole, ["b"]) == {"b": expected["b"]}
    assert frame_tags_of(tmp_path / "absent.parquet", ["a"]) == {}


def test_clip_columns_carry_the_unified_tags_action_and_context(tmp_path: Path) -> None:
    path = tmp_path / "frame_tags.parquet"
    _write(path, actions=True)
    cols = read_frame_tags(path)["a"].clip_columns("car", np.array([10, 20, 30]))
    assert cols["frame_action"] == ["braking", "none", None]
    assert cols["frame_context"] == ["none", "on_crosswalk", None]
    assert cols["frame_lane"] == ["left", "host", None]


def test_a_frame_tags_file_without_a_column_is_refused_by_name(tmp_path: Path) -> None:
    path = tmp_path / "frame_tags.parquet"
    pq.write_table(pa.table({"log_id": ["a"], "timestamp_ns": [1], "track_id": ["car"], "lane": ["left"]}), path)
    with pytest.raises(ValueError, match=r"frame_tags.parquet: missing column\(s\) \['motion', 'host_motion'"):
        read_frame_tags(path)
    path.write_bytes(b"not parquet")
    with pytest.raises(ValueError, match="frame_tags.parquet: unreadable Parquet file"):
        read_frame_tags(path)
