"""Features that place objects relative to the ego: the map's lanes, and the gap to the ego."""

from __future__ import annotations

from types import SimpleNamespace
from typing import cast

import numpy as np

from captioning.map_context import MapLookup, MapRaster
from captioning.tags import LANES, Lane
from scenarios.evaluate import evaluate
from scenarios.features import crossing_distance_m, map_ego_lane
from scenarios.program import Is, Objects
from scenes.map import PedestrianCrossing, VectorMap
from tests.scenarios.synthetic import car, make_features


def _lookup(lane: list[int], heading_rad: list[float]) -> MapLookup:
    k = len(lane)
    lanes = np.asarray(lane)[:, None]  # (K, 1): one frame
    return MapLookup(lane=lanes, lateral_m=np.zeros((k, 1)), lane_heading_rad=np.asarray(heading_rad)[:, None],
                     to_lane_end_m=np.zeros((k, 1)), junction=np.full((k, 1), -1), crosswalk=np.zeros((k, 1), bool))


def test_map_ego_lane_reads_the_lane_segments_and_their_neighbours() -> None:
    # lanes 0 (the ego's), 1 its left neighbour, 2 its right one, 3 the other direction, 4 unrelated
    raster = cast(MapRaster, SimpleNamespace(lane_left=np.asarray([1, -1, 0, -1, -1]),
                                             lane_right=np.asarray([2, 0, -1, -1, -1])))
    xy = np.asarray([[30.0, 0.0], [10.0, 3.5], [-5.0, -3.5], [20.0, 7.0], [20.0, 40.0], [40.0, 0.0], [0.0, 0.0]])
    lane = [0, 1, 2, 3, 3, -1, 0]  # the 5th object is on the other direction's lane but 40 m aside
    heading = [0.0, 0.0, 0.0, np.pi, np.pi, np.nan, 0.0]
    codes = map_ego_lane(raster, _lookup(lane, heading), xy[:, None, :], np.zeros(1))[:, 0]
    names = [LANES[c] if c >= 0 else None for c in codes.tolist()]
    assert names == [Lane.HOST, Lane.LEFT, Lane.RIGHT, Lane.ONCOMING, None, None, None]


def test_map_ego_lane_says_nothing_where_the_ego_is_off_the_lanes() -> None:
    raster = cast(MapRaster, SimpleNamespace(lane_left=np.asarray([-1]), lane_right=np.asarray([-1])))
    xy = np.asarray([[10.0, 0.0], [0.0, 0.0]])[:, None, :]
    assert (map_ego_lane(raster, _lookup([0, -1], [0.0, np.nan]), xy, np.zeros(1)) == -1).all()


def test_approaching_the_ego_needs_the_object_to_move_and_the_gap_to_shrink() -> None:
    frames = 10
    t = np.arange(frames) / 10.0
    towards = np.stack([30.0 - 5.0 * t, np.zeros(frames)], axis=1)
    away = np.stack([30.0 + 5.0 * t, np.zeros(frames)], axis=1)
    across = np.stack([np.full(frames, 30.0), -5.0 + 5.0 * t], axis=1)
    x = make_features([car(towards, yaw=np.pi), car(away, yaw=0.0), car(across, yaw=np.pi / 2),
                       car((30.0, 10.0), speed=0.0)], frames=frames)
    approaching = evaluate(Is(Objects("car"), "approaching_ego"), x).selection.mask.all(axis=1)
    away_mask = evaluate(Is(Objects("car"), "moving_away_from_ego"), x).selection.mask.all(axis=1)
    assert approaching.tolist() == [True, False, False, False, False]
    assert away_mask.tolist() == [False, True, False, False, False]


def test_a_standing_object_the_ego_drives_towards_is_not_approaching() -> None:
    frames = 10
    t = np.arange(frames) / 10.0
    x = make_features([car((30.0, 0.0), speed=0.0)], frames=frames)
    ego_xy = np.stack([10.0 * t, np.zeros(frames)], axis=1).astype(np.float32)
    xy, velocity = x.xy_m.copy(), x.velocity_mps.copy()
    xy[-1], velocity[-1] = ego_xy, np.asarray([10.0, 0.0], np.float32)
    x = type(x)(**{**x.__dict__, "xy_m": xy, "velocity_mps": velocity})
    assert not evaluate(Is(Objects("car"), "approaching_ego"), x).selection.mask.any()


def test_crossing_distance_is_zero_inside_and_measured_to_the_outline_within_the_band() -> None:
    # A crossing 4 m wide (x from 0 to 4) and 10 m long (y from 0 to 10).
    crossing = PedestrianCrossing(1, np.array([[0.0, 0.0, 0.0], [0.0, 10.0, 0.0]]),
                                  np.array([[4.0, 0.0, 0.0], [4.0, 10.0, 0.0]]))
    vector_map = VectorMap(pedestrian_crossings={1: crossing})
    xy = np.array([[2.0, 5.0], [-0.9, 5.0], [-1.1, 5.0], [4.5, 10.5], [5.0, 11.0], [np.inf, np.inf]])
    np.testing.assert_allclose(crossing_distance_m(vector_map, xy, 1.0),
                               [0.0, 0.9, np.inf, np.hypot(0.5, 0.5), np.inf, np.inf])
    assert crossing_distance_m(vector_map, xy, 0.0).tolist() == [0.0, np.inf, np.inf, np.inf, np.inf, np.inf]
