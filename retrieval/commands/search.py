"""``scenesearch search``: the clips that best match a sentence."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "find the moments that match a sentence (text → clip, or --captions for rule-caption search)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("index_dir", type=Path, metavar="INDEX_DIR", help="index directory (`scenesearch index`)")
    parser.add_argument("query", help='a sentence, e.g. "a car in the left lane approaches, then stops"')
    parser.add_argument("-k", type=int, default=10, help="number of results (default 10)")
    parser.add_argument("--filter", action="append", metavar="FIELD=VALUE", dest="filters",
                        help="keep clips whose FIELD equals VALUE (repeatable; VALUE may be a,b for any of "
                             "several); any clause of the filter language also works, e.g. 'start_ns >= 5'")
    parser.add_argument("--view", choices=["fused", "camera", "bev"], default="fused",
                        help="which clip embedding to search (default fused; camera: the clips the camera saw)")
    parser.add_argument("--captions", action="store_true",
                        help="search the rule captions with the frozen sentence encoder instead of the model")
    parser.add_argument("--json", action="store_true", help="print JSON for scripts instead of a table")


def run(args: argparse.Namespace) -> int:
    from retrieval.captions_search import CaptionSearch, is_caption_index
    from retrieval.querying import parse_cli_filters
    from retrieval.records import format_table
    from retrieval.scenesearch import SceneSearch

    filters = parse_cli_filters(args.filters)
    if is_caption_index(args.index_dir):  # built with `scenesearch index --captions`
        results = CaptionSearch.open(args.index_dir).search(args.query, k=args.k, filters=filters)
    elif args.captions:
        search = SceneSearch.open(args.index_dir, views=(args.view,))
        results = search.search_captions(args.query, k=args.k, filters=filters)
    else:
        search = SceneSearch.open(args.index_dir, views=(args.view,))
        results = search.search_text(args.query, k=args.k, filters=filters, view=args.view)
    if args.json:
        print(json.dumps({"query": args.query, "results": [r.to_dict() for r in results]}, indent=2))
    else:
        print(format_table(results))
    return 0
