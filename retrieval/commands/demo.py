"""``scenesearch demo``: the whole pipeline on a small simulated city, ending with ``DIR/report.html``.

Each size flag is checked against the upper bound of the config field it ends up in (``--logs`` against
:class:`scenes.sim.SimulationConfig`'s ``logs``, ``--epochs`` against :class:`encoders.train_config.TrainConfig`'s,
...; ``--workers`` against :data:`MAX_WORKERS`) before the first stage runs, so that a value a later
stage would refuse stops the demo at once, naming the flag.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scenesearch_base.config import check_flag_bound

#: Ray workers ``--workers`` may ask for, at most.
MAX_WORKERS = 1024

HELP = "simulate, caption, build clips, train, index and evaluate a small city; write DIR/report.html"


def configure(parser: argparse.ArgumentParser) -> None:
    from encoders.presets import preset_names
    from retrieval.demo_config import VAL_FRACTION
    from retrieval.demo_config import DemoConfig as D  # the defaults the help shows
    from scenes.sim.config import NetworkKind

    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder for everything the demo makes")
    parser.add_argument("--logs", type=int, help=f"simulated logs (default {D.logs})")
    parser.add_argument("--duration-s", type=float, help=f"length of each log in seconds (default {D.duration_s:g})")
    parser.add_argument("--seed", type=int, help=f"simulation seed (default {D.seed})")
    parser.add_argument("--frames-per-clip", type=int, help=f"frames per clip (default {D.frames_per_clip})")
    parser.add_argument("--camera-width-px", type=int, help=f"camera view width of clips (default {D.camera_width_px})")
    parser.add_argument("--camera-height-px", type=int,
                        help=f"camera view height of clips (default {D.camera_height_px})")
    parser.add_argument("--bev-resolution-m", type=float,
                        help=f"BEV cell size of clips in metres (default {D.bev_resolution_m:g})")
    parser.add_argument("--preset", dest="train_preset", choices=preset_names(),
                        help=f"the training recipe (default {D.train_preset}; tiny for a smoke run)")
    parser.add_argument("--epochs", type=int, help="training epochs (default: the recipe's)")
    parser.add_argument("--batch-size", type=int, help="training batch size (default: the recipe's)")
    parser.add_argument("--test-fraction", type=float,
                        help=f"share of the logs held out for testing (default {D.test_fraction:g}; "
                        f"validation takes {VAL_FRACTION:g})")
    parser.add_argument("--no-sensors", action="store_true", help="skip LiDAR/camera rendering (BEV from boxes)")
    parser.add_argument("--extra-logs", type=int, metavar="N",
                        help=f"extra training-only logs, simulated without sensors (default {D.extra_logs})")
    parser.add_argument("--val-logs", type=int, metavar="N",
                        help=f"validation-only logs, simulated with sensors from another seed, where the tag "
                             f"thresholds and the camera weight are chosen (default {D.val_logs})")
    parser.add_argument("--map-less-share", type=float, metavar="F",
                        help=f"share of the extra logs simulated without their map (default {D.map_less_share:g})")
    parser.add_argument("--jitter-share", type=float, metavar="F",
                        help=f"share of the extra logs whose boxes scatter as real labels do (default "
                        f"{D.jitter_share:g})")
    parser.add_argument("--extra-networks", nargs="+", metavar="LAYOUT", choices=[k.value for k in NetworkKind],
                        help=f"road networks that share the extra logs evenly (default "
                        f"{' '.join(D.extra_networks)})")
    parser.add_argument("--query", action="append", help="example query (repeatable; replaces the defaults)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="Ray workers of the simulation and the clips (default: one per CPU core when Ray is "
                             "installed; 0 or 1: serially); the outputs are the same")
    parser.add_argument("--quick", action="store_true", help="smallest sizes, a smoke run of every stage")
    parser.add_argument("--stages", nargs="+", metavar="STAGE",
                        help="run only these stages (simulate caption clips train index eval report)")


def size_bounds() -> dict[str, tuple[str, float]]:
    """Each size flag's ``args`` attribute → (flag, upper bound), the bound of the config field it sets."""
    from encoders.clips.config import CameraClipConfig, ClipsConfig
    from encoders.train_config import TrainConfig
    from scenes.sim.config import SimulationConfig

    logs = SimulationConfig.upper_bounds["logs"]
    return {"logs": ("--logs", logs), "extra_logs": ("--extra-logs", logs), "val_logs": ("--val-logs", logs),
            "duration_s": ("--duration-s", SimulationConfig.upper_bounds["duration_s"]),
            "frames_per_clip": ("--frames-per-clip", ClipsConfig.upper_bounds["frames_per_clip"]),
            "camera_width_px": ("--camera-width-px", CameraClipConfig.upper_bounds["width_px"]),
            "camera_height_px": ("--camera-height-px", CameraClipConfig.upper_bounds["height_px"]),
            "epochs": ("--epochs", TrainConfig.upper_bounds["epochs"]),
            "batch_size": ("--batch-size", TrainConfig.upper_bounds["batch_size"]),
            "workers": ("--workers", MAX_WORKERS)}


def check_sizes(args: argparse.Namespace) -> None:
    """Refuse a size flag above its upper bound (:func:`size_bounds`), naming the flag, before any stage runs."""
    for name, (flag, bound) in size_bounds().items():
        value = getattr(args, name, None)
        if value is not None:
            check_flag_bound(flag, value, bound)


def run(args: argparse.Namespace) -> int:
    import sys

    check_sizes(args)

    from retrieval.demo import STAGES, Demo, DemoStageError, config_from_args

    demo = Demo(args.out, config_from_args(args), say=lambda m: print(m, flush=True))
    try:
        demo.run(tuple(args.stages) if args.stages else STAGES)
    except DemoStageError as exc:
        print(f"scenesearch demo: error: {exc}", file=sys.stderr)
        return 1
    return 0
