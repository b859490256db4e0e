"""``scenesearch mine LOG_DIR... --description TEXT [...] --out predictions.pkl``: scenario mining.

Each description is compiled to a program (:mod:`scenarios.compiler`; a program in the program
syntax is read as such), printed with its rendering and any word it did not use, then answered on
every log: which objects it refers to at which timestamps, and the objects they relate to. The
answers are written in Argoverse 2's scenario-mining format (:mod:`scenarios.submission`), at the
benchmark's 2 Hz (``--all-timestamps`` keeps every annotation timestamp). ``--cache DIR`` keeps each
log's features, so later runs skip building them.

Exit status, as every batch command's: 0 when every log was answered, 1 when some were skipped
(listed), 2 when nothing was done (no log could be read, or a description names nothing: the message
lists the words it did not understand).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scenesearch_base.ray_cluster import Execution
from scenesearch_base.ray_cluster import add_arguments as add_execution_arguments

HELP = ("answer scenario descriptions per object and timestamp on logs (Argoverse 2 scenario-mining "
        "submission pickle)")
#: Descriptions in one run, at most.
MAX_DESCRIPTIONS = 10_000


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log_dirs", nargs="+", type=Path, metavar="LOG_DIR", help="log folders (AV2 layout)")
    parser.add_argument("--description", action="append", default=[], metavar="TEXT",
                        help="a description in words or in the program syntax (repeatable)")
    parser.add_argument("--descriptions-file", type=Path, metavar="FILE",
                        help="more descriptions, one a line (blank lines and lines starting with # are left out)")
    parser.add_argument("--out", type=Path, required=True, metavar="PKL", help="the submission pickle to write")
    parser.add_argument("--all-timestamps", action="store_true",
                        help="answer at every annotation timestamp (default: 2 Hz from the first, as evaluated)")
    parser.add_argument("--cache", type=Path, metavar="DIR", help="keep each log's features here for later runs")
    add_execution_arguments(parser)


def _descriptions(args: argparse.Namespace) -> list[str]:
    texts = list(args.description)
    if args.descriptions_file is not None:
        try:
            lines = args.descriptions_file.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"--descriptions-file {args.descriptions_file}: unreadable ({exc})") from None
        found = [line.strip() for line in lines if line.strip() and not line.lstrip().startswith("#")]
        if not found:
            raise ValueError(f"--descriptions-file {args.descriptions_file}: holds no descriptions (all "
                             f"{len(lines)} lines are blank or comments)")
        texts += found
    if not texts:
        raise ValueError("give at least one --description TEXT (or --descriptions-file FILE)")
    if len(texts) > MAX_DESCRIPTIONS:
        raise ValueError(f"{len(texts)} descriptions: at most {MAX_DESCRIPTIONS} in one run")
    return list(dict.fromkeys(texts))


def run(args: argparse.Namespace) -> int:
    from scenarios.mining import compile_all, mine
    from scenarios.submission import write_submission
    from scenesearch_base.atomic import check_output_file
    from scenesearch_base.folders import check_inputs

    texts = _descriptions(args)
    check_inputs(args.out, args.log_dirs)
    check_output_file(args.out)  # before any work
    compiled = compile_all(texts)  # a description that names nothing is refused before any log is read
    for c in compiled:
        print(f"{c.description!r}\n  program: {c.text}\n  reads:   {c.rendering}"
              + (f"\n  words not used: {', '.join(c.unused)}" if c.unused else ""))
    result = mine(args.log_dirs, texts, cache_dir=args.cache, execution=Execution.from_args(args))
    for log_dir, reason in result.skipped.items():
        print(f"skipped log {log_dir}: {reason}")
    for note in result.notes:
        print(f"note: {note}")
    if not result.answers:
        print(f"no log could be answered; {args.out} was not written")
        return 2
    submission = write_submission(result.answers, args.out, all_timestamps=args.all_timestamps)
    referred = sum(int(a.referred_mask.any()) for a in result.answers)
    logs = len(args.log_dirs) - len(result.skipped)
    print(f"answered {len(texts)} description(s) on {logs} log(s) in {result.seconds:.2f} s "
          f"({result.cached} from the feature cache); {referred} of {len(result.answers)} (log, description) "
          f"pairs refer to an object; wrote {args.out} ({len(submission)} keys)")
    return 1 if result.skipped else 0
