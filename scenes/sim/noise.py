"""What a real LiDAR detector and tracker do to perfect boxes.

Applied in this order, each step seeded by the caller's generator:

1. range: boxes whose centre is beyond ``max_range_m`` from the ego are not detected;
2. occlusion: seen from the ego origin, a box is dropped when at least ``occlusion_fraction`` of
   its angular extent is covered by boxes whose centres are nearer (a 2-D ray test);
3. misses: each remaining box is missed with ``miss_probability``;
4. id switches: events arrive per track as a Poisson process of rate ``id_switch_rate_per_s``;
   after the k-th one the track continues under a new id;
5. jitter: Gaussian noise on the centre (x, y) and on the yaw (:func:`jitter_boxes`, which alone is
   what real labels carry: the simulator's ``jitter_share`` logs).
"""

from __future__ import annotations

import uuid

import numpy as np
from numpy.typing import NDArray

from scenes.geometry import quat_to_yaw, wrap_angle_rad, yaw_to_quat
from scenes.sim.config import TrackerNoiseConfig
from scenes.tracks import Annotations, EgoTrajectory

_SWITCH_NAMESPACE = uuid.UUID("6f1c5bde-2b7e-4d8e-9a57-3c0d7f4f2a10")


def box_corners_xy(center_xy_m: NDArray[np.float64], size_lw_m: NDArray[np.float64],
                   yaw_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """Footprint corners of upright boxes.

    Args:
        center_xy_m: (N, 2) centres.
        size_lw_m: (N, 2) lengths and widths.
        yaw_rad: (N,) headings.

    Returns:
        (N, 4, 2) corners, counter-clockwise.
    """
    signs = np.array([[0.5, 0.5], [-0.5, 0.5], [-0.5, -0.5], [0.5, -0.5]])
    local = signs[None] * size_lw_m[:, None, :]  # (N, 4, 2)
    c, s = np.cos(yaw_rad)[:, None], np.sin(yaw_rad)[:, None]
    x = local[..., 0] * c - local[..., 1] * s
    y = local[..., 0] * s + local[..., 1] * c
    return np.stack([x, y], axis=-1) + center_xy_m[:, None, :]


def occluded_mask(center_xy_m: NDArray[np.float64], size_lw_m: NDArray[np.float64], yaw_rad: NDArray[np.float64],
                  fraction: float, rays: int) -> NDArray[np.bool_]:
    """Boxes of one frame hidden behind nearer boxes, as seen from the origin.

    Each box's angular extent is sampled by ``rays`` rays; a ray is blocked when it falls inside
    the angular extent of a box whose centre is nearer. A box with at least ``fraction`` of its rays
    blocked is occluded.

    Args:
        center_xy_m: (N, 2) centres in the sensor frame.
        size_lw_m: (N, 2) lengths and widths.
        yaw_rad: (N,) headings in the sensor frame.
        fraction: share of blocked rays that hides a box.
        rays: rays per box.

    Returns:
        (N,) booleans.
    """
    n = center_xy_m.shape[0]
    if n < 2:
        return np.zeros(n, dtype=bool)
    corners = box_corners_xy(center_xy_m, size_lw_m, yaw_rad)  # (N, 4, 2)
    bearing = np.arctan2(center_xy_m[:, 1], center_xy_m[:, 0])  # (N,)
    # Corner angles relative to the box's own bearing: no wrap-around trouble behind the ego.
    rel = wrap_angle_rad(np.arctan2(corners[..., 1], corners[..., 0]) - bearing[:, None])  # (N, 4)
    lo, hi = rel.min(axis=1) + bearing, rel.max(axis=1) + bearing  # (N,)
    dist = np.linalg.norm(center_xy_m, axis=1)
    # A box around the sensor itself has no meaningful angular extent; it is never hidden.
    inside = dist < 0.5 * np.linalg.norm(size_lw_m, axis=1)
    frac = (np.arange(rays) + 0.5) / rays
    ray_angle = lo[:, None] + (hi - lo)[:, None] * frac[None]  # (N, R)
    # Angle of each ray relative to each other box's bearing, then inside that box's extent?
    d = wrap_angle_rad(ray_angle[:, :, None] - bearing[None, None, :])  # (N, R, M)
    covered = (d >= (lo - bearing)[None, None, :]) & (d <= (hi - bearing)[None, None, :])
    nearer = (dist[None, :] < dist[:, None]) & ~np.eye(n, dtype=bool)  # (N, M) M is nearer than N
    blocked = np.any(covered & nearer[:, None, :], axis=2)  # (N, R)
    return (blocked.mean(axis=1) >= fraction) & ~inside


def apply_tracker_noise(
    annotations: Annotations, ego: EgoTrajectory, config: TrackerNoiseConfig, rng: np.random.Generator
) -> Annotations:
    """Degrade perfect annotations as a LiDAR detector and tracker would.

    Args:
        annotations: perfect boxes in the ego frame (the sensor sits at the ego origin).
        ego: the log's ``city_SE3_ego``; frames outside its time span are dropped (a detector only
            runs while the vehicle's pose is known).
        config: the noise model.
        rng: the source of randomness; the same generator state gives the same output.

    Returns:
        New annotations, sorted by (timestamp, track id); the input is not changed.
    """
    ann = annotations.sorted()
    n = len(ann)
    if n == 0:
        return ann
    ts = ann.timestamp_ns
    keep = (ts >= ego.timestamps_ns[0]) & (ts <= ego.timestamps_ns[-1])
    center = ann.center_xyz_m
    keep &= np.linalg.norm(center[:, :2], axis=1) <= config.max_range_m
    yaw = ann.yaw_rad
    frame_starts = np.flatnonzero(np.r_[True, ts[1:] != ts[:-1]])
    frame_ends = np.r_[frame_starts[1:], n]
    for a, b in zip(frame_starts, frame_ends):
        idx = a + np.flatnonzero(keep[a:b])
        if idx.size < 2:
            continue
        hidden = occluded_mask(center[idx, :2], ann.size_lwh_m[idx, :2], yaw[idx],
                               config.occlusion_fraction, config.occlusion_rays)
        keep[idx[hidden]] = False
    keep &= rng.random(n) >= config.miss_probability
    ann = ann.select(keep)
    n = len(ann)
    if n == 0:
        return ann

    track_ids = ann.track_id.copy()
    uniq, inverse = np.unique(ann.track_id, return_inverse=True)
    t0 = np.full(uniq.shape[0], np.iinfo(np.int64).max)
    t1 = np.full(uniq.shape[0], np.iinfo(np.int64).min)
    np.minimum.at(t0, inverse, ann.timestamp_ns)
    np.maximum.at(t1, inverse, ann.timestamp_ns)
    span_s = (t1 - t0).astype(np.float64) * 1e-9
    counts = rng.poisson(config.id_switch_rate_per_s * span_s)
    if counts.any():
        for k in np.flatnonzero(counts):
            rows = np.flatnonzero(inverse == k)
            switch_ns = np.sort(rng.integers(t0[k], t1[k] + 1, size=int(counts[k])))
            generation = np.searchsorted(switch_ns, ann.timestamp_ns[rows], side="right")
            for g in np.unique(generation[generation > 0]):
                new_id = str(uuid.uuid5(_SWITCH_NAMESPACE, f"{uniq[k]}/{g}"))
                track_ids[rows[generation == g]] = new_id

    ann = Annotations(ann.timestamp_ns, track_ids, ann.category, ann.center_xyz_m, ann.size_lwh_m, ann.quat_wxyz,
                      ann.num_interior_pts)
    return jitter_boxes(ann, config, rng)


def jitter_boxes(annotations: Annotations, config: TrackerNoiseConfig, rng: np.random.Generator) -> Annotations:
    """Every box with Gaussian noise on its centre (x, y; ``center_std_m``) and heading (``yaw_std_rad``),
    and nothing else: the frame-to-frame scatter of real labels, hand-drawn or automatic.

    The noise is drawn row by row in the given order, so the same generator state and rows give the
    same boxes.

    Returns:
        New annotations, sorted by (timestamp, track id); the input is not changed.
    """
    a, n = annotations, len(annotations)
    noisy_center = a.center_xyz_m.copy()
    noisy_center[:, :2] += rng.normal(0.0, config.center_std_m, size=(n, 2))
    noisy_yaw = wrap_angle_rad(quat_to_yaw(a.quat_wxyz) + rng.normal(0.0, config.yaw_std_rad, size=n))
    return Annotations(a.timestamp_ns, a.track_id, a.category, noisy_center, a.size_lwh_m,
                       yaw_to_quat(noisy_yaw), a.num_interior_pts).sorted()
