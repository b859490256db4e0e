"""``scenesearch eval-tracking``: CLEAR-MOT and IDF1 of a tracked log against ground truth."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "MOTA, MOTP, IDF1 per category of a predicted log against a ground-truth log (centre distance matching)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("pred_log", type=Path, help="log whose annotations are the tracker's output")
    parser.add_argument("gt_log", type=Path, help="log with ground-truth tracks")
    parser.add_argument("--out", type=Path, required=True, help="metrics.json to write")
    parser.add_argument("--max-distance-m", type=float, default=2.0, help="largest centre distance of a match")


def run(args: argparse.Namespace) -> int:
    from common.atomic import atomic_write_text
    from scenes.log import Log
    from scenes.tracking.evaluate import evaluate_tracking

    pred, gt = Log.open(args.pred_log), Log.open(args.gt_log)
    metrics = evaluate_tracking(pred.annotations, pred.ego, gt.annotations, gt.ego, args.max_distance_m)
    atomic_write_text(args.out, json.dumps(metrics, indent=2, sort_keys=True))
    print(f"{'category':<12}{'MOTA':>8}{'MOTP_m':>8}{'IDF1':>8}{'IDSW':>6}{'FP':>7}{'FN':>7}{'GT':>7}")
    for category, m in metrics.items():
        mota, motp, idf1 = (m[k] if m[k] is not None else float("nan") for k in ("MOTA", "MOTP", "IDF1"))
        print(f"{category:<12}{mota:>8.3f}{motp:>8.3f}{idf1:>8.3f}{m['IDSW']:>6}{m['FP']:>7}{m['FN']:>7}{m['GT']:>7}")
    print(f"wrote {args.out}")
    return 0
