"""Caption rows read log by log, and the clip table spooled log by log."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from encoders.clips.layout import CLIPS_FILE
from encoders.clips.table import CLIP_SCHEMA, ClipsInputError, ClipTableSpool, captions_by_log
from scenesearch_base.atomic import is_temporary


def _captions(log_id: str, tracks: list[str], start_ns: int = 0) -> pa.Table:
    return pa.table({"log_id": [log_id] * len(tracks), "track_id": tracks,
                     "start_ns": pa.array([start_ns + i for i in range(len(tracks))], pa.int64()),
                     "end_ns": pa.array([start_ns + i + 10 for i in range(len(tracks))], pa.int64()),
                     "caption": [f"{t} moves" for t in tracks], "category": ["car"] * len(tracks)})


def _grouped(path: Path, parts: list[pa.Table]) -> None:
    with pq.ParquetWriter(path, parts[0].schema) as writer:
        for part in parts:
            writer.write_table(part)


def test_logs_of_their_own_row_groups_are_read_by_their_task_to_the_same_rows(tmp_path: Path) -> None:
    """As ``caption`` writes them (a log per row group, here ``a`` in two): references that read the
    same rows, with the file's row numbers, as a whole read does."""
    parts = [_captions("a", ["ego", "car"]), _captions("b", ["bus"]), _captions("a", ["van"], start_ns=50)]
    grouped, whole = tmp_path / "grouped.parquet", tmp_path / "whole.parquet"
    _grouped(grouped, parts)
    pq.write_table(pa.concat_tables(parts), whole)
    whole_read = captions_by_log(whole)  # several logs in a row group (a file written at once): rows held
    assert whole_read["a"].path is None
    expected = {log_id: rows.load() for log_id, rows in whole_read.items()}
    assert [(r.track_id, r.row) for r in expected["a"]] == [("car", 1), ("van", 3)]
    assert [(r.track_id, r.row) for r in expected["b"]] == [("bus", 2)]
    refs = captions_by_log(grouped)
    assert list(refs) == ["a", "b"]  # the order of each log's first row
    assert refs["a"].path == str(grouped.resolve()) and refs["a"].row_groups == (0, 2) and refs["a"].rows == ()
    assert refs["a"].first_row == 1 and refs["b"].first_row == 2
    assert {log_id: ref.load() for log_id, ref in refs.items()} == expected
    held = captions_by_log(grouped, refer=False)  # a staged copy of a URI's file: held
    assert held["a"].path is None and held["a"].load() == expected["a"]


def test_a_bad_row_in_a_later_row_group_is_refused_by_its_row_number_before_any_log_is_read(
        tmp_path: Path) -> None:
    bad = _captions("b", ["bus"]).set_column(4, "caption", pa.array(["  "]))
    path = tmp_path / "captions.parquet"
    _grouped(path, [_captions("a", ["car", "van"]), bad])
    with pytest.raises(ClipsInputError, match=r"captions.parquet, row 2, field 'caption': empty"):
        captions_by_log(path)


def _rows(log_id: str, n: int, **extra: Any) -> list[dict[str, Any]]:
    return [{"clip_id": f"{log_id}:t{i}:0", "log_id": log_id, "track_id": f"t{i}", "caption": "c", "split": None,
             "has_camera": i % 2 == 0, "frame_indices": [0, 1], **extra} for i in range(n)]


def test_the_spooled_table_is_written_in_the_given_order_with_each_log_split(tmp_path: Path) -> None:
    with ClipTableSpool(tmp_path) as table:
        table.add("b", _rows("b", 2, parked=True))
        table.add("empty", [])
        table.add("a", _rows("a", 3, parked=False))
        assert table.num_rows == 5 and not (tmp_path / CLIPS_FILE).exists()
        spools = [p.name for p in tmp_path.iterdir()]
        assert len(spools) == 1 and is_temporary(spools[0])  # beside the table, swept if the run is killed
        table.publish(["a", "missing", "b"], {"a": "train", "b": "test"})
    assert [p.name for p in tmp_path.iterdir()] == [CLIPS_FILE]
    out = pq.read_table(tmp_path / CLIPS_FILE)
    assert out.column("clip_id").to_pylist() == ["a:t0:0", "a:t1:0", "a:t2:0", "b:t0:0", "b:t1:0"]
    assert out.column("split").to_pylist() == ["train"] * 3 + ["test"] * 2
    assert out.column_names == [*CLIP_SCHEMA.names, "parked"]  # every row has it
    assert out.column("parked").to_pylist() == [False] * 3 + [True] * 2


def test_behaviour_columns_some_rows_lack_are_left_out_and_a_failed_run_writes_nothing(tmp_path: Path) -> None:
    with ClipTableSpool(tmp_path) as table:
        table.add("a", _rows("a", 1, parked=True))
        table.add("b", _rows("b", 1))
        with pytest.raises(ValueError, match="log b: spooled twice"):
            table.add("b", _rows("b", 1))
        table.publish(["a", "b"], {"a": "val", "b": "val"})
    assert pq.read_schema(tmp_path / CLIPS_FILE).names == CLIP_SCHEMA.names
    with pytest.raises(RuntimeError), ClipTableSpool(tmp_path / "new") as table:
        table.add("a", _rows("a", 1))
        raise RuntimeError("the run stops")
    assert list((tmp_path / "new").iterdir()) == []
