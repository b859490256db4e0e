"""``scenesearch similar``: the clips most like a given clip."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "find the moments most like a given clip (clip → clip)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("index_dir", type=Path, metavar="INDEX_DIR", help="index directory (`scenesearch index`)")
    parser.add_argument("clip_id", metavar="CLIP_ID", help="an indexed clip id, LOG_ID:TRACK_ID:START_NS")
    parser.add_argument("-k", type=int, default=10, help="number of results (default 10)")
    parser.add_argument("--filter", action="append", metavar="FIELD=VALUE", dest="filters",
                        help="keep clips whose FIELD equals VALUE (repeatable)")
    parser.add_argument("--view", choices=["fused", "camera", "bev"], default="fused",
                        help="which clip embedding to compare (default fused; camera: the clips the camera saw)")
    parser.add_argument("--other-moments", action="store_true",
                        help="leave out the clips of the query's own moment: the other objects in view at the same "
                             "time in its log")
    parser.add_argument("--json", action="store_true", help="print JSON for scripts instead of a table")


def run(args: argparse.Namespace) -> int:
    from retrieval.querying import check_text, parse_cli_filters
    from retrieval.records import format_table
    from retrieval.scenesearch import SceneSearch

    # The text check of queries (retrieval.querying), before the index loads and naming the argument.
    check_text(args.clip_id, "argument CLIP_ID")
    for item in args.filters or []:
        check_text(item, "--filter")
    search = SceneSearch.open(args.index_dir, views=(args.view,))
    results = search.search_clip(args.clip_id, k=args.k, filters=parse_cli_filters(args.filters), view=args.view,
                                 other_moments=args.other_moments)
    if args.json:
        print(json.dumps({"clip_id": args.clip_id, "results": [r.to_dict() for r in results]}, indent=2))
    else:
        query = search.get(args.clip_id)
        print(f"query: {query.clip_id} ({query.category}): {query.caption}")
        print(format_table(results))
    return 0
