"""The objects' own motion over ground (captioning.object_motion): what the behaviour rules threshold."""

from __future__ import annotations

import numpy as np

from captioning.config import CaptioningConfig
from captioning.neighbors import motion_codes, track_motion
from captioning.object_motion import TRACK_KINEMATICS_COLUMNS, scatter_to_log_grid, track_kinematics
from captioning.pipeline import caption_arrays

from .conftest import DT_S, Scene


def test_track_kinematics_are_the_speed_the_behaviour_rules_tag() -> None:
    """A car brakes at 2 m/s² from 12 m/s while the ego follows at a steady 10 m/s; a walker stands. The
    kinematics on the log grid are the car's own over ground (the ego's motion taken out), and their speed
    is the behaviour table's ``speed_mps`` exactly, so that the encoders read what the tags are made of; their
    velocity relative to the ego is what the neighbour motion rules threshold."""
    t = np.arange(60) * DT_S
    s = Scene(ego_xy_m=np.stack([10.0 * t, np.zeros(60)], 1), ego_yaw_rad=np.zeros(60))
    car_x = 30.0 + 12.0 * t - t**2  # 12 m/s, braking at 2 m/s²
    s.add("car", "car", np.stack([car_x, np.zeros(60)], 1), 0.0)
    s.add("walker", "pedestrian", np.tile([20.0, 5.0], (60, 1)), 0.0)
    arrays = s.arrays()
    config = CaptioningConfig()
    kin = track_kinematics(arrays["timestamps_ns"], arrays["valid"], arrays["center_ego_xy_m"],  # type: ignore[arg-type]
                           arrays["yaw_ego_rad"], arrays["city_SE3_ego"], config)  # type: ignore[arg-type]
    assert kin.shape == (2, 60, len(TRACK_KINEMATICS_COLUMNS))
    inner = slice(10, 50)
    np.testing.assert_allclose(kin[0, inner, 0], (12.0 - 2.0 * t)[inner], atol=0.05)
    np.testing.assert_allclose(kin[0, inner, 1], -2.0, atol=0.1)
    np.testing.assert_allclose(kin[0, inner, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(kin[1, inner, :3], 0.0, atol=1e-6)
    # Relative to the ego: the car pulls away at 2 m/s, then closes in as it brakes below the ego's 10 m/s;
    # the walker comes back at the ego's speed. What the neighbour rules threshold for approach / away.
    np.testing.assert_allclose(kin[0, inner, 3], (2.0 - 2.0 * t)[inner], atol=0.05)
    np.testing.assert_allclose(kin[1, inner, 3], -10.0, atol=1e-6)
    np.testing.assert_allclose(kin[:, inner, 4], 0.0, atol=1e-6)
    tags = caption_arrays(config=config, **arrays)  # type: ignore[arg-type]
    assert tags.behavior is not None
    np.testing.assert_array_equal(kin[..., 0], tags.behavior.speed_mps)
    empty = track_kinematics(arrays["timestamps_ns"], np.zeros((1, 60), bool), np.zeros((1, 60, 2)),  # type: ignore[arg-type]
                             np.zeros((1, 60)), arrays["city_SE3_ego"], config)  # type: ignore[arg-type]
    assert np.isnan(empty).all()


def test_relative_velocity_is_what_the_motion_rules_threshold() -> None:
    """A car overtakes the ego on its left and pulls away; a slower car ahead is closed in on: the approach / away
    codes that :func:`captioning.neighbors.motion_codes` makes from the kinematics' relative velocity are the
    neighbour tags' own motion codes (before flicker suppression) wherever the tags are defined."""
    t = np.arange(80) * DT_S
    s = Scene(ego_xy_m=np.stack([8.0 * t, np.zeros(80)], 1), ego_yaw_rad=np.zeros(80))
    s.add("overtaker", "car", np.stack([-10.0 + 12.0 * t, np.full(80, 3.5)], 1), 0.0)
    s.add("slower", "car", np.stack([40.0 + 4.0 * t, np.zeros(80)], 1), 0.0)
    arrays = s.arrays()
    config = CaptioningConfig()
    kin = track_kinematics(arrays["timestamps_ns"], arrays["valid"], arrays["center_ego_xy_m"],  # type: ignore[arg-type]
                           arrays["yaw_ego_rad"], arrays["city_SE3_ego"], config)  # type: ignore[arg-type]
    motion = track_motion(arrays["timestamps_ns"], arrays["valid"], arrays["center_ego_xy_m"],  # type: ignore[arg-type]
                          arrays["yaw_ego_rad"], arrays["city_SE3_ego"], config)  # type: ignore[arg-type]
    lanes = np.zeros(kin.shape[:2], np.int64)  # the ongoing lanes: distance along the ego's heading
    moving = np.ones(kin.shape[:2], bool)
    ours = motion_codes(lanes, arrays["center_ego_xy_m"], np.nan_to_num(kin[..., 3:]), moving, config)  # type: ignore[arg-type]
    rules = motion_codes(lanes[:, : motion.grid.frame.shape[1]], motion.positions[..., 2:],
                         np.nan_to_num(motion.derivative[..., 2:]), moving[:, : motion.grid.frame.shape[1]], config)
    np.testing.assert_array_equal(ours, scatter_to_log_grid(motion.grid, rules, kin.shape[:2], -1))
    approach = ours[1, 40]
    assert (ours[1, 10:70] == approach).all()  # the slower car, all along
    assert (ours[0, 10:20] == approach).all()  # the overtaker from behind, until it draws level at 2.5 s
    assert (ours[0, 30:70] == ours[0, 69]).all() and ours[0, 69] != approach  # then pulls away
