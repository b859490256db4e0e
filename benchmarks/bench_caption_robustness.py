"""Tracking quality and caption robustness: detections → tracker → captions, against ground truth.

Per sequence: CLEAR-MOT/IDF1 of the tracker (centre distance ≤ 2 m) and how often captions from
tracker output agree with captions from ground-truth tracks (:mod:`captioning.robustness`).
Sources: the development KITTI sequences with real PointRCNN detections (score ≥ 0.9), when
``../shared/realdata`` is present, and simulated logs with simulated detections.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from captioning.robustness import caption_agreement
from scenes.kitti import import_kitti_sequence
from scenes.log import Log
from scenes.sim import SimulationConfig, simulate
from scenes.tracking import TrackerConfig, import_kitti_detections
from scenes.tracking.evaluate import evaluate_tracking
from scenes.tracking.log_tracking import track_log
from scenes.tracking.simulated import write_simulated_detections

KITTI = Path(__file__).resolve().parents[1] / ".." / "shared" / "realdata" / "kitti_tracking"
#: Development sequences of KITTI's validation split (the others are reserved for acceptance).
KITTI_SEQUENCES = ("0001", "0006", "0008", "0010")
#: AB3DMOT's published figures on KITTI val, Car, same PointRCNN detections (3D IoU matching, all
#: eleven val sequences, KITTI's ignore regions): for reference only, not the same protocol.
AB3DMOT_PUBLISHED_CAR = {"MOTA": 0.8624, "MOTP": 0.7843}


def _figures(pred: Log, gt: Log) -> dict[str, Any]:
    metrics = evaluate_tracking(pred.annotations, pred.ego, gt.annotations, gt.ego)
    return {"tracking": {c: {k: m[k] for k in ("MOTA", "MOTP", "IDF1", "IDSW")} for c, m in metrics.items()},
            "captions": caption_agreement(pred, gt).to_dict()}


def run(quick: bool = False) -> dict[str, Any]:
    out: dict[str, Any] = {"kitti": {}, "simulated": {}, "ab3dmot_published_car": AB3DMOT_PUBLISHED_CAR}
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        if KITTI.is_dir():
            for seq in KITTI_SEQUENCES[:2] if quick else KITTI_SEQUENCES:
                poses, calib = KITTI / "poses_orbslam3" / f"{seq}.txt", KITTI / "calib" / f"{seq}.txt"
                gt = import_kitti_sequence(KITTI / "label_02" / f"{seq}.txt", poses, calib, tmp / "gt")
                dets = [KITTI / "detection_pointrcnn" / c / f"{seq}.txt" for c in ("Car", "Pedestrian", "Cyclist")]
                pred = import_kitti_detections(dets, poses, calib, tmp / "pred", TrackerConfig(score_threshold=0.9))
                out["kitti"][seq] = _figures(Log.open(pred.log_dir), Log.open(gt.log_dir))
        else:
            out["kitti"] = "skipped: ../shared/realdata/kitti_tracking is absent"
        config = SimulationConfig(logs=2 if quick else 4, duration_s=20, seed=3, sensors=False)
        for log_dir in simulate(config, tmp / "sim"):
            write_simulated_detections(log_dir, seed=config.seed)
            tracked = track_log(log_dir, log_dir / "detections.parquet", tmp / "sim_tracked")
            out["simulated"][log_dir.name] = _figures(Log.open(tracked.log_dir), Log.open(log_dir))
    return out
