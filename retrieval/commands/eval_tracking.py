"""``scenesearch eval-tracking``: CLEAR-MOT, IDF1 and HOTA of tracked logs against ground truth."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from scenes.tracking.log_evaluation import PairEvaluation

HELP = ("MOTA, MOTP, IDF1, HOTA per category of predicted logs against ground truth (centre distance matching; "
        "KITTI's ignore rules for KITTI logs)")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("pred", type=Path, help="log whose annotations are the tracker's output, or a folder of logs")
    parser.add_argument("gt", type=Path, help="log with ground-truth tracks, or a folder of logs paired by name")
    parser.add_argument("--out", type=Path, required=True, help="metrics.json to write")
    parser.add_argument("--max-distance-m", type=float, default=2.0,
                        help="largest centre distance of a MOTA/IDF1 match (similarity 0.5); HOTA's thresholds "
                             "run from 0.1 to 1.9 times it")
    parser.add_argument("--protocol", choices=("auto", "plain", "kitti"), default="auto",
                        help="which boxes count: 'kitti' applies the KITTI benchmark's ignore rules (DontCare "
                             "regions, Van under car, Person_sitting under pedestrian, truncated or occluded "
                             "objects), 'plain' counts every box, 'auto' (default) is 'kitti' for logs imported "
                             "from KITTI labels")
    parser.add_argument("--kitti-labels", type=Path,
                        help="KITTI label file, or the label_02 folder (<sequence>.txt), for the KITTI rules; "
                             "default: the file the ground truth was imported from")


def _row(name: str, m: dict[str, Any]) -> str:
    def num(key: str) -> str:
        return f"{m[key]:>7.3f}" if m[key] is not None else f"{'-':>7}"

    return (f"{name:<12}{num('MOTA')}{num('MOTP')}{num('IDF1')}{num('HOTA')}{num('DetA')}{num('AssA')}"
            f"{m['IDSW']:>6}{m['FP']:>7}{m['FN']:>7}{m['GT']:>7}{m['ignored_GT']:>8}{m['ignored_pred']:>8}")


def _print_table(title: str, figures: dict[str, dict[str, Any]]) -> None:
    print(title)
    print(f"{'category':<12}{'MOTA':>7}{'MOTP_m':>7}{'IDF1':>7}{'HOTA':>7}{'DetA':>7}{'AssA':>7}"
          f"{'IDSW':>6}{'FP':>7}{'FN':>7}{'GT':>7}{'ign_GT':>8}{'ign_prd':>8}")
    for category, m in figures.items():
        print(_row(category, m))


def run(args: argparse.Namespace) -> int:
    from scenes.errors import ScenesError
    from scenes.tracking.log_evaluation import Protocol, evaluate_log_pair, pair_logs, pool
    from scenesearch_base.atomic import atomic_write_text, check_output_file

    check_output_file(args.out)  # before the work that would fill it

    if not args.max_distance_m > 0:
        raise ValueError(f"--max-distance-m must be positive, got {args.max_distance_m}")
    pairs, skipped = pair_logs(args.pred, args.gt)
    protocol = Protocol(args.protocol)
    if pairs == [(args.pred, args.gt)]:
        # One pair: errors are the command's, and the file holds the categories alone.
        one = evaluate_log_pair(args.pred, args.gt, protocol, args.kitti_labels, args.max_distance_m)
        figures = one.figures()
        atomic_write_text(args.out, json.dumps(figures, indent=2, sort_keys=True))
        _print_table(_how(one), figures)
        print(f"wrote {args.out}")
        return 0
    done: list[PairEvaluation] = []
    for pred_dir, gt_dir in pairs:
        try:
            done.append(evaluate_log_pair(pred_dir, gt_dir, protocol, args.kitti_labels, args.max_distance_m))
        except (ScenesError, FileNotFoundError, ValueError) as exc:
            skipped[pred_dir.name] = str(exc)
    for name, why in skipped.items():
        print(f"skipped {name}: {why}", file=sys.stderr)
    if not done:
        print(f"scenesearch eval-tracking: error: no log pair could be scored; {args.out} left as it was",
              file=sys.stderr)
        return 2
    combined = {c.value: n.figures() for c, n in pool(done).items() if n.num_gt > 0}
    payload = {
        "combined": combined,
        "logs": {e.pred_log.name: {"protocol": e.protocol.value, "labels": str(e.labels_path or ""),
                                   "categories": e.figures()} for e in done},
        "skipped": skipped,
        "max_distance_m": args.max_distance_m,
    }
    atomic_write_text(args.out, json.dumps(payload, indent=2, sort_keys=True))
    for e in done:
        _print_table(f"{e.pred_log.name}: {_how(e)}", e.figures())
    _print_table(f"combined over {len(done)} logs", combined)
    print(f"wrote {args.out} ({len(done)} logs scored, {len(skipped)} skipped)")
    return 0


def _how(evaluation: PairEvaluation) -> str:
    if evaluation.labels_path is None:
        return f"protocol {evaluation.protocol.value}"
    return f"protocol {evaluation.protocol.value} (ignore rules from {evaluation.labels_path})"
