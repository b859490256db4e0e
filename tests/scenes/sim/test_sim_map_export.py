from pathlib import Path

import numpy as np
import pytest

from scenes.behavior import JunctionKind
from scenes.map import VectorMap
from scenes.sim.config import NetworkKind
from scenes.sim.map_export import export_map, junction_table, offset_polyline
from scenes.sim.netparse import SumoNet, read_net
from scenes.sim.network import build_network


@pytest.fixture(scope="module")
def grid_net(tmp_path_factory: pytest.TempPathFactory) -> SumoNet:
    return read_net(build_network(NetworkKind.GRID, 0, tmp_path_factory.mktemp("netcache")))


def test_offset_polyline_goes_left_for_positive_offsets() -> None:
    line = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    left = offset_polyline(line, 1.0)
    np.testing.assert_allclose(left[0], [0.0, 1.0, 0.0])
    np.testing.assert_allclose(left[-1], [9.0, 10.0, 0.0])
    np.testing.assert_allclose(left[1], [9.0, 1.0, 0.0])  # mitred corner stays 1 m from both legs


def test_network_is_cached(tmp_path: Path) -> None:
    first = build_network(NetworkKind.GRID, 0, tmp_path)
    mtime = first.stat().st_mtime_ns
    assert build_network(NetworkKind.GRID, 5, tmp_path) == first  # grid ignores the seed
    assert first.stat().st_mtime_ns == mtime
    assert list(tmp_path.iterdir()) == [first]  # no temporary leftovers


def test_grid_has_what_the_city_needs(grid_net: SumoNet) -> None:
    types = {j.type for j in grid_net.junctions.values()}
    assert {"traffic_light", "priority"} <= types
    kinds = set(junction_table(grid_net).column("kind").to_pylist())
    assert {JunctionKind.THREE_WAY.value, JunctionKind.FOUR_WAY.value} <= kinds
    lanes_per_edge: dict[str, int] = {}
    for lane in grid_net.lanes.values():
        if lane.edge_function == "" and "passenger" in lane.allowed:
            lanes_per_edge[lane.edge_id] = lanes_per_edge.get(lane.edge_id, 0) + 1
    assert min(lanes_per_edge.values()) >= 2
    assert any(lane.allowed == {"pedestrian"} for lane in grid_net.lanes.values())  # sidewalks


def test_exported_map_is_consistent(grid_net: SumoNet) -> None:
    vector_map = export_map(grid_net)
    lanes = vector_map.lane_segments
    assert any(s.is_intersection for s in lanes.values())
    assert any(not s.is_intersection for s in lanes.values())
    assert len(vector_map.pedestrian_crossings) > 0
    assert len(vector_map.drivable_areas) > 0
    for s in lanes.values():
        for succ in s.successors:
            assert s.id in lanes[succ].predecessors
        if s.left_neighbor_id is not None:
            assert lanes[s.left_neighbor_id].right_neighbor_id == s.id
        # The left boundary lies to the left of the right one, seen along the lane.
        d = s.right_lane_boundary[-1, :2] - s.right_lane_boundary[0, :2]
        v = s.left_lane_boundary[0, :2] - s.right_lane_boundary[0, :2]
        assert d[0] * v[1] - d[1] * v[0] > 0
    # Road lanes lead into junction lanes and back out.
    road = next(s for s in lanes.values() if not s.is_intersection and s.successors)
    assert all(lanes[n].is_intersection for n in road.successors)
    # Round trip through the AV2 JSON schema.
    assert VectorMap.from_json_dict(vector_map.to_json_dict()).lane_segments.keys() == lanes.keys()


def test_crossings_are_rectangles_of_the_crossing_width(grid_net: SumoNet) -> None:
    crossing = next(iter(export_map(grid_net).pedestrian_crossings.values()))
    gap = np.linalg.norm(crossing.edge1[0] - crossing.edge2[0])
    assert 2.0 <= gap <= 6.0


def test_netgenerate_failure_carries_its_message(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from scenes.sim import SimulationError

    monkeypatch.setattr("scenes.sim.network.layout_args", lambda kind, seed: ["--grid", "--no-such-option", "1"])
    with pytest.raises(SimulationError, match="no-such-option"):
        build_network(NetworkKind.GRID, 0, tmp_path)
    assert not any(p.suffix == ".xml" for p in tmp_path.rglob("*"))
