"""Tag targets of logs without behaviour labels come from the captioning rules, and say so."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from encoders.clips.build import build_clips
from encoders.clips.layout import TARGETS_STEM, rendered_log_dir
from encoders.tagging.attributes import ATTRIBUTES, Attribute
from encoders.tagging.evaluate import sources_line
from encoders.tagging.rasterize import rasterize_targets
from encoders.tagging.targets import (
    TargetSource,
    add_attribute_targets,
    map_junction_masks,
    open_targets,
    rule_behavior,
    target_files,
    targets_source,
)
from scenes.bev import BevGrid
from scenes.log import Log
from tests.encoders.clip_fixtures import FINE_CLIPS, synthetic_captions, write_synthetic_log
from tests.encoders.tagging_fixtures import add_synthetic_labels

NUM_FRAMES = 40
GRID = BevGrid(-20.0, 60.0, -20.0, 20.0, 0.5)


def cell(x: float, y: float) -> tuple[int, int]:
    return int((GRID.x_max_m - x) / GRID.resolution_m), int((GRID.y_max_m - y) / GRID.resolution_m)


def test_rules_give_targets_to_a_log_without_labels(tmp_path: Path) -> None:
    log = Log.open(write_synthetic_log(tmp_path, "unlabelled", num_frames=NUM_FRAMES, with_camera=False,
                                       with_lidar=False))
    dense = log.dense_tracks()
    beh = rule_behavior(log, dense)
    t = rasterize_targets(log, GRID, dense, behavior=beh)
    idx = {a: i for i, a in enumerate(ATTRIBUTES)}
    # The parked car stands off the lanes (city x 25 m, y −4 m; the lanes end at y −1.75 m) for the whole
    # log, while the ego drives by along +x at 5 m/s.
    parked = t[:, idx[Attribute.PARKED]]
    ego_x = 5.0 * 0.1 * np.arange(NUM_FRAMES)
    assert all(parked[f][cell(25.0 - ego_x[f], -4.0)] == 1.0 for f in range(NUM_FRAMES))
    assert parked.sum() == pytest.approx(NUM_FRAMES * 10 * 4, rel=0.05)  # the box's cells only
    assert t[:, idx[Attribute.STOPPED]].sum() == 0.0
    # The follower drives along its lane at the ego's 5 m/s, 12 m behind the ego.
    keeping = t[NUM_FRAMES // 2, idx[Attribute.KEEPING_LANE]]
    assert keeping[cell(-12.0, 0.0)] == 1.0
    assert t[NUM_FRAMES // 2, idx[Attribute.VEHICLE_SPEED]][cell(-12.0, 0.0)] == pytest.approx(5.0, abs=0.2)


def test_junction_kinds_of_rule_targets_come_from_the_map(tmp_path: Path) -> None:
    log = Log.open(write_synthetic_log(tmp_path, "unlabelled", num_frames=4, with_camera=False, with_lidar=False))
    # The synthetic map's intersection lanes (x 60–80 m) join two roads only: no 3- or 4-way junction.
    masks = map_junction_masks(log, GRID, log.dense_tracks().city_SE3_ego, ("three_way", "four_way"))
    assert masks.shape == (4, 2, *GRID.shape) and masks.sum() == 0.0


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path]]:
    root = tmp_path_factory.mktemp("rule_targets")
    labelled = write_synthetic_log(root / "logs", "labelled", num_frames=NUM_FRAMES, with_camera=False,
                                   with_lidar=False)
    add_synthetic_labels(labelled, NUM_FRAMES)
    unlabelled = write_synthetic_log(root / "logs", "unlabelled", num_frames=NUM_FRAMES, with_camera=False,
                                     with_lidar=False)
    (root / "captions").mkdir()
    pq.write_table(synthetic_captions([labelled, unlabelled]), root / "captions" / "captions.parquet")
    build_clips([labelled, unlabelled], root / "captions", root / "clips", FINE_CLIPS)
    return root / "clips", [labelled, unlabelled]


def test_add_attribute_targets_uses_labels_where_present_and_says_which(clips: tuple[Path, list[Path]]) -> None:
    clips_dir, logs = clips
    report = add_attribute_targets(clips_dir, logs)
    assert report.written == ["labelled", "unlabelled"] and report.skipped == []
    assert report.sources == {"labelled": TargetSource.LABELS.value, "unlabelled": TargetSource.RULES.value}
    table = report.table()
    assert "labelled" in table and "rules" in table and "labels" in table
    for log_id, source in report.sources.items():
        meta = json.loads(target_files(rendered_log_dir(clips_dir, log_id), TARGETS_STEM)[1].read_text())
        assert meta["source"] == source == targets_source(clips_dir, log_id)
        assert open_targets(clips_dir, log_id).targets.shape[0] == NUM_FRAMES
    # The labels and the rules agree on the parked car.
    parked = ATTRIBUTES.index(Attribute.PARKED)
    a = np.asarray(open_targets(clips_dir, "labelled").targets[0, parked])
    b = np.asarray(open_targets(clips_dir, "unlabelled").targets[0, parked])
    assert a[cell(25.0, -4.0)] == b[cell(25.0, -4.0)] == 1.0  # frame 0: the ego at the city origin
    again = add_attribute_targets(clips_dir, logs)
    assert again.reused == ["labelled", "unlabelled"] and again.sources == report.sources
    said = sources_line({"meta": {"test_logs": ["labelled", "unlabelled"], "target_sources": report.sources}})
    assert "1 from the simulator labels" in said and "1 from the captioning rules" in said
