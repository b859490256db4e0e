"""The rules' durations are seconds: a log captioned at 10 Hz and the same log at 2 Hz agree.

A 2 Hz log (nuScenes, a tracker run at 2 Hz) is the 10 Hz log with every fifth annotation timestamp
kept. Its tracks are all tagged and captioned (none skipped for "no run" that lasts long enough in
seconds), and its per-frame tags equal the 10 Hz tags at the shared timestamps in most frames.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

from captioning.config import CaptioningConfig, RuleSet
from captioning.errors import ConfigError
from captioning.frames import FrameCounts, frames_at, savgol_frames
from captioning.outputs import write_outputs
from captioning.pipeline import LogCaptions, caption_arrays, caption_log
from captioning.tags import NO_TAG
from scenes.log import Log
from tests.scenes.av2_fixtures import DEV_LOGS, require, rewritten_log

from .conftest import DT_S, Scene, ego_path

STEP = 5  # 10 Hz → 2 Hz
T = 200  # 20 s at 10 Hz


def scene_10hz() -> Scene:
    """An ego that cruises, brakes to a stop, waits and drives off, among traffic of every lane, with box jitter."""
    t_s = np.arange(T) * DT_S
    ego_speed = np.interp(t_s, [0, 6, 9, 12, 14, 20], [10, 10, 0, 0, 6, 9])
    s = ego_path(ego_speed, num_frames=T)
    rng = np.random.default_rng(7)

    def jitter(xy: np.ndarray) -> np.ndarray:
        return xy + rng.normal(0, 0.05, xy.shape)

    ego = s.ego_xy_m
    # Ahead in the host lane: drives away first, then the ego closes in while it waits.
    lead_x = np.cumsum(np.interp(t_s, [0, 5, 8, 20], [14, 14, 0, 0])) * DT_S + 25.0
    s.add("lead", "car", jitter(np.c_[lead_x, np.zeros(T)]), 0.0)
    # Left lane, overtaking the ego at a steady 16 m/s.
    s.add("overtaker", "car", jitter(np.c_[-30.0 + 16.0 * t_s, np.full(T, 3.6)]), 0.0)
    # Oncoming in the left lane.
    s.add("oncoming", "car", jitter(np.c_[200.0 - 12.0 * t_s, np.full(T, 3.6)]), math.pi)
    # Crossing ahead, right to left, over a road far ahead.
    s.add("crosser", "car", jitter(np.c_[np.full(T, 120.0), -40.0 + 6.0 * t_s]), math.pi / 2)
    # Parked at the right curb.
    s.add("parked", "car", jitter(np.tile([60.0, -3.5], (T, 1))), 0.0)
    # A pedestrian walking along the right side.
    s.add("walker", "pedestrian", jitter(np.c_[40.0 + 1.3 * t_s, np.full(T, -6.0)]), 0.0)
    # A car following the ego, seen in two stretches (a tracker's long miss between them).
    seen = np.ones(T, bool)
    seen[90:110] = False
    s.add("follower", "car", jitter(ego + np.c_[np.full(T, -15.0), np.zeros(T)]), 0.0, seen)
    # A short track: 1 s (two frames at 2 Hz, long enough in seconds).
    brief = np.zeros(T, bool)
    brief[150:160] = True
    s.add("brief", "car", jitter(np.c_[30.0 + 20.0 * t_s, np.full(T, -3.6)]), 0.0, brief)
    return s


def subsampled(data: dict[str, object], step: int) -> dict[str, object]:
    """The arrays of :meth:`Scene.arrays` at every ``step``-th timestamp."""
    out = dict(data)
    for key in ("timestamps_ns", "city_SE3_ego"):
        out[key] = np.asarray(data[key])[::step]
    for key in ("valid", "center_ego_xy_m", "yaw_ego_rad"):
        out[key] = np.asarray(data[key])[:, ::step]
    return out


def agreement(full: np.ndarray, low: np.ndarray) -> float:
    """Share of the frames tagged at 10 Hz (at the 2 Hz timestamps) whose 2 Hz tag is the same.

    Args:
        full: (K, T) codes at 10 Hz.
        low: (K, T // STEP) codes at 2 Hz.
    """
    shared = np.asarray(full)[:, ::STEP]
    tagged = shared != NO_TAG
    return float((shared[tagged] == np.asarray(low)[tagged]).mean())


def caption_both(config: CaptioningConfig) -> tuple[LogCaptions, LogCaptions]:
    data = scene_10hz().arrays()
    full = caption_arrays(config=config, **data)  # type: ignore[arg-type]
    low = caption_arrays(config=config, **subsampled(data, STEP))  # type: ignore[arg-type]
    return full, low


def test_frames_at_rounds_to_the_nearest_frame_with_a_minimum() -> None:
    assert frames_at(0.5, 0.1, 1) == 5 and frames_at(0.5, 0.5, 1) == 1 and frames_at(0.5, 0.5, 2) == 2
    assert frames_at(0.3, 0.5, 0) == 1 and frames_at(0.2, 0.5, 0) == 0
    assert frames_at(0.5, math.nan, 2) == 2  # a single frame: no interval
    assert savgol_frames(0.9, 0.1, 2) == (9, 2) and savgol_frames(0.8, 0.1, 2) == (9, 2)
    assert savgol_frames(0.7, 0.1, 2) == (7, 2) and savgol_frames(0.7, 0.1, 9) == (7, 5)
    assert savgol_frames(0.9, 0.5, 2) == (3, 1)  # 2 Hz: a straight line through three frames
    assert savgol_frames(0.9, 0.0999, 2) == (9, 2) and savgol_frames(0.9, 0.1001, 2) == (9, 2)  # clock jitter
    assert savgol_frames(0.9, math.nan, 2) == (3, 1)


def test_defaults_are_todays_frame_counts_at_10_hz_and_defined_at_2_hz() -> None:
    config = CaptioningConfig()
    ten = FrameCounts.of(config, 0.1)
    assert (ten.window, ten.min_run, ten.max_gap, ten.segment_min, ten.segment_max) == (9, 5, 3, 8, 300)
    assert (ten.behavior_window, ten.accel_window, ten.behavior_min_run) == (9, 5, 5)
    assert (ten.polyorder, ten.behavior_polyorder, ten.accel_polyorder) == (2, 2, 2)
    two = FrameCounts.of(config, 0.5)
    assert (two.window, two.min_run, two.max_gap, two.segment_min, two.segment_max) == (3, 1, 1, 2, 60)
    assert (two.behavior_window, two.accel_window, two.behavior_min_run) == (3, 3, 2)
    assert (two.polyorder, two.behavior_polyorder, two.accel_polyorder) == (1, 1, 1)


@pytest.mark.parametrize("rules", [RuleSet.BEHAVIOR, RuleSet.PAPER])
def test_a_2_hz_log_is_tagged_and_captioned_like_its_10_hz_original(rules: RuleSet) -> None:
    full, low = caption_both(CaptioningConfig(rules=rules))
    assert low.skipped_tracks == {} and full.skipped_tracks == {}
    # Every track captioned at 10 Hz is captioned at 2 Hz, and the ego's segments survive.
    assert {c.track_id for c in low.captions} == {c.track_id for c in full.captions}
    assert len(low.host_segments) >= 1
    # Per-frame tags at the shared timestamps.
    nb_full, nb_low = full.neighbors, low.neighbors
    assert agreement(nb_full.lane, nb_low.lane) >= 0.95
    assert agreement(nb_full.motion, nb_low.motion) >= 0.85
    assert agreement(full.host_motion[None], low.host_motion[None]) >= 0.8
    assert agreement(full.host_direction[None], low.host_direction[None]) >= 0.95
    if rules == RuleSet.BEHAVIOR:
        assert full.action_code is not None and low.action_code is not None
        assert agreement(full.action_code, low.action_code) >= 0.85


def test_a_short_track_long_enough_in_seconds_gets_own_behaviour_tags_at_2_hz() -> None:
    _, low = caption_both(CaptioningConfig())
    k = list(low.track_ids).index("brief")
    assert low.valid[k].sum() == 2  # 1 s at 2 Hz
    assert low.behavior is not None and low.behavior.taggable[k]
    assert low.behavior.known_cell[k][low.valid[k]].all()


def test_old_frame_keys_are_refused_naming_their_replacement(tmp_path: Path) -> None:
    path = tmp_path / "old.yaml"
    path.write_text("smoothing: {window_frames: 9, max_gap_frames: 3}\nsegments: {min_frames: 8}\n"
                    "behavior: {accel_window_frames: 5}\n")
    with pytest.raises(ConfigError) as info:
        CaptioningConfig.from_yaml(path)
    message = str(info.value)
    assert message.startswith(f"{path}: key 'smoothing.window_frames' is now 'smoothing.window_s' (seconds")
    for old, new in [("smoothing.max_gap_frames", "smoothing.max_gap_s"), ("segments.min_frames", "segments.min_s"),
                     ("behavior.accel_window_frames", "behavior.accel_window_s")]:
        assert f"key '{old}' is now '{new}'" in message
    with pytest.raises(ConfigError, match=r"key 'behavior\.min_run_frames' is now 'behavior\.min_run_s'"):
        CaptioningConfig.from_dict({"behavior": {"min_run_frames": 5}}, source="c.yaml")


def every_fifth_timestamp(table: pa.Table) -> pa.Table:
    """Annotations at every fifth timestamp (10 Hz → 2 Hz)."""
    ts = np.unique(table.column("timestamp_ns").to_numpy())
    return table.filter(pc.is_in(table.column("timestamp_ns"), pa.array(ts[::STEP])))


def test_the_development_av2_log_at_2_hz_is_captioned(tmp_path: Path) -> None:
    source = require(DEV_LOGS["7fab2350"])
    log_2hz = rewritten_log(source, tmp_path / source.name, every_fifth_timestamp)
    full = caption_log(Log.open(source))
    low = caption_log(Log.open(log_2hz))
    assert 0.15 < len(low.timestamps_ns) / len(full.timestamps_ns) < 0.25
    # Few tracks skipped (those seen in a single 2 Hz frame only), none for a too short run.
    assert len(low.skipped_tracks) <= 0.1 * len(low.track_ids)
    assert not any("behavior.min_run_s" in reason for reason in low.skipped_tracks.values())
    assert len(low.captions) >= 0.8 * len(full.captions)
    frames_path, captions_path = write_outputs(tmp_path / "captions", [low])
    assert frames_path.is_file() and captions_path.is_file()
    # Tags where both logs observe a track: the 2 Hz grid also holds the fixture's few LiDAR sweeps,
    # whose annotations the 2 Hz log lacks.
    row_of = {str(track): k for k, track in enumerate(full.track_ids)}
    rows = np.array([row_of[str(track)] for track in low.track_ids])
    shared = np.searchsorted(full.timestamps_ns, low.timestamps_ns)
    assert (full.timestamps_ns[shared] == low.timestamps_ns).all()
    for name in ("lane", "motion"):
        a = getattr(full.neighbors, name)[rows][:, shared]
        b = getattr(low.neighbors, name)
        tagged = (a != NO_TAG) & low.valid
        assert tagged.sum() >= 2000
        assert float((a[tagged] == b[tagged]).mean()) >= 0.9, name
