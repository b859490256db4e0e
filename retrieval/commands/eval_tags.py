"""``scenesearch eval-tags RUN_DIR CLIPS_DIR --out DIR [--inputs-run map=RUN ...] [--logs LOG_DIR...]``.

Writes Table 1 (per attribute × region: L1 for continuous attributes, F1 for discrete ones, on the
clips folder's test split) and Table 2 (inputs: none = dataset statistics, map, LiDAR, both; one
run per row, ``RUN_DIR`` is the row its training inputs name) as ``DIR/tags.md`` and ``DIR/tags.json``.
Logs without tag targets get them first when their folders are given with ``--logs``: from the
simulator's behaviour labels where a log has them, from the captioning rules otherwise (the report says which);
one task per log, on Ray with ``--workers N`` or ``--ray-address`` (log folders may then be URIs).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scenesearch_base.ray_cluster import Execution
from scenesearch_base.ray_cluster import add_arguments as add_execution_arguments
from scenesearch_base.storage import expand

HELP = "evaluate scene tags per attribute × region and per input (Tables 1 and 2) into DIR/tags.{md,json}"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a trained run with a tagging model")
    parser.add_argument("clips_dir", type=Path, metavar="CLIPS_DIR", help="the clips folder (with tag targets)")
    parser.add_argument("--out", type=Path, required=True, help="folder for tags.md and tags.json")
    parser.add_argument("--inputs-run", action="append", default=[], metavar="INPUTS=RUN_DIR",
                        help="a run trained on other inputs, e.g. map=runs/map (repeatable)")
    parser.add_argument("--logs", nargs="+", default=[], metavar="LOG_DIR",
                        help="log folders (paths or URIs): write missing tag targets into CLIPS_DIR first")
    parser.add_argument("--split", default="test", choices=["train", "val", "test"],
                        help="held-out split (default test)")
    add_execution_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from encoders.tagging.ablation import parse_inputs
    from encoders.tagging.evaluate import TAG_REPORT_FOLDER, evaluate_runs, write_report
    from encoders.tagging.targets import add_attribute_targets
    from scenesearch_base.folders import claim_folder

    inputs = [args.run_dir, args.clips_dir]
    claim_folder(args.out, TAG_REPORT_FOLDER, inputs)  # before the evaluation
    runs: dict[str, Path] = {}
    for item in args.inputs_run:
        key, sep, path = item.partition("=")
        if not sep:
            raise ValueError(f"--inputs-run {item!r}: write INPUTS=RUN_DIR, e.g. map=runs/map")
        runs[parse_inputs(key).value] = Path(path)
    if args.logs:
        report = add_attribute_targets(args.clips_dir, expand(args.logs), progress=print,
                                       execution=Execution.from_args(args))
        print(report.table())
        for item in report.skipped:
            print(f"  skipped {item['log_id']}: {item['reason']}")
    result = evaluate_runs(args.run_dir, args.clips_dir, runs, args.split, progress=print)
    json_path, md_path = write_report(args.out, result, inputs)
    print(md_path.read_text())
    print(f"wrote {json_path} and {md_path}")
    return 0
