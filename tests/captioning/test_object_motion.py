"""The objects' own motion over ground (captioning.object_motion): what the behaviour rules threshold."""

from __future__ import annotations

import numpy as np

from captioning.config import CaptioningConfig
from captioning.object_motion import track_kinematics
from captioning.pipeline import caption_arrays

from .conftest import DT_S, Scene


def test_track_kinematics_are_the_speed_the_behaviour_rules_tag() -> None:
    """A car brakes at 2 m/s² from 12 m/s while the ego follows at a steady 10 m/s; a walker stands. The
    kinematics on the log grid are the car's own over ground (the ego's motion taken out), and their speed
    is the behaviour table's ``speed_mps`` exactly, so that the encoders read what the tags are made of."""
    t = np.arange(60) * DT_S
    s = Scene(ego_xy_m=np.stack([10.0 * t, np.zeros(60)], 1), ego_yaw_rad=np.zeros(60))
    car_x = 30.0 + 12.0 * t - t**2  # 12 m/s, braking at 2 m/s²
    s.add("car", "car", np.stack([car_x, np.zeros(60)], 1), 0.0)
    s.add("walker", "pedestrian", np.tile([20.0, 5.0], (60, 1)), 0.0)
    arrays = s.arrays()
    config = CaptioningConfig()
    kin = track_kinematics(arrays["timestamps_ns"], arrays["valid"], arrays["center_ego_xy_m"],  # type: ignore[arg-type]
                           arrays["yaw_ego_rad"], arrays["city_SE3_ego"], config)  # type: ignore[arg-type]
    assert kin.shape == (2, 60, 3)
    inner = slice(10, 50)
    np.testing.assert_allclose(kin[0, inner, 0], (12.0 - 2.0 * t)[inner], atol=0.05)
    np.testing.assert_allclose(kin[0, inner, 1], -2.0, atol=0.1)
    np.testing.assert_allclose(kin[0, inner, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(kin[1, inner], 0.0, atol=1e-6)
    tags = caption_arrays(config=config, **arrays)  # type: ignore[arg-type]
    assert tags.behavior is not None
    np.testing.assert_array_equal(kin[..., 0], tags.behavior.speed_mps)
    empty = track_kinematics(arrays["timestamps_ns"], np.zeros((1, 60), bool), np.zeros((1, 60, 2)),  # type: ignore[arg-type]
                             np.zeros((1, 60)), arrays["city_SE3_ego"], config)  # type: ignore[arg-type]
    assert np.isnan(empty).all()
