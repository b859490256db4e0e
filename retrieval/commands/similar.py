"""``scenesearch similar``: the clips most like a given clip.

The clip is named by its id, by its rank in the last search of the index (``#3``) or by its readable
short id (``log8/track8@12.4s``), as the tables of ``search`` and ``similar`` print them
(:mod:`retrieval.short_ids`). Clip → clip search needs neither the model nor the caption index, so
neither is loaded; the view's vectors are memory-mapped.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "find the moments most like a given clip (clip → clip)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("index_dir", type=Path, metavar="INDEX_DIR", help="index directory (`scenesearch index`)")
    parser.add_argument("clip_id", metavar="CLIP_ID",
                        help="an indexed clip: its id LOG_ID:TRACK_ID:START_NS, #N (rank N of the last search of "
                             "this index) or the short id the tables print, LOG/TRACK@SECONDSs")
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
    import shutil

    from retrieval.commands.search import print_results, wrap
    from retrieval.querying import check_text, parse_cli_filters
    from retrieval.records import time_in_log
    from retrieval.result_table import object_first
    from retrieval.scenesearch import SceneSearch
    from retrieval.short_ids import ShortIds

    # The text check of queries (retrieval.querying), before the index loads and naming the argument.
    check_text(args.clip_id, "argument CLIP_ID")
    for item in args.filters or []:
        check_text(item, "--filter")
    search = SceneSearch.open(args.index_dir, views=(args.view,), lazy_captions=True, mmap=True)
    short = ShortIds.of_table(search.views[args.view].metadata.table, search.clips_dir)
    clip_id = short.resolve(args.clip_id, args.index_dir)
    results = search.search_clip(clip_id, k=args.k, filters=parse_cli_filters(args.filters), view=args.view,
                                 other_moments=args.other_moments)
    query = search.get(clip_id)
    readable = short.readable(query.log_id, query.track_id, query.start_ns)
    named = f"{args.clip_id.strip()} = " if args.clip_id.strip().startswith("#") else ""
    when = time_in_log(query, short.spans([query.log_id])[query.log_id])
    width = shutil.get_terminal_size().columns
    before = wrap(f"query: {named}{readable} ({query.category}, {when})", width) + "\n" + \
        wrap(f"    {object_first(query.caption)}", width)
    print_results(args.index_dir, f"more like {readable}", results, short, args.json, {"clip_id": clip_id}, before)
    return 0
