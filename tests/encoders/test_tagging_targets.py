"""Ground-truth rasters from boxes, behaviour labels and junctions of a synthetic log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from encoders.clips.blocks import BlockArray
from encoders.tagging.attributes import ATTRIBUTES, BEHAVIOR_ATTRIBUTES, JUNCTION_ATTRIBUTES, Attribute, TagError
from encoders.tagging.rasterize import approach_strips, behavior_grid, rasterize_targets
from encoders.tagging.targets import write_targets
from scenes.behavior import BehaviorLabel, JunctionKind
from scenes.bev import BevGrid
from scenes.log import Log
from scenes.map import LaneSegment, VectorMap
from tests.encoders.clip_fixtures import write_synthetic_log
from tests.encoders.tagging_fixtures import add_synthetic_labels

NUM_FRAMES = 6


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Log:
    root = tmp_path_factory.mktemp("tag_targets")
    log_dir = write_synthetic_log(root, "synthetic_tags", num_frames=NUM_FRAMES, with_camera=False, with_lidar=False)
    add_synthetic_labels(log_dir, NUM_FRAMES)
    return Log.open(log_dir)


def test_targets_put_labels_on_boxes_and_junctions(log: Log) -> None:
    grid = BevGrid(-20.0, 60.0, -20.0, 20.0, 0.5)
    t = rasterize_targets(log, grid)
    idx = {a: i for i, a in enumerate(ATTRIBUTES)}
    assert t.shape == (NUM_FRAMES, len(ATTRIBUTES), 160, 80)

    def cell(x: float, y: float) -> tuple[int, int]:
        return int((grid.x_max_m - x) / grid.resolution_m), int((grid.y_max_m - y) / grid.resolution_m)

    parked = t[0, idx[Attribute.PARKED]]
    assert parked[cell(25.0, -4.0)] == 1.0 and parked[cell(14.0, 3.5)] == 0.0
    assert parked.sum() == 10 * 4  # cell centres inside x ∈ [22.75, 27.25], y ∈ [−4.95, −3.05]
    braking = t[0, idx[Attribute.BRAKING]]  # lead brakes (the ego too, but it has no box)
    assert braking[cell(14.0, 3.5)] == 1.0 and braking[cell(25.0, -4.0)] == 0.0
    assert t[0, idx[Attribute.VEHICLE_SPEED]][cell(14.0, 3.5)] == pytest.approx(7.0)
    # Densities are fractional coverage: three 4.5 × 1.9 m cars.
    assert t[0, idx[Attribute.VEHICLE_DENSITY]].sum() * 0.25 == pytest.approx(3 * 4.5 * 1.9, rel=0.06)  # 1/8 m samples
    assert 0.0 < t[0, idx[Attribute.VEHICLE_DENSITY]].max() <= 1.0
    assert t[:, idx[Attribute.PEDESTRIAN_DENSITY]].sum() == 0.0
    # The 4-way junction: city x ∈ [25, 35] m, |y| ≤ 5 m; the ego moves along +x at 5 m/s.
    four = t[:, idx[Attribute.FOUR_WAY]]
    assert four[0][cell(30.0, 0.0)] == 1.0 and four[0][cell(20.0, 0.0)] == 0.0
    assert four[0].sum() * 0.25 == pytest.approx(100.0, rel=0.05)
    x_last = 30.0 - 5.0 * (NUM_FRAMES - 1) * 0.1
    assert four[-1][cell(x_last, 0.0)] == 1.0 and four[-1][cell(x_last + 6.0, 0.0)] == 0.0
    assert t[:, idx[Attribute.THREE_WAY]].sum() == 0.0  # 130 m behind: off the grid


def test_behavior_grid_joins_labels_and_leaders(log: Log) -> None:
    dense = log.dense_tracks()
    beh = behavior_grid(log.log_dir, dense)
    ids = [str(t) for t in dense.track_ids]
    lead = ids.index("lead")
    assert beh.ego_leader_index.tolist() == [lead] * NUM_FRAMES
    assert beh.flags[lead, :, 2].all() and not beh.flags[ids.index("parked"), :, 2].any()  # braking column


def test_a_log_without_labels_is_refused(tmp_path: Path) -> None:
    log_dir = write_synthetic_log(tmp_path, "unlabelled", num_frames=3, with_camera=False, with_lidar=False)
    with pytest.raises(TagError, match="no behaviour labels"):
        rasterize_targets(Log.open(log_dir), BevGrid())


def test_write_targets_is_float16_with_presence(tmp_path: Path) -> None:
    t = np.zeros((2, 3, 4, 4), np.float32)
    t[1, 2, 0, 0] = 0.5
    write_targets(tmp_path, t, ["a", "b", "c"])
    arr = BlockArray(tmp_path / "bev_attributes.blocks")
    assert arr.dtype == np.float16 and arr.shape == (2, 3, 4, 4)
    assert np.array_equal(arr[:], t.astype(np.float16)) and arr[1, 2, 0, 0] == 0.5
    import json

    meta = json.loads((tmp_path / "bev_attributes.json").read_text())
    assert meta["present"] == [[0, 0, 0], [0, 0, 1]] and meta["attributes"] == ["a", "b", "c"]
    assert not list(tmp_path.glob(".*tmp*"))


def test_behaviour_and_junction_attributes_are_the_simulators_words() -> None:
    # The targets read the behaviour-label columns and junction kinds by these names.
    assert [a.value for a in BEHAVIOR_ATTRIBUTES] == [label.value for label in BehaviorLabel]
    assert {a.value for a in JUNCTION_ATTRIBUTES} <= {kind.value for kind in JunctionKind}
    assert {label.value for label in BehaviorLabel} <= {attribute.value for attribute in Attribute}


def _lane(lane_id: int, x0: float, x1: float, inter: bool, succ: tuple[int, ...] = (),
          pred: tuple[int, ...] = ()) -> LaneSegment:
    """A lane along +x between x0 and x1 with y ∈ [−3.5, 0] (left boundary at y = 0)."""
    left = np.array([[x0, 0.0, 0.0], [x1, 0.0, 0.0]])
    right = np.array([[x0, -3.5, 0.0], [x1, -3.5, 0.0]])
    return LaneSegment(lane_id, inter, "VEHICLE", left, right, successors=succ, predecessors=pred)


def test_approach_strips_reach_back_along_entering_lanes() -> None:
    # 12 m lane → 10 m lane → junction lane inside the outline x ∈ [0, 10] → exit lane.
    lanes = {1: _lane(1, -22.0, -10.0, False, (2,)), 2: _lane(2, -10.0, 0.0, False, (3,), (1,)),
             3: _lane(3, 0.0, 10.0, True, (4,), (2,)), 4: _lane(4, 10.0, 30.0, False, (), (3,))}
    outline = np.array([[0.0, -10.0], [10.0, -10.0], [10.0, 10.0], [0.0, 10.0]])
    strips, elsewhere = approach_strips(VectorMap(lanes), [outline, outline + 100.0], approach_m=15.0)
    xs = sorted((float(s[:, 0].min()), float(s[:, 0].max())) for s in strips)
    # All of lane 2 (10 m) and the last 5 m of lane 1; nothing of the exit lane.
    assert xs[0] == pytest.approx((-15.0, -10.0), abs=0.6) and xs[1] == pytest.approx((-10.0, 0.0))
    assert len(strips) == 2 and all(s[:, 1].min() == pytest.approx(-3.5) for s in strips)
    assert elsewhere == []  # another junction: no lane enters it


def test_targets_are_reused_only_while_their_array_verifies(tmp_path: Path) -> None:
    from encoders.clips.layout import rendered_log_dir
    from encoders.tagging.targets import targets_reusable

    folder = rendered_log_dir(tmp_path, "L")
    folder.mkdir(parents=True)
    write_targets(folder, np.ones((2, 3, 4, 4), np.float32), ["a", "b", "c"])
    assert targets_reusable(tmp_path, "L")
    data = bytearray((folder / "bev_attributes.blocks").read_bytes())
    data[-1] ^= 0x01  # same size, other content
    (folder / "bev_attributes.blocks").write_bytes(bytes(data))
    assert not targets_reusable(tmp_path, "L")
    write_targets(folder, np.ones((2, 3, 4, 4), np.float32), ["a", "b", "c"])
    with open(folder / "bev_attributes.blocks", "r+b") as fh:
        fh.truncate(64)
    assert not targets_reusable(tmp_path, "L")
    (folder / "bev_attributes.blocks").unlink()
    assert not targets_reusable(tmp_path, "L")
