"""The HTTP API and web page over one index directory (``scenesearch serve``).

Endpoints (OpenAPI at ``/openapi.json``, interactive docs at ``/docs``)::

    GET /health                         liveness and what is served
    GET /api/fields                     filter fields and the values the page offers
    GET /api/search?q=&k=&filter=&view=&mode=
    GET /api/similar/{clip_id}?k=&filter=&view=
    GET /api/clips/{clip_id}            metadata, caption, tags and the tag timeline
    GET /api/clips/{clip_id}/preview    the animated preview (GIF)
    GET /api/export?ids= | q=&k=        embeddings of a result set
    GET /                               the search page (static files, no network fetches)

Errors are JSON ``{"detail": "..."}``: 422 for malformed parameters, 404 for unknown clips, 413
for queries longer than the limit, 409 when the index's model changed, 503 when the model is gone.
Clip ids are only ever looked up in the index, and preview files are served only from inside the
clips directory, so no request can read a file outside it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from fastapi import FastAPI, HTTPException, Query, Request
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from retrieval.errors import (
    IndexDirError,
    ModelMismatchError,
    RetrievalError,
    UnknownClipError,
    UnknownViewError,
)
from retrieval.querying import parse_cli_filters
from retrieval.records import SearchResult
from retrieval.scenesearch import SceneSearch

STATIC_DIR = Path(__file__).parent / "static"

#: Filter fields the page offers as menus, with their distinct values.
MENU_FIELDS = ("category", "log_id", "time_of_day", "weather")
VIEWS = ("fused", "camera", "bev")
MODES = ("model", "captions")


@dataclass(frozen=True)
class ServiceLimits:
    """Limits that keep one request cheap.

    Attributes:
        max_k: the most results one request may ask for.
        max_query_chars: the longest query accepted (longer → 413).
        max_filters: the most ``filter`` parameters in one request.
        max_export_ids: the most clips one export may name.
    """

    max_k: int = 100
    max_query_chars: int = 500
    max_filters: int = 8
    max_export_ids: int = 1000


def _status_of(exc: RetrievalError) -> int:
    if isinstance(exc, UnknownClipError):
        return 404
    if isinstance(exc, ModelMismatchError):
        return 409
    if isinstance(exc, IndexDirError):
        return 503
    return 422  # empty query, k out of range, bad filter, unknown view: malformed parameters


def _result_json(result: SearchResult) -> dict[str, Any]:
    out = result.to_dict()
    out.pop("preview_path", None)  # a server path: the page uses the preview URL instead
    out["preview_url"] = f"/api/clips/{result.clip_id}/preview" if result.preview_path else None
    out["duration_s"] = round(result.duration_s, 2)
    return out


def create_app(search: SceneSearch, limits: ServiceLimits | None = None) -> FastAPI:
    """The FastAPI application serving ``search``."""
    limits = limits or ServiceLimits()
    clips_root = search.clips_dir.resolve()
    app = FastAPI(
        title="scenesearch",
        description="Natural-language and example-based search over driving-log clips.",
        version="1",
    )

    @app.exception_handler(RetrievalError)
    async def _retrieval_error(_request: Request, exc: RetrievalError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=_status_of(exc))

    # k and the filters are checked where the search builds its query (retrieval.querying), against
    # this service's max_k; here only the count of filter parameters is limited.
    def filters_of(items: list[str] | None) -> Any:
        if items and len(items) > limits.max_filters:
            raise HTTPException(422, f"at most {limits.max_filters} filter parameters, got {len(items)}")
        return parse_cli_filters([i for i in items or [] if i.strip()])

    def check_view(view: str) -> str:
        if view not in search.views:
            raise UnknownViewError(view, list(search.views))
        return view

    @app.get("/health", summary="Liveness and what is served")
    def health() -> dict[str, Any]:
        return {"status": "ok", "clips": len(search), "views": list(search.views),
                "model": search.manifest.model_sha256[:12], "text_encoder": search.manifest.text_encoder}

    @app.get("/api/fields", summary="Filter fields, with the values offered as menus")
    def fields() -> dict[str, Any]:
        table = search.views[next(iter(search.views))].metadata.table
        menus = {f: sorted({str(v) for v in table.column(f).to_pylist() if v is not None})
                 for f in MENU_FIELDS if f in table.column_names}
        tags: set[str] = set()
        if "tags" in table.column_names:
            for row in table.column("tags").to_pylist():
                tags.update(row or [])
        return {"fields": search.fields, "menus": menus, "tags": sorted(tags), "views": list(search.views),
                "modes": list(MODES), "limits": {"max_k": limits.max_k, "max_query_chars": limits.max_query_chars}}

    @app.get("/api/search", summary="Clips matching a sentence")
    def api_search(
        q: Annotated[str, Query(description="a sentence, e.g. 'a car in the left lane approaches, then stops'")],
        k: Annotated[int, Query(description="number of results")] = 10,
        filter: Annotated[list[str] | None, Query(description="FIELD=VALUE or a filter expression")] = None,
        view: Annotated[str, Query(description="fused, camera or bev")] = "fused",
        mode: Annotated[str, Query(description="model (trained encoder) or captions (rule captions)")] = "model",
    ) -> dict[str, Any]:
        if len(q) > limits.max_query_chars:
            raise HTTPException(413, f"query is {len(q)} characters; the limit is {limits.max_query_chars}")
        if mode not in MODES:
            raise HTTPException(422, f"unknown mode {mode!r}; valid modes: {', '.join(MODES)}")
        spec = filters_of(filter)
        start = time.perf_counter()
        if mode == "captions":
            results = search.search_captions(q, k=k, filters=spec, max_k=limits.max_k)
        else:
            results = search.search_text(q, k=k, filters=spec, view=check_view(view), max_k=limits.max_k)
        elapsed_ms = (time.perf_counter() - start) * 1e3
        return {"query": q, "k": k, "view": view, "mode": mode, "elapsed_ms": round(elapsed_ms, 2),
                "results": [_result_json(r) for r in results]}

    @app.get("/api/similar/{clip_id:path}", summary="Clips most like an indexed clip")
    def api_similar(
        clip_id: str,
        k: Annotated[int, Query(description="number of results")] = 10,
        filter: Annotated[list[str] | None, Query(description="FIELD=VALUE or a filter expression")] = None,
        view: Annotated[str, Query(description="fused, camera or bev")] = "fused",
    ) -> dict[str, Any]:
        results = search.search_clip(clip_id, k=k, filters=filters_of(filter), view=check_view(view),
                                     max_k=limits.max_k)
        return {"clip_id": clip_id, "k": k, "view": view, "results": [_result_json(r) for r in results]}

    @app.get("/api/clips/{clip_id:path}/preview", summary="Animated preview of a clip", response_model=None)
    def api_preview(clip_id: str) -> FileResponse:
        record = search.get(clip_id)  # 404 for any id that is not indexed, traversal attempts included
        if not record.preview_path:
            raise HTTPException(404, f"clip {clip_id!r} has no preview")
        path = Path(record.preview_path).resolve()
        if not path.is_relative_to(clips_root) or not path.is_file():
            raise HTTPException(404, f"the preview of clip {clip_id!r} is missing")
        media = "image/webp" if path.suffix == ".webp" else "video/mp4" if path.suffix == ".mp4" else "image/gif"
        return FileResponse(path, media_type=media)

    @app.get("/api/clips/{clip_id:path}", summary="Metadata, caption, tags and tag timeline of a clip")
    def api_clip(clip_id: str) -> dict[str, Any]:
        record = search.get(clip_id)
        row = search.views[next(iter(search.views))].get(clip_id)
        out = _result_json(record)
        out.pop("score", None)
        out.pop("rank", None)
        extra = {key: _plain(value) for key, value in row.items() if key not in out and key != "id"}
        tags = list(record.tags)
        # The unified tag sequence is ordered in time; without per-step times, steps share the window evenly.
        step_s = record.duration_s / max(len(tags), 1)
        out["timeline"] = [{"tag": tag, "start_s": round(i * step_s, 2), "end_s": round((i + 1) * step_s, 2)}
                           for i, tag in enumerate(tags)]
        out["metadata"] = extra
        return out

    @app.get("/api/export", summary="Embeddings of a result set")
    def api_export(
        ids: Annotated[str | None, Query(description="comma-separated clip ids")] = None,
        q: Annotated[str | None, Query(description="a query whose results to export (instead of ids)")] = None,
        k: Annotated[int, Query(description="results of q to export")] = 10,
        view: Annotated[str, Query(description="fused, camera or bev")] = "fused",
    ) -> dict[str, Any]:
        view = check_view(view)
        if (ids is None) == (q is None):
            raise HTTPException(422, "give exactly one of ids (comma-separated clip ids) or q (a query)")
        if q is not None:
            if len(q) > limits.max_query_chars:
                raise HTTPException(413, f"query is {len(q)} characters; the limit is {limits.max_query_chars}")
            clip_ids = [r.clip_id for r in search.search_text(q, k=k, view=view, max_k=limits.max_k)]
        else:
            clip_ids = [c for c in (ids or "").split(",") if c]
            if not clip_ids or len(clip_ids) > limits.max_export_ids:
                raise HTTPException(422, f"ids must name 1 to {limits.max_export_ids} clips")
            for clip_id in clip_ids:
                search.get(clip_id)  # 404 for unknown ids
        x = np.asarray(search.views[view].reconstruct(clip_ids), dtype=np.float32)
        return {"view": view, "model": search.manifest.model_sha256, "dim": int(x.shape[1]),
                "clip_ids": clip_ids, "embeddings": x.round(6).tolist()}

    @app.get("/", include_in_schema=False, response_model=None)
    def index_page() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", media_type="text/html")

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    return app


def _plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value

