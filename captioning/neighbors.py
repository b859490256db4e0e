"""Neighbour tags: stationarity (eq. 3), baseline lane (eq. 4), lane (eq. 5), motion (eqs. 6, 7).

Gaps
----
Gaps of up to ``smoothing.max_gap_s`` of missed frames inside a track (missed detections) are
bridged by linear interpolation before differentiating and suppressing flicker; longer gaps split the
track into runs that are differentiated separately. A gap misses its frames of the grid, but never
more than the frames of the log's rate (:mod:`captioning.frames`) that fit between the observations
on either side: extra frames in the grid (LiDAR sweeps without annotations between 2 Hz
annotations) are no misses, and neither is a dropped sweep (no frame, nothing to miss). Tags are
reported on observed frames only.

Stationarity (eq. 3)
--------------------
Each track's centre is expressed in the host's pose at the log's first frame (which removes the
host's own motion) and differentiated along time. A track is *stationary* when the
``neighbor.stationary_quantile`` quantile (default 0.8) of its per-frame absolute speed along the
first-frame x axis **and** along its y axis is below ``T_s``. A quantile instead of the maximum
makes a few tracker glitches harmless; instead of the median, it keeps a car that waits and then
drives off. Stationary tracks get no lane and motion tags and no caption.

Motion (generalised eqs. 6, 7)
------------------------------
The paper compares signed offsets and assumes objects ahead of the host (with sign typos).
Here the *distance* along one axis is used: ``d = |x|`` for every lane except the lateral lanes off the
host band (``left_lateral``, ``right_lateral``), which use ``d = |y|``; with ``ḋ = sign(p)·ṗ`` from the
ego-frame relative velocity, ``approach`` if ``ḋ < −T_m``, ``away`` if ``ḋ > T_m``, else ``constant``.
For objects ahead (x > 0) this is the paper's rule; for objects behind it is the correct mirror
(a follower closing in approaches). ``stationary`` overrides these where the neighbour itself
(host-compensated) moves slower than ``T_s`` along both axes at that frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from captioning.config import CaptioningConfig
from captioning.frames import FrameCounts
from captioning.smoothing import (
    BoolArray,
    IntArray,
    run_bounds,
    seconds_since_first,
    suppress_flicker,
    time_derivative,
)
from captioning.tags import (
    BASELINE_CODE_OF_LANE_CODE,
    BASELINE_LANES,
    LANES,
    MOTIONS,
    NO_TAG,
    BaselineLane,
    Lane,
    Motion,
    paper_lateral_m,
)
from scenes.geometry import FloatArray, wrap_angle_rad

_ONGOING, _LATERAL, _ONCOMING = (BASELINE_LANES.index(b) for b in BaselineLane)
_L = {lane: LANES.index(lane) for lane in Lane}
_M = {motion: MOTIONS.index(motion) for motion in Motion}


@dataclass(frozen=True)
class NeighborTags:
    """Per-frame neighbour tags on the (K, T) grid.

    Attributes:
        stationary: (K,) eq. 3, for tracks with at least one differentiable frame.
        taggable: (K,) tracks with at least one differentiable observed frame (not isolated frames).
        tagged: (K, T) frames that carry lane and motion tags (observed, differentiable, non-stationary track).
        baseline_lane: (K, T) :data:`~captioning.tags.BASELINE_LANES` codes (int8), NO_TAG elsewhere.
        lane: (K, T) :data:`~captioning.tags.LANES` codes.
        motion: (K, T) :data:`~captioning.tags.MOTIONS` codes.
    """

    stationary: BoolArray
    taggable: BoolArray
    tagged: BoolArray
    baseline_lane: NDArray[np.int8]
    lane: NDArray[np.int8]
    motion: NDArray[np.int8]


def host_compensated_xy(center_ego_xy_m: FloatArray, first_SE3_ego_planar: FloatArray) -> FloatArray:
    """Centres in the host's first-frame pose.

    Args:
        center_ego_xy_m: (K, T, 2) centres in the ego frame at each sample.
        first_SE3_ego_planar: (K, T, 6) rows ``(r00, r01, tx, r10, r11, ty)`` of
            ``first_SE3_city · city_SE3_ego`` at each sample.

    Returns:
        (K, T, 2) centres in the host's first-frame pose.
    """
    x, y = center_ego_xy_m[..., 0], center_ego_xy_m[..., 1]
    p = first_SE3_ego_planar
    out = np.empty(center_ego_xy_m.shape)
    out[..., 0] = p[..., 0] * x + p[..., 1] * y + p[..., 2]
    out[..., 1] = p[..., 3] * x + p[..., 4] * y + p[..., 5]
    return out


@dataclass(frozen=True)
class CompactGrid:
    """Tracks re-laid from the (K, T) log grid onto (K, L) rows that start at each track's first
    frame (L = longest span), so long logs with short tracks cost O(tracks × span), not O(K × T).

    Attributes:
        frame: (K, L) log frame index of each cell (clipped into range).
        valid: (K, L) observed cells.
        inside: (K, L) cells between the track's first and last observation.
        rows: (N,) row of each observed cell.
        cols: (N,) column of each observed cell.
    """

    frame: IntArray
    valid: BoolArray
    inside: BoolArray
    rows: IntArray
    cols: IntArray

    @staticmethod
    def of(valid: BoolArray) -> CompactGrid:
        k, t = valid.shape
        observed = valid.any(axis=1)
        first = np.argmax(valid, axis=1)
        last = t - 1 - np.argmax(valid[:, ::-1], axis=1)
        span = np.where(observed, last - first + 1, 0)
        length = max(int(span.max()) if k else 0, 1)
        cols = np.arange(length)[None, :]
        frame = np.minimum(first[:, None] + cols, t - 1)
        rows = np.arange(k)[:, None]
        inside = cols < span[:, None]
        cvalid = inside & valid[rows, frame]
        obs_rows, obs_cols = np.nonzero(cvalid)
        return CompactGrid(frame=frame, valid=cvalid, inside=inside, rows=obs_rows, cols=obs_cols)

    def gather(self, grid: NDArray[np.generic]) -> NDArray[np.generic]:
        """(K, T, ...) → (K, L, ...)."""
        return grid[np.arange(grid.shape[0])[:, None], self.frame]

    def scatter(self, compact: IntArray, shape: tuple[int, int]) -> NDArray[np.int8]:
        """(K, L) codes → (K, T) int8 codes (vocabularies are tiny), NO_TAG outside observed cells."""
        out = np.full(shape, NO_TAG, dtype=np.int8)
        out[self.rows, self.frame[self.rows, self.cols]] = compact[self.rows, self.cols]
        return out


def bridge_gaps(
    values: FloatArray, yaw_rad: FloatArray, valid: BoolArray, inside: BoolArray, t_s: FloatArray, max_gap_frames: int,
    interval_s: float,
) -> BoolArray:
    """Fill gaps of at most ``max_gap_frames`` missed frames inside tracks, in place.

    A gap between observations at ``t0`` and ``t1`` misses its frames of the grid, but at most
    ``round((t1 − t0) / interval_s) − 1`` (see the module docstring).

    Positions are interpolated linearly in time between the observations on either side; the
    heading keeps the last observed value (a gap is too short for it to matter).

    Args:
        values: (K, L, C) samples, changed in place at bridged cells.
        yaw_rad: (K, L) headings, changed in place at bridged cells.
        valid: (K, L) observed cells.
        inside: (K, L) cells between each track's first and last observation.
        t_s: (K, L) sample times.
        interval_s: the log's frame interval (:func:`~captioning.frames.frame_interval_s`).

    Returns:
        (K, L) observed or bridged cells.
    """
    if max_gap_frames <= 0 or not interval_s > 0:
        return valid
    gap = inside & ~valid
    gap_start, gap_end = run_bounds(gap)
    rows, cols = np.nonzero(gap)
    before = gap_start[rows, cols] - 1  # observed: a gap inside a track has observations on both sides
    after = gap_end[rows, cols] + 1
    t0, t1 = t_s[rows, before], t_s[rows, after]
    missed = np.minimum(after - before - 1, np.floor((t1 - t0) / interval_s + 0.5) - 1)
    short = missed <= max_gap_frames
    rows, cols, before, after, t0, t1 = rows[short], cols[short], before[short], after[short], t0[short], t1[short]
    if rows.size == 0:
        return valid
    bridge = np.zeros_like(valid)
    bridge[rows, cols] = True
    weight = ((t_s[rows, cols] - t0) / (t1 - t0))[:, None]
    values[rows, cols] = values[rows, before] + weight * (values[rows, after] - values[rows, before])
    yaw_rad[rows, cols] = yaw_rad[rows, before]
    return valid | bridge


def quantile_below(values: FloatArray, q: float, threshold: float) -> BoolArray:
    """Whether each row's ``q`` quantile (linear interpolation, over its finite entries) is below
    ``threshold``, without sorting: counting the entries below the threshold settles it unless the
    quantile falls between the largest entry below and the smallest at or above, which are then
    interpolated exactly as the quantile would be.

    Args:
        values: (K, T) samples, NaN where missing.

    Returns:
        (K,) booleans; False for rows without samples.
    """
    finite = np.isfinite(values)
    n = finite.sum(axis=1)
    pos = q * np.maximum(n - 1, 0)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
    below = finite & (values < threshold)
    count = below.sum(axis=1)
    largest_below = np.where(below, values, -np.inf).max(axis=1)
    smallest_above = np.where(finite & ~below, values, np.inf).min(axis=1)
    between = (count == lo + 1) & (hi > lo)
    with np.errstate(invalid="ignore"):
        interpolated = largest_below + (pos - lo) * (smallest_above - largest_below)
    return (n > 0) & ((count >= hi + 1) | (between & (interpolated < threshold)))


def baseline_lane_codes(yaw_ego_rad: FloatArray, config: CaptioningConfig) -> IntArray:
    """Eq. 4 per frame.

    Args:
        yaw_ego_rad: (...) neighbour heading relative to the host heading.
    """
    phi_deg = np.abs(np.degrees(wrap_angle_rad(yaw_ego_rad)))
    lo, hi = config.neighbor.lateral_deg
    return np.where(
        phi_deg > config.neighbor.oncoming_min_deg,
        _ONCOMING,
        np.where((phi_deg > lo) & (phi_deg < hi), _LATERAL, _ONGOING),
    ).astype(np.int64)


def lane_codes(baseline: IntArray, y_ego_m: FloatArray, config: CaptioningConfig) -> IntArray:
    """Eq. 5 per frame, with the paper's right-positive lateral offset.

    Args:
        baseline: (...) baseline-lane codes.
        y_ego_m: (...) lateral offsets in the ego frame (left positive).
    """
    y_paper_m = paper_lateral_m(y_ego_m)
    th = config.neighbor.host_lane_half_width_m
    left, right = y_paper_m < -th, y_paper_m > th
    ongoing = np.where(left, _L[Lane.LEFT], np.where(right, _L[Lane.RIGHT], _L[Lane.HOST]))
    lateral = np.where(
        left, _L[Lane.LEFT_LATERAL], np.where(right, _L[Lane.RIGHT_LATERAL], _L[Lane.HOST_LATERAL])
    )
    return np.where(baseline == _ONCOMING, _L[Lane.ONCOMING], np.where(baseline == _LATERAL, lateral, ongoing)).astype(
        np.int64
    )


def motion_codes(
    lane: IntArray, rel_xy_m: FloatArray, rel_vel_xy_mps: FloatArray, moving: BoolArray, config: CaptioningConfig
) -> IntArray:
    """Generalised eqs. 6, 7 per frame.

    Args:
        lane: (K, T) lane codes.
        rel_xy_m: (K, T, 2) centres in the ego frame.
        rel_vel_xy_mps: (K, T, 2) their time derivatives.
        moving: (K, T) whether the neighbour itself moves at the frame.
    """
    lateral_axis = (lane == _L[Lane.LEFT_LATERAL]) | (lane == _L[Lane.RIGHT_LATERAL])
    pos = np.where(lateral_axis, rel_xy_m[..., 1], rel_xy_m[..., 0])
    vel = np.where(lateral_axis, rel_vel_xy_mps[..., 1], rel_vel_xy_mps[..., 0])
    ddist = np.sign(pos) * vel
    tm = config.neighbor.relative_speed_mps
    rel = np.where(ddist < -tm, _M[Motion.APPROACH], np.where(ddist > tm, _M[Motion.AWAY], _M[Motion.CONSTANT]))
    return np.where(moving, rel, _M[Motion.STATIONARY]).astype(np.int64)


@dataclass(frozen=True)
class TrackMotion:
    """Tracks on the compact grid, gaps bridged, differentiated: what the neighbour tags and the own
    behaviour (:mod:`captioning.behavior`) both start from.

    Attributes:
        grid: the compact grid (K, L) of every array here.
        t_s: (K, L) sample times.
        positions: (K, L, 4) centres in the host's first-frame pose, then in the ego frame (bridged).
        yaw_ego_rad: (K, L) headings in the ego frame (bridged).
        bridged: (K, L) observed or bridged cells.
        run_start: (K, L) first column of each bridged cell's run (:func:`~captioning.smoothing.run_bounds`).
        run_end: (K, L) its last column.
        derivative: (K, L, 4) time derivatives of ``positions`` (``smoothing`` window); NaN where undefined.
        city_SE3_first: (4, 4) the host's first-frame pose: ``city = city_SE3_first · first``.
        interval_s: the log's frame interval (:func:`~captioning.frames.frame_interval_s`), at which the
            config's durations are converted to frames (:meth:`~captioning.frames.FrameCounts.of`).
    """

    grid: CompactGrid
    t_s: FloatArray
    positions: FloatArray
    yaw_ego_rad: FloatArray
    bridged: BoolArray
    run_start: IntArray
    run_end: IntArray
    derivative: FloatArray
    city_SE3_first: FloatArray
    interval_s: float


def track_motion(
    timestamps_ns: IntArray,
    valid: BoolArray,
    center_ego_xy_m: FloatArray,
    yaw_ego_rad: FloatArray,
    city_SE3_ego: FloatArray,
    config: CaptioningConfig,
) -> TrackMotion:
    """Gather, bridge and differentiate the tracks (see :class:`TrackMotion`); K and T must be > 0.

    Args:
        timestamps_ns: (T,) frame timestamps.
        valid: (K, T) observed mask.
        center_ego_xy_m: (K, T, 2) centres in the ego frame (anything where not observed).
        yaw_ego_rad: (K, T) headings in the ego frame.
        city_SE3_ego: (T, 4, 4) ego poses.
    """
    frames = FrameCounts.of_log(config, timestamps_ns)
    grid = CompactGrid.of(valid)
    cvalid = grid.valid
    rel_xy: FloatArray = np.where(cvalid[..., None], grid.gather(center_ego_xy_m), 0.0)  # (K, L, 2)
    yaw = np.asarray(grid.gather(yaw_ego_rad), dtype=np.float64)
    first_SE3_ego = np.einsum("ij,tjk->tik", np.linalg.inv(city_SE3_ego[0]), city_SE3_ego)  # (T, 4, 4)
    planar = first_SE3_ego[:, [0, 0, 0, 1, 1, 1], [0, 1, 3, 0, 1, 3]]  # (T, 6): the planar rows only
    first_xy = host_compensated_xy(rel_xy, planar[grid.frame])
    t_s = seconds_since_first(timestamps_ns)[grid.frame]  # (K, L)
    positions = np.concatenate([first_xy, rel_xy], axis=2)  # (K, L, 4)
    bridged = bridge_gaps(positions, yaw, cvalid, grid.inside, t_s, frames.max_gap, frames.interval_s)
    runs = run_bounds(bridged)
    d = time_derivative(positions, bridged, t_s, frames.window, frames.polyorder, runs=runs)  # (K, L, 4)
    return TrackMotion(grid, t_s, positions, yaw, bridged, *runs, d, np.asarray(city_SE3_ego[0], dtype=np.float64),
                       frames.interval_s)


def neighbor_tags(
    tracks: TrackMotion | None,
    shape: tuple[int, int],
    config: CaptioningConfig,
    stationary_objects: bool = False,
) -> NeighborTags:
    """All neighbour tags, vectorised over tracks × frames.

    Args:
        tracks: :func:`track_motion` of the log's tracks; None where K or T is 0 (every tag is then empty).
        shape: (K, T), the log's tracks and frames.
        config: the captioning config :func:`track_motion` was given.
        stationary_objects: tag stationary tracks too, and let motion be the distance rule alone
            (approach / away / constant, the ego's doing for an object that stands): whether an
            object stands is then its own-behaviour tag (:mod:`captioning.behavior`), not a motion.
    """
    k, t = shape
    nb = config.neighbor
    if tracks is None:
        empty = np.full((k, t), NO_TAG, dtype=np.int8)
        return NeighborTags(np.zeros(k, bool), np.zeros(k, bool), np.zeros((k, t), bool), empty, empty, empty)
    grid, positions, yaw, d = tracks.grid, tracks.positions, tracks.yaw_ego_rad, tracks.derivative
    cvalid = grid.valid
    abs_first_vel = np.abs(d[..., :2])
    rel_vel = d[..., 2:]
    differentiable: BoolArray = np.asarray(np.isfinite(d).all(axis=2), dtype=bool)
    observed = differentiable & cvalid
    taggable: BoolArray = np.asarray(observed.any(axis=1), dtype=bool)
    q, ts = nb.stationary_quantile, nb.stationary_speed_mps
    still_x = quantile_below(np.where(observed, abs_first_vel[..., 0], np.nan), q, ts)
    still_y = quantile_below(np.where(observed, abs_first_vel[..., 1], np.nan), q, ts)
    stationary = taggable & still_x & still_y
    # Bridged frames carry tags while flicker is suppressed; only observed frames are reported.
    tagged = differentiable & (taggable & (stationary_objects | ~stationary))[:, None]
    moving = (abs_first_vel[..., 0] >= nb.stationary_speed_mps) | (abs_first_vel[..., 1] >= nb.stationary_speed_mps)
    if stationary_objects:
        moving = np.ones_like(moving)

    m = FrameCounts.of(config, tracks.interval_s).min_run
    raw_lane = lane_codes(baseline_lane_codes(yaw, config), positions[..., 3], config)
    lane = suppress_flicker(np.where(tagged, raw_lane, NO_TAG), m)
    baseline = np.where(tagged, BASELINE_CODE_OF_LANE_CODE[np.maximum(lane, 0)], NO_TAG)
    raw_motion = motion_codes(lane, positions[..., 2:], rel_vel, moving, config)
    motion = suppress_flicker(np.where(tagged, raw_motion, NO_TAG), m)
    shape = (k, t)
    lane_grid = grid.scatter(lane, shape)
    return NeighborTags(
        stationary=stationary,
        taggable=taggable,
        tagged=lane_grid != NO_TAG,
        baseline_lane=grid.scatter(baseline, shape),
        lane=lane_grid,
        motion=grid.scatter(motion, shape),
    )
