"""Over 10 simulated minutes of logs every action class occurs, turns at 3-way and 4-way junctions too."""

from pathlib import Path

import numpy as np
import pytest

from scenes.behavior import BehaviorLabel, JunctionKind, read_behavior_labels, read_junctions
from scenes.log import Log
from scenes.sim import SimulationConfig, simulate
from scenes.sim.props import FURNITURE_TYPES


@pytest.mark.slow
def test_ten_simulated_minutes_contain_every_action(tmp_path: Path) -> None:
    config = SimulationConfig(logs=20, duration_s=30.0, seed=3, cache_dir=str(tmp_path / "cache"))
    assert config.logs * config.duration_s >= 600
    counts = dict.fromkeys(BehaviorLabel, 0)
    turns: set[tuple[str, str]] = set()
    blocked_with_leader = 0
    categories: set[str] = set()
    for log_dir in simulate(config, tmp_path / "logs"):
        categories |= set(Log.open(log_dir).annotations.category.tolist())
        labels = read_behavior_labels(log_dir)
        junctions = read_junctions(log_dir)
        assert labels is not None and junctions is not None
        kind_of = dict(zip(junctions.column("junction_id").to_pylist(), junctions.column("kind").to_pylist()))
        junction_ids = np.asarray(labels.column("junction_id").to_pylist(), dtype=object)
        leaders = np.asarray(labels.column("leader_id").to_pylist(), dtype=object)
        for label in BehaviorLabel:
            flags = labels.column(label.value).to_numpy(zero_copy_only=False)
            counts[label] += int(flags.sum())
            if label in (BehaviorLabel.LEFT_TURN, BehaviorLabel.RIGHT_TURN, BehaviorLabel.BLOCKED_BY):
                turns |= {(label.value, kind_of.get(j, "")) for j in junction_ids[flags]}
            if label is BehaviorLabel.BLOCKED_BY:
                blocked_with_leader += int(sum(leader is not None for leader in leaders[flags]))
    missing = [label.value for label, n in counts.items() if n == 0]
    assert not missing, f"labels never seen: {missing}; counts {counts}"
    for turn in ("left_turn", "right_turn", "blocked_by"):
        for kind in (JunctionKind.THREE_WAY, JunctionKind.FOUR_WAY):
            assert (turn, kind.value) in turns, f"no {turn} at a {kind.value} junction"
    assert blocked_with_leader == counts[BehaviorLabel.BLOCKED_BY]
    # SUMO's traffic, every class of it, and some of the street furniture placed beside it
    # (scenes.sim.props; every kind of it at a higher density in test_sim_props).
    traffic = {"REGULAR_VEHICLE", "BOX_TRUCK", "BUS", "MOTORCYCLIST", "BICYCLIST", "PEDESTRIAN"}
    furniture = {t.av2_label for t in FURNITURE_TYPES}
    assert traffic <= categories and categories - traffic and categories - traffic <= furniture
