"""``scenesearch eval``: retrieval figures of a trained model on a split, beside baselines from the same run."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "measure text → clip, temporal order and clip → clip figures on a split, with baselines"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="training run (model.safetensors, config.json)")
    parser.add_argument("clips_dir", type=Path, metavar="CLIPS_DIR", help="clips directory (clips.parquet, logs/)")
    parser.add_argument("--split", default="test", help="split to evaluate (default test; 'all': every clip)")
    parser.add_argument("--out", type=Path, default=Path("metrics.json"), help="metrics file (default metrics.json)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random baseline")
    parser.add_argument("--index", type=Path, metavar="INDEX_DIR",
                        help="an index of the same model and clips: reuse its clip embeddings")
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON instead of a table")


def run(args: argparse.Namespace) -> int:
    from common.atomic import atomic_write_text
    from retrieval.evaluation import evaluate, metrics_table

    metrics = evaluate(args.run_dir, args.clips_dir, split=args.split, seed=args.seed,
                       progress=lambda m: print(m, flush=True), index_dir=args.index)
    atomic_write_text(args.out, json.dumps(metrics, indent=2))
    print(json.dumps(metrics, indent=2) if args.json else metrics_table(metrics))
    print(f"wrote {args.out}")
    return 0
