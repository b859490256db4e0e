"""``scenesearch search``: the clips that best match a sentence."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "find the moments that match a sentence (text → clip; --captions: rule-caption search; --hybrid: both mixed)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("index_dir", type=Path, metavar="INDEX_DIR", help="index directory (`scenesearch index`)")
    from retrieval.querying import MAX_QUERY_CHARS

    parser.add_argument("query", metavar="QUERY", help='a sentence, e.g. "a car in the left lane approaches, then '
                                                       f'stops" (at most {MAX_QUERY_CHARS} characters)')
    parser.add_argument("-k", type=int, default=10, help="number of results (default 10)")
    parser.add_argument("--filter", action="append", metavar="FIELD=VALUE", dest="filters",
                        help="keep clips whose FIELD equals VALUE (repeatable; VALUE may be a,b for any of "
                             "several); any clause of the filter language also works, e.g. 'start_ns >= 5'")
    parser.add_argument("--view", choices=["fused", "camera", "bev"], default="fused",
                        help="which clip embedding to search (default fused; camera: the clips the camera saw)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--captions", action="store_true",
                      help="search the rule captions with the frozen sentence encoder instead of the model")
    mode.add_argument("--hybrid", action="store_true",
                      help="mix the model's and the rule captions' scores (each standardised per query) with the "
                           "weight the index chose on its validation clips")
    parser.add_argument("--weight", type=float, metavar="W",
                        help="with --hybrid: the rule captions' share in [0, 1] instead of the index's "
                             "(0: the model alone, 1: rule captions alone)")
    parser.add_argument("--json", action="store_true", help="print JSON for scripts instead of a table")


def run(args: argparse.Namespace) -> int:
    from retrieval.captions_search import CaptionSearch, is_caption_index
    from retrieval.querying import check_query, check_text, parse_cli_filters
    from retrieval.records import format_table
    from retrieval.scenesearch import SceneSearch

    # The query check of the API and the service, here before the index loads and naming the argument.
    check_query(args.query, "argument QUERY")
    for item in args.filters or []:
        check_text(item, "--filter")
    filters = parse_cli_filters(args.filters)
    if args.weight is not None and not args.hybrid:
        raise ValueError("--weight is the weight of hybrid search: add --hybrid")
    weight: float | None = None
    if is_caption_index(args.index_dir):  # built with `scenesearch index --captions`
        if args.hybrid:
            raise ValueError(f"{args.index_dir} holds rule captions only (`scenesearch index --captions`): hybrid "
                             "search needs the model's clip embeddings too (`scenesearch index RUN_DIR CLIPS_DIR`)")
        results = CaptionSearch.open(args.index_dir).search(args.query, k=args.k, filters=filters)
    elif args.captions:
        search = SceneSearch.open(args.index_dir, views=(args.view,))
        results = search.search_captions(args.query, k=args.k, filters=filters)
    elif args.hybrid:
        search = SceneSearch.open(args.index_dir, views=(args.view,))
        weight = search.hybrid.weight if args.weight is None else args.weight
        results = search.search_hybrid(args.query, k=args.k, filters=filters, view=args.view, weight=weight)
    else:
        search = SceneSearch.open(args.index_dir, views=(args.view,))
        results = search.search_text(args.query, k=args.k, filters=filters, view=args.view)
    if args.json:
        out = {"query": args.query, "results": [r.to_dict() for r in results]}
        if weight is not None:
            out["hybrid_weight"] = weight
        print(json.dumps(out, indent=2))
    else:
        print(format_table(results))
    return 0
