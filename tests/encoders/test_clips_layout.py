"""The clips folder contract: clip ids, and readers whose errors name the file and the field."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from encoders.clips.layout import (
    CLIPS_FILE,
    MANIFEST_FILE,
    clip_id,
    grid_from_manifest,
    parse_clip_id,
    preview_file_name,
    read_clip_rows,
    read_clip_table,
    read_manifest,
    rendered_log_dir,
)


def test_clip_id_round_trip() -> None:
    cid = clip_id("2b044433-ddc1-3580-b560-d46474934089", "a:b", 1_700_000_000_000_000_000)
    assert cid == "2b044433-ddc1-3580-b560-d46474934089:a:b:1700000000000000000"
    # The start and the track are split off the end; a track id holding a colon is read into the log id.
    assert parse_clip_id(clip_id("log", "ego", -5)) == ("log", "ego", -5)
    assert parse_clip_id("host:with:colons:car_1:42") == ("host:with:colons", "car_1", 42)
    for bad in ("log:track", "log:track:soon", ":track:1"):
        with pytest.raises(ValueError, match="expected 'log_id:track_id:start_ns'"):
            parse_clip_id(bad)
    assert preview_file_name("log:t/1:5") == "log_t_1_5.gif"
    assert rendered_log_dir("clips", "log") == Path("clips/logs/log")


def test_readers_name_the_file_and_field(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=f"{MANIFEST_FILE}: clips manifest not found"):
        read_manifest(tmp_path)
    with pytest.raises(FileNotFoundError, match=f"{CLIPS_FILE}: no clip table"):
        read_clip_table(tmp_path)
    (tmp_path / MANIFEST_FILE).write_text("{")
    with pytest.raises(ValueError, match=f"{MANIFEST_FILE}: unreadable clips manifest"):
        read_manifest(tmp_path)
    bev = {"x_min_m": -10, "x_max_m": 30, "y_min_m": -20, "y_max_m": 20, "resolution_m": 0.5}
    (tmp_path / MANIFEST_FILE).write_text(json.dumps({"bev": bev}))
    assert grid_from_manifest(read_manifest(tmp_path)).shape == (80, 80)
    (tmp_path / MANIFEST_FILE).write_text(json.dumps({"bev": bev, "format_version": 1}))  # plain .npy arrays
    with pytest.raises(ValueError, match=f"{MANIFEST_FILE}: format_version 1.*run `scenesearch clips` again"):
        read_manifest(tmp_path)
    (tmp_path / MANIFEST_FILE).write_text(json.dumps({"bev": bev, "format_version": 2}))  # images not filtered
    assert read_manifest(tmp_path)["format_version"] == 2

    ids = [clip_id("log", "car", 1), clip_id("log", "bus", 2)]
    pq.write_table(pa.table({"clip_id": ids, "caption": ["a car", "a bus"]}), tmp_path / CLIPS_FILE)
    assert read_clip_table(tmp_path, columns=["caption"]).column_names == ["caption"]
    with pytest.raises(ValueError, match=rf"{CLIPS_FILE}: missing column\(s\) \['split'\]"):
        read_clip_table(tmp_path, columns=["split"])
    assert [r["caption"] for r in read_clip_rows(tmp_path, ids[::-1])] == ["a bus", "a car"]
    with pytest.raises(KeyError, match="no clip with clip_id 'log:van:3'"):
        read_clip_rows(tmp_path, [ids[0], "log:van:3"])


def test_caption_windows_in_seconds_are_refused_naming_the_field(tmp_path: Path) -> None:
    """A hand-made caption table with ``start_ns`` in float seconds: said, not read as a 1-ns window."""
    from encoders.clips.table import ClipsInputError, captions_by_log

    path = tmp_path / "captions.parquet"
    pq.write_table(pa.table({"log_id": ["log"], "track_id": ["car"], "start_ns": [1.5], "end_ns": [4.5],
                             "caption": ["A car approaches."], "category": ["car"]}), path)
    with pytest.raises(ClipsInputError, match=r"captions.parquet, field 'start_ns': double; expected int64 "
                                              "nanoseconds"):
        captions_by_log(path)

