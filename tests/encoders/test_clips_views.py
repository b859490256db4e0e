"""A clip's track and ego-motion features (encoders.clips.views: object_track, object_velocity, ego_motion)."""

from __future__ import annotations

import numpy as np

from captioning.config import CaptioningConfig
from captioning.host import classify_host, host_kinematics
from captioning.tags import HOST_DIRECTIONS, HOST_MOTIONS, HostDirection, HostMotion
from encoders.clips.views import EGO_MOTION_FEATURES, ego_motion, ego_rates, object_track, rotate_object_track
from scenes.geometry import SE3


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


def _arc(t_s: np.ndarray, speed_mps: np.ndarray, yaw_rate_rps: float) -> np.ndarray:
    """(F, 3) x, y, yaw of a path at the given speeds turning at a constant rate."""
    dt = np.diff(t_s, prepend=t_s[0])
    yaw = yaw_rate_rps * t_s
    x = np.cumsum(speed_mps * np.cos(yaw) * dt)
    y = np.cumsum(speed_mps * np.sin(yaw) * dt)
    return np.stack([x, y, yaw], axis=1)


def test_ego_rates_are_the_host_rules_kinematics() -> None:
    """Braking at 2 m/s² through a left bend at 0.2 rad/s, with 5 cm of odometry noise: the smoothed rates are
    the true ones, where differencing the raw speed between a clip's frames gives nothing usable; and they are
    exactly what the captioning rules threshold (captioning.host), so a model reads what the tags are made of."""
    t_s = np.arange(80) * 0.1
    pose = _arc(t_s, 20.0 - 2.0 * t_s, 0.2)
    pose[:, :2] += np.random.default_rng(0).normal(0.0, 0.05, size=(len(t_s), 2))
    accel, yaw_rate = ego_rates(t_s, pose)
    inner = slice(10, -10)
    np.testing.assert_allclose(accel[inner], -2.0, atol=0.6)
    np.testing.assert_allclose(yaw_rate[inner], 0.2, atol=0.01)
    raw_speed = np.linalg.norm(np.gradient(pose[:, :2], t_s, axis=0), axis=1)
    assert np.abs(np.gradient(raw_speed, t_s)[inner] + 2.0).max() > 3.0  # the raw derivative: noise
    city_SE3_ego = np.stack([SE3.from_yaw(yaw, np.array([x, y, 0.0])).matrix for x, y, yaw in pose])
    kin = host_kinematics((t_s * 1e9).astype(np.int64), city_SE3_ego, CaptioningConfig())
    np.testing.assert_allclose(accel, kin.accel_mps2, atol=1e-9)
    np.testing.assert_allclose(yaw_rate, kin.yaw_rate_rps, atol=1e-9)
    motion, direction = classify_host(kin, CaptioningConfig())
    assert set(motion[inner]) == {HOST_MOTIONS.index(HostMotion.DECELERATING)}
    assert set(direction[inner]) == {HOST_DIRECTIONS.index(HostDirection.STEERING_LEFT)}


def test_ego_motion_samples_the_rates_at_the_clip_frames() -> None:
    t_s = np.arange(40) * 0.1
    pose = _arc(t_s, np.full(40, 10.0), -0.1)
    accel, yaw_rate = ego_rates(t_s, pose)
    indices = np.arange(0, 40, 4)
    m = ego_motion(pose, np.full(40, 10.0), indices, accel, yaw_rate)
    assert m.shape == (10, EGO_MOTION_FEATURES) and m.dtype == np.float32
    np.testing.assert_allclose(m[:, 4:], np.stack([accel, yaw_rate], axis=1)[indices], atol=1e-6)
    np.testing.assert_allclose(m[:, 5], -0.1, atol=1e-4)
    # A log of one frame has nothing to differentiate: zeros, not NaN.
    assert [r.tolist() for r in ego_rates(np.zeros(1), pose[:1])] == [[0.0], [0.0]]


