"""The HTTP API and web page over one index directory (``scenesearch serve``).

Endpoints (OpenAPI at ``/openapi.json``, interactive docs at ``/docs``)::

    GET /health                         liveness and what is served
    GET /api/fields                     filter fields and values with counts, switches, the index summary,
                                        example queries, the score scale of each mode
    GET /api/search?q=&k=&offset=&filter=&view=&mode=&weight=&program=
    GET /api/similar/{clip_id}?k=&offset=&filter=&view=&other_moments=&same_track=
    GET /api/clips/{clip_id}            metadata, caption, tags and the tag timeline
    GET /api/clips/{clip_id}/preview?referred=&related=
                                        the animated preview (GIF): the stored one, else (or with tracks
                                        given, marking them) drawn from the clips folder's rendered frames
    GET /api/map?view=                  the embedding map: every clip's 2-D projection and action
    GET /api/export?ids= | q=&k=        embeddings of a result set
    GET /docs, /redoc                   interactive API docs, their scripts served from the installed
                                        ``fastapi_offline`` package (no network)
    GET /                               the search page (static files, no network fetches)

A search compiles its query to a scenario program first and keeps to the moments it selects
(:mod:`retrieval.scenario_search`); its answer says what the query read as (``scenario``, with the words
it left unused and a phrasing the index knows), and, for each result, the tracks the program refers to
and relates to (its ``preview_url`` then draws them); ``program=false`` ranks every moment.

Pages: ``k`` results from ``offset`` (ranks count from the first page); ``total`` is how many the search
can return and ``next_offset`` where the next page starts (null after the last), so every result of
an index can be paged through, ``max_k`` at a time. Every answer of a search carries the time of each
moment within its log (``time_in_log``), its object sentence and its tags in words
(:mod:`retrieval.service.explain`), the scale of its scores (``score_scale``) and, where the index has
validation clips, whether its best score is weak for the mode (``confidence``).

Errors are JSON ``{"detail": "..."}``: 422 for a malformed, unknown or repeated parameter, one that
is not valid UTF-8 or one that holds a control character (the message names it), 404 for unknown
clips, 413 for queries longer than the limit (:func:`retrieval.querying.check_query`, the check of
the CLI and the Python API too), 409 when the
index's model changed, 503 when the model is gone, 429 (with ``Retry-After``) when every search
slot is taken, 504 when a request is not answered within the time limit (see
:mod:`retrieval.service.limits`; the connection-level limits are in :mod:`retrieval.service.server`).
Clip ids are only ever looked up in the index, and preview files are served only from inside the
clips directory, so no request can read a file outside it.
"""

from __future__ import annotations

import time
import typing
from dataclasses import replace
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any
from urllib.parse import unquote_to_bytes

import numpy as np
from fastapi import Depends, FastAPI, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles

from retrieval.errors import (
    IndexDirError,
    ModelMismatchError,
    RetrievalError,
    UnknownClipError,
    UnknownViewError,
)
from retrieval.hybrid import check_weight
from retrieval.querying import QueryTooLongError, check_k, parse_cli_filters
from retrieval.records import SearchResult
from retrieval.scenario_search import ScenarioMatch, filled_up
from retrieval.scenesearch import SceneSearch
from retrieval.service.docs_pages import add_docs
from retrieval.service.limits import RequestTimeout, SearchGate, ServiceBusyError, ServiceLimits, check_chars
from retrieval.service.results import ResultContext, ranked_prefix

STATIC_DIR = Path(__file__).parent / "static"
VIEWS = ("fused", "camera", "bev")


class SearchMode(StrEnum):
    """What answers a text query: the trained encoder, the rule captions (no trained model), or both mixed."""

    MODEL = "model"
    CAPTIONS = "captions"
    HYBRID = "hybrid"


MODES = tuple(m.value for m in SearchMode)


def _status_of(exc: RetrievalError) -> int:
    if isinstance(exc, UnknownClipError):
        return 404
    if isinstance(exc, ModelMismatchError):
        return 409
    if isinstance(exc, IndexDirError):
        return 503
    if isinstance(exc, QueryTooLongError):
        return 413
    return 422  # empty query, k out of range, bad filter, unknown view: malformed parameters


