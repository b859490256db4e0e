"""A straightforward per-frame Python implementation of the same rules.

It exists as a test oracle (the vectorised code must give the same tags) and as the speed
baseline of ``benchmarks/bench_captioning.py``. Nothing else should use it: it is slow on purpose,
with one Python step per track and frame, exactly as the rules read. The config's durations become
frames as in the vectorised code (:class:`~captioning.frames.FrameCounts`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from captioning.config import CaptioningConfig
from captioning.frames import FrameCounts
from captioning.smoothing import FloatArray, savgol_derivative_coefficients
from captioning.tags import (
    BASELINE_OF_LANE,
    HOST_DIRECTIONS,
    HOST_MOTIONS,
    LANES,
    MOTIONS,
    NO_TAG,
    BaselineLane,
    HostDirection,
    HostMotion,
    Lane,
    Motion,
)

T = TypeVar("T")


@dataclass(frozen=True)
class ReferenceTags:
    """Same meaning as the vectorised results: codes per frame, NO_TAG where untagged.

    Attributes:
        host_motion: (T,) codes.
        host_direction: (T,) codes.
        stationary: (K,) eq. 3 per track.
        taggable: (K,) tracks with a differentiable frame.
        lane: (K, T) codes.
        baseline_lane: (K, T) codes.
        motion: (K, T) codes.
    """

    host_motion: NDArray[np.int64]
    host_direction: NDArray[np.int64]
    stationary: NDArray[np.bool_]
    taggable: NDArray[np.bool_]
    lane: NDArray[np.int64]
    baseline_lane: NDArray[np.int64]
    motion: NDArray[np.int64]


def _derivative_at(values: list[float], valid: list[bool], i: int, window: int, polyorder: int) -> float:
    """Derivative per frame index at frame ``i`` (see :mod:`captioning.smoothing`)."""
    a = i
    while a - 1 >= 0 and valid[a - 1]:
        a -= 1
    b = i
    while b + 1 < len(valid) and valid[b + 1]:
        b += 1
    n = b - a + 1
    if n == 1:
        return math.nan
    if n < window:
        if i == a:
            return values[i + 1] - values[i]
        if i == b:
            return values[i] - values[i - 1]
        return 0.5 * (values[i + 1] - values[i - 1])
    start = min(max(i - window // 2, a), b - window + 1)
    coeffs = savgol_derivative_coefficients(window, polyorder)[i - start]
    return float(sum(float(coeffs[j]) * values[start + j] for j in range(window)))


def _time_derivatives(values: list[float], valid: list[bool], t_s: list[float], frames: FrameCounts) -> list[float]:
    w, p = frames.window, frames.polyorder
    out = []
    for i in range(len(values)):
        if not valid[i]:
            out.append(math.nan)
            continue
        out.append(_derivative_at(values, valid, i, w, p) / _derivative_at(t_s, valid, i, w, p))
    return out


def _suppress(codes: list[int], min_run: int) -> list[int]:
    t = len(codes)
    if min_run <= 1:
        return list(codes)
    run_len = [0] * t
    i = 0
    while i < t:
        j = i
        while j + 1 < t and codes[j + 1] == codes[i]:
            j += 1
        for f in range(i, j + 1):
            run_len[f] = j - i + 1
        i = j + 1
    hole = [run_len[f] < min_run and codes[f] != NO_TAG for f in range(t)]
    out = list(codes)
    for f in range(t):
        if not hole[f]:
            continue
        prev = next((codes[g] for g in range(f - 1, -1, -1) if not hole[g]), NO_TAG)
        nxt = next((codes[g] for g in range(f + 1, t) if not hole[g]), NO_TAG)
        out[f] = prev if prev != NO_TAG else nxt if nxt != NO_TAG else codes[f]
    return out


def _by_threshold(value: float, threshold: float, below: T, within: T, above: T) -> T:
    """``below`` under −``threshold``, ``above`` over +``threshold``, else ``within`` (the rules' three-way test)."""
    if value < -threshold:
        return below
    if value > threshold:
        return above
    return within


def reference_tags(
    timestamps_ns: NDArray[np.int64],
    valid: NDArray[np.bool_],
    center_ego_xy_m: FloatArray,
    yaw_ego_rad: FloatArray,
    city_SE3_ego: FloatArray,
    config: CaptioningConfig,
) -> ReferenceTags:
    """Per-frame tags, one Python step at a time; the arguments (and their shapes) are those of
    :func:`captioning.neighbors.track_motion`, and the results must equal those of
    :func:`captioning.neighbors.neighbor_tags` on its tracks."""
    frames = FrameCounts.of_log(config, timestamps_ns)
    h, nb, m, max_gap = config.host, config.neighbor, frames.min_run, frames.max_gap
    k_count, t_count = valid.shape
    t_s = [float(ts - timestamps_ns[0]) * 1e-9 for ts in timestamps_ns.tolist()]
    everywhere = [True] * t_count

    # Host (eqs. 1, 2).
    yaw = np.unwrap([math.atan2(city_SE3_ego[f, 1, 0], city_SE3_ego[f, 0, 0]) for f in range(t_count)]).tolist()
    vx = _time_derivatives([float(city_SE3_ego[f, 0, 3]) for f in range(t_count)], everywhere, t_s, frames)
    vy = _time_derivatives([float(city_SE3_ego[f, 1, 3]) for f in range(t_count)], everywhere, t_s, frames)
    omega = _time_derivatives(yaw, everywhere, t_s, frames)
    speed = [math.hypot(a, b) for a, b in zip(vx, vy)]
    accel = _time_derivatives(speed, everywhere, t_s, frames)
    host_motion, host_direction = [], []
    for f in range(t_count):
        v, a, w = speed[f], accel[f], omega[f]
        if math.isnan(v) or math.isnan(a):
            host_motion.append(NO_TAG)
        elif v < h.stationary_speed_mps:
            host_motion.append(HOST_MOTIONS.index(HostMotion.STATIONARY))
        else:
            host_motion.append(HOST_MOTIONS.index(_by_threshold(
                a, h.accel_mps2, HostMotion.DECELERATING, HostMotion.CRUISING, HostMotion.ACCELERATING)))
        if math.isnan(w):
            host_direction.append(NO_TAG)
        else:
            host_direction.append(HOST_DIRECTIONS.index(_by_threshold(
                w, h.yaw_rate_rps, HostDirection.STEERING_RIGHT, HostDirection.HEADING_STRAIGHT,
                HostDirection.STEERING_LEFT)))

    first_SE3_city = np.linalg.inv(city_SE3_ego[0])
    stationary = np.zeros(k_count, dtype=bool)
    taggable = np.zeros(k_count, dtype=bool)
    lanes = np.full((k_count, t_count), NO_TAG, dtype=np.int64)
    baselines = np.full((k_count, t_count), NO_TAG, dtype=np.int64)
    motions = np.full((k_count, t_count), NO_TAG, dtype=np.int64)
    lo_deg, hi_deg = nb.lateral_deg
    for k in range(k_count):
        obs = [bool(v) for v in valid[k]]
        first_x, first_y = [], []
        for f in range(t_count):
            if obs[f]:
                p_city = city_SE3_ego[f] @ np.array([center_ego_xy_m[k, f, 0], center_ego_xy_m[k, f, 1], 0.0, 1.0])
                p_first = first_SE3_city @ p_city
                first_x.append(float(p_first[0]))
                first_y.append(float(p_first[1]))
            else:
                first_x.append(0.0)
                first_y.append(0.0)
        rel_x = [float(center_ego_xy_m[k, f, 0]) if obs[f] else 0.0 for f in range(t_count)]
        rel_y = [float(center_ego_xy_m[k, f, 1]) if obs[f] else 0.0 for f in range(t_count)]
        heading = [float(yaw_ego_rad[k, f]) for f in range(t_count)]
        # Bridge short gaps: linear in time between the observations on either side.
        bridged = list(obs)
        for f in range(t_count):
            if obs[f] or max_gap <= 0:
                continue
            before = f - 1
            while before >= 0 and not obs[before]:
                before -= 1
            after = f + 1
            while after < t_count and not obs[after]:
                after += 1
            if before < 0 or after >= t_count:
                continue
            in_time = math.floor((t_s[after] - t_s[before]) / frames.interval_s + 0.5) - 1
            if min(after - before - 1, in_time) > max_gap:  # missed frames: of the grid, at most as many as fit
                continue
            w = (t_s[f] - t_s[before]) / (t_s[after] - t_s[before])
            for channel in (first_x, first_y, rel_x, rel_y):
                channel[f] = channel[before] + w * (channel[after] - channel[before])
            heading[f] = heading[before]
            bridged[f] = True
        dfx = _time_derivatives(first_x, bridged, t_s, frames)
        dfy = _time_derivatives(first_y, bridged, t_s, frames)
        drx = _time_derivatives(rel_x, bridged, t_s, frames)
        dry = _time_derivatives(rel_y, bridged, t_s, frames)
        ok = [bridged[f] and not math.isnan(dfx[f]) for f in range(t_count)]
        ok_observed = [ok[f] and obs[f] for f in range(t_count)]
        if not any(ok_observed):
            continue
        taggable[k] = True
        qx = float(np.quantile([abs(dfx[f]) for f in range(t_count) if ok_observed[f]], nb.stationary_quantile))
        qy = float(np.quantile([abs(dfy[f]) for f in range(t_count) if ok_observed[f]], nb.stationary_quantile))
        if qx < nb.stationary_speed_mps and qy < nb.stationary_speed_mps:
            stationary[k] = True
            continue
        raw_lane = []
        for f in range(t_count):
            if not ok[f]:
                raw_lane.append(NO_TAG)
                continue
            phi = abs(math.degrees(math.atan2(math.sin(heading[f]), math.cos(heading[f]))))
            y_paper = -rel_y[f]  # the paper's lateral axis points right
            if y_paper < -nb.host_lane_half_width_m:
                side = "left"
            elif y_paper > nb.host_lane_half_width_m:
                side = "right"
            else:
                side = "host"
            if phi > nb.oncoming_min_deg:
                lane = Lane.ONCOMING
            elif lo_deg < phi < hi_deg:
                lane = Lane(f"{side}_lateral")
            else:
                lane = Lane(side)
            raw_lane.append(LANES.index(lane))
        lane_codes = _suppress(raw_lane, m)
        raw_motion = []
        for f in range(t_count):
            if not ok[f]:
                raw_motion.append(NO_TAG)
                continue
            lane = LANES[lane_codes[f]]
            if abs(dfx[f]) < nb.stationary_speed_mps and abs(dfy[f]) < nb.stationary_speed_mps:
                raw_motion.append(MOTIONS.index(Motion.STATIONARY))
                continue
            if lane in (Lane.LEFT_LATERAL, Lane.RIGHT_LATERAL):
                pos, vel = rel_y[f], dry[f]
            else:
                pos, vel = rel_x[f], drx[f]
            ddist = (1.0 if pos > 0 else -1.0 if pos < 0 else 0.0) * vel
            raw_motion.append(MOTIONS.index(_by_threshold(
                ddist, nb.relative_speed_mps, Motion.APPROACH, Motion.CONSTANT, Motion.AWAY)))
        motion_codes = _suppress(raw_motion, m)
        for f in range(t_count):
            if ok_observed[f]:
                lanes[k, f] = lane_codes[f]
                baselines[k, f] = list(BaselineLane).index(BASELINE_OF_LANE[LANES[lane_codes[f]]])
                motions[k, f] = motion_codes[f]
    return ReferenceTags(
        host_motion=np.array(_suppress(host_motion, m), dtype=np.int64),
        host_direction=np.array(_suppress(host_direction, m), dtype=np.int64),
        stationary=stationary,
        taggable=taggable,
        lane=lanes,
        baseline_lane=baselines,
        motion=motions,
    )
