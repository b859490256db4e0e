"""``scenesearch simulate --out DIR --logs N --duration-s S --seed K [--network grid|spider|random]``.

Writes N logs of a SUMO-simulated city in the AV2 layout, with behaviour labels and appearance
metadata (see :mod:`scenes.sim`). Deterministic for a given seed. Flags override the values of
``--config FILE.yaml`` (a serialised :class:`scenes.sim.SimulationConfig`). SUMO runs once; writing
each log and rendering its sensors is one task per log, on Ray with ``--workers N`` or
``--ray-address`` (:mod:`scenesearch_base.ray_runner`), with the same bytes as the serial path. ``--out`` may
be a ``pyarrow.fs`` URI. A flag's value above its upper bound in :class:`scenes.sim.SimulationConfig`
(e.g. ``--logs``, ``--duration-s``, ``--egos``) is refused before anything is simulated, naming the flag.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scenes.sim import NetworkKind, PostLogHook, SimulationConfig, simulate_tracks_and_map
from scenesearch_base.config import with_option
from scenesearch_base.ray_cluster import Execution
from scenesearch_base.ray_cluster import add_arguments as add_execution_arguments
from scenesearch_base.storage import as_location

#: The flag that sets each field of :class:`SimulationConfig` (what an error names).
FLAGS = {"logs": "--logs", "duration_s": "--duration-s", "seed": "--seed", "warmup_s": "--warmup-s",
         "egos_per_run": "--egos", "tracker_noise": "--tracker-noise", "sensors": "--no-sensors",
         "map_less_share": "--map-less-share", "jitter_share": "--jitter-share",
         "furniture_per_km": "--furniture-per-km", "standing_pedestrians_per_km": "--standing-pedestrians-per-km",
         "cache_dir": "--cache-dir"}

HELP = "simulate a city with SUMO and write N drive logs (AV2 layout, behaviour labels)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="folder (or URI) to write the logs into")
    parser.add_argument("--config", type=Path, help="YAML simulation config; flags override its values")
    parser.add_argument("--logs", type=int, help="number of logs (default 8)")
    parser.add_argument("--duration-s", type=float, help="length of each log in seconds (default 25)")
    parser.add_argument("--seed", type=int, help="seed of network, traffic and appearance (default 0)")
    parser.add_argument("--network", metavar="{grid,spider,random}", help="road network layout (default grid)")
    parser.add_argument("--warmup-s", type=float, help="simulated seconds before the first log (default 60)")
    parser.add_argument("--egos", type=int, dest="egos_per_run", help="egos driving at once (default 4)")
    parser.add_argument("--tracker-noise", action="store_true", default=None,
                        help="degrade boxes as a LiDAR detector and tracker would (labels stay exact)")
    parser.add_argument("--no-sensors", dest="sensors", action="store_false", default=None,
                        help="skip rendering LiDAR sweeps and camera frames (tracks, map and labels only)")
    parser.add_argument("--map-less-share", type=float, metavar="F",
                        help="share of the logs written without their map, as track-only real logs come (default 0)")
    parser.add_argument("--jitter-share", type=float, metavar="F",
                        help="share of the logs whose boxes scatter from frame to frame as real labels do "
                             "(default 0)")
    parser.add_argument("--furniture-per-km", type=float, metavar="R",
                        help="groups of cones, bollards, barrels and signs (category other) per km of sidewalk "
                             "(default 1.5; 0: none)")
    parser.add_argument("--standing-pedestrians-per-km", type=float, metavar="R",
                        help="groups of people standing still per km of sidewalk (default 1; 0: none)")
    parser.add_argument("--sensor-config", type=Path,
                        help="YAML sensor config (scenes.sensorsim.SensorConfig): beams, resolution, camera size")
    parser.add_argument("--emit-detections", action="store_true",
                        help="also write <log>/detections.parquet: per-frame detections without ids, simulated from "
                             "the boxes (misses, false positives, noise), for `scenesearch track`")
    parser.add_argument("--cache-dir", help="folder for generated road networks (default: system temp)")
    parser.add_argument("--overwrite", action="store_true", help="replace logs already in --out")
    add_execution_arguments(parser)


def build_config(args: argparse.Namespace) -> SimulationConfig:
    """The config file's values, overridden by the flags given."""
    config = SimulationConfig.from_yaml(args.config) if args.config else SimulationConfig()
    for name, flag in FLAGS.items():
        value = getattr(args, name, None)
        if value is not None:
            config = with_option(config, flag, **{name: value})
    if args.network is not None:
        config = with_option(config, "--network", network=NetworkKind.parse(args.network))
    return config


def post_log_hooks(config: SimulationConfig, emit_detections: bool = False,
                   sensor_config: Path | None = None) -> list[PostLogHook]:
    """Steps run on each log folder before it is renamed into place, so a log appears whole or not at all."""
    hooks: list[PostLogHook] = []
    if config.sensors:
        from dataclasses import replace

        from scenes.sensorsim.config import SensorConfig
        from scenes.sensorsim.render import render_log_sensors

        base = SensorConfig.from_yaml(sensor_config) if sensor_config else SensorConfig()
        sensors = replace(base, seed=config.seed) if sensor_config is None else base

        def render(log_dir: Path) -> None:
            render_log_sensors(log_dir, sensors, progress=False)

        hooks.append(render)
    if emit_detections:
        from scenes.tracking.simulated import write_simulated_detections

        def emit(log_dir: Path) -> None:
            # The hook sees the log under its temporary name: seed from the log's own id.
            from scenes.av2_io import read_metadata

            meta = read_metadata(log_dir)
            write_simulated_detections(log_dir, seed=config.seed, log_id=meta.log_id if meta else None)

        hooks.append(emit)
    return hooks


def run(args: argparse.Namespace) -> int:
    config = build_config(args)
    hooks = post_log_hooks(config, args.emit_detections, args.sensor_config)
    result = simulate_tracks_and_map(config, as_location(args.out), overwrite=args.overwrite, post_log=hooks,
                                     execution=Execution.from_args(args))
    for log_dir in result.log_dirs:
        print(log_dir)
    print(f"wrote {len(result.log_dirs)} logs of {config.duration_s:g} s ({config.network.value}, seed "
          f"{config.seed}) in {result.wall_s:.1f} s: {result.simulated_s:.0f} simulated s, "
          f"{result.realtime_factor:.0f}x real time")
    return 0
