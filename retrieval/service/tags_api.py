"""Tag-query endpoints of the HTTP API (mounted beside the search endpoints).

    GET /api/tags/vocabulary                        attributes (with kinds), regions, operators, logs
    GET /api/tags/series?log_id=&tag=&region=       a scene tag of one log over time
    GET /api/tags/find?tag=&region=&threshold=&min_duration_s=&k=&log_id=
                                                    ranked spans where a compositional tag holds

Mount on the application of :func:`retrieval.service.app.create_app`::

    from retrieval.service.tags_api import register_tag_routes
    from retrieval.tagging import TagSearch

    register_tag_routes(app, TagSearch(run_dir), log_dirs)

Errors are JSON ``{"detail": ...}``: 422 for an unknown attribute or region, a malformed composition,
a map region of a log without a map (the message lists the valid values) or a number that is not
finite, 413 for a tag expression longer than the limit, 404 for a log that is not served. On a service
started without tag queries (:func:`register_tags_unavailable`) every ``/api/tags/`` route answers 404
saying what starts them. Logs are
only looked up among ``log_dirs``, never opened by a path from the request.

On an application of ``create_app`` the queries share its search gate (429 when busy) and time
limit. :class:`~retrieval.tagging.TagSearch` keeps per-log caches and renders a log's frames on
first use, so its queries run one at a time.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Annotated, Any, TypeVar

from fastapi import FastAPI, HTTPException, Query
from starlette.concurrency import run_in_threadpool

from encoders.tagging.attributes import Region, TagError
from encoders.tagging.scene_tags import OPS, TRANSFORMS
from retrieval.errors import InvalidKError
from retrieval.querying import check_k
from retrieval.service.limits import SearchGate, ServiceLimits, check_chars
from retrieval.tagging import TagSearch
from scenes.errors import ScenesError

T = TypeVar("T")


def register_tag_routes(app: FastAPI, search: TagSearch, log_dirs: Sequence[Path | str], max_k: int = 200) -> None:
    """Add the ``/api/tags/*`` routes to ``app``, answering from ``search`` over ``log_dirs``."""
    logs = {Path(d).name: Path(d) for d in log_dirs}
    limits: ServiceLimits = getattr(app.state, "limits", None) or ServiceLimits()
    gate: SearchGate | None = getattr(app.state, "search_gate", None)
    one_at_a_time = threading.Lock()

    async def run(fn: Callable[[], T]) -> T:
        def locked() -> T:
            with one_at_a_time:
                try:
                    return fn()
                except TagError as exc:
                    raise HTTPException(422, str(exc)) from None
                except ScenesError as exc:  # a served log that fails to read (changed since the start)
                    raise HTTPException(503, f"the log cannot be read: {exc}") from None

        return await (gate.run(locked) if gate is not None else run_in_threadpool(locked))

    def log_dir_of(log_id: str) -> Path:
        if log_id not in logs:
            raise HTTPException(404, f"unknown log {log_id!r}; served logs: {', '.join(sorted(logs)[:20])}")
        return logs[log_id]

    def transform(kappa: float | None) -> tuple[str, float]:
        return ("indicator", kappa) if kappa is not None else ("identity", 0.5)

    @app.get("/api/tags/vocabulary", summary="Tag attributes, regions and operators")
    def vocabulary() -> dict[str, Any]:
        kinds = {a: search.tagger.head.config.kind(a).value for a in search.attributes}
        return {"attributes": [{"name": a, "kind": kinds[a]} for a in search.attributes],
                "regions": [r.value for r in Region], "operators": {"&": OPS[0], "|": OPS[1]},
                "transforms": list(TRANSFORMS), "logs": sorted(logs)}

    @app.get("/api/tags/series", summary="A scene tag of one log over time")
    async def series(
        log_id: Annotated[str, Query(description="a served log")],
        tag: Annotated[str, Query(description="an attribute or a composition, e.g. 'stopped & four_way'")],
        region: Annotated[str, Query(description="full, front, behind, around, intersection or crosswalk")] = "full",
        kappa: Annotated[float | None, Query(description="compose 1{V >= kappa} instead of values",
                                             allow_inf_nan=False)] = None,
    ) -> dict[str, Any]:
        check_chars("tag", tag, limits)
        log_dir = log_dir_of(log_id)
        h, k = transform(kappa)
        ts, values = await run(lambda: search.series(log_dir, tag, region, h, k))
        t0 = int(ts[0]) if ts.shape[0] else 0
        return {"log_id": log_id, "tag": tag, "region": region, "timestamps_ns": ts.tolist(),
                "time_s": [round((int(t) - t0) * 1e-9, 3) for t in ts], "values": [round(float(v), 4) for v in values]}

    @app.get("/api/tags/find", summary="Log spans where a compositional tag holds, best first")
    async def find(
        tag: Annotated[str, Query(description="e.g. 'blocked_by & four_way'")],
        region: Annotated[str, Query(description="full, front, behind, around, intersection or crosswalk")] = "front",
        threshold: Annotated[float, Query(description="pooled value a frame must reach", allow_inf_nan=False)] = 0.5,
        min_duration_s: Annotated[float, Query(description="shortest span kept", ge=0, allow_inf_nan=False)] = 0.5,
        k: Annotated[int, Query(description="number of spans")] = 20,
        log_id: Annotated[list[str] | None, Query(description="restrict to these logs")] = None,
        kappa: Annotated[float | None, Query(description="compose 1{V >= kappa} instead of values",
                                             allow_inf_nan=False)] = None,
    ) -> dict[str, Any]:
        check_chars("tag", tag, limits)
        try:
            check_k(k, max_k)
        except InvalidKError as exc:
            raise HTTPException(422, str(exc)) from None
        dirs = [log_dir_of(lid) for lid in dict.fromkeys(log_id)] if log_id else list(logs.values())
        h, kap = transform(kappa)
        spans = await run(lambda: search.find(dirs, tag, region, threshold, min_duration_s, k, h, kap))
        return {"tag": tag, "region": region, "threshold": threshold, "k": k,
                "results": [s.to_dict() for s in spans]}


def register_tags_unavailable(app: FastAPI, reason: str) -> None:
    """Answer every ``/api/tags/...`` route with 404 and ``reason``: what the service needs to serve tag
    queries, rather than a bare "Not Found" that reads as a wrong address."""

    @app.get("/api/tags/{rest:path}", include_in_schema=False)
    def unavailable(rest: str) -> None:
        raise HTTPException(404, f"tag queries are not served: {reason}")

