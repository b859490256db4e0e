"""Host (ego) tags: motion (eq. 1) and direction (eq. 2) per frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from captioning.config import CaptioningConfig, SmoothingConfig
from captioning.frames import FrameCounts, frame_interval_s, savgol_frames
from captioning.smoothing import IntArray, seconds_since_first, suppress_flicker, time_derivative
from captioning.tags import HOST_DIRECTIONS, HOST_MOTIONS, NO_TAG, HostDirection, HostMotion
from scenes.geometry import FloatArray


@dataclass(frozen=True)
class HostKinematics:
    """Smoothed host kinematics on the frame grid.

    Attributes:
        speed_mps: (T,) planar speed; NaN when the log has a single frame.
        accel_mps2: (T,) rate of change of the speed.
        yaw_rate_rps: (T,) heading rate, positive = turning left.
        interval_s: the frame interval the durations were converted at (:func:`~captioning.frames.frame_interval_s`).
    """

    speed_mps: FloatArray
    accel_mps2: FloatArray
    yaw_rate_rps: FloatArray
    interval_s: float


def host_kinematics(
    timestamps_ns: IntArray, city_SE3_ego: FloatArray, config: CaptioningConfig
) -> HostKinematics:
    """Speed, acceleration and yaw rate from poses (Savitzky–Golay, see :mod:`captioning.smoothing`).

    Args:
        timestamps_ns: (T,) frame timestamps.
        city_SE3_ego: (T, 4, 4) ego poses at the frames.
    """
    yaw_rad = np.arctan2(city_SE3_ego[:, 1, 0], city_SE3_ego[:, 0, 0])
    return planar_kinematics(seconds_since_first(timestamps_ns), city_SE3_ego[:, :2, 3], yaw_rad, config.smoothing)


def planar_kinematics(
    t_s: FloatArray, xy_m: FloatArray, yaw_rad: FloatArray, smoothing: SmoothingConfig
) -> HostKinematics:
    """Speed, acceleration and yaw rate of a planar path, as the host rules see them.

    The one home of the host's kinematics: the rules threshold them (:func:`classify_host`), and the
    encoders read the same values (:mod:`encoders.clips.views`), so that pose noise a real log's
    odometry adds is smoothed away alike for both.

    Args:
        t_s: (T,) sample times in seconds.
        xy_m: (T, 2) positions.
        yaw_rad: (T,) headings (unwrapped here).
        smoothing: the Savitzky–Golay filter; its window is converted to frames at the samples' median
            interval (:mod:`captioning.frames`).
    """
    interval_s = frame_interval_s(t_s)
    window_frames, polyorder = savgol_frames(smoothing.window_s, interval_s, smoothing.polyorder)
    t = xy_m.shape[0]
    values = np.concatenate([xy_m, np.unwrap(yaw_rad)[:, None]], axis=1)[None]  # (1, T, 3)
    valid = np.ones((1, t), dtype=bool)
    d = time_derivative(values, valid, t_s, window_frames, polyorder)[0]  # (T, 3)
    speed = np.hypot(d[:, 0], d[:, 1])
    accel = time_derivative(speed[None, :, None], valid, t_s, window_frames, polyorder)[0, :, 0]
    return HostKinematics(speed_mps=speed, accel_mps2=accel, yaw_rate_rps=d[:, 2], interval_s=interval_s)


def classify_host(kin: HostKinematics, config: CaptioningConfig) -> tuple[IntArray, IntArray]:
    """Eqs. 1 and 2 per frame, before flicker suppression.

    Returns:
        (T,) :data:`~captioning.tags.HOST_MOTIONS` codes and (T,) :data:`~captioning.tags.HOST_DIRECTIONS`
        codes; :data:`~captioning.tags.NO_TAG` where the kinematics are undefined.
    """
    h = config.host
    v, a, w = kin.speed_mps, kin.accel_mps2, kin.yaw_rate_rps
    motion = np.where(
        v < h.stationary_speed_mps,
        HOST_MOTIONS.index(HostMotion.STATIONARY),
        np.where(
            a > h.accel_mps2,
            HOST_MOTIONS.index(HostMotion.ACCELERATING),
            np.where(
                a < -h.accel_mps2,
                HOST_MOTIONS.index(HostMotion.DECELERATING),
                HOST_MOTIONS.index(HostMotion.CRUISING),
            ),
        ),
    )
    direction = np.where(
        w < -h.yaw_rate_rps,
        HOST_DIRECTIONS.index(HostDirection.STEERING_RIGHT),
        np.where(
            w > h.yaw_rate_rps,
            HOST_DIRECTIONS.index(HostDirection.STEERING_LEFT),
            HOST_DIRECTIONS.index(HostDirection.HEADING_STRAIGHT),
        ),
    )
    motion = np.where(np.isfinite(v) & np.isfinite(a), motion, NO_TAG).astype(np.int64)
    direction = np.where(np.isfinite(w), direction, NO_TAG).astype(np.int64)
    return motion, direction


def host_tags(timestamps_ns: IntArray, city_SE3_ego: FloatArray, config: CaptioningConfig) -> tuple[IntArray, IntArray]:
    """Per-frame host motion and direction codes after flicker suppression.

    Args:
        timestamps_ns: (T,) frame timestamps.
        city_SE3_ego: (T, 4, 4) ego poses.

    Returns:
        (T,) motion codes and (T,) direction codes.
    """
    return host_tags_of(host_kinematics(timestamps_ns, city_SE3_ego, config), config)


def host_tags_of(kin: HostKinematics, config: CaptioningConfig) -> tuple[IntArray, IntArray]:
    """:func:`host_tags` from kinematics computed already (they also serve the ego as a leader)."""
    motion, direction = classify_host(kin, config)
    m = FrameCounts.of(config, kin.interval_s).min_run
    return suppress_flicker(motion[None], m)[0], suppress_flicker(direction[None], m)[0]
