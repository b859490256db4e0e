"""``scenesearch render-sensors LOG_DIR ...``: simulate LiDAR sweeps and camera frames for logs.

Writes, per log, ``sensors/lidar/<ns>.feather``, ``sensors/cameras/<camera>/<ns>.jpg``, instance
masks beside them and the calibration, from the log's annotations, ego poses, map and metadata.
A log that cannot be rendered is reported with the reason and skipped; the exit status is 1 then,
and 2 when no log could be rendered.
A flag's value above its upper bound in :mod:`scenes.sensorsim.config` (``--beams``, ``--azimuth-steps``,
``--width``, ``--height``) or ``--threads`` above :data:`MAX_THREADS` is refused before any log is read,
naming the flag.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from scenesearch_base.config import check_flag_bound, with_option

#: Ray-casting threads ``--threads`` may ask for, at most.
MAX_THREADS = 1024

HELP = "render simulated LiDAR sweeps, camera frames and instance masks for logs"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log_dirs", nargs="+", type=Path, metavar="LOG_DIR", help="log folders (AV2 layout)")
    parser.add_argument("--config", type=Path, help="SensorConfig YAML; the flags below override it")
    parser.add_argument("--seed", type=int, help="noise and building placement seed")
    parser.add_argument("--beams", type=int, help="LiDAR beams")
    parser.add_argument("--azimuth-steps", type=int, help="LiDAR firings per revolution")
    parser.add_argument("--width", type=int, help="camera image width in pixels")
    parser.add_argument("--height", type=int, help="camera image height in pixels")
    parser.add_argument("--no-lidar", action="store_true", help="skip the LiDAR")
    parser.add_argument("--no-camera", action="store_true", help="skip the camera and instance masks")
    parser.add_argument("--threads", type=int, default=0, help="ray-casting threads (0: all cores)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def build_config(args: argparse.Namespace) -> object:
    from scenes.sensorsim.config import SensorConfig

    config = SensorConfig.from_yaml(args.config) if args.config else SensorConfig()
    lidar, camera = config.lidar, config.camera
    if args.beams is not None:
        lidar = with_option(lidar, "--beams", beams=args.beams)
    if args.azimuth_steps is not None:
        lidar = with_option(lidar, "--azimuth-steps", azimuth_steps=args.azimuth_steps)
    if args.width is not None:
        camera = with_option(camera, "--width", width_px=args.width)
    if args.height is not None:
        camera = with_option(camera, "--height", height_px=args.height)
    if args.threads < 0:
        raise ValueError(f"--threads {args.threads}: must be at least 0 (0: all cores)")
    check_flag_bound("--threads", args.threads, MAX_THREADS)
    return dataclasses.replace(
        config,
        lidar=lidar,
        camera=camera,
        seed=config.seed if args.seed is None else args.seed,
        render_lidar=config.render_lidar and not args.no_lidar,
        render_camera=config.render_camera and not args.no_camera,
    )


def run(args: argparse.Namespace) -> int:
    from scenes.errors import ScenesError
    from scenes.sensorsim.config import SensorConfig
    from scenes.sensorsim.render import render_log_sensors

    config = build_config(args)
    assert isinstance(config, SensorConfig)
    failed = 0
    for log_dir in args.log_dirs:
        try:
            report = render_log_sensors(log_dir, config, progress=not args.quiet, nthreads=args.threads)
        except ScenesError as exc:
            failed += 1
            print(f"skipped {log_dir}: {exc}", file=sys.stderr)
            continue
        print(report.summary())
    if failed:
        print(f"{failed} of {len(args.log_dirs)} logs skipped", file=sys.stderr)
    return 2 if failed == len(args.log_dirs) else 1 if failed else 0
