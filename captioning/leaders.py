"""Leaders: ``blocked_by`` and ``braking_for`` (own-behaviour tags of :mod:`captioning.behavior`).

A follower's leader is the nearest vehicle (the ego included) ahead of it within
``behavior.leader_half_width_m`` of its heading line, heading within ``behavior.leader_max_heading_deg``
of it (crossing traffic is no leader). Only vehicles that may carry one of the two tags (slow or
braking, not parked) are paired with the vehicles of their frame, so the cost grows with them, not
with the square of the objects.
"""

from __future__ import annotations

import numpy as np

from captioning.config import CaptioningConfig
from captioning.neighbors import CompactGrid
from captioning.smoothing import BoolArray
from scenes.geometry import FloatArray


def wrap_rad(angle_rad: FloatArray) -> FloatArray:
    """Angles into [−π, π) (cheaper than :func:`~scenes.geometry.wrap_angle_rad` where ±π do not matter)."""
    return np.asarray(np.mod(angle_rad + np.pi, 2.0 * np.pi) - np.pi, dtype=np.float64)


def leader_tags(
    grid: CompactGrid,
    movers: BoolArray,
    braking: BoolArray,
    xy: FloatArray,
    yaw_rad: FloatArray,
    length_m: FloatArray,
    speed_mps: FloatArray,
    city_SE3_ego: FloatArray,
    config: CaptioningConfig,
    ego_speed_mps: FloatArray | None,
    ego_accel_mps2: FloatArray | None,
) -> tuple[BoolArray, BoolArray]:
    """``blocked_by`` and ``braking_for`` on the compact grid: each follower against the vehicles of its frame.

    Only followers that may carry a tag (slow or braking vehicles, not parked) are paired, so the
    cost grows with them, not with the square of the objects.

    Args:
        grid: the compact grid of all arrays here, (K, L).
        movers: vehicles that are not parked, with known kinematics.
        braking, xy, yaw_rad, length_m, speed_mps: their braking flags, city centres, headings,
            lengths and speeds.
    """
    b = config.behavior
    blocked = np.zeros(movers.shape, dtype=bool)
    braking_for = np.zeros(movers.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        follower = movers & ((speed_mps < b.blocked_speed_mps) | braking)
    fr, fc = np.nonzero(follower)
    if fr.size == 0:
        return blocked, braking_for
    t = city_SE3_ego.shape[0]
    ft = grid.frame[fr, fc]
    # Leaders: the movers of each frame, grouped by frame, then the ego.
    mr, mc = np.nonzero(movers)
    mt = grid.frame[mr, mc]
    order = np.argsort(mt, kind="stable")
    mr, mc, mt = mr[order], mc[order], mt[order]
    offsets = np.searchsorted(mt, np.arange(t + 1))
    counts = offsets[ft + 1] - offsets[ft]
    pair_f = np.repeat(np.arange(fr.size), counts)
    within = np.arange(pair_f.size) - np.repeat(np.cumsum(counts) - counts, counts)
    lead = offsets[ft][pair_f] + within
    lr, lc = mr[lead], mc[lead]
    # The ego: its box centre and length from the bumpers around its origin.
    ego_yaw = np.arctan2(city_SE3_ego[:, 1, 0], city_SE3_ego[:, 0, 0])
    ego_xy = city_SE3_ego[:, :2, 3] + 0.5 * (b.ego_front_m - b.ego_rear_m) * np.stack(
        [np.cos(ego_yaw), np.sin(ego_yaw)], axis=1)
    ego_v = np.zeros(t) if ego_speed_mps is None else np.nan_to_num(ego_speed_mps)
    ego_brake = np.zeros(t, bool) if ego_accel_mps2 is None else np.nan_to_num(ego_accel_mps2) <= -b.braking_decel_mps2
    # Geometry first, on every pair; the rest only for the pairs ahead in the follower's corridor.
    who = np.concatenate([pair_f, np.arange(fr.size)])
    lead_r = np.concatenate([lr, np.full(fr.size, -1)])  # −1: the ego
    lead_c = np.concatenate([lc, np.zeros(fr.size, np.int64)])
    l_xy = np.concatenate([xy[lr, lc], ego_xy[ft]])
    f_yaw = yaw_rad[fr, fc]
    d = l_xy - xy[fr, fc][who]
    c, s = np.cos(f_yaw)[who], np.sin(f_yaw)[who]
    ahead = c * d[:, 0] + s * d[:, 1]
    side = -s * d[:, 0] + c * d[:, 1]
    with np.errstate(invalid="ignore"):
        near = (ahead > 0) & (np.abs(side) <= b.leader_half_width_m) & (lead_r != fr[who])
    who, lead_r, lead_c, ahead = who[near], lead_r[near], lead_c[near], ahead[near]
    ego = lead_r < 0
    lr_, lc_ = np.maximum(lead_r, 0), lead_c
    ft_w = ft[who]
    l_yaw = np.where(ego, ego_yaw[ft_w], yaw_rad[lr_, lc_])
    l_half = 0.5 * np.where(ego, b.ego_front_m + b.ego_rear_m, length_m[lr_, lc_])
    l_speed = np.where(ego, ego_v[ft_w], speed_mps[lr_, lc_])
    l_brake = np.where(ego, ego_brake[ft_w], braking[lr_, lc_])
    gap = ahead - 0.5 * length_m[fr, fc][who] - l_half
    aligned = np.abs(wrap_rad(l_yaw - f_yaw[who])) <= np.radians(b.leader_max_heading_deg)
    with np.errstate(invalid="ignore"):
        ok = aligned & np.isfinite(gap)
    if not ok.any():
        return blocked, braking_for
    who, gap, l_speed, l_brake = who[ok], gap[ok], l_speed[ok], l_brake[ok]
    nearest = np.lexsort((gap, who))
    first = np.r_[True, who[nearest][1:] != who[nearest][:-1]]
    pick = nearest[first]  # the nearest leader of each follower that has one
    f = who[pick]
    g = gap[pick]
    v = speed_mps[fr[f], fc[f]]
    with np.errstate(invalid="ignore"):
        is_blocked = (v < b.blocked_speed_mps) & (g <= b.blocked_gap_m)
        reach = np.maximum(b.braking_for_min_gap_m, b.braking_for_headway_s * v)
        is_for = braking[fr[f], fc[f]] & (g <= reach) & ((l_speed[pick] < v) | l_brake[pick])
    blocked[fr[f], fc[f]] = is_blocked
    braking_for[fr[f], fc[f]] = is_for
    return blocked, braking_for
