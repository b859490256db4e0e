"""caption_arrays / write_outputs / the CLI: bad input, skipped tracks, file formats."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from captioning.config import CaptioningConfig, RuleSet, SmoothingConfig, WindowsConfig, WindowStrategy
from captioning.errors import TrackDataError
from captioning.outputs import write_outputs
from captioning.pipeline import SKIP_ISOLATED, caption_arrays
from captioning.tables import CAPTIONS_SCHEMA, FRAME_TAGS_SCHEMA


def busy_scene(make_scene):  # type: ignore[no-untyped-def]
    t = np.arange(60) * 0.1
    scene = make_scene(10.0)
    scene.add_relative("lefty", "car", np.c_[30.0 - 4.0 * t, np.full(60, 3.5)], 0.0)  # left lane, approaching
    gappy = np.ones(60, bool)
    gappy[20:24] = False
    scene.add_relative("gappy", "truck", np.c_[15.0 + 3.0 * t, np.full(60, -3.5)], 0.0, valid=gappy)
    single = np.zeros(60, bool)
    single[10] = True
    scene.add_relative("blip", "pedestrian", np.c_[5.0 + t, np.full(60, 6.0)], 0.0, valid=single)
    scene.add("parked", "car", np.tile([45.0, -4.0], (60, 1)), 0.0)
    return scene


def test_frame_tags_and_captions(make_scene) -> None:  # type: ignore[no-untyped-def]
    result = busy_scene(make_scene).caption()
    frames = result.frame_tags_table()
    assert frames.schema.equals(FRAME_TAGS_SCHEMA)
    assert frames.num_rows == 60 + 60 + 56 + 1 + 60  # ego + observed object frames only
    rows = frames.to_pylist()
    ego = [r for r in rows if r["track_id"] == "ego"]
    assert {r["host_motion"] for r in ego} == {"cruising"} and ego[0]["x_m"] is None
    lefty = [r for r in rows if r["track_id"] == "lefty"]
    assert lefty[30]["lane"] == "left" and lefty[30]["motion"] == "approach" and lefty[30]["stationary"] is False
    assert lefty[30]["y_m"] == pytest.approx(3.5)
    parked = [r for r in rows if r["track_id"] == "parked"]
    assert all(r["stationary"] is True and r["lane"] is None for r in parked)
    blip = [r for r in rows if r["track_id"] == "blip"]
    assert blip[0]["stationary"] is None and blip[0]["lane"] is None
    assert result.skipped_tracks == {"blip": SKIP_ISOLATED}
    # The gap is untagged, the frames around it are tagged.
    gappy_ts = {r["timestamp_ns"] for r in rows if r["track_id"] == "gappy"}
    assert int(result.timestamps_ns[21]) not in gappy_ts
    assert result.neighbors.tagged[1, 19] and result.neighbors.tagged[1, 24]

    captions = result.captions_table()
    assert captions.schema.equals(CAPTIONS_SCHEMA)
    by_track = {c.track_id: c for c in result.captions}
    assert set(by_track) == {"ego", "lefty", "gappy"}
    lefty_caption = by_track["lefty"]
    assert lefty_caption.tags == ("left:approach",)
    assert lefty_caption.host_tags == ("cruising:heading_straight",)
    assert lefty_caption.caption == (
        "The ego vehicle is cruising straight. A car in the left lane approaches."
    )
    assert len(lefty_caption.paraphrases) == 3
    assert by_track["gappy"].num_frames == 56 - 0  # tagged frames inside the host segment
    assert all(c.num_frames >= 8 for c in result.captions)


def test_sliding_windows(make_scene) -> None:  # type: ignore[no-untyped-def]
    config = CaptioningConfig(windows=WindowsConfig(strategy=WindowStrategy.SLIDING, length_s=2.0, stride_s=1.0))
    result = busy_scene(make_scene).caption(config)
    lefty = [c for c in result.captions if c.track_id == "lefty"]
    assert len(lefty) == 5 and all(c.window == "sliding" for c in lefty)
    assert [c.start_ns for c in lefty] == [0, 1_000_000_000, 2_000_000_000, 3_000_000_000, 4_000_000_000]
    assert [c.window for c in result.captions if c.track_id == "ego"] == ["host_segments"]


@pytest.mark.parametrize(("field", "track"), [("center_ego_xy_m", "lefty"), ("yaw_ego_rad", "gappy")])
def test_nan_in_a_track_names_log_track_frame_and_field(make_scene, field: str, track: str) -> None:  # type: ignore[no-untyped-def]
    data = busy_scene(make_scene).arrays()
    k = list(data["track_ids"]).index(track)
    data[field][k, 17] = np.nan
    with pytest.raises(TrackDataError) as info:
        caption_arrays(config=CaptioningConfig(), **data)  # type: ignore[arg-type]
    message = str(info.value)
    assert "scene" in message and track in message and "frame 17" in message and field in message


def test_nan_outside_observed_frames_is_fine(make_scene) -> None:  # type: ignore[no-untyped-def]
    data = busy_scene(make_scene).arrays()
    assert np.isnan(data["center_ego_xy_m"][1, 21]).all()  # gap of "gappy"
    caption_arrays(config=CaptioningConfig(), **data)  # type: ignore[arg-type]


def test_nan_ego_pose_is_an_error(make_scene) -> None:  # type: ignore[no-untyped-def]
    data = busy_scene(make_scene).arrays()
    data["city_SE3_ego"][33, 0, 3] = np.nan
    with pytest.raises(TrackDataError, match=r"track ego, frame 33 .*city_SE3_ego"):
        caption_arrays(config=CaptioningConfig(), **data)  # type: ignore[arg-type]


def test_write_outputs_atomically(make_scene, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    result = busy_scene(make_scene).caption()
    frames_path, captions_path = write_outputs(tmp_path / "out", [result, result])
    published = sorted(p.name for p in (tmp_path / "out").iterdir() if not p.name.startswith("."))
    assert published == ["captions.parquet", "frame_tags.parquet", "logs.json"]
    frames = pq.read_table(frames_path)
    captions = pq.read_table(captions_path)
    assert frames.num_rows == 2 * result.frame_tags_table().num_rows
    assert captions.column("tags").to_pylist()[1] == list(result.captions[1].tags)
    assert captions.column("caption").to_pylist() == captions.column("canonical_caption").to_pylist()


def test_empty_log_list_writes_empty_files(tmp_path: Path) -> None:
    frames_path, captions_path = write_outputs(tmp_path, [])
    assert pq.read_table(frames_path).num_rows == 0 and pq.read_table(captions_path).schema.equals(CAPTIONS_SCHEMA)


@pytest.mark.parametrize(("num_frames", "num_tracks"), [(0, 0), (1, 2), (3, 1), (5, 0)])
def test_tiny_logs_give_no_captions_and_no_errors(num_frames: int, num_tracks: int) -> None:
    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    poses[:, 0, 3] = np.arange(num_frames)
    result = caption_arrays(
        "tiny", (np.arange(num_frames) * 100_000_000).astype(np.int64),
        np.array([f"t{i}" for i in range(num_tracks)], dtype=np.str_), np.array(["car"] * num_tracks, dtype=np.str_),
        np.ones((num_tracks, num_frames), bool), np.ones((num_tracks, num_frames, 2)),
        np.zeros((num_tracks, num_frames)), poses, CaptioningConfig(rules=RuleSet.PAPER),
    )
    assert result.captions == []
    assert result.frame_tags_table().num_rows == num_frames * (1 + num_tracks)
    assert len(result.skipped_tracks) == (num_tracks if num_frames == 1 else 0)


def test_missed_detections_are_bridged_for_derivatives_but_not_reported(make_scene) -> None:  # type: ignore[no-untyped-def]
    # A parked car seen by a jittery tracker that misses every fourth frame: with gaps bridged the
    # car stays stationary; cut into 3-frame runs differentiated apart it would look like it moves.
    rng = np.random.default_rng(3)
    xy = np.tile([25.0, -3.5], (60, 1)) + rng.normal(0, 0.15, (60, 2))
    seen = np.arange(60) % 4 != 3
    scene = make_scene(8.0).add("parked", "car", xy, 0.0, valid=seen)
    assert scene.caption().neighbors.stationary.tolist() == [True]
    unbridged = CaptioningConfig(smoothing=SmoothingConfig(max_gap_s=0.0))
    assert scene.caption(unbridged).neighbors.stationary.tolist() == [False]
    # Two frames with one missed between them can be differentiated; frames are reported only where seen.
    pair = np.zeros(60, bool)
    pair[[30, 32]] = True
    result = make_scene(0.0).add("pair", "car", np.c_[10.0 + 5.0 * np.arange(60) * 0.1, np.zeros(60)], 0.0,
                                 valid=pair).caption()
    assert result.neighbors.taggable.tolist() == [True] and result.skipped_tracks == {}
    assert np.flatnonzero(result.neighbors.tagged[0]).tolist() == [30, 32]
