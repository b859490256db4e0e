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
    parser.add_argument("--model-card", action="store_true",
                        help="also write the figures, beside their baselines, into the run's model_card.md (a "
                             "section per clips folder and split, replaced when evaluated again)")


def run(args: argparse.Namespace) -> int:
    from encoders.model_card import MODEL_CARD_FILE, with_section
    from retrieval.evaluation import evaluate
    from scenesearch_base.atomic import atomic_write_text, check_output_file

    check_output_file(args.out)  # before the work that would fill it
    from retrieval.metrics_tables import metrics_markdown, metrics_table

    metrics = evaluate(args.run_dir, args.clips_dir, split=args.split, seed=args.seed,
                       progress=lambda m: print(m, flush=True), index_dir=args.index)
    atomic_write_text(args.out, json.dumps(metrics, indent=2))
    print(json.dumps(metrics, indent=2) if args.json else metrics_table(metrics))
    print(f"wrote {args.out}")
    if args.model_card:
        card = Path(args.run_dir) / MODEL_CARD_FILE
        heading = f"Evaluation: split {args.split} of `{Path(args.clips_dir).resolve()}`"
        body = ("Text → clip and the other figures of `scenesearch eval`, each beside its baselines from the same "
                "run (`metrics.json` holds every figure).\n\n" + metrics_markdown(metrics))
        atomic_write_text(card, with_section(card.read_text(encoding="utf-8") if card.is_file() else "", heading, body))
        print(f"wrote the figures into {card}")
    return 0