def test_object_rates_and_velocity_are_what_the_rules_threshold() -> None:
    """The ego cruises at 10 m/s while a car ahead brakes at 1.5 m/s² through a left bend at 0.2 rad/s: in the
    ego's frame the car's box hardly moves, yet its own speed, acceleration and yaw rate over ground come out
    (what the rules threshold for braking and turning), with the ego's own motion taken out, and its velocity
    relative to the ego is the derivative of its box in the ego frame (what they threshold for approach and
    away); unobserved frames and runs too short for the rules give zeros."""
    from captioning.object_motion import track_kinematics
    from encoders.clips.views import OBJECT_RATES_COLUMNS, OBJECT_VELOCITY_COLUMNS, object_rates_and_velocity

    t_s = np.arange(80) * 0.1
    ego = _arc(t_s, np.full(80, 10.0), 0.0)
    car = _arc(t_s, 15.0 - 1.5 * t_s, 0.2)
    car[:, 0] += 20.0
    dx, dy = car[:, 0] - ego[:, 0], car[:, 1] - ego[:, 1]
    c, s = np.cos(ego[:, 2]), np.sin(ego[:, 2])
    boxes = np.stack([c * dx + s * dy, -s * dx + c * dy, np.full(80, 4.5), np.full(80, 1.9), car[:, 2] - ego[:, 2]], 1)
    boxes[40:43] = np.nan  # three unobserved frames, bridged by the rules
    boxes[70:] = np.nan
    boxes[79] = boxes[0]  # a lone observation after a long gap: no run long enough
    both = object_rates_and_velocity(boxes.astype(np.float32), ego, t_s)
    assert both.shape == (80, len(OBJECT_RATES_COLUMNS) + len(OBJECT_VELOCITY_COLUMNS)) and both.dtype == np.float32
    rates, velocity = both[:, :3], both[:, 3:]
    inner = np.r_[10:35, 48:62]  # the bridged gap blurs the heading rate next to it
    np.testing.assert_allclose(rates[inner, 0], (15.0 - 1.5 * t_s)[inner], atol=0.25)
    np.testing.assert_allclose(rates[inner, 1], -1.5, atol=0.2)
    np.testing.assert_allclose(rates[inner, 2], 0.2, atol=0.01)
    step = np.gradient(boxes[:, :2], t_s, axis=0)  # (F, 2) the box's own change in the ego frame
    np.testing.assert_allclose(velocity[inner], step[inner], atol=0.05)
    assert (both[70:] == 0).all()
    # The one home of these kinematics: the rules' own function on the same track.
    city_SE3_ego = np.stack([SE3.from_yaw(yaw, np.array([x, y, 0.0])).matrix for x, y, yaw in ego])
    valid = np.isfinite(boxes[:, 0])
    kin = track_kinematics((t_s * 1e9).round().astype(np.int64), valid[None], np.nan_to_num(boxes[None, :, :2]),
                           np.nan_to_num(boxes[None, :, 4]), city_SE3_ego, CaptioningConfig())[0]
    np.testing.assert_allclose(both, np.nan_to_num(kin), atol=1e-4)
    assert object_rates_and_velocity(np.full((5, 5), np.nan), ego[:5], t_s[:5]).tolist() == [[0.0] * 5] * 5


def test_a_logs_tracks_together_get_each_tracks_own_kinematics() -> None:
    """Every track of a log in one pass gives, bit for bit, what each track gives alone; a track never
    observed, and a log of one frame, give zeros."""
    from encoders.clips.views import log_rates_and_velocity, object_rates_and_velocity

    rng = np.random.default_rng(4)
    t_s = np.arange(60) * 0.1
    ego = _arc(t_s, np.full(60, 8.0), 0.05)
    tracks = np.full((60, 4, 5), np.nan, np.float32)  # (F, K, 5)
    for k, (start, stop) in enumerate([(0, 60), (5, 40), (30, 58)]):
        n = stop - start
        tracks[start:stop, k] = np.c_[np.cumsum(rng.normal(0.3, 0.05, n)) + 5 * k, rng.normal(2.0 * k, 0.05, n),
                                      np.full(n, 4.5), np.full(n, 1.9), rng.normal(0.0, 0.02, n)]
    together = log_rates_and_velocity(tracks, ego, t_s)
    assert together.shape == (4, 60, 5) and together.dtype == np.float32
    for k in range(4):
        np.testing.assert_array_equal(together[k], object_rates_and_velocity(tracks[:, k], ego, t_s))
    assert not together[3].any() and together[0].any()
    assert log_rates_and_velocity(tracks[:1], ego[:1], t_s[:1]).shape == (4, 1, 5)
