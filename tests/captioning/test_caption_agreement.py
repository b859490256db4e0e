"""Agreement with simulator labels, on hand-made labels."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from captioning.agreement import agreement
from scenes.behavior import BEHAVIOR_SCHEMA, BehaviorLabel


def labels_table(timestamps_ns: np.ndarray, rows: dict[str, dict[str, np.ndarray]]) -> pa.Table:
    columns: dict[str, list] = {name: [] for name in BEHAVIOR_SCHEMA.names}
    t = timestamps_ns.shape[0]
    for track_id, flags in rows.items():
        columns["timestamp_ns"] += timestamps_ns.tolist()
        columns["track_id"] += [track_id] * t
        for label in BehaviorLabel:
            columns[label.value] += flags.get(label.value, np.zeros(t, bool)).tolist()
        columns["speed_mps"] += [5.0] * t
        columns["leader_id"] += [None] * t
        columns["junction_id"] += [None] * t
    return pa.table(columns, schema=BEHAVIOR_SCHEMA)


def test_lane_change_and_turn_agreement(make_scene) -> None:  # type: ignore[no-untyped-def]
    t = np.arange(80) * 0.1
    # "mover" changes from the host lane to the left lane around frame 40; "stayer" is labelled a
    # right lane change but never moves sideways; the ego turns left from frame 50.
    y_mover = np.clip((t - 3.5) * 3.5, 0.0, 3.5)
    rate = np.where(np.arange(80) >= 50, 0.3, 0.0)
    scene = make_scene(8.0, rate, num_frames=80)
    scene.add_relative("mover", "car", np.c_[15.0 + 2.0 * t, y_mover], 0.0)
    scene.add_relative("stayer", "car", np.c_[-15.0 + 0.0 * t, np.full(80, -3.5)], 0.0)
    result = scene.caption()
    change = (np.arange(80) >= 35) & (np.arange(80) <= 45)
    turn = np.arange(80) >= 55
    table = labels_table(
        result.timestamps_ns,
        {"mover": {"left_lane_change": change}, "stayer": {"right_lane_change": change},
         "ego": {"left_turn": turn}},
    )
    report = agreement(result, table)
    assert report.lane_change_events == 2 and report.lane_change_evaluable == 2
    assert report.lane_change_transition == 1 and report.lane_change_directed == 1
    assert report.lane_change_rate == 0.5
    assert report.band_crossing_events == 1 and report.band_crossing_transition == 1  # only "mover" crosses
    assert report.ego_turn_events == 1 and report.ego_turn_steering == 1
    # Labelled the wrong way round, the directed count drops.
    wrong = labels_table(result.timestamps_ns, {"mover": {"right_lane_change": change}})
    assert agreement(result, wrong).lane_change_directed == 0
