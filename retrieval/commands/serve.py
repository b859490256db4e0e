"""``scenesearch serve``: the HTTP API and web page over an index directory."""

from __future__ import annotations

import argparse
import socket
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from retrieval.service.limits import ServiceLimits

HELP = "serve the search API and web page for an index directory (http://HOST:PORT/)"


def configure(parser: argparse.ArgumentParser) -> None:
    from retrieval.service.limits import ServiceLimits

    d = ServiceLimits()
    parser.add_argument("index_dir", type=Path, help="an index directory written by `scenesearch index`")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="port to listen on, 1 … 65535 (default 8000)")
    parser.add_argument("--max-k", type=int, default=d.max_k, help="the most results one request may ask for")
    parser.add_argument("--request-timeout-s", type=float, default=d.request_timeout_s,
                        help=f"answer every request within this time, else 504 (default {d.request_timeout_s:g})")
    parser.add_argument("--read-timeout-s", type=float, default=d.read_timeout_s,
                        help="time a client has to send its whole request, else 408 and the connection closes "
                             f"(default {d.read_timeout_s:g})")
    parser.add_argument("--max-concurrent-searches", type=int, default=d.max_concurrent_searches,
                        help=f"searches computed at once (default {d.max_concurrent_searches})")
    parser.add_argument("--max-waiting-searches", type=int, default=d.max_waiting_searches,
                        help="searches that may wait for a slot; past them requests get 429 "
                             f"(default {d.max_waiting_searches})")
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="CPU threads one search's model call may use (default 1: requests already run in "
                             "parallel, and more threads per call only contend for the same cores)")
    parser.add_argument("--logs", type=Path, nargs="+", metavar="LOG_DIR",
                        help="logs that tag queries (/api/tags/…) may search; needs a run trained with tagging")
    parser.add_argument("--no-warmup", action="store_true",
                        help="do not load the text model before serving (the first query then pays for it)")


def run(args: argparse.Namespace) -> int:
    from retrieval.service import ServiceLimits

    # Checked before the index loads, so a bad option is reported at once (ValueError names it).
    limits = ServiceLimits(max_k=args.max_k, request_timeout_s=args.request_timeout_s,
                           read_timeout_s=args.read_timeout_s, max_concurrent_searches=args.max_concurrent_searches,
                           max_waiting_searches=args.max_waiting_searches)
    if args.torch_threads < 1:
        raise ValueError(f"--torch-threads must be at least 1, got {args.torch_threads}")
    sockets = _bind(args.host, args.port)  # before anything loads or is announced: the address is usable
    try:
        _serve(args, limits, sockets)
    finally:
        for sock in sockets:
            sock.close()
    return 0


def _bind(host: str, port: int) -> list[socket.socket]:
    """Sockets on ``host:port``; a :class:`ValueError` naming ``--host`` or ``--port`` when they cannot be had."""
    from retrieval.service import ListenError, listen_sockets

    try:
        return listen_sockets(host, port)
    except ListenError as exc:
        shown = repr(exc.value) if exc.option == "host" else exc.value
        raise ValueError(f"--{exc.option} {shown}: {exc.reason}") from None


def _serve(args: argparse.Namespace, limits: ServiceLimits, sockets: list[socket.socket]) -> None:
    import torch

    from retrieval.scenesearch import SceneSearch
    from retrieval.service import create_app, serve

    # On few busy cores a caption query is far slower with more than one thread, as the threads of
    # concurrent calls spin against each other (benchmarks/bench_service.py;
    # docs/research/benchmark-highlights.md).
    torch.set_num_threads(args.torch_threads)
    search = SceneSearch.open(args.index_dir)
    if not args.no_warmup:
        try:
            search.embedder.embed_texts(["warm up"])
        except Exception as exc:  # serve caption search and clip → clip even when the model is gone
            print(f"note: text queries with the trained model are unavailable: {exc}")
    app = create_app(search, limits)
    if args.logs:
        from retrieval.service.tags_api import register_tag_routes
        from retrieval.tagging import TagSearch
        from scenes.log import Log

        for log_dir in args.logs:  # a log that does not open would answer its first tag query with a 500
            Log.open(log_dir)
        run_dir = Path(search.manifest.run_dir)
        if not (run_dir / "tagging.json").is_file():
            raise ValueError(f"--logs: the run {run_dir} was trained without tagging; tag queries are unavailable")
        register_tag_routes(app, TagSearch(run_dir, clips_dir=search.clips_dir), list(args.logs))
        print(f"tag queries over {len(args.logs)} logs at /api/tags/series and /api/tags/find")
    else:
        from retrieval.service.tags_api import register_tags_unavailable

        register_tags_unavailable(app, "the service was started without --logs (start it with "
                                       "`scenesearch serve INDEX --logs LOG_DIR ...` from a run trained with tagging)")
    print(f"serving {args.index_dir} ({len(search)} clips) on http://{args.host}:{args.port}/ "
          f"(requests answered within {limits.request_timeout_s:g} s, {limits.max_concurrent_searches} searches at "
          f"once, {limits.max_waiting_searches} waiting)")
    serve(app, args.host, args.port, limits, sockets=sockets)
