"""``scenesearch search``: the clips that best match a sentence.

The table fits the terminal and names each moment by a short id that ``scenesearch similar`` reads back:
its rank (``#3``, remembered per index directory) or its readable form (``log8/track8@12.4s``); see
:mod:`retrieval.short_ids`. Only what the query needs is loaded: the caption index only for caption or
hybrid ranking, the model only for model or hybrid ranking, and the views' vectors memory-mapped.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from retrieval.records import SearchResult
    from retrieval.scenario_search import ScenarioMatch
    from retrieval.short_ids import ShortIds

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
    from retrieval.scenesearch import SceneSearch
    from retrieval.short_ids import ShortIds

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
        moments, logs_dir = captions.metadata.table, captions.base_dir
        if args.no_program:
            results = captions.search(args.query, k=args.k, filters=filters)
        else:
            results, match = captions.search_scenario(args.query, k=args.k, filters=filters)
    else:
        search = SceneSearch.open(args.index_dir, views=(args.view,), lazy_captions=True, mmap=True)
        moments, logs_dir = search.views[args.view].metadata.table, search.clips_dir
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
    print_results(args.index_dir, args.query, results, ShortIds.of_table(moments, logs_dir), args.json,
                  {"hybrid_weight": weight} if weight is not None else {},
                  _scenario_lines(match) if match is not None else "", match)
    return 0


def print_results(index_dir: Path, query: str, results: list[SearchResult], short: ShortIds, as_json: bool,
                  extra: dict[str, object] | None = None, before: str = "", match: ScenarioMatch | None = None) -> None:
    """Print ``results`` as JSON or as a table that fits the terminal, and remember them for ``#N`` ids.

    Args:
        index_dir: the index searched (the key of the remembered results).
        query: what was searched (a sentence, or the query clip's id).
        results: the ranked results.
        short: the short ids of the index's moments.
        as_json: JSON for scripts (each result with its ``short_id`` and ``time_in_log``) instead of a table.
        extra: more top-level JSON fields.
        before: text printed above the table, wrapped to the terminal.
        match: the scenario match, whose referred and related tracks each JSON result names.
    """
    import shutil

    from retrieval.records import time_in_log
    from retrieval.result_table import format_table
    from retrieval.short_ids import remember

    ids = short.readable_ids(results)
    spans = short.spans(r.log_id for r in results)
    remember(index_dir, query, [r.clip_id for r in results])
    if as_json:
        rows = []
        for r in results:
            row = _with_objects(r.to_dict(), match)
            row["short_id"] = ids.get(r.clip_id)
            span = spans.get(r.log_id)
            row["time_in_log"] = time_in_log(r, span).to_dict() if span is not None else None
            rows.append(row)
        print(json.dumps({"query": query, **(extra or {}), "results": rows,
                          **({"scenario": match.to_dict()} if match is not None else {})}, indent=2))
        return
    width = shutil.get_terminal_size().columns
    if before:
        print(wrap(before, width))
    print(format_table(results, width, ids, spans))


def wrap(text: str, width: int, indent: str = "    ") -> str:
    """``text`` with each of its lines wrapped to ``width`` columns, continuations indented by ``indent``."""
    import textwrap

    return "\n".join(part for line in text.splitlines()
                     for part in textwrap.wrap(line, max(width, len(indent) + 20), subsequent_indent=indent,
                                               break_on_hyphens=False) or [""])


def _with_objects(result: dict[str, object], match: ScenarioMatch | None) -> dict[str, object]:
    """A result's record with the tracks the program refers to and relates to in its window."""
    if match is not None:
        result.update(match.result_fields(str(result["clip_id"])))
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
        if match.filled:
            lines.append(f"the last {len(match.filled)} result(s) are the search's next best, which the program "
                         "does not select: it selects no more moments here")
    else:
        lines.append(f"ranking every moment: {match.fallback}")
    lines += [f"note: {n}" for n in match.notes]
    return "\n".join(lines)