def _is_repeatable(annotation: Any) -> bool:
    """Whether a query parameter's type takes several values (``list[str] | None``)."""
    if typing.get_origin(annotation) in (list, tuple, set, frozenset):
        return True
    return any(_is_repeatable(a) for a in typing.get_args(annotation) if a is not type(None))


def check_utf8(query_string: bytes) -> None:
    """422 naming the first query parameter whose name or value is not valid UTF-8 once percent-decoded.

    Starlette decodes parameters with replacement characters, so ``?q=car%ff`` would otherwise reach
    the search as ``"car\ufffd"``, a query nobody typed.
    """
    for pair in query_string.split(b"&"):
        raw_name, _, raw_value = pair.partition(b"=")
        name_bytes = unquote_to_bytes(raw_name.replace(b"+", b" "))
        name = name_bytes.decode("utf-8", errors="replace")
        for part in (name_bytes, unquote_to_bytes(raw_value.replace(b"+", b" "))):
            try:
                part.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise HTTPException(422, f"parameter {name!r} is not valid UTF-8: byte 0x{part[exc.start]:02x} at "
                                         f"byte {exc.start}") from None


async def strict_parameters(request: Request) -> None:
    """422 for a query parameter the endpoint does not take, a single-valued one given twice, or one
    that is not valid UTF-8 (:func:`check_utf8`).

    FastAPI alone ignores unknown parameters and keeps the last of repeated ones, so a typo
    (``?kk=5``) or a clash (``?k=1&k=50``) would silently give another search than was asked for.
    """
    route = request.scope.get("route")
    if not isinstance(route, APIRoute) or not route.include_in_schema:
        return  # the page itself: its address carries the page's own state (``/?q=...``)
    check_utf8(request.scope.get("query_string", b""))
    # Per route of this app: its query parameters, and those that may repeat. Filled on first use, on
    # the event loop's thread (async dependencies run there), so no lock is needed.
    known: dict[int, tuple[frozenset[str], frozenset[str]]] = request.app.state.route_parameters
    if id(route) not in known:
        params = route.dependant.query_params
        known[id(route)] = (frozenset(p.alias for p in params),
                            frozenset(p.alias for p in params if _is_repeatable(p.field_info.annotation)))
    names, repeatable = known[id(route)]
    for name in dict.fromkeys(request.query_params.keys()):
        if name not in names:
            valid = ", ".join(sorted(names)) or "none"
            raise HTTPException(422, f"unknown parameter {name!r} for {route.path}; valid parameters: {valid}")
        count = len(request.query_params.getlist(name))
        if count > 1 and name not in repeatable:
            raise HTTPException(422, f"parameter {name!r} is given {count} times; give it once")


def _describe(error: Any) -> str:
    """One FastAPI validation error as ``parameter 'k': <why> (got '...')``."""
    loc = [str(x) for x in error.get("loc", ())]
    name = loc[-1] if len(loc) > 1 else ".".join(loc) or "request"
    text = f"parameter {name!r}: {error.get('msg', 'invalid')}"
    if error.get("type") != "missing" and "input" in error:
        got = repr(error["input"])
        text += f" (got {got[:60] + '…' if len(got) > 60 else got})"
    return text


