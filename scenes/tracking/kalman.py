"""A constant-velocity Kalman filter over many 3D boxes at once.

State per track (10): ``x y z yaw l w h vx vy vz`` in the city frame; measurement (7):
``x y z yaw l w h``. Every operation works on a batch of N tracks: ``states`` (N, 10),
``covariances`` (N, 10, 10), so one frame costs a handful of numpy calls however many tracks.
"""

from __future__ import annotations

import numpy as np

from scenes.geometry import FloatArray, wrap_angle_rad
from scenes.tracking.config import TrackerConfig

STATE_DIM = 10
MEAS_DIM = 7
YAW = 3

#: Measurement matrix: the first seven state entries are observed directly.
H = np.hstack([np.eye(MEAS_DIM), np.zeros((MEAS_DIM, STATE_DIM - MEAS_DIM))])


def transition(dt_s: float) -> FloatArray:
    """(10, 10) constant-velocity transition over ``dt_s`` seconds."""
    f = np.eye(STATE_DIM)
    f[0, 7] = f[1, 8] = f[2, 9] = dt_s
    return f


def process_noise(dt_s: float, config: TrackerConfig) -> FloatArray:
    """(10, 10) process noise: white acceleration on position/velocity, small random walks elsewhere."""
    q = np.zeros((STATE_DIM, STATE_DIM))
    a2 = config.accel_noise_mps2**2
    for pos, vel in ((0, 7), (1, 8), (2, 9)):
        q[pos, pos] = a2 * dt_s**4 / 4.0
        q[pos, vel] = q[vel, pos] = a2 * dt_s**3 / 2.0
        q[vel, vel] = a2 * dt_s**2
    q[2, 2] *= 0.1  # objects rarely move vertically
    q[9, 9] *= 0.1
    q[YAW, YAW] = (1.0 * dt_s) ** 2  # up to ~1 rad/s of turning
    q[4, 4] = q[5, 5] = q[6, 6] = (0.05 * dt_s) ** 2  # sizes change only through noise
    return q


def measurement_noise(config: TrackerConfig) -> FloatArray:
    """(7, 7) measurement noise."""
    p, y, s = config.position_noise_m**2, config.yaw_noise_rad**2, config.size_noise_m**2
    return np.diag([p, p, p, y, s, s, s])


def initial_states(measurements: FloatArray, config: TrackerConfig) -> tuple[FloatArray, FloatArray]:
    """States and covariances of new tracks.

    Args:
        measurements: (N, 7) boxes ``x y z yaw l w h``.

    Returns:
        (N, 10) states with zero velocity and (N, 10, 10) covariances.
    """
    n = measurements.shape[0]
    states = np.zeros((n, STATE_DIM))
    states[:, :MEAS_DIM] = measurements
    v2 = config.initial_velocity_std_mps**2
    diag = np.concatenate([np.diag(measurement_noise(config)), [v2, v2, v2 * 0.1]])
    covariances = np.repeat(np.diag(diag)[None], n, axis=0)
    return states, covariances


def predict(states: FloatArray, covariances: FloatArray, dt_s: float, config: TrackerConfig) -> tuple[
        FloatArray, FloatArray]:
    """Advance every track by ``dt_s``.

    Args:
        states: (N, 10) states.
        covariances: (N, 10, 10) covariances.

    Returns:
        (N, 10) predicted states and (N, 10, 10) covariances (new arrays).
    """
    f = transition(dt_s)
    new_states = states @ f.T
    new_states[:, YAW] = wrap_angle_rad(new_states[:, YAW])
    new_cov = f @ covariances @ f.T + process_noise(dt_s, config)
    return new_states, new_cov


def align_yaw(measured_yaw_rad: FloatArray, predicted_yaw_rad: FloatArray) -> FloatArray:
    """Flip measured headings by π where they point against the prediction.

    Detectors often confuse a box's front and back; a flip of more than 90° between frames is far
    likelier to be that confusion than a real turn at 10 Hz.

    Args:
        measured_yaw_rad: (N,) detected headings.
        predicted_yaw_rad: (N,) predicted headings of the matched tracks.

    Returns:
        (N,) headings within 90° of the prediction.
    """
    diff = wrap_angle_rad(measured_yaw_rad - predicted_yaw_rad)
    flip = np.abs(diff) > np.pi / 2
    return np.asarray(wrap_angle_rad(np.where(flip, measured_yaw_rad + np.pi, measured_yaw_rad)))


def update(states: FloatArray, covariances: FloatArray, measurements: FloatArray, config: TrackerConfig) -> tuple[
        FloatArray, FloatArray]:
    """Fuse one measurement into each track.

    Args:
        states: (N, 10) predicted states.
        covariances: (N, 10, 10) predicted covariances.
        measurements: (N, 7) matched boxes (yaw already aligned with :func:`align_yaw`).

    Returns:
        (N, 10) updated states and (N, 10, 10) covariances (new arrays).
    """
    innovation = measurements - states @ H.T  # (N, 7)
    innovation[:, YAW] = wrap_angle_rad(innovation[:, YAW])
    s = H @ covariances @ H.T + measurement_noise(config)  # (N, 7, 7)
    ph_t = covariances @ H.T  # (N, 10, 7)
    # K = P Hᵀ S⁻¹, solved rather than inverted: Kᵀ = S⁻¹ (P Hᵀ)ᵀ since S is symmetric.
    gain = np.swapaxes(np.linalg.solve(s, np.swapaxes(ph_t, 1, 2)), 1, 2)  # (N, 10, 7)
    new_states = states + np.einsum("nij,nj->ni", gain, innovation)
    new_states[:, YAW] = wrap_angle_rad(new_states[:, YAW])
    identity = np.eye(STATE_DIM)[None]
    new_cov = (identity - gain @ H[None]) @ covariances
    return new_states, new_cov


def heading_from_motion(states: FloatArray, min_speed_mps: float) -> FloatArray:
    """Flip headings by π where they point against a confident motion.

    A detector cannot always tell a box's front from its back; a moving object, though, drives
    forwards. Where the filtered planar speed is at least ``min_speed_mps`` and the heading is more
    than 90° away from the velocity, the heading is turned round.

    Args:
        states: (N, 10) states.

    Returns:
        (N, 10) states with corrected headings (a new array).
    """
    out = states.copy()
    speed = np.hypot(states[:, 7], states[:, 8])
    motion_yaw = np.arctan2(states[:, 8], states[:, 7])
    against = (speed >= min_speed_mps) & (np.cos(states[:, YAW] - motion_yaw) < 0)
    out[against, YAW] = wrap_angle_rad(states[against, YAW] + np.pi)
    return out
