"""``scenesearch search``: the clips that best match a sentence."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from retrieval.scenario_search import ScenarioMatch

HELP = ("find the moments that match a sentence: its scenario program selects them, the model ranks them "
        "(--captions: rule-caption search; --hybrid: both mixed; --no-program: rank every moment)")


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
    parser.add_argument("--no-program", action="store_true",
                        help="rank every moment, without compiling the query to a scenario program first")
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
    match = None
    if is_caption_index(args.index_dir):  # built with `scenesearch index --captions`
        if args.hybrid:
            raise ValueError(f"{args.index_dir} holds rule captions only (`scenesearch index --captions`): hybrid "
                             "search needs the model's clip embeddings too (`scenesearch index RUN_DIR CLIPS_DIR`)")
        captions = CaptionSearch.open(args.index_dir)
        if args.no_program:
            results = captions.search(args.query, k=args.k, filters=filters)
        else:
            results, match = captions.search_scenario(args.query, k=args.k, filters=filters)
    else:
        search = SceneSearch.open(args.index_dir, views=(args.view,))
        ranking = "captions" if args.captions else "hybrid" if args.hybrid else "model"
        if args.hybrid:
            weight = search.hybrid.weight if args.weight is None else args.weight
        if args.no_program:
            results = (search.search_captions(args.query, k=args.k, filters=filters) if args.captions else
                       search.search_hybrid(args.query, k=args.k, filters=filters, view=args.view, weight=weight)
                       if args.hybrid else search.search_text(args.query, k=args.k, filters=filters, view=args.view))
        else:
            results, match = search.search_scenario(args.query, k=args.k, filters=filters, view=args.view,
                                                     ranking=ranking, weight=weight)
    if args.json:
        out: dict[str, object] = {"query": args.query, "results": [_with_objects(r.to_dict(), match) for r in results]}
        if weight is not None:
            out["hybrid_weight"] = weight
        if match is not None:
            out["scenario"] = match.to_dict()
        print(json.dumps(out, indent=2))
    else:
        if match is not None:
            print(_scenario_lines(match))
        print(format_table(results))
    return 0


def _with_objects(result: dict[str, object], match: ScenarioMatch | None) -> dict[str, object]:
    """A result's record with the tracks the program refers to and relates to in its window."""
    if match is not None and match.fallback is None:
        result["referred_tracks"] = list(match.referred.get(str(result["clip_id"]), ()))
        result["related_tracks"] = list(match.related.get(str(result["clip_id"]), ()))
    return result


def _scenario_lines(match: ScenarioMatch) -> str:
    """What the query compiled to, and whether it decided the moments (or why not)."""
    lines = []
    if match.compiled is not None:
        lines.append(f"program: {match.compiled.text}\nreads:   {match.compiled.rendering}")
        if match.compiled.unused:
            lines.append(f"words the program does not use: {', '.join(match.compiled.unused)}")
    if match.fallback is None:
        lines.append(f"{len(match.clip_ids)} moment(s) match the program; ranked by the search below")
    else:
        lines.append(f"ranking every moment: {match.fallback}")
    lines += [f"note: {n}" for n in match.notes[:5]]
    return "\n".join(lines)
