"""Captions from tracker output against captions from ground truth, on real KITTI detections."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from captioning.robustness import caption_agreement, match_tracks
from scenes.kitti import import_kitti_sequence
from scenes.log import Log
from scenes.tracking import TrackerConfig, import_kitti_detections
from tests.realdata import REALDATA

KITTI = REALDATA / "kitti_tracking"


def test_match_tracks_pairs_nearest_within_the_threshold() -> None:
    ts = np.array([0, 1])
    gt = np.array([[[0.0, 0.0], [1.0, 0.0]], [[10.0, 0.0], [np.nan, np.nan]]])
    pred = np.array([[[10.5, 0.0], [50.0, 0.0]], [[0.2, 0.1], [1.1, 0.0]]])
    np.testing.assert_array_equal(match_tracks(ts, gt, ts, pred, 2.0), [[1, 1], [0, -1]])


@pytest.mark.skipif(not KITTI.is_dir(), reason="../shared/realdata/kitti_tracking is absent")
def test_tracked_captions_agree_with_ground_truth_captions(tmp_path: Path) -> None:
    seq = "0006"
    poses, calib = KITTI / "poses_orbslam3" / f"{seq}.txt", KITTI / "calib" / f"{seq}.txt"
    gt = import_kitti_sequence(KITTI / "label_02" / f"{seq}.txt", poses, calib, tmp_path / "gt")
    dets = [KITTI / "detection_pointrcnn" / c / f"{seq}.txt" for c in ("Car", "Pedestrian", "Cyclist")]
    pred = import_kitti_detections(dets, poses, calib, tmp_path / "pred", TrackerConfig(score_threshold=0.9))
    agreement = caption_agreement(Log.open(pred.log_dir), Log.open(gt.log_dir))
    # Measured: 13 of 17 captions matched, all 13 with the same tag sequence; frame tags agree > 99%.
    assert agreement.gt_captions >= 10
    assert agreement.matched >= 0.6 * agreement.gt_captions
    assert agreement.sequence_agreement_matched >= 0.8
    assert agreement.frame_lane_agreement >= 0.95 and agreement.frame_motion_agreement >= 0.95
    # Identical logs agree completely.
    same = caption_agreement(Log.open(gt.log_dir), Log.open(gt.log_dir))
    assert same.sequence_agreement == 1.0 and same.frame_lane_agreement == 1.0
