"""One test per branch of the paper's equations, on hand-built tracks with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from captioning.config import CaptioningConfig, NeighborConfig
from captioning.tags import BASELINE_LANES, HOST_DIRECTIONS, HOST_MOTIONS, LANES, MOTIONS, NO_TAG, paper_lateral_m

MID = slice(12, -12)  # frames away from the track ends


def host_values(result, codes_name):  # type: ignore[no-untyped-def]
    vocab = HOST_MOTIONS if codes_name == "host_motion" else HOST_DIRECTIONS
    return {vocab[c].value for c in getattr(result, codes_name)[MID]}


# ---- eq. 1: host motion ----------------------------------------------------------------------


def test_host_stationary(make_scene) -> None:  # type: ignore[no-untyped-def]
    result = make_scene(0.0).caption()
    assert host_values(result, "host_motion") == {"stationary"}
    assert host_values(result, "host_direction") == {"heading_straight"}


def test_host_cruising(make_scene) -> None:  # type: ignore[no-untyped-def]
    assert host_values(make_scene(10.0).caption(), "host_motion") == {"cruising"}


def test_host_accelerating(make_scene) -> None:  # type: ignore[no-untyped-def]
    speed = 3.0 + 2.0 * np.arange(60) * 0.1  # +2 m/s²
    assert host_values(make_scene(speed).caption(), "host_motion") == {"accelerating"}


def test_host_decelerating(make_scene) -> None:  # type: ignore[no-untyped-def]
    speed = 15.0 - 2.0 * np.arange(60) * 0.1
    assert host_values(make_scene(speed).caption(), "host_motion") == {"decelerating"}


def test_host_below_stationary_speed_beats_acceleration(make_scene) -> None:  # type: ignore[no-untyped-def]
    speed = 0.1 + 0.005 * np.arange(60)  # slow creep, accelerating but < T_v
    assert host_values(make_scene(speed).caption(), "host_motion") == {"stationary"}


# ---- eq. 2: host direction -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("yaw_rate_rps", "expected"),
    [(0.3, "steering_left"), (-0.3, "steering_right"), (0.05, "heading_straight"), (-0.05, "heading_straight")],
)
def test_host_direction(make_scene, yaw_rate_rps: float, expected: str) -> None:  # type: ignore[no-untyped-def]
    assert host_values(make_scene(8.0, yaw_rate_rps).caption(), "host_direction") == {expected}


# ---- eq. 3: stationary neighbours ------------------------------------------------------------


def test_parked_car_is_stationary_while_ego_drives(make_scene) -> None:  # type: ignore[no-untyped-def]
    scene = make_scene(10.0).add("parked", "car", np.tile([40.0, -3.0], (60, 1)), 0.0)
    result = scene.caption()
    assert result.neighbors.stationary.tolist() == [True]
    assert (result.neighbors.lane == NO_TAG).all()
    assert [c.track_id for c in result.captions if c.track_id != "ego"] == []


def test_moving_car_is_not_stationary(make_scene) -> None:  # type: ignore[no-untyped-def]
    xy = np.c_[20.0 + 8.0 * np.arange(60) * 0.1, np.zeros(60)]
    result = make_scene(0.0).add("mover", "car", xy, 0.0).caption()
    assert result.neighbors.stationary.tolist() == [False]


def test_stationarity_ignores_a_few_glitches(make_scene) -> None:  # type: ignore[no-untyped-def]
    xy = np.tile([15.0, 4.0], (60, 1))
    xy[30] += (2.0, 0.0)  # one-frame box jump, as trackers produce
    result = make_scene(0.0).add("glitch", "car", xy, 0.0).caption()
    assert result.neighbors.stationary.tolist() == [True]


def test_car_that_waits_then_drives_off_is_not_stationary(make_scene) -> None:  # type: ignore[no-untyped-def]
    x = np.r_[np.full(40, 15.0), 15.0 + 6.0 * np.arange(1, 21) * 0.1]
    result = make_scene(0.0).add("waiter", "car", np.c_[x, np.zeros(60)], 0.0).caption()
    assert result.neighbors.stationary.tolist() == [False]
    motions = [MOTIONS[c].value for c in result.neighbors.motion[0]]
    assert motions[5] == "stationary" and motions[-5] == "away"


# ---- eq. 4: baseline lane, eq. 5: lane ---------------------------------------------------------


def lane_of(make_scene, y_m: float, rel_yaw_deg: float) -> tuple[str, str]:  # type: ignore[no-untyped-def]
    """Lane of an object at lateral offset y, moving at 5 m/s along x, relative to a stationary ego."""
    yaw = np.radians(rel_yaw_deg)
    t = np.arange(60) * 0.1
    # Moves along x whatever its heading, so that only the heading decides the baseline lane.
    xy = np.c_[15.0 + 5.0 * t, np.full(60, y_m)]
    result = make_scene(0.0).add("obj", "car", xy, yaw).caption()
    assert result.neighbors.tagged[0, 30]
    return BASELINE_LANES[result.neighbors.baseline_lane[0, 30]].value, LANES[result.neighbors.lane[0, 30]].value


@pytest.mark.parametrize(
    ("rel_yaw_deg", "baseline"),
    [(0.0, "ongoing"), (30.0, "ongoing"), (140.0, "ongoing"), (-140.0, "ongoing"), (90.0, "lateral"),
     (-100.0, "lateral"), (170.0, "oncoming"), (-170.0, "oncoming"), (180.0, "oncoming")],
)
def test_baseline_lane(make_scene, rel_yaw_deg: float, baseline: str) -> None:  # type: ignore[no-untyped-def]
    assert lane_of(make_scene, 0.0, rel_yaw_deg)[0] == baseline


@pytest.mark.parametrize(
    ("y_m", "rel_yaw_deg", "lane"),
    [(3.0, 0.0, "left"), (-3.0, 0.0, "right"), (0.5, 0.0, "host"), (-1.0, 0.0, "host"),
     (3.0, 90.0, "left_lateral"), (-3.0, 90.0, "right_lateral"), (0.0, 90.0, "host_lateral"),
     (3.0, 175.0, "oncoming"), (-3.0, 175.0, "oncoming")],
)
def test_lane(make_scene, y_m: float, rel_yaw_deg: float, lane: str) -> None:  # type: ignore[no-untyped-def]
    assert lane_of(make_scene, y_m, rel_yaw_deg)[1] == lane


def test_paper_sign_convention() -> None:
    # Ego frame: y left. Paper: y right. A neighbour 3 m to the left has paper offset -3 m.
    assert paper_lateral_m(np.array([3.0, -2.0])).tolist() == [-3.0, 2.0]


def test_lane_thresholds_come_from_config(make_scene) -> None:  # type: ignore[no-untyped-def]
    wide = CaptioningConfig(neighbor=NeighborConfig(host_lane_half_width_m=4.0))
    xy = np.c_[15.0 + 5.0 * np.arange(60) * 0.1, np.full(60, 3.0)]
    result = make_scene(0.0).add("obj", "car", xy, 0.0).caption(wide)
    assert LANES[result.neighbors.lane[0, 30]].value == "host"


# ---- eqs. 6, 7: motion -----------------------------------------------------------------------


def motions_of(make_scene, ego_speed: float, start_xy: tuple[float, float], vel_xy: tuple[float, float],  # type: ignore[no-untyped-def]
               yaw_deg: float = 0.0) -> set[str]:
    t = np.arange(60) * 0.1
    xy = np.c_[start_xy[0] + vel_xy[0] * t, start_xy[1] + vel_xy[1] * t]
    result = make_scene(ego_speed).add("obj", "car", xy, np.radians(yaw_deg)).caption()
    return {MOTIONS[c].value for c in result.neighbors.motion[0, MID]}


def test_motion_approach_ahead(make_scene) -> None:  # type: ignore[no-untyped-def]
    assert motions_of(make_scene, 10.0, (30.0, 0.0), (5.0, 0.0)) == {"approach"}


def test_motion_away_ahead(make_scene) -> None:  # type: ignore[no-untyped-def]
    assert motions_of(make_scene, 10.0, (10.0, 0.0), (15.0, 0.0)) == {"away"}


def test_motion_constant_ahead(make_scene) -> None:  # type: ignore[no-untyped-def]
    assert motions_of(make_scene, 10.0, (20.0, 3.5), (10.3, 0.0)) == {"constant"}


def test_motion_approach_from_behind(make_scene) -> None:  # type: ignore[no-untyped-def]
    # A faster follower closes in: the paper's signed rule (objects ahead) would say "away".
    assert motions_of(make_scene, 10.0, (-40.0, 0.0), (15.0, 0.0)) == {"approach"}


def test_motion_away_behind(make_scene) -> None:  # type: ignore[no-untyped-def]
    assert motions_of(make_scene, 10.0, (-10.0, 0.0), (5.0, 0.0)) == {"away"}


def test_motion_lateral_lane_uses_lateral_axis(make_scene) -> None:  # type: ignore[no-untyped-def]
    # Crossing toward the ego from the left, at a constant longitudinal distance: only y shrinks.
    assert motions_of(make_scene, 0.0, (15.0, 12.0), (0.0, -2.0), yaw_deg=-90.0) == {"approach"}
    assert motions_of(make_scene, 0.0, (15.0, -4.0), (0.0, -2.0), yaw_deg=-90.0) == {"away"}


def test_motion_host_lateral_uses_longitudinal_axis(make_scene) -> None:  # type: ignore[no-untyped-def]
    # Crossing right in front (inside the host band) while the ego drives at it: the longitudinal
    # distance shrinks although the pedestrian moves only sideways.
    t = np.arange(60) * 0.1
    xy = np.c_[np.full(60, 60.0), -1.7 + 0.6 * t]
    result = make_scene(10.0).add("x", "pedestrian", xy, np.pi / 2).caption()
    assert result.neighbors.tagged[0, MID].all()
    assert {LANES[c].value for c in result.neighbors.lane[0, MID]} == {"host_lateral"}
    assert {MOTIONS[c].value for c in result.neighbors.motion[0, MID]} == {"approach"}


def test_motion_stationary_frame_of_moving_track(make_scene) -> None:  # type: ignore[no-untyped-def]
    # Drives for 30 frames, then stops: a non-stationary track whose last frames are stationary.
    x = np.r_[10.0 + 6.0 * np.arange(30) * 0.1, np.full(30, 10.0 + 6.0 * 2.9)]
    result = make_scene(0.0).add("stopper", "car", np.c_[x, np.zeros(60)], 0.0).caption()
    motions = [MOTIONS[c].value for c in result.neighbors.motion[0]]
    assert motions[10] == "away" and motions[50] == "stationary"
