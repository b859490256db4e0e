"""Simulated detections → tracker → metrics, on ground truth with known motion."""

from __future__ import annotations

import numpy as np

from scenes.sim.config import TrackerNoiseConfig
from scenes.tracking import TrackerConfig, track_detections
from scenes.tracking.evaluate import evaluate_tracking
from scenes.tracking.simulated import DetectorNoiseConfig, simulate_detections
from scenes.tracks import Annotations, EgoTrajectory

PERIOD_NS = 100_000_000


def _ground_truth(frames: int = 80, cars: int = 8, seed: int = 0) -> tuple[Annotations, EgoTrajectory]:
    """Cars each in its own lane, moving with the traffic, the ego driving along x at 8 m/s.

    Speeds stay near the ego's, so every car stays within the detector's range all along.
    """
    rng = np.random.default_rng(seed)
    ts = np.arange(frames, dtype=np.int64) * PERIOD_NS
    ego_x = 0.8 * np.arange(frames)
    ego = EgoTrajectory.from_xy_yaw(ts, np.stack([ego_x, np.zeros(frames)], 1), np.zeros(frames))
    x0 = rng.uniform(-15, 45, cars)
    lane_y = (np.arange(cars) - cars / 2 + 0.5) * 3.5 + rng.normal(0, 0.2, cars)
    v = rng.uniform(5, 11, cars)
    rows_t, rows_id, rows_c = [], [], []
    for f in range(frames):
        city_x = x0 + v * f * 0.1
        rows_t.append(np.full(cars, ts[f]))
        rows_id.append([f"car{i}" for i in range(cars)])
        rows_c.append(np.stack([city_x - ego_x[f], lane_y, np.full(cars, 0.8)], 1))
    center = np.concatenate(rows_c)
    yaw = np.zeros(len(center))
    ann = Annotations.from_yaw(np.concatenate(rows_t), np.concatenate(rows_id), ["REGULAR_VEHICLE"] * len(center),
                               center, np.tile([4.5, 1.9, 1.6], (len(center), 1)), yaw)
    return ann, ego


def test_detections_are_deterministic_and_degraded() -> None:
    gt, ego = _ground_truth()
    cfg = DetectorNoiseConfig(false_positives_per_frame=1.0)
    a = simulate_detections(gt, ego, cfg, np.random.default_rng(3))
    b = simulate_detections(gt, ego, cfg, np.random.default_rng(3))
    np.testing.assert_array_equal(a.center_xyz_m, b.center_xyz_m)
    true_count = int((a.score > 0).sum())
    assert true_count > 0
    # Misses and occlusion remove some real boxes; false positives add about one per frame.
    real = len(a) - np.sum(np.isin(a.category, ["pedestrian", "cyclist"]))
    assert real < len(gt) + 2 * 80
    assert ((a.score >= 0) & (a.score <= 1)).all()


def test_tracking_simulated_detections_recovers_the_ground_truth() -> None:
    gt, ego = _ground_truth()
    noise = DetectorNoiseConfig(tracker_noise=TrackerNoiseConfig(miss_probability=0.1, center_std_m=0.15,
                                                                 occlusion_fraction=1.0),
                                false_positives_per_frame=1.0)
    dets = simulate_detections(gt, ego, noise, np.random.default_rng(0))
    pred = track_detections(dets, ego, TrackerConfig(score_threshold=0.5), frame_timestamps_ns=ego.timestamps_ns)
    car = evaluate_tracking(pred, ego, gt, ego)["car"]
    assert car["MOTA"] > 0.8, car
    assert car["IDSW"] <= 3, car
    # Without noise the tracker reproduces the truth almost exactly (births cost nothing offline).
    clean = DetectorNoiseConfig(tracker_noise=TrackerNoiseConfig(miss_probability=0.0, center_std_m=0.0,
                                                                 yaw_std_rad=0.0, occlusion_fraction=1.0),
                                false_positives_per_frame=0.0)
    dets = simulate_detections(gt, ego, clean, np.random.default_rng(0))
    pred = track_detections(dets, ego, TrackerConfig(score_threshold=0.0), frame_timestamps_ns=ego.timestamps_ns)
    perfect = evaluate_tracking(pred, ego, gt, ego)["car"]
    assert perfect["MOTA"] > 0.98 and perfect["IDSW"] == 0, perfect
