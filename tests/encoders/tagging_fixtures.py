"""Small labelled logs and a tiny trained tagging model, for tests and smoke runs.

:func:`add_synthetic_labels` gives the synthetic log of :mod:`tests.encoders.clip_fixtures` behaviour labels
(``lead`` brakes and the ego brakes for it, ``parked`` is parked, ``follower`` keeps its lane) and a
4-way junction outline at city x ∈ [25, 35] m, |y| ≤ 5 m (the ego drives along +x from x = 0).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from encoders.config import BevConfig, TemporalConfig
from scenes.behavior import BEHAVIOR_SCHEMA, BehaviorLabel, write_behavior_labels, write_junctions
from tests.encoders.clip_fixtures import FINE_CLIPS, FRAME_PERIOD_NS, START_NS, synthetic_captions, write_synthetic_log


def add_synthetic_labels(log_dir: Path, num_frames: int) -> None:
    """Write ``behavior_labels.feather`` and ``junctions.feather`` for a synthetic log."""
    rows = []
    for f in range(num_frames):
        ts = START_NS + f * FRAME_PERIOD_NS
        for tid in ("lead", "parked", "follower", "ego"):
            flags = {label.value: False for label in BehaviorLabel}
            flags["braking"] = tid in ("lead", "ego")
            flags["braking_for"] = tid == "ego"
            flags["parked"] = tid == "parked"
            flags["keeping_lane"] = tid == "follower"
            rows.append({"timestamp_ns": ts, "track_id": tid, **flags, "speed_mps": 7.0 if tid == "lead" else 0.0,
                         "leader_id": "lead" if tid == "ego" else None, "junction_id": None})
    write_behavior_labels(log_dir, pa.Table.from_pylist(rows, schema=BEHAVIOR_SCHEMA))
    square_x = [25.0, 35.0, 35.0, 25.0]
    square_y = [-5.0, -5.0, 5.0, 5.0]
    write_junctions(log_dir, pa.table({
        "junction_id": ["J1", "J2"], "kind": ["four_way", "three_way"], "num_arms": pa.array([4, 3], pa.int64()),
        "center_x_m": [30.0, -100.0], "center_y_m": [0.0, 0.0],
        "polygon_x_m": [square_x, [x - 130 for x in square_x]], "polygon_y_m": [square_y, square_y]}))


def tiny_bev_config() -> BevConfig:
    """A BEV tower of a few channels (4 LiDAR height bins and 6 map channels, as the clip stage renders)."""
    return BevConfig(lidar_channels=4, map_channels=6, widths=(4, 8), embed_channels=8, downsample=2,
                     temporal=TemporalConfig(width=16, layers=1, heads=2, max_frames=16))


def build_tagging_fixture(root: Path, num_logs: int = 3, num_frames: int = 12, steps: int = 3) -> dict[str, object]:
    """Labelled synthetic logs, their clips and tag targets, and a tiny tagging run trained ``alone``.

    Returns:
        ``{"logs": [log dirs], "clips": clips dir, "run": run dir}``.
    """
    from encoders.clips.build import build_clips
    from encoders.tagging.config import TagTrainConfig
    from encoders.tagging.targets import add_attribute_targets
    from encoders.tagging.training import train_tags

    logs = [write_synthetic_log(root / "logs", f"tagged_{i}", num_frames=num_frames, with_camera=False,
                                with_lidar=False, seed=i) for i in range(num_logs)]
    for log_dir in logs:
        add_synthetic_labels(log_dir, num_frames)
    (root / "captions").mkdir(parents=True, exist_ok=True)
    pq.write_table(synthetic_captions(logs, 1, num_frames - 2), root / "captions" / "captions.parquet")
    config = dataclasses.replace(FINE_CLIPS, frames_per_clip=4)
    build_clips(logs, root / "captions", root / "clips", config)
    add_attribute_targets(root / "clips", logs)
    cfg = TagTrainConfig(mode="alone", bev=tiny_bev_config(), steps=steps, batch_size=2, window_frames=3,
                         device="cpu", warmup_steps=1)
    train_tags(root / "clips", root / "run", cfg)
    return {"logs": logs, "clips": root / "clips", "run": root / "run"}
