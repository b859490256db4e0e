"""``scenesearch serve``: the HTTP API and web page over an index directory."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "serve the search API and web page for an index directory (http://HOST:PORT/)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("index_dir", type=Path, help="an index directory written by `scenesearch index`")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="port to listen on (default 8000)")
    parser.add_argument("--max-k", type=int, default=100, help="the most results one request may ask for")
    parser.add_argument("--logs", type=Path, nargs="+", metavar="LOG_DIR",
                        help="logs that tag queries (/api/tags/…) may search; needs a run trained with tagging")
    parser.add_argument("--no-warmup", action="store_true",
                        help="do not load the text model before serving (the first query then pays for it)")


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from retrieval.scenesearch import SceneSearch
    from retrieval.service import ServiceLimits, create_app

    search = SceneSearch.open(args.index_dir)
    if not args.no_warmup:
        try:
            search.embedder.embed_texts(["warm up"])
        except Exception as exc:  # serve caption search and clip → clip even when the model is gone
            print(f"note: text queries with the trained model are unavailable: {exc}")
    app = create_app(search, ServiceLimits(max_k=args.max_k))
    if args.logs:
        from retrieval.service.tags_api import register_tag_routes
        from retrieval.tagging import TagSearch

        run_dir = Path(search.manifest.run_dir)
        if not (run_dir / "tagging.json").is_file():
            raise ValueError(f"--logs: the run {run_dir} was trained without tagging; tag queries are unavailable")
        register_tag_routes(app, TagSearch(run_dir, clips_dir=search.clips_dir), list(args.logs))
        print(f"tag queries over {len(args.logs)} logs at /api/tags/series and /api/tags/find")
    print(f"serving {args.index_dir} ({len(search)} clips) on http://{args.host}:{args.port}/")
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning")
    return 0
