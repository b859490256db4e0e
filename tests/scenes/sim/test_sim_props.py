"""Street furniture and standing people: placed on sidewalks, static in the city, labelled as standing."""

from pathlib import Path

import numpy as np
import pytest

from scenes.behavior import read_behavior_labels
from scenes.geometry import point_polyline_distance
from scenes.log import Log
from scenes.sim import SimulationConfig, simulate
from scenes.sim.netparse import SumoNet, read_net
from scenes.sim.network import build_network
from scenes.sim.pipeline import _heading_rad
from scenes.sim.props import (
    CURB_INSET_M,
    FURNITURE_TYPES,
    PROP_TYPES,
    STANDING_PEDESTRIAN_TYPE,
    Props,
    place_props,
    prop_rows,
    sidewalks,
)
from scenes.sim.runner import ObjectRows


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("netcache")


@pytest.fixture(scope="module")
def net(cache: Path) -> SumoNet:
    config = SimulationConfig(seed=1, cache_dir=str(cache))
    return read_net(build_network(config.network, config.seed, cache))


def test_furniture_stands_at_the_curb_and_people_on_the_sidewalk(net: SumoNet) -> None:
    props = place_props(net, seed=1, furniture_per_km=20.0, standing_per_km=10.0)
    walks = sidewalks(net)
    roads = [lane for lane in net.lanes.values() if lane.edge_function == "" and "passenger" in lane.allowed]
    assert len(props) > 50
    assert set(props.type_id.tolist()) == set(PROP_TYPES)
    for xy, type_id in zip(props.center_xy_m, props.type_id):
        kind = PROP_TYPES[str(type_id)]
        to_walk = min(float(point_polyline_distance(xy[None], lane.shape_xy_m)[0]) for lane in walks)
        to_road = min(float(point_polyline_distance(xy[None], lane.shape_xy_m)[0]) for lane in roads)
        assert to_walk <= 1.0 + 1e-6  # inside a 2 m sidewalk
        if kind.at_curb:
            assert to_walk == pytest.approx(1.0 - CURB_INSET_M, abs=1e-6)
            # The curb is the road side: nearer the road than the sidewalk's centre line is.
            assert to_road < 1.0 + 0.5 * 3.2 + 1e-6


def test_placement_is_seeded_and_follows_the_density(net: SumoNet) -> None:
    a = place_props(net, seed=3, furniture_per_km=5.0, standing_per_km=5.0)
    b = place_props(net, seed=3, furniture_per_km=5.0, standing_per_km=5.0)
    np.testing.assert_array_equal(a.center_xy_m, b.center_xy_m)
    np.testing.assert_array_equal(a.type_id, b.type_id)
    assert not np.array_equal(place_props(net, seed=4, furniture_per_km=5.0, standing_per_km=5.0).center_xy_m,
                              a.center_xy_m)
    assert len(place_props(net, seed=3, furniture_per_km=0.0, standing_per_km=0.0)) == 0
    only_people = place_props(net, seed=3, furniture_per_km=0.0, standing_per_km=5.0)
    assert set(only_people.type_id.tolist()) == {STANDING_PEDESTRIAN_TYPE.id}
    dense = place_props(net, seed=3, furniture_per_km=50.0, standing_per_km=0.0)
    assert len(dense) > 4 * len(place_props(net, seed=3, furniture_per_km=5.0, standing_per_km=0.0))


def test_rows_are_the_props_near_the_ego_at_each_step_as_sumo_reports_them() -> None:
    props = Props(np.array(["prop_0", "prop_1"]), np.array([FURNITURE_TYPES[2].id, STANDING_PEDESTRIAN_TYPE.id]),
                  np.array([[10.0, 0.0], [100.0, 0.0]]), np.array([0.5, -2.0]))
    n = 3
    ego = ObjectRows(
        step=np.array([7, 8, 9]), sumo_id=np.full(n, "ego_0"), type_id=np.full(n, "ego"), is_person=np.zeros(n, bool),
        front_xy_m=np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]]), angle_deg=np.zeros(n), speed_mps=np.full(n, 10.0),
        accel_mps2=np.zeros(n), lane_id=np.full(n, "e_1"), lane_index=np.ones(n, np.int64), lateral_m=np.zeros(n),
        stop_state=np.zeros(n, np.int64), leader_id=np.full(n, ""), leader_gap_m=np.full(n, np.inf),
        leader_speed_mps=np.full(n, np.nan), leader_accel_mps2=np.full(n, np.nan), lane_pos_m=np.zeros(n),
    )
    rows = prop_rows(props, ego, radius_m=50.0)
    # The barrel is within 50 m at steps 7 and 8, the person at steps 8 (60 m: no) and 9.
    assert sorted(zip(rows.step.tolist(), rows.sumo_id.tolist())) == [(7, "prop_0"), (8, "prop_0"), (9, "prop_1")]
    assert np.all(rows.speed_mps == 0) and np.all(rows.lane_id == "") and np.all(rows.leader_id == "")
    assert rows.is_person.tolist() == [False, False, True]
    # Back through the pipeline's own conversion: compass angle → yaw, front → centre.
    yaw = _heading_rad(rows.angle_deg)
    np.testing.assert_allclose(yaw, [0.5, 0.5, -2.0], atol=1e-9)
    length = np.array([PROP_TYPES[str(t)].length_m for t in rows.type_id])
    center = rows.front_xy_m - 0.5 * length[:, None] * np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    np.testing.assert_allclose(center, [[10.0, 0.0], [10.0, 0.0], [100.0, 0.0]], atol=1e-9)


def test_simulated_logs_hold_static_furniture_and_standing_people(tmp_path: Path, cache: Path) -> None:
    config = SimulationConfig(logs=2, duration_s=4.0, seed=1, warmup_s=20.0, egos_per_run=2, cache_dir=str(cache),
                              furniture_per_km=20.0, standing_pedestrians_per_km=10.0)
    seen: set[str] = set()
    for log_dir in simulate(config, tmp_path / "logs"):
        log = Log.open(log_dir)
        labels = read_behavior_labels(log_dir)
        assert labels is not None
        stopped = dict(zip(zip(labels.column("timestamp_ns").to_pylist(), labels.column("track_id").to_pylist()),
                           labels.column("stopped").to_pylist()))
        for track in log.tracks().values():
            kind = next((t for t in PROP_TYPES.values() if t.av2_label == track.raw_category
                         and np.allclose(track.size_lwh_m[0], [t.length_m, t.width_m, t.height_m])), None)
            if kind is None:
                continue
            seen.add(kind.id)
            assert track.category == kind.category
            # Static in the city frame, whatever the ego does.
            np.testing.assert_allclose(track.center_city_xyz_m - track.center_city_xyz_m[:1], 0.0, atol=1e-6)
            assert all(stopped[(int(t), track.track_id)] for t in track.timestamps_ns)
    assert "standing_pedestrian" in seen and len(seen) >= 3
