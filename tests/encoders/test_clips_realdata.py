"""Clips from real logs: the development AV2 log with real sweeps and a KITTI sequence (tracks only)
load through the same dataset class. Skipped when ../shared/realdata is absent."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from encoders.clips.build import build_clips
from encoders.clips.config import BevSourceChoice, ClipsConfig
from encoders.data import ClipDataset, collate_clips
from scenes.log import Log
from tests.realdata import REALDATA

AV2_LOG = REALDATA / "av2" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
KITTI = REALDATA / "kitti_tracking"

needs_av2 = pytest.mark.skipif(not AV2_LOG.is_dir(), reason=f"real AV2 development log not found at {AV2_LOG}")
needs_kitti = pytest.mark.skipif(
    not (KITTI / "label_02" / "0001.txt").is_file(), reason=f"KITTI tracking sequence 0001 not found under {KITTI}"
)


def _captions(log: Log, first: int, last: int, min_points: int = 0) -> list[dict]:
    """One caption per track observed over frames first..last (a hand-written captions.parquet)."""
    dense = log.dense_tracks()
    ts = dense.timestamps_ns
    rows = []
    ann = log.annotations
    at_last = ann.timestamp_ns == ts[last]
    points = dict(zip(ann.track_id[at_last], ann.num_interior_pts[at_last]))
    for k, track_id in enumerate(dense.track_ids):
        if not dense.valid[k, first : last + 1].all() or (min_points and points.get(track_id, 0) < min_points):
            continue
        x, y = dense.center_ego_xyz_m[k, last, :2]
        if not (-18 < x < 58 and -18 < y < 18):
            continue
        caption = f"a {dense.categories[k]} nearby"
        rows.append({"log_id": log.log_id, "track_id": str(track_id), "category": str(dense.categories[k]),
                     "start_ns": int(ts[first]), "end_ns": int(ts[last]), "tags": ["front:stationary"],
                     "caption": caption, "canonical_caption": caption, "paraphrases": [], "host_tags": []})
    return rows


@needs_av2
def test_av2_log_with_real_sweeps(tmp_path: Path) -> None:
    log = Log.open(AV2_LOG)
    frames = np.searchsorted(log.timestamps_ns, log.lidar_timestamps_ns)
    first, last = int(frames[0]), int(frames[-1])  # the two frames that have real sweeps
    rows = _captions(log, first, last, min_points=30)
    assert len(rows) >= 5
    (tmp_path / "c").mkdir()
    pq.write_table(pa.Table.from_pylist(rows), tmp_path / "c" / "captions.parquet")
    # Sweeps cover 2 of 156 frames: 'auto' would render boxes; ask for LiDAR and cut clips around the sweeps.
    config = replace(ClipsConfig(), previews=False, bev=replace(ClipsConfig().bev, source=BevSourceChoice.LIDAR))
    report = build_clips([AV2_LOG], tmp_path / "c", tmp_path / "clips", config)
    stats = report.logs[log.log_id]
    assert stats["bev_source"] == "lidar" and stats["frames_without_sweep"] == 154 and not stats["corrupt_sweeps"]
    ds = ClipDataset(tmp_path / "clips")
    assert len(ds) == len(rows)
    batch = collate_clips([ds[i] for i in range(len(ds))])
    assert not batch["has_camera"].any()  # calibration but no images
    occupied = batch["bev_lidar"][:, :, 1:].amax(dim=2) > 0  # (B, T, H, W), above the ground bin
    obj = batch["bev_object"][:, :, 0] > 0.5
    # Real geometry: the annotated boxes with LiDAR points inside sit on occupied cells, far more
    # often than cells at random.
    inside = float((occupied & obj).sum() / obj.sum())
    overall = float(occupied.float().mean())
    assert inside > 0.4 and inside > 2.5 * overall
    # Box-rendered BEV of the same log ('auto'): flagged, and the boxes fill their own cells.
    report = build_clips([AV2_LOG], tmp_path / "c", tmp_path / "clips_boxes", replace(config, bev=ClipsConfig().bev))
    assert report.logs[log.log_id]["bev_source"] == "boxes"
    boxes = ClipDataset(tmp_path / "clips_boxes")
    item = boxes[0]
    assert float((item["bev_lidar"][:, 1:].amax(dim=1)[item["bev_object"][:, 0] > 0.5] > 0).float().mean()) > 0.9


@needs_kitti
def test_kitti_sequence_without_sensors(tmp_path: Path) -> None:
    from scenes.kitti import import_kitti_sequence

    report = import_kitti_sequence(KITTI / "label_02" / "0001.txt", KITTI / "poses_orbslam3" / "0001.txt",
                                   KITTI / "calib" / "0001.txt", tmp_path / "logs")
    log = Log.open(report.log_dir)
    rows = []
    for start in range(0, len(log.timestamps_ns) - 30, 30):
        rows += [r for r in _captions(log, start, start + 29) if r["track_id"] not in {x["track_id"] for x in rows}]
    assert len(rows) >= 3
    (tmp_path / "c").mkdir()
    pq.write_table(pa.Table.from_pylist(rows), tmp_path / "c" / "captions.parquet")
    result = build_clips([report.log_dir], tmp_path / "c", tmp_path / "clips", replace(ClipsConfig(), previews=False))
    assert result.logs[log.log_id]["bev_source"] == "boxes"
    ds = ClipDataset(tmp_path / "clips")
    batch = collate_clips([ds[i] for i in range(len(ds))])
    assert batch["bev_object"].shape[0] == len(rows) and not batch["has_camera"].any()
    # Each clip's object is marked in most of its frames, on cells the box-rendered occupancy fills.
    marked = batch["bev_object"][:, :, 0] > 0.5  # (B, T, H, W)
    assert float(marked.flatten(2).any(dim=2).float().mean()) > 0.9
    occupied = batch["bev_lidar"][:, :, 1:].amax(dim=2) > 0
    assert float((occupied & marked).sum() / marked.sum()) > 0.95
    augmented = ClipDataset(tmp_path / "clips", augment=True)[0]
    assert augmented["bev_lidar"].shape == batch["bev_lidar"].shape[1:]
