"""``scenesearch validate LOG_DIR...``: check logs against the log contract.

Prints one line per log: ``OK <log> (facts)`` or ``FAIL <log>`` followed by each problem (file,
row or frame, field). Every log is checked, whatever the ones before it hold. A log named twice in
one batch (the same folder, or two folders with the same log id, which later stages key their
output by) is checked once and each repeat fails as a duplicate. ``--json`` prints one JSON object
per log instead.

Exit status: 0 when every log is OK, 1 when some are OK and some fail (each listed), 2 when none is OK.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from scenes import schema
from scenes.errors import Problem
from scenes.validate import ValidationReport, validate_log

HELP = "check logs (AV2 layout) for missing files, bad columns, NaNs, implausible values, time order, pose jumps"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log_dirs", nargs="+", type=Path, metavar="LOG_DIR", help="log folders to check")
    parser.add_argument("--json", action="store_true", help="print one JSON object per log")
    parser.add_argument(
        "--max-pose-gap-s", type=float, default=schema.DEFAULT_MAX_POSE_GAP_S, metavar="S",
        help="largest gap between the ego poses an annotation timestamp is interpolated between "
        f"(default {schema.DEFAULT_MAX_POSE_GAP_S:g}); raise it only for logs whose poses really are this sparse",
    )


def run(args: argparse.Namespace) -> int:
    if not args.max_pose_gap_s > 0:
        raise ValueError(f"--max-pose-gap-s must be > 0, got {args.max_pose_gap_s}")
    failed = 0
    first_by_folder: dict[Path, Path] = {}
    first_by_id: dict[str, Path] = {}
    for log_dir in args.log_dirs:
        folder = Path(os.path.realpath(log_dir))  # never raises, even inside a symbolic-link loop
        earlier = first_by_folder.get(folder) or first_by_id.get(folder.name)
        if earlier is not None:
            same = "the same log folder as" if first_by_folder.get(folder) else "the same log id as"
            report = ValidationReport(log_dir, [Problem(log_dir, f"duplicated log in the batch: {same} {earlier}")])
        else:
            first_by_folder[folder] = log_dir
            first_by_id[folder.name] = log_dir
            report = _validate(log_dir, args.max_pose_gap_s)
        failed += int(not report.ok)
        if args.json:
            print(json.dumps(report.to_json_dict(), sort_keys=True))
            continue
        print(report.summary())
        for problem in report.problems:
            print(f"  {problem}")
    total = len(args.log_dirs)
    if not args.json and total > 1:
        print(f"{total - failed} of {total} logs OK")
    if not failed:
        return 0
    return 2 if failed == total else 1


def _validate(log_dir: Path, max_pose_gap_s: float) -> ValidationReport:
    """The log's report; a failure of the file system (permissions, a vanished disk) fails this log
    only, so that the logs after it are still checked."""
    try:
        return validate_log(log_dir, max_pose_gap_s)
    except OSError as exc:
        where = Path(exc.filename) if exc.filename else log_dir
        return ValidationReport(log_dir, [Problem(where, f"cannot read: {exc.strerror or exc}")])
