"""Log reading speed: ``Log.open`` (read + validate) rows/s, and packing tracks onto the frame grid.

Synthetic log: 300 tracks × 600 frames at 10 Hz (180k annotation rows; 60 × 150 with ``quick``),
ego poses at 200 Hz. Baseline, in the same run: packing the dense (K, T) arrays with a Python loop
over frames and tracks (interpolating the ego pose per frame), against the vectorised
:func:`scenes.tracks.dense_tracks`. Target: ≥ 10× faster than the loop, ``Log.open`` ≥ 200k rows/s.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from scenes import av2_io
from scenes.geometry import quat_to_rotmat, quat_to_yaw, wrap_angle_rad, yaw_to_quat
from scenes.log import Log
from scenes.tracks import Annotations, DenseTracks, EgoTrajectory, dense_tracks
from scenes.validate import validate_log

T0 = 1_600_000_000_000_000_000


def _synthetic(n_tracks: int, n_frames: int, seed: int = 0) -> tuple[Annotations, EgoTrajectory]:
    rng = np.random.default_rng(seed)
    frame_ts = T0 + np.arange(n_frames, dtype=np.int64) * 100_000_000
    ts = np.repeat(frame_ts, n_tracks)
    ids = np.tile(np.array([f"track{k:05d}" for k in range(n_tracks)]), n_frames)
    n = ts.shape[0]
    ann = Annotations.from_yaw(ts, ids, np.full(n, "REGULAR_VEHICLE"), rng.normal(size=(n, 3)) * 30,
                               rng.uniform(1, 5, (n, 3)), rng.uniform(-np.pi, np.pi, n))
    pose_ts = T0 + np.arange(n_frames * 20, dtype=np.int64) * 5_000_000
    t_s = (pose_ts - T0) * 1e-9
    ego = EgoTrajectory(pose_ts, yaw_to_quat(0.05 * t_s), np.c_[10 * t_s, np.sin(t_s), np.zeros_like(t_s)])
    return ann, ego


def _dense_loop(ann: Annotations, ego: EgoTrajectory) -> np.ndarray:
    """Reference: per-frame, per-row Python loop producing the (K, T, 3) city-frame centres."""
    frame_ts = sorted({int(t) for t in ann.timestamp_ns})
    track_ids = sorted({str(t) for t in ann.track_id})
    k_of = {tid: k for k, tid in enumerate(track_ids)}
    out = np.full((len(track_ids), len(frame_ts), 3), np.nan)
    yaw = ann.yaw_rad
    for f, ts in enumerate(frame_ts):
        pose = ego.interpolate(np.array([ts]))
        rot = quat_to_rotmat(pose.quat_wxyz[0])
        ego_yaw = float(quat_to_yaw(pose.quat_wxyz[0]))
        for row in np.flatnonzero(ann.timestamp_ns == ts):
            out[k_of[str(ann.track_id[row])], f] = rot @ ann.center_xyz_m[row] + pose.translation_m[0]
            wrap_angle_rad(yaw[row] + ego_yaw)
    return out


def _best(fn: Any, repeats: int) -> tuple[float, Any]:
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def run(quick: bool = False) -> dict[str, Any]:
    n_tracks, n_frames = (60, 150) if quick else (300, 600)
    ann, ego = _synthetic(n_tracks, n_frames)
    with tempfile.TemporaryDirectory() as tmp:
        log_dir = Path(tmp) / "bench_log"
        av2_io.write_annotations(log_dir, ann)
        av2_io.write_ego_poses(log_dir, ego)
        open_s, log = _best(lambda: Log.open(log_dir), 3)
        validate_s, report = _best(lambda: validate_log(log_dir), 1)
        assert report.ok, report.problems
        dense_s, dense = _best(lambda: dense_tracks(log.annotations, log.ego), 3)
        loop_s, reference = _best(lambda: _dense_loop(log.annotations, log.ego), 1)
    assert isinstance(dense, DenseTracks)
    np.testing.assert_allclose(dense.center_city_xyz_m, reference, atol=1e-6)
    return {
        "rows": len(ann),
        "log_open_s": round(open_s, 4),
        "log_open_rows_per_s": round(len(ann) / open_s),
        "validate_log_s": round(validate_s, 4),
        "dense_tracks_s": round(dense_s, 4),
        "dense_loop_baseline_s": round(loop_s, 4),
        "dense_speedup_vs_loop": round(loop_s / dense_s, 1),
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run(quick=True), indent=2))
