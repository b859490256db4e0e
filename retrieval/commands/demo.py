"""``scenesearch demo``: the whole pipeline on a small simulated city, ending with ``DIR/report.html``."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "simulate, caption, build clips, train, index and evaluate a small city; write DIR/report.html"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder for everything the demo makes")
    parser.add_argument("--logs", type=int, help="simulated logs (default 12)")
    parser.add_argument("--duration-s", type=float, help="length of each log in seconds (default 20)")
    parser.add_argument("--seed", type=int, help="simulation seed (default 0)")
    parser.add_argument("--frames-per-clip", type=int, help="frames per clip (default 12)")
    parser.add_argument("--camera-width-px", type=int, help="camera view width of clips (default 64)")
    parser.add_argument("--camera-height-px", type=int, help="camera view height of clips (default 32)")
    parser.add_argument("--bev-resolution-m", type=float, help="BEV cell size of clips in metres (default 1.25)")
    parser.add_argument("--epochs", type=int, help="training epochs (default 12)")
    parser.add_argument("--batch-size", type=int, help="training batch size (default 16)")
    parser.add_argument("--test-fraction", type=float,
                        help="share of the logs held out for testing (default 0.25; validation takes 0.15)")
    parser.add_argument("--tag-weight", type=float, help="weight of the tagging loss in training (default 0.2)")
    parser.add_argument("--no-sensors", action="store_true", help="skip LiDAR/camera rendering (BEV from boxes)")
    parser.add_argument("--query", action="append", help="example query (repeatable; replaces the defaults)")
    parser.add_argument("--quick", action="store_true", help="smallest sizes, a smoke run of every stage")
    parser.add_argument("--stages", nargs="+", metavar="STAGE",
                        help="run only these stages (simulate caption clips train index eval report)")


def run(args: argparse.Namespace) -> int:
    import sys

    from retrieval.demo import STAGES, Demo, DemoStageError, config_from_args

    demo = Demo(args.out, config_from_args(args), say=lambda m: print(m, flush=True))
    try:
        demo.run(tuple(args.stages) if args.stages else STAGES)
    except DemoStageError as exc:
        print(f"scenesearch demo: error: {exc}", file=sys.stderr)
        return 1
    return 0
