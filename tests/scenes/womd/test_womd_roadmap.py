"""WOMD map → AV2 map: lane boundaries from boundary features, intersections from crossing centre
lines, crossings from crosswalk polygons, drivable areas bounded by road edges."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from scenes.womd.drivable import drivable_polygons
from scenes.womd.roadmap import (
    DEFAULT_HALF_WIDTH_M,
    MAX_HALF_WIDTH_M,
    Boundary,
    WomdLane,
    WomdMap,
    crossing_edges,
    crossing_lanes,
    lane_half_widths,
    vector_map_from_womd,
)


def _line(x0: float, y0: float, x1: float, y1: float, n: int = 21) -> np.ndarray:
    return np.stack([np.linspace(x0, x1, n), np.linspace(y0, y1, n), np.zeros(n)], axis=1)


def test_half_widths_follow_lines_fill_gaps_and_stop_at_kerbs() -> None:
    lane = WomdLane(
        1, _line(0, 0, 20, 0),
        left_boundaries=(Boundary(0, 5, 10, 1), Boundary(15, 20, 11, 1)),  # a gap over points 6..14
        right_boundaries=(Boundary(0, 20, 12, 0),),
    )
    womd = WomdMap(
        lanes={1: lane},
        road_lines={10: (1, _line(-5, 1.5, 6, 1.5)), 11: (1, _line(14, 2.0, 25, 2.0))},
        road_edges={12: _line(-5, -1.2, 25, -1.2)},
    )
    left, right = lane_half_widths(lane, womd)
    np.testing.assert_allclose(left[:6], 1.5)
    np.testing.assert_allclose(left[15:], 2.0)
    np.testing.assert_allclose(left[6:15], np.interp(np.arange(6, 15), [5, 15], [1.5, 2.0]))  # filled between
    # The right side has only a kerb 1.2 m away: the other side's half-width, capped by the kerb.
    np.testing.assert_allclose(right, 1.2)


def test_half_widths_without_features_and_clamped() -> None:
    bare = WomdLane(1, _line(0, 0, 20, 0))
    left, right = lane_half_widths(bare, WomdMap(lanes={1: bare}))
    np.testing.assert_allclose(left, DEFAULT_HALF_WIDTH_M)
    np.testing.assert_allclose(right, DEFAULT_HALF_WIDTH_M)
    wide = WomdLane(1, _line(0, 0, 20, 0), right_boundaries=(Boundary(0, 20, 5, 2),))
    left, right = lane_half_widths(wide, WomdMap(lanes={1: wide}, road_lines={5: (2, _line(0, -9, 20, -9))}))
    np.testing.assert_allclose(right, MAX_HALF_WIDTH_M)
    np.testing.assert_allclose(left, MAX_HALF_WIDTH_M)  # a side without features takes the other side's


def test_crossing_centre_lines_are_intersections() -> None:
    lanes = {
        1: WomdLane(1, _line(-20, 0, 20, 0)),  # east
        2: WomdLane(2, _line(0, -20, 0, 20)),  # north: crosses 1
        3: WomdLane(3, _line(20, 3.5, -20, 3.5)),  # west, beside 1: opposing traffic is no crossing
        4: WomdLane(4, _line(20, 0, 40, 0)),  # 1's successor
        5: WomdLane(5, _line(20, 0, 35, 3)),  # splits off 4 at a shallow angle
    }
    assert crossing_lanes(lanes) == {1, 2, 3}


def test_crosswalk_edges() -> None:
    square = np.array([[0, 0, 0], [0, 10, 0], [3, 10, 0], [3, 0, 0], [0, 0, 0]], dtype=float)  # closed
    edge1, edge2 = crossing_edges(square)  # type: ignore[misc]
    np.testing.assert_allclose(edge1, [[0, 0, 0], [0, 10, 0]])
    np.testing.assert_allclose(edge2, [[3, 0, 0], [3, 10, 0]])
    wide = np.array([[0, 0, 0], [10, 0, 0], [10, 3, 0], [0, 3, 0]], dtype=float)
    edge1, edge2 = crossing_edges(wide)  # type: ignore[misc]
    np.testing.assert_allclose(edge1, [[0, 0, 0], [10, 0, 0]])
    np.testing.assert_allclose(edge2, [[0, 3, 0], [10, 3, 0]])
    # Six corners: the long sides of the rectangle along the principal axis.
    hexagon = np.array([[0, 0, 1], [5, -1, 1], [10, 0, 1], [10, 3, 1], [5, 4, 1], [0, 3, 1]], dtype=float)
    edge1, edge2 = crossing_edges(hexagon)  # type: ignore[misc]
    assert np.linalg.norm(edge1[1] - edge1[0]) == pytest.approx(10.0)
    assert abs(edge1[0, 1] - edge2[0, 1]) == pytest.approx(5.0)
    assert crossing_edges(np.zeros((2, 3))) is None


def _filled(polygons: list[np.ndarray], point: tuple[float, float]) -> bool:
    """Whether ``point`` lies inside a polygon filled as the BEV rasteriser fills it (even-odd)."""
    for poly in polygons:
        canvas = np.zeros((400, 400), np.uint8)
        px = np.round((poly - [-50, -50]) * 4).astype(np.int32)
        cv2.fillPoly(canvas, [px], 1)
        x, y = round((point[0] + 50) * 4), round((point[1] + 50) * 4)
        if canvas[y, x]:
            return True
    return False


def test_drivable_surface_stops_at_road_edges_and_keeps_islands_out() -> None:
    # A ring road around an island: four lanes forming a square loop, kerbs inside (the island) and
    # one kerb outside along the south side only.
    half = 1.8
    lanes = [np.array([[x0, y0 - half], [x1, y0 - half], [x1, y0 + half], [x0, y0 + half]])
             for x0, x1, y0 in ((-20, 20, -20), (-20, 20, 20))]
    lanes += [np.array([[x0 - half, -20], [x0 + half, -20], [x0 + half, 20], [x0 - half, 20]]) for x0 in (-20, 20)]
    island = np.array([[-15, -15], [15, -15], [15, 15], [-15, 15], [-15, -15]], dtype=float)
    south_kerb = np.array([[-40, -23], [40, -23]], dtype=float)
    polygons = drivable_polygons(lanes, [island, south_kerb], reach_m=5.0, resolution_m=0.25)
    assert len(polygons) == 1
    assert _filled(polygons, (0, -20)) and _filled(polygons, (0, 20))  # lanes
    assert _filled(polygons, (0, -16)) and _filled(polygons, (0, 16))  # up to the island's kerb
    assert not _filled(polygons, (0, 0)) and not _filled(polygons, (0, -14))  # the island stays out
    assert _filled(polygons, (0, -22.5)) and not _filled(polygons, (0, -24))  # the south kerb stops growth
    assert _filled(polygons, (0, 25)) and not _filled(polygons, (0, 28))  # the north side grows 5 m


def test_vector_map_ids_and_driveways() -> None:
    lane = WomdLane(1, _line(0, 0, 30, 0), exit_lanes=(2, 99), entry_lanes=(98,))
    nxt = WomdLane(2, _line(30, 0, 60, 0), entry_lanes=(1,))
    driveway = np.array([[10, 5, 0], [14, 5, 0], [14, 12, 0], [10, 12, 0]], dtype=float)
    vector_map = vector_map_from_womd(WomdMap(lanes={1: lane, 2: nxt}, driveways={7: driveway}))
    assert vector_map.lane_segments[1].successors == (2,)  # lanes outside the map are dropped
    assert vector_map.lane_segments[1].predecessors == ()
    assert vector_map.lane_segments[2].predecessors == (1,)
    np.testing.assert_allclose(vector_map.drivable_areas[7].area_boundary, driveway)
    grown = [a for i, a in vector_map.drivable_areas.items() if i != 7]
    assert len(grown) == 1 and min(vector_map.drivable_areas) == 7 and max(vector_map.drivable_areas) == 8
    assert grown[0].area_boundary[:, 0].min() == pytest.approx(-5.0, abs=0.6)
