"""Tracker and tracking-metric speed: frames/s with 100 objects per frame on one core.

Tracker baseline, in the same run: the same tracker with one small Kalman filter per object updated
in a Python loop (the layout of AB3DMOT's reference code), instead of one batched filter per frame.
Target: ≥ 200 frames/s.

Metrics (``eval-tracking``: CLEAR-MOT, IDF1 and HOTA over 19 thresholds) baseline, in the same run:
``motmetrics`` computing CLEAR-MOT and IDF1 alone on the same boxes.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from scenes.geometry import FloatArray
from scenes.tracking import Detections, TrackerConfig, kalman, track_detections
from scenes.tracking.evaluate import tracking_counts
from scenes.tracks import Annotations, EgoTrajectory

PERIOD_NS = 100_000_000


def _scene(frames: int, objects: int, seed: int = 0) -> tuple[Detections, EgoTrajectory]:
    rng = np.random.default_rng(seed)
    start = rng.uniform([-40, -40], [60, 40], size=(objects, 2))
    vel = rng.normal(0, 5, size=(objects, 2))
    t = np.arange(frames)[:, None, None] * 0.1
    xy = start[None] + vel[None] * t + rng.normal(0, 0.1, size=(frames, objects, 2))  # (F, N, 2)
    yaw = np.broadcast_to(np.arctan2(vel[:, 1], vel[:, 0]), (frames, objects))
    n = frames * objects
    ts = np.repeat(np.arange(frames, dtype=np.int64) * PERIOD_NS, objects)
    dets = Detections(
        timestamp_ns=ts,
        category=np.array(["car"] * n, dtype=np.str_),
        score=np.full(n, 0.9),
        center_xyz_m=np.concatenate([xy.reshape(n, 2), np.full((n, 1), 0.8)], axis=1),
        size_lwh_m=np.tile([4.5, 1.9, 1.6], (n, 1)),
        yaw_rad=yaw.reshape(n),
        source_line=np.arange(1, n + 1),
    )
    ego = EgoTrajectory.from_xy_yaw(np.arange(frames, dtype=np.int64) * PERIOD_NS, np.zeros((frames, 2)),
                                    np.zeros(frames))
    return dets, ego


@contextmanager
def _per_object_filters() -> Iterator[None]:
    """Swap the batched filter for a loop of single-object filters."""
    batched_predict, batched_update = kalman.predict, kalman.update

    def predict(states: FloatArray, cov: FloatArray, dt_s: float, cfg: TrackerConfig) -> tuple[FloatArray, FloatArray]:
        out = [batched_predict(states[i : i + 1], cov[i : i + 1], dt_s, cfg) for i in range(states.shape[0])]
        if not out:
            return states.copy(), cov.copy()
        return np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out])

    def update(states: FloatArray, cov: FloatArray, meas: FloatArray, cfg: TrackerConfig) -> tuple[
            FloatArray, FloatArray]:
        out = [batched_update(states[i : i + 1], cov[i : i + 1], meas[i : i + 1], cfg) for i in range(states.shape[0])]
        return np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out])

    kalman.predict, kalman.update = predict, update  # type: ignore[assignment]
    try:
        yield
    finally:
        kalman.predict, kalman.update = batched_predict, batched_update


def _time(dets: Detections, ego: EgoTrajectory, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        track_detections(dets, ego, TrackerConfig(), frame_timestamps_ns=ego.timestamps_ns)
        best = min(best, time.perf_counter() - start)
    return best


def _eval_scene(frames: int, objects: int, seed: int = 1) -> tuple[Annotations, Annotations, EgoTrajectory]:
    """Ground truth on a grid 6 m apart and a prediction with noise, misses, switches and false alarms."""
    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid(np.arange(10), np.arange(objects // 10)), -1).reshape(-1, 2) * 6.0
    f = np.repeat(np.arange(frames), objects)
    o = np.tile(np.arange(objects), frames)
    xy = grid[o] + 0.2 * f[:, None]
    keep = rng.random(f.size) > 0.1
    pred_id = np.array([f"p{i}-{j // 50}" for i, j in zip(o, f)])  # a new id every 50 frames
    fp = rng.poisson(2.0, frames)
    pf = np.concatenate([f[keep], np.repeat(np.arange(frames), fp)])
    pxy = np.concatenate([xy[keep] + rng.normal(0, 0.5, (int(keep.sum()), 2)),
                          rng.uniform(-10, 70, (int(fp.sum()), 2))])
    pids = np.concatenate([pred_id[keep], [f"fp{k}" for k in range(int(fp.sum()))]])

    def table(fr: np.ndarray, ids: np.ndarray, centres: np.ndarray) -> Annotations:
        n = fr.size
        return Annotations.from_yaw(fr * PERIOD_NS, ids, ["REGULAR_VEHICLE"] * n,
                                    np.concatenate([centres, np.full((n, 1), 0.8)], 1),
                                    np.tile([4.5, 1.9, 1.6], (n, 1)), np.zeros(n))

    ego = EgoTrajectory.from_xy_yaw(np.arange(frames) * PERIOD_NS, np.zeros((frames, 2)), np.zeros(frames))
    return table(pf, pids, pxy), table(f, np.array([f"g{i}" for i in o]), xy), ego


def _time_eval(frames: int, objects: int) -> tuple[float, float]:
    """Seconds of our metrics and of motmetrics's CLEAR-MOT + IDF1 on the same scene."""
    import motmetrics as mm

    pred, gt, ego = _eval_scene(frames, objects)
    start = time.perf_counter()
    tracking_counts(pred, ego, gt, ego)
    ours_s = time.perf_counter() - start
    start = time.perf_counter()
    acc = mm.MOTAccumulator(auto_id=True)
    number: dict[str, int] = {}
    for ts in np.arange(frames) * PERIOD_NS:
        g, p = gt.timestamp_ns == ts, pred.timestamp_ns == ts
        dist = np.linalg.norm(gt.center_xyz_m[g, None, :2] - pred.center_xyz_m[None, p, :2], axis=2)
        dist[dist > 2.0] = np.nan
        acc.update([number.setdefault(str(t), len(number)) for t in gt.track_id[g]],
                   [number.setdefault(str(t), len(number)) for t in pred.track_id[p]], dist)
    mm.metrics.create().compute(acc, metrics=["mota", "motp", "idf1", "num_switches"])
    return ours_s, time.perf_counter() - start


def run(quick: bool = False) -> dict[str, Any]:
    from threadpoolctl import threadpool_limits

    frames = 100 if quick else 300
    dets, ego = _scene(frames, 100)
    with threadpool_limits(1):  # one core, as the target says
        ours_s = _time(dets, ego, repeats=2 if quick else 3)
        with _per_object_filters():
            base_s = _time(dets, ego, repeats=1)
        eval_s, motmetrics_s = _time_eval(frames, 100)
    return {
        "eval_frames_per_s": round(frames / eval_s, 1),
        "eval_baseline_motmetrics_frames_per_s": round(frames / motmetrics_s, 1),
        "eval_speedup_vs_motmetrics": round(motmetrics_s / eval_s, 2),
        "detections_per_frame": 100,
        "frames": frames,
        "frames_per_s": round(frames / ours_s, 1),
        "baseline_per_object_filters_frames_per_s": round(frames / base_s, 1),
        "speedup_vs_per_object_filters": round(base_s / ours_s, 2),
        "target_frames_per_s": 200,
        "meets_target": frames / ours_s >= 200,
    }
