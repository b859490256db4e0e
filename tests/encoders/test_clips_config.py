"""Clips configuration round trip and the split by log."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import scenesearch_base.config
from encoders.clips.config import BevSourceChoice, ClipsConfig, ClipsConfigError, Split, SplitConfig
from encoders.clips.splits import assign_splits
from encoders.clips.table import sample_frame_indices, window_frames


def test_config_round_trips_through_yaml(tmp_path: Path) -> None:
    config = ClipsConfig()
    config = replace(
        config,
        frames_per_clip=8,
        previews=False,
        bev=replace(config.bev, source=BevSourceChoice.BOXES, z_bins_m=(-1.0, 0.5, 3.0), num_sweeps=5),
        camera=replace(config.camera, highlight_rgb=(0, 255, 0), width_px=128),
        split=SplitConfig(seed=7, train_fraction=0.6, val_fraction=0.2, train_only=("sim_1", "sim_2"),
                          val_only=("val_1",), test_only=("kept_1",)),
    )
    path = tmp_path / "clips.yaml"
    config.to_yaml(path)
    assert ClipsConfig.from_yaml(path) == config
    assert ClipsConfig.from_yaml(path) != ClipsConfig()


@pytest.mark.parametrize(
    ("text", "message"),
    [("bev:\n  resolution: 0.5\n", r"unknown keys bev\.resolution"), ("bev:\n  source: radar\n", r"source.*radar"),
     ("frames_per_clip: 0\n", "frames_per_clip")],
)
def test_config_rejects_unknown_fields_and_bad_values(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "clips.yaml"
    path.write_text(text)
    with pytest.raises(ClipsConfigError, match=message) as info:
        ClipsConfig.from_yaml(path)
    assert str(path) in str(info.value) and isinstance(info.value, scenesearch_base.config.ConfigError)


def test_splits_are_by_log_deterministic_and_cover_every_split() -> None:
    logs = [f"log_{i:03d}" for i in range(200)]
    a = assign_splits(logs, SplitConfig(seed=3))
    b = assign_splits(list(reversed(logs)), SplitConfig(seed=3))
    assert a == b
    counts = {s: sum(1 for v in a.values() if v == s) for s in Split}
    assert 110 <= counts[Split.TRAIN] <= 170 and 12 <= counts[Split.VAL] <= 50 and 12 <= counts[Split.TEST] <= 50
    # Adding logs does not move the others (hash of seed and log id only).
    more = assign_splits([*logs, "extra_1", "extra_2"], SplitConfig(seed=3))
    assert all(more[k] == v for k, v in a.items())
    assert assign_splits(logs, SplitConfig(seed=4)) != a
    for n in (3, 4, 5):
        few = assign_splits([f"x{i}" for i in range(n)], SplitConfig(seed=0))
        assert set(few.values()) == {Split.TRAIN, Split.VAL, Split.TEST}


def test_train_only_logs_train_and_leave_the_other_logs_where_they_were() -> None:
    logs = [f"log_{i:03d}" for i in range(3)]
    extra = [f"sim_{i}" for i in range(20)]
    alone = assign_splits(logs, SplitConfig(seed=0))
    mixed = assign_splits([*logs, *extra], SplitConfig(seed=0, train_only=(*extra, "not_given")))
    assert {k: mixed[k] for k in logs} == alone  # the few logs still fill every split
    assert all(mixed[k] is Split.TRAIN for k in extra) and "not_given" not in mixed


def test_val_and_test_only_logs_keep_their_split_and_leave_the_others_where_they_were() -> None:
    logs = [f"log_{i:03d}" for i in range(12)]
    val, test = [f"val_{i}" for i in range(4)], ["kept_0"]
    alone = assign_splits(logs, SplitConfig(seed=0))
    mixed = assign_splits([*logs, *val, *test, "extra_0"], SplitConfig(seed=0, train_only=("extra_0",),
                                                                      val_only=(*val, "not_given"), test_only=test))
    assert {k: mixed[k] for k in logs} == alone
    assert all(mixed[k] is Split.VAL for k in val) and mixed["kept_0"] is Split.TEST
    assert mixed["extra_0"] is Split.TRAIN and "not_given" not in mixed
    # A hashed split left without a log still takes one from the hashed logs, not from the forced ones.
    few = assign_splits(["a", "b", "c", *val], SplitConfig(seed=0, val_only=tuple(val)))
    assert {few[k] for k in "abc"} == {Split.TRAIN, Split.VAL, Split.TEST}


def test_a_log_named_for_two_splits_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ClipsConfigError, match=r"log\(s\) both named more than once"):
        ClipsConfig(split=SplitConfig(train_only=("both",), test_only=("both",)))
    path = tmp_path / "clips.yaml"
    path.write_text("split:\n  val_only: [x]\n  test_only: [x]\n")
    with pytest.raises(ClipsConfigError, match="x named more than once") as info:
        ClipsConfig.from_yaml(path)
    assert str(path) in str(info.value)


def test_frame_sampling_is_uniform_and_repeats_short_windows() -> None:
    idx = sample_frame_indices(10, 40, 16)
    assert idx[0] == 10 and idx[-1] == 40 and (np.diff(idx) >= 1).all()
    short = sample_frame_indices(5, 7, 16)
    assert sorted(set(short.tolist())) == [5, 6, 7] and len(short) == 16
    ts = 1_000 + np.arange(10) * 100
    assert window_frames(ts, 1_200, 1_500, 10) == (2, 5)
    assert window_frames(ts, 500, 1_500, 10) is None
    assert window_frames(ts, 1_200, 9_000, 10) is None


@pytest.mark.parametrize(("data", "message"), [
    ({"frames_per_clip": 257}, "key 'frames_per_clip': 257 is above its upper bound 256"),
    ({"camera": {"width_px": 5000}}, "key 'camera.width_px': 5000 is above its upper bound 4096"),
    ({"bev": {"num_sweeps": 51}}, "key 'bev.num_sweeps': 51 is above its upper bound 50"),
    ({"bev": {"resolution_m": 0.001}}, "at most 2048 along a side"),
    ({"bev": {"z_bins_m": list(range(70))}}, "at most 64 height bins"),
])
def test_sizes_above_their_bounds_are_refused(data: dict[str, object], message: str) -> None:
    with pytest.raises(ClipsConfigError, match=re.escape(message)):
        ClipsConfig.from_dict(data, source="clips.yaml")


def test_sizes_at_their_bounds_are_taken() -> None:
    config = ClipsConfig.from_dict({"frames_per_clip": 256, "bev": {"num_sweeps": 50}})
    assert config.frames_per_clip == 256 and config.bev.num_sweeps == 50
