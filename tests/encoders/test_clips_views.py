"""The object's own track through a clip (encoders.clips.views.object_track)."""

from __future__ import annotations

import numpy as np

from encoders.clips.views import object_track, rotate_object_track


def test_track_relative_and_ground_fixed() -> None:
    """The ego drives 1 m a frame along x; an object stands 20 m ahead in the first frame: relative to
    the ego it approaches, on the ground it stays put. An unobserved frame is all zeros."""
    t = 5
    ego = np.zeros((t, 4), np.float32)
    ego[:, 0] = np.arange(t)
    box = np.stack([20.0 - np.arange(t), np.full(t, 3.5), np.full(t, 4.5), np.full(t, 1.9), np.zeros(t)], axis=1)
    box[2] = np.nan
    x = object_track(box, ego)
    assert x.shape == (t, 11) and x.dtype == np.float32
    np.testing.assert_array_equal(x[2], 0.0)
    seen = [0, 1, 3, 4]
    np.testing.assert_allclose(x[seen, 0] * 50, 20.0 - np.arange(t)[seen], atol=1e-5)  # relative x shrinks
    np.testing.assert_allclose(x[seen, 4] * 50, 20.0, atol=1e-5)  # ground-fixed x stays
    np.testing.assert_allclose(x[seen, 5] * 50, 3.5, atol=1e-5)
    np.testing.assert_allclose(x[seen, 8:], [[0.45, 0.19, 1.0]] * 4, atol=1e-6)


def test_track_of_a_turning_ego_and_its_rotation() -> None:
    """The ego turns by 90° in place: an object fixed on the ground 10 m ahead ends up on its right,
    heading turned by −90° relative to the ego; rotating the features equals rotating the inputs."""
    ego = np.array([[0, 0, 0, 0], [0, 0, np.pi / 2, 0]], np.float32)
    box = np.array([[10.0, 0, 4, 2, 0], [0, -10.0, 4, 2, -np.pi / 2]])
    x = object_track(box, ego)
    np.testing.assert_allclose(x[:, 4:8], [[0.2, 0, 1, 0]] * 2, atol=1e-6)  # the same place and heading
    theta = 0.3
    turned = x.copy()
    rotate_object_track(turned, theta)
    c, s = np.cos(theta), np.sin(theta)
    rotated_box = box.copy()
    rotated_box[:, :2] = box[:, :2] @ np.array([[c, s], [-s, c]])
    rotated_box[:, 4] += theta
    expected = object_track(rotated_box, ego)
    np.testing.assert_allclose(turned[:, :4], expected[:, :4], atol=1e-6)


def test_object_velocity_from_the_logs_neighbouring_frames() -> None:
    from encoders.clips.views import object_velocity

    time_s = np.array([0.0, 0.1, 0.2, 0.3, 0.45, 0.6])
    xy = np.stack([10.0 - 4.0 * time_s, 2.0 + 1.0 * time_s], axis=1)  # closing in at 4 m/s, drifting left at 1
    xy[5] = np.nan  # unobserved: its neighbour uses a one-sided difference
    v = object_velocity(xy, time_s, np.array([0, 2, 4, 4, 5]))
    np.testing.assert_allclose(v[:4], [[-4.0, 1.0]] * 4, atol=1e-5)  # ends and uneven steps alike
    np.testing.assert_array_equal(v[4], [0.0, 0.0])  # unobserved itself
    alone = np.full((3, 2), np.nan)
    alone[1] = (5.0, 5.0)
    np.testing.assert_array_equal(object_velocity(alone, time_s[:3], np.array([1])), [[0.0, 0.0]])
