"""Tracker speed: frames/s with 100 detections per frame on one core.

Baseline, in the same run: the same tracker with one small Kalman filter per object updated in a
Python loop (the layout of AB3DMOT's reference code), instead of one batched filter per frame.
Target: ≥ 200 frames/s.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from scenes.geometry import FloatArray
from scenes.tracking import Detections, TrackerConfig, kalman, track_detections
from scenes.tracks import EgoTrajectory

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


def run(quick: bool = False) -> dict[str, Any]:
    from threadpoolctl import threadpool_limits

    frames = 100 if quick else 300
    dets, ego = _scene(frames, 100)
    with threadpool_limits(1):  # one core, as the target says
        ours_s = _time(dets, ego, repeats=2 if quick else 3)
        with _per_object_filters():
            base_s = _time(dets, ego, repeats=1)
    return {
        "detections_per_frame": 100,
        "frames": frames,
        "frames_per_s": round(frames / ours_s, 1),
        "baseline_per_object_filters_frames_per_s": round(frames / base_s, 1),
        "speedup_vs_per_object_filters": round(base_s / ours_s, 2),
        "target_frames_per_s": 200,
        "meets_target": frames / ours_s >= 200,
    }