def create_app(search: SceneSearch, limits: ServiceLimits | None = None) -> FastAPI:
    """The FastAPI application serving ``search``.

    Searches (text, caption, clip → clip, export) go through one :class:`SearchGate`; every request
    is answered within ``limits.request_timeout_s``. The gate is ``app.state.search_gate``, for
    routes added later (:func:`retrieval.service.tags_api.register_tag_routes`).
    """
    limits = limits or ServiceLimits()
    clips_root = search.clips_dir.resolve()
    gate = SearchGate(limits.max_concurrent_searches, limits.max_waiting_searches)
    preview_gate = SearchGate(1, limits.max_waiting_previews)  # drawing is one at a time (ResultContext)
    app = FastAPI(
        title="scenesearch",
        description="Natural-language and example-based search over driving-log clips.",
        version="1",
        dependencies=[Depends(strict_parameters)],
        docs_url=None,  # served below from local files, never from a CDN
        redoc_url=None,
    )
    context = ResultContext(search)
    app.state.result_context = context
    app.state.search_gate = gate
    app.state.route_parameters = {}
    app.state.limits = limits
    app.add_middleware(RequestTimeout, timeout_s=limits.request_timeout_s)

    @app.exception_handler(RetrievalError)
    async def _retrieval_error(_request: Request, exc: RetrievalError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=_status_of(exc))

    @app.exception_handler(RequestValidationError)
    async def _invalid_parameter(_request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse({"detail": "; ".join(_describe(e) for e in exc.errors())}, status_code=422)

    @app.exception_handler(ServiceBusyError)
    async def _busy(_request: Request, exc: ServiceBusyError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=429,
                            headers={"Retry-After": str(limits.retry_after_s)})

    # k and the filters are checked where the search builds its query (retrieval.querying), against
    # this service's max_k; here only the count and length of filter parameters are limited.
    def filters_of(items: list[str] | None) -> Any:
        if items and len(items) > limits.max_filters:
            raise HTTPException(422, f"parameter 'filter': at most {limits.max_filters} filters, got {len(items)}")
        for item in items or []:
            check_chars("filter", item, limits)
        return parse_cli_filters([i for i in items or [] if i.strip()])

    def check_view(view: str) -> str:
        if view not in search.views:
            raise UnknownViewError(view, list(search.views))
        return view

    def check_page(k: int, offset: int) -> int:
        """The results to ask the search for: this page's ``k`` (at most ``max_k``) after ``offset``."""
        check_k(k, limits.max_k)
        return offset + k

    def page(results: list[SearchResult], offset: int, k: int, total: int) -> tuple[list[SearchResult], Any]:
        shown = results[offset:offset + k]
        return shown, (offset + k if offset + k < total and len(shown) == k else None)

    def selects(query: str) -> bool:
        """Whether ``query``'s program selects some indexed moment (an example worth offering)."""
        try:
            return search.scenarios.match(query, context.metadata.table).fallback is None
        except Exception:
            return False

    @app.get("/health", summary="Liveness and what is served")
    def health() -> dict[str, Any]:
        return {"status": "ok", "clips": len(search), "views": list(search.views),
                "model": search.manifest.model_sha256[:12], "text_encoder": search.manifest.text_encoder}

    @app.get("/api/fields", summary="Filter fields and values with counts, the index summary and example queries")
    def fields() -> dict[str, Any]:
        # Scans every clip's metadata once (the index does not change while served).
        return {"fields": search.fields, **context.summary(selects), "views": list(search.views),
                "modes": list(MODES), "score_scales": {m: ResultContext.score_scale(m) for m in (*MODES, "similar")},
                "hybrid_weight": search.hybrid.weight,
                "limits": {"max_k": limits.max_k, "max_query_chars": limits.max_query_chars}}

    @app.get("/api/search", summary="Clips matching a sentence")
    async def api_search(
        q: Annotated[str, Query(description="a sentence, e.g. 'a car in the left lane approaches, then stops'")],
        k: Annotated[int, Query(description="results on this page, at most the service's max_k")] = 10,
        offset: Annotated[int, Query(ge=0, le=10_000_000, description="results to skip: the page's first rank "
                                                                       "is offset + 1")] = 0,
        filter: Annotated[list[str] | None, Query(description="FIELD=VALUE or a filter expression")] = None,
        view: Annotated[str, Query(description="fused, camera or bev (model mode)")] = "fused",
        mode: Annotated[SearchMode, Query(description="model (trained encoder), captions (rule captions) or "
                                                      "hybrid (both scores mixed)")] = SearchMode.MODEL,
        weight: Annotated[float | None, Query(description="hybrid mode: the rule captions' share in [0, 1] "
                                                          "(default: the index's, chosen on its validation clips)")]
        = None,
        program: Annotated[bool, Query(description="compile the query to a scenario program and keep to the moments "
                                                   "it selects (false: rank every moment)")] = True,
    ) -> dict[str, Any]:
        check_chars("q", q, limits)
        spec = filters_of(filter)
        check_view(view)  # in every mode: a view the index does not serve is an error, never echoed
        if weight is not None and mode is not SearchMode.HYBRID:
            raise HTTPException(422, "parameter 'weight': the weight of hybrid search; add mode=hybrid")
        mixed = search.hybrid.weight if weight is None else check_weight(weight)
        wanted = check_page(k, offset)

        def work() -> dict[str, Any]:
            start = time.perf_counter()
            captions = mode is SearchMode.CAPTIONS
            metadata = search.captions.metadata if captions else search.views[view].metadata
            found: dict[str, ScenarioMatch] = {}

            def fetch(n: int) -> list[SearchResult]:
                if program:  # filled after the pages of its selection, below
                    results, found["match"] = search.search_scenario(q, k=n, filters=spec, view=view,
                                                                     ranking=mode.value, weight=mixed,
                                                                     max_k=max(limits.max_k, n), fill=False)
                    return results
                return ranked(n)

            def ranked(n: int) -> list[SearchResult]:
                deep = max(limits.max_k, n)  # pages reach every result, max_k at a time
                if captions:
                    return search.search_captions(q, k=n, filters=spec, max_k=deep)
                if mode is SearchMode.HYBRID:
                    return search.search_hybrid(q, k=n, filters=spec, view=view, weight=mixed, max_k=deep)
                return search.search_text(q, k=n, filters=spec, view=view, max_k=deep)

            first = fetch(wanted)
            match = found.get("match")
            within = match.clip_ids if match is not None and match.fallback is None else None
            total = context.total(metadata, spec, None if captions else view, within)
            results = ranked_prefix(lambda n: first if n == wanted else fetch(n), wanted, total)
            if within is not None and match is not None and len(results) < wanted:  # the search's next best
                results, filled = filled_up(results, wanted, lambda: ranked_prefix(ranked, wanted, len(metadata)))
                match, total = replace(match, filled=filled), len(results)
            elapsed_ms = (time.perf_counter() - start) * 1e3
            shown, next_offset = page(results, offset, k, total)
            # Caption search uses no clip view: the answer says so rather than echoing the parameter.
            out = {"query": q, "k": k, "offset": offset, "total": total, "next_offset": next_offset,
                   "view": None if captions else view, "mode": mode.value, "elapsed_ms": round(elapsed_ms, 2),
                   "score_scale": ResultContext.score_scale(mode.value),
                   "confidence": context.confidence(mode.value, view, mixed, results),
                   "results": [context.result_json(r, match, q) for r in shown]}
            if match is not None:
                out["scenario"] = match.to_dict()
                unused = match.compiled.unused if match.compiled is not None else ()
                out["scenario"]["suggestion"] = context.suggest(q, unused)
            return out | ({"hybrid_weight": mixed} if mode is SearchMode.HYBRID else {})

        return await gate.run(work)

    @app.get("/api/similar/{clip_id:path}", summary="Clips most like an indexed clip")
    async def api_similar(
        clip_id: str,
        k: Annotated[int, Query(description="results on this page, at most the service's max_k")] = 10,
        offset: Annotated[int, Query(ge=0, le=10_000_000, description="results to skip")] = 0,
        filter: Annotated[list[str] | None, Query(description="FIELD=VALUE or a filter expression")] = None,
        view: Annotated[str, Query(description="fused, camera or bev")] = "fused",
        other_moments: Annotated[bool, Query(description="leave out the other objects in view at the same time "
                                                         "in the clip's log (fewer than k may come back)")] = False,
        same_track: Annotated[bool, Query(description="keep the clip's own object in its other time windows (by "
                                                      "default they are left out: they are the same moment "
                                                      "a little later)")] = False,
    ) -> dict[str, Any]:
        spec = filters_of(filter)
        check_view(view)
        wanted = check_page(k, offset)

        def work() -> dict[str, Any]:
            def fetch(n: int) -> list[SearchResult]:
                return context.similar(clip_id, n, spec, view, max(limits.max_k, n), other_moments, same_track)

            results = ranked_prefix(fetch, wanted, len(search))
            shown = results[offset:offset + k]
            more = len(shown) == k and (len(results) > wanted or wanted < len(search) - 1)
            query = context.result_json(search.get(clip_id))
            query.pop("score", None)
            query.pop("rank", None)
            return {"clip_id": clip_id, "k": k, "offset": offset, "next_offset": offset + k if more else None,
                    "view": view, "other_moments": other_moments, "same_track": same_track, "query": query,
                    "score_scale": ResultContext.score_scale("similar"),
                    "results": [context.result_json(r) for r in shown]}

        return await gate.run(work)

    @app.get("/api/clips/{clip_id:path}/preview", summary="Animated preview of a clip", response_model=None)
    async def api_preview(
        clip_id: str,
        referred: Annotated[str | None, Query(description="comma-separated tracks a scenario query refers to, "
                                                          "drawn in orange (the preview is drawn anew)")] = None,
        related: Annotated[str | None, Query(description="comma-separated tracks they relate to, drawn in cyan")]
        = None,
    ) -> Response:
        record = search.get(clip_id)  # 404 for any id that is not indexed, traversal attempts included
        marks = [[t for t in (v or "").split(",") if t][:32] for v in (referred, related)]
        for name, value in (("referred", referred), ("related", related)):
            if value:
                check_chars(name, value, limits)
        # Drawn from the rendered frames where marks are asked for or no preview was stored at build time.
        if any(marks) or not record.preview_path:
            drawn = context.drawn_preview(clip_id, marks[0], marks[1])  # kept from before: no wait
            if drawn is None:
                drawn = await preview_gate.run(lambda: context.preview(clip_id, marks[0], marks[1]))
            if drawn is not None:
                return Response(drawn, media_type="image/gif", headers={"Cache-Control": "max-age=3600"})
        if not record.preview_path:
            raise HTTPException(404, f"clip {clip_id!r} has no preview, and its rendered frames are not at hand")
        path = Path(record.preview_path).resolve()
        if not path.is_relative_to(clips_root) or not path.is_file():
            raise HTTPException(404, f"the preview of clip {clip_id!r} is missing")
        media = "image/webp" if path.suffix == ".webp" else "video/mp4" if path.suffix == ".mp4" else "image/gif"
        return FileResponse(path, media_type=media)

    @app.get("/api/clips/{clip_id:path}", summary="Metadata, caption, tags and tag timeline of a clip")
    def api_clip(clip_id: str) -> dict[str, Any]:
        record = search.get(clip_id)
        row = search.views[next(iter(search.views))].get(clip_id)
        out = context.result_json(record)
        out.pop("score", None)
        out.pop("rank", None)
        extra = {key: _plain(value) for key, value in row.items() if key not in out and key != "id"}
        tags = list(record.tags)
        # The unified tag sequence is ordered in time; without per-step times, steps share the window evenly.
        step_s = record.duration_s / max(len(tags), 1)
        out["timeline"] = [{"tag": tag, "label": label, "start_s": round(i * step_s, 2),
                            "end_s": round((i + 1) * step_s, 2)}
                           for i, (tag, label) in enumerate(zip(tags, out["tag_labels"]))]
        out["metadata"] = extra
        return out

    @app.get("/api/map", summary="Embedding map: every clip's 2-D projection (PCA), coloured by action")
    async def api_map(view: Annotated[str, Query(description="fused, camera or bev")] = "fused") -> dict[str, Any]:
        check_view(view)
        return await gate.run(lambda: context.embedding_map(view))

    @app.get("/api/export", summary="Embeddings of a result set")
    async def api_export(
        ids: Annotated[str | None, Query(description="comma-separated clip ids")] = None,
        q: Annotated[str | None, Query(description="a query whose results to export (instead of ids)")] = None,
        k: Annotated[int, Query(description="results of q to export")] = 10,
        view: Annotated[str, Query(description="fused, camera or bev")] = "fused",
    ) -> dict[str, Any]:
        view = check_view(view)
        if (ids is None) == (q is None):
            raise HTTPException(422, "give exactly one of ids (comma-separated clip ids) or q (a query)")
        clip_ids: list[str] = []
        if q is not None:
            check_chars("q", q, limits)
        else:
            clip_ids = [c for c in (ids or "").split(",") if c]
            if not clip_ids or len(clip_ids) > limits.max_export_ids:
                raise HTTPException(422, f"parameter 'ids' must name 1 to {limits.max_export_ids} clips")

        def work() -> dict[str, Any]:
            if q is not None:
                found = [r.clip_id for r in search.search_text(q, k=k, view=view, max_k=limits.max_k)]
            else:
                found = clip_ids
                for clip_id in found:
                    search.get(clip_id)  # 404 for unknown ids
            x = np.asarray(search.views[view].reconstruct(found), dtype=np.float32)
            return {"view": view, "model": search.manifest.model_sha256, "dim": int(x.shape[1]),
                    "clip_ids": found, "embeddings": x.round(6).tolist()}

        return await gate.run(work)

    @app.get("/", include_in_schema=False, response_model=None)
    def index_page() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", media_type="text/html")

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    add_docs(app)
    return app


def _plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value
