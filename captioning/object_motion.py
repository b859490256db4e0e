"""The objects' own motion over ground: speed, its rate of change and the heading rate of each track.

What the own-behaviour rules (:mod:`captioning.behavior`) threshold for standing, braking and turning,
and, with the velocity relative to the ego that the neighbour motion rules threshold
(:func:`captioning.neighbors.motion_codes`), what the encoders read per clip frame
(:func:`encoders.clips.views.object_rates_and_velocity`): one computation for both, so that a model reads
exactly the quantities the tags are made of.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from captioning.config import CaptioningConfig
from captioning.frames import FrameCounts
from captioning.leaders import wrap_rad
from captioning.neighbors import CompactGrid, TrackMotion, track_motion
from captioning.smoothing import BoolArray, IntArray, savgol_coefficients, time_derivative
from scenes.geometry import FloatArray

_G = TypeVar("_G", bound=np.generic)


def scatter_to_log_grid(grid: CompactGrid, values: NDArray[_G], shape: tuple[int, int], fill: object) -> NDArray[_G]:
    """(K, L, ...) compact values → (K, T, ...) on the log grid, ``fill`` outside observed cells."""
    out = np.full(shape + values.shape[2:], fill, dtype=values.dtype)
    out[grid.rows, grid.frame[grid.rows, grid.cols]] = values[grid.rows, grid.cols]
    return out


def _yaw_rate_rps(yaw_rad: FloatArray, ok: BoolArray, t_s: FloatArray, window_frames: int) -> FloatArray:
    """(K, L) heading rate from the wrapped heading change across ``window_frames`` frames centred on each
    cell (NaN where either end is unusable): cheap, and a turn lasts far longer than the window."""
    h = window_frames // 2
    out = np.full(yaw_rad.shape, np.nan)
    if yaw_rad.shape[1] <= 2 * h:
        return out
    both = ok[:, 2 * h :] & ok[:, : -2 * h]
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = wrap_rad(yaw_rad[:, 2 * h :] - yaw_rad[:, : -2 * h]) / (t_s[:, 2 * h :] - t_s[:, : -2 * h])
    out[:, h:-h] = np.where(both, rate, np.nan)
    return out


def _interior_rate(
    values: FloatArray, t_s: FloatArray, run_start: IntArray, run_end: IntArray, window_frames: int, polyorder: int
) -> FloatArray:
    """(K, L) Savitzky–Golay rate of change of ``values`` where the centred window lies inside the cell's run
    (NaN elsewhere, e.g. the first and last ``window_frames // 2`` frames of a run): one correlation along
    time, no per-window gathering at run ends.

    Args:
        values: (K, L) samples (NaN outside runs).
        t_s: (K, L) sample times.
        run_start: (K, L) first column of each cell's run (:func:`~captioning.smoothing.run_bounds`).
        run_end: (K, L) its last column.
    """
    h = window_frames // 2
    if window_frames > values.shape[1]:  # the window fits no run (and its weights would be large)
        return np.full(values.shape, np.nan)
    weights = savgol_coefficients(window_frames, polyorder, 1)[h]
    both = np.stack([np.nan_to_num(values), t_s], axis=2)
    from scipy.ndimage import correlate1d  # imported here: a cost a search's start-up never needs
    d = correlate1d(both, weights, axis=1, mode="constant", cval=0.0)
    col = np.arange(values.shape[1])[None, :]
    inside = (col - h >= run_start) & (col + h <= run_end)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(inside, d[..., 0] / d[..., 1], np.nan)


@dataclass(frozen=True)
class ObjectKinematics:
    """The tracks' own motion over ground on a :class:`~captioning.neighbors.TrackMotion`'s compact grid
    (K, L): what the own-behaviour rules threshold (standing, braking, turning without a map).

    Attributes:
        enough: (K, L) cells of a bridged run long enough for own-behaviour tags.
        speed_mps: (K, L) smoothed speed, NaN outside ``enough``.
        accel_mps2: (K, L) its rate of change inside each run, NaN where undefined.
        yaw_rad: (K, L) headings in the city frame.
        yaw_rate_rps: (K, L) heading rate (positive = left) across the smoothing window, NaN where undefined.
    """

    enough: BoolArray
    speed_mps: FloatArray
    accel_mps2: FloatArray
    yaw_rad: FloatArray
    yaw_rate_rps: FloatArray


def object_kinematics(motion: TrackMotion, city_SE3_ego: FloatArray, config: CaptioningConfig) -> ObjectKinematics:
    """The one home of the objects' own kinematics: :func:`captioning.behavior.behavior_tags` thresholds them, and
    :func:`track_kinematics` gives them to the encoders on the log grid.

    Args:
        motion: the tracks gathered, bridged and differentiated (:func:`captioning.neighbors.track_motion`).
        city_SE3_ego: (T, 4, 4) ego poses.
    """
    frames = FrameCounts.of(config, motion.interval_s)
    start, end = motion.run_start, motion.run_end
    enough = motion.bridged & (end - start + 1 >= frames.behavior_min_run)
    ego_yaw = np.arctan2(city_SE3_ego[:, 1, 0], city_SE3_ego[:, 0, 0])
    yaw = motion.yaw_ego_rad + ego_yaw[motion.grid.frame]
    # Speed: the neighbour tags' derivatives when the windows agree; then its rate of change.
    w, p, wa = frames.behavior_window, frames.behavior_polyorder, frames.accel_window
    if (w, p) == (frames.window, frames.polyorder):
        vel = motion.derivative[..., :2]
    else:
        vel = time_derivative(motion.positions[..., :2], enough, motion.t_s, w, p)
    speed = np.where(enough, np.hypot(vel[..., 0], vel[..., 1]), np.nan)
    accel = _interior_rate(speed, motion.t_s, start, end, wa, frames.accel_polyorder)
    return ObjectKinematics(enough, speed, accel, yaw, _yaw_rate_rps(yaw, enough, motion.t_s, w))


#: What :func:`track_kinematics` gives per frame: the object's own motion over ground (the behaviour rules'
#: quantities), then its velocity relative to the ego in that frame's ego frame (the neighbour rules').
TRACK_KINEMATICS_COLUMNS = ("speed_mps", "accel_mps2", "yaw_rate_rps", "rel_vx_mps", "rel_vy_mps")


def track_kinematics(timestamps_ns: IntArray, valid: BoolArray, center_ego_xy_m: FloatArray, yaw_ego_rad: FloatArray,
                     city_SE3_ego: FloatArray, config: CaptioningConfig) -> FloatArray:
    """(K, T, 5) each track's :data:`TRACK_KINEMATICS_COLUMNS` on the log grid: ``speed_mps, accel_mps2,
    yaw_rate_rps`` over ground (:func:`object_kinematics`; NaN where unobserved or in a run too short for
    the behaviour rules), then ``rel_vx_mps, rel_vy_mps``, the smoothed derivative of the centre in the ego
    frame that :func:`captioning.neighbors.motion_codes` thresholds for approach / away (NaN where
    unobserved or not differentiable).

    Args:
        timestamps_ns: (T,) frame timestamps.
        valid: (K, T) observed mask.
        center_ego_xy_m: (K, T, 2) centres in the ego frame.
        yaw_ego_rad: (K, T) headings in the ego frame.
        city_SE3_ego: (T, 4, 4) ego poses.
    """
    if not valid.any():
        return np.full((*valid.shape, len(TRACK_KINEMATICS_COLUMNS)), np.nan)
    motion = track_motion(timestamps_ns, valid, center_ego_xy_m, yaw_ego_rad, city_SE3_ego, config)
    kin = object_kinematics(motion, city_SE3_ego, config)
    own = np.stack([kin.speed_mps, kin.accel_mps2, kin.yaw_rate_rps], axis=2)  # (K, L, 3)
    relative = np.where(motion.bridged[..., None], motion.derivative[..., 2:], np.nan)  # (K, L, 2), the ego frame
    stacked = np.concatenate([np.where(kin.enough[..., None], own, np.nan), relative], axis=2)  # (K, L, 5)
    return scatter_to_log_grid(motion.grid, stacked, valid.shape, np.nan)
