"""``scenesearch validate LOG_DIR...``: check logs against the log contract.

Prints one line per log: ``OK <log> (facts)`` or ``FAIL <log>`` followed by each problem (file,
row or frame, field). Every log is checked, whatever the ones before it hold. Exits 1 if any log
fails. ``--json`` prints one JSON object per log instead.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from scenes.errors import Problem
from scenes.validate import ValidationReport, validate_log

HELP = "check logs (AV2 layout) for missing files, bad columns, NaNs, time order, pose jumps"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log_dirs", nargs="+", type=Path, metavar="LOG_DIR", help="log folders to check")
    parser.add_argument("--json", action="store_true", help="print one JSON object per log")


def run(args: argparse.Namespace) -> int:
    failed = 0
    for log_dir in args.log_dirs:
        report = _validate(log_dir)
        failed += int(not report.ok)
        if args.json:
            print(json.dumps(report.to_json_dict(), sort_keys=True))
            continue
        print(report.summary())
        for problem in report.problems:
            print(f"  {problem}")
    if not args.json and len(args.log_dirs) > 1:
        print(f"{len(args.log_dirs) - failed} of {len(args.log_dirs)} logs OK")
    return 1 if failed else 0


def _validate(log_dir: Path) -> ValidationReport:
    """The log's report; a failure of the file system (permissions, a vanished disk) fails this log
    only, so that the logs after it are still checked."""
    try:
        return validate_log(log_dir)
    except OSError as exc:
        where = Path(exc.filename) if exc.filename else log_dir
        return ValidationReport(log_dir, [Problem(where, f"cannot read: {exc.strerror or exc}")])
