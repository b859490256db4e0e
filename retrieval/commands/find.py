"""``scenesearch find RUN_DIR LOG_DIR... --tag "blocked_by & four_way" --region front``.

Ranks the time spans of the logs where a compositional tag holds in a region (the retrieval setting
of Segal et al.): per frame, the composed tag tensor pooled over the region; runs of frames at or
above ``--threshold`` lasting at least ``--min-duration-s``, scored by their mean value.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "rank logs and time spans by a compositional scene tag (e.g. 'blocked_by & four_way' in front)"


def configure(parser: argparse.ArgumentParser) -> None:
    from encoders.tagging.attributes import Region

    parser.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a trained run with a tagging model")
    parser.add_argument("log_dirs", type=Path, nargs="+", metavar="LOG_DIR", help="log folders (AV2 layout)")
    parser.add_argument("--tag", required=True, help="'a & b' (and), 'a | b' (or) or one attribute")
    parser.add_argument("--region", default="front",
                        help=f"one of: {', '.join(r.value for r in Region)} (default front)")
    parser.add_argument("--threshold", type=float, default=0.5, help="pooled value a frame must reach (default 0.5)")
    parser.add_argument("--min-duration-s", type=float, default=0.5, help="shortest span kept (default 0.5)")
    parser.add_argument("--indicator", type=float, metavar="KAPPA", help="compose 1{V >= KAPPA} instead of values")
    parser.add_argument("-k", "--top", type=int, default=20, help="spans to print (default 20)")
    parser.add_argument("--json", action="store_true", help="print JSON lines")
    parser.add_argument("--cache", type=Path, help="folder for rendered BEV frames (default RUN_DIR/tag_cache)")


def run(args: argparse.Namespace) -> int:
    from retrieval.tagging import TagSearch

    search = TagSearch(args.run_dir, args.cache)
    h, kappa = ("indicator", args.indicator) if args.indicator is not None else ("identity", 0.5)
    spans = search.find(args.log_dirs, args.tag, args.region, args.threshold, args.min_duration_s, args.top, h, kappa)
    if args.json:
        for s in spans:
            print(json.dumps(s.to_dict()))
        return 0
    print(f"# {args.tag!r} in {args.region}: {len(spans)} span(s) over {len(args.log_dirs)} log(s)")
    for rank, s in enumerate(spans, 1):
        print(f"{rank:3d}  {s.log_id}  {s.start_ns}..{s.end_ns}  ({s.duration_s:.1f} s, {s.frames} frames)  "
              f"score {s.score:.3f}  peak {s.peak:.3f}")
    return 0
