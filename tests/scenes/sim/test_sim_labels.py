from typing import Any

import numpy as np

from scenes.behavior import BehaviorLabel
from scenes.sim.labels import LaneInfo, compute_labels
from scenes.sim.runner import ObjectRows

LANES = LaneInfo(direction={":J_0_0": "l", ":J_1_0": "r", ":J_2_0": "s"},
                 junction={":J_0_0": "J", ":J_1_0": "J", ":J_2_0": "J", "E_1": "K", "E_2": "K"},
                 length_m={"E_1": 100.0, "E_2": 100.0})


def _rows(n: int, **columns: Any) -> ObjectRows:
    base: dict[str, Any] = {
        "step": np.arange(n), "sumo_id": ["v"] * n, "type_id": ["car"] * n, "is_person": [False] * n,
        "front_xy_m": np.zeros((n, 2)), "angle_deg": np.zeros(n), "speed_mps": np.full(n, 10.0),
        "accel_mps2": np.zeros(n), "lane_id": ["E_1"] * n, "lane_index": np.ones(n), "lateral_m": np.zeros(n),
        "stop_state": np.zeros(n), "leader_id": [""] * n, "leader_gap_m": np.full(n, np.inf),
        "leader_speed_mps": np.full(n, np.nan), "leader_accel_mps2": np.full(n, np.nan),
        "lane_pos_m": np.full(n, 10.0),
    }
    base.update(columns)
    return ObjectRows(
        step=np.asarray(base["step"], np.int64), sumo_id=np.asarray(base["sumo_id"], np.str_),
        type_id=np.asarray(base["type_id"], np.str_), is_person=np.asarray(base["is_person"], bool),
        front_xy_m=np.asarray(base["front_xy_m"], float), angle_deg=np.asarray(base["angle_deg"], float),
        speed_mps=np.asarray(base["speed_mps"], float), accel_mps2=np.asarray(base["accel_mps2"], float),
        lane_id=np.asarray(base["lane_id"], np.str_), lane_index=np.asarray(base["lane_index"], np.int64),
        lateral_m=np.asarray(base["lateral_m"], float), stop_state=np.asarray(base["stop_state"], np.int64),
        leader_id=np.asarray(base["leader_id"], np.str_), leader_gap_m=np.asarray(base["leader_gap_m"], float),
        leader_speed_mps=np.asarray(base["leader_speed_mps"], float),
        leader_accel_mps2=np.asarray(base["leader_accel_mps2"], float),
        lane_pos_m=np.asarray(base["lane_pos_m"], float),
    )


def test_cruising_vehicle_keeps_its_lane_only() -> None:
    labels = compute_labels(_rows(5), LANES)
    assert labels.flags[BehaviorLabel.KEEPING_LANE].all()
    others = [v for k, v in labels.flags.items() if k is not BehaviorLabel.KEEPING_LANE]
    assert not np.any(others)


def test_left_lane_change_covers_the_whole_lateral_motion() -> None:
    # Moving from lane 1 to lane 2: offset grows to the left, the index flips, offset shrinks to 0.
    lateral = [0.0, 0.0, 0.5, 1.0, 1.5, -1.5, -1.0, -0.5, 0.0, 0.0]
    index = [1, 1, 1, 1, 1, 2, 2, 2, 2, 2]
    labels = compute_labels(_rows(10, lateral_m=lateral, lane_index=index,
                                  lane_id=[f"E_{i}" for i in index]), LANES)
    left = labels.flags[BehaviorLabel.LEFT_LANE_CHANGE]
    assert left.tolist() == [False, False, True, True, True, True, True, True, False, False]
    assert not labels.flags[BehaviorLabel.RIGHT_LANE_CHANGE].any()
    assert not (left & labels.flags[BehaviorLabel.KEEPING_LANE]).any()


def test_right_lane_change_with_rows_out_of_order() -> None:
    lateral = [0.0, -0.8, -1.5, 1.5, 0.8, 0.0]
    index = [2, 2, 2, 1, 1, 1]
    rows = _rows(6, lateral_m=lateral, lane_index=index, lane_id=[f"E_{i}" for i in index])
    perm = np.array([3, 0, 5, 1, 4, 2])
    labels = compute_labels(rows.select(perm), LANES)
    expected = np.array([False, True, True, True, True, False])[perm]
    assert labels.flags[BehaviorLabel.RIGHT_LANE_CHANGE].tolist() == expected.tolist()


def test_offset_without_index_change_is_not_a_lane_change() -> None:
    labels = compute_labels(_rows(4, lateral_m=[0.0, 0.4, 0.4, 0.0]), LANES)
    assert not labels.flags[BehaviorLabel.LEFT_LANE_CHANGE].any()
    assert not labels.flags[BehaviorLabel.RIGHT_LANE_CHANGE].any()


def test_turns_come_from_the_connection_direction() -> None:
    labels = compute_labels(_rows(3, lane_id=[":J_0_0", ":J_1_0", ":J_2_0"]), LANES)
    assert labels.flags[BehaviorLabel.LEFT_TURN].tolist() == [True, False, False]
    assert labels.flags[BehaviorLabel.RIGHT_TURN].tolist() == [False, True, False]
    assert labels.junction_id.tolist() == ["J", "J", "J"]
    # Going straight through a junction keeps the lane; turning does not.
    assert labels.flags[BehaviorLabel.KEEPING_LANE].tolist() == [False, False, True]


def test_blocked_by_a_close_leader() -> None:
    labels = compute_labels(_rows(3, speed_mps=[0.0, 0.0, 0.0], leader_id=["w", "w", ""],
                                  leader_gap_m=[2.0, 30.0, np.inf], leader_speed_mps=[0.0, 0.0, np.nan]), LANES)
    assert labels.flags[BehaviorLabel.BLOCKED_BY].tolist() == [True, False, False]
    assert labels.flags[BehaviorLabel.STOPPED].all()
    assert labels.leader_id.tolist() == ["w", "", ""]


def test_braking_for_a_slower_leader() -> None:
    labels = compute_labels(_rows(3, accel_mps2=[-3.0, -3.0, -3.0], leader_id=["w", "w", ""],
                                  leader_gap_m=[12.0, 12.0, np.inf], leader_speed_mps=[5.0, 15.0, np.nan],
                                  leader_accel_mps2=[0.0, 0.0, np.nan]), LANES)
    assert labels.flags[BehaviorLabel.BRAKING].all()
    assert labels.flags[BehaviorLabel.BRAKING_FOR].tolist() == [True, False, False]


def test_parked_is_not_stopped_and_pedestrians_keep_no_lane() -> None:
    labels = compute_labels(_rows(2, speed_mps=[0.0, 1.2], stop_state=[131, 0], is_person=[False, True],
                                  lane_id=["E_1", ""]), LANES)
    assert labels.flags[BehaviorLabel.PARKED].tolist() == [True, False]
    assert labels.flags[BehaviorLabel.STOPPED].tolist() == [False, False]
    assert not labels.flags[BehaviorLabel.KEEPING_LANE].any()


def test_vehicles_near_the_stop_line_are_at_the_junction() -> None:
    labels = compute_labels(_rows(3, lane_pos_m=[10.0, 85.0, 99.0], speed_mps=[10.0, 0.0, 0.0]), LANES)
    assert labels.junction_id.tolist() == ["", "K", "K"]
