"""``scenesearch track``: per-frame 3D detections → tracks, written as a new log."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

HELP = "track per-frame 3D detections (Parquet/feather table) of a log into a new log with tracks"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log_dir", type=Path, help="the log (its ego poses are used; annotations are replaced)")
    parser.add_argument("--detections", type=Path, required=True,
                        help="table: timestamp_ns, category, score, tx_m, ty_m, tz_m, length_m, width_m, height_m, "
                             "yaw_rad (ego frame)")
    parser.add_argument("--out", type=Path, required=True, help="folder that receives <log_id>/")
    parser.add_argument("--config", type=Path, help="tracker YAML (keys of scenes.tracking.TrackerConfig)")
    parser.add_argument("--score-threshold", type=float, help="ignore detections scoring below this (overrides config)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output log")


def run(args: argparse.Namespace) -> int:
    from scenes.tracking.config import TrackerConfig
    from scenes.tracking.log_tracking import track_log

    config = TrackerConfig.from_yaml(args.config) if args.config else TrackerConfig()
    if args.score_threshold is not None:
        config = replace(config, score_threshold=args.score_threshold)
    report = track_log(args.log_dir, args.detections, args.out, config, overwrite=args.overwrite)
    print(f"{report.log_dir}: {report.tracks} tracks, {report.rows} boxes from {report.detections} detections "
          f"over {report.frames} frames")
    return 0
