"""Tag-query endpoints of the HTTP API (mounted beside the search endpoints).

    GET /api/tags/vocabulary                        attributes (with kinds), regions, operators, logs
    GET /api/tags/series?log_id=&tag=&region=       a scene tag of one log over time
    GET /api/tags/find?tag=&region=&threshold=&min_duration_s=&k=&log_id=
                                                    ranked spans where a compositional tag holds

Mount on the application of :func:`retrieval.service.app.create_app`::

    from retrieval.service.tags_api import register_tag_routes
    from retrieval.tagging import TagSearch

    register_tag_routes(app, TagSearch(run_dir), log_dirs)

Errors are JSON ``{"detail": ...}``: 422 for an unknown attribute or region, a malformed composition
or a map region of a log without a map (the message lists the valid values), 404 for a log that is
not served. Logs are only looked up among ``log_dirs``, never opened by a path from the request.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

from fastapi import FastAPI, HTTPException, Query

from encoders.tagging.attributes import Region, TagError
from encoders.tagging.scene_tags import OPS, TRANSFORMS
from retrieval.errors import InvalidKError
from retrieval.querying import check_k
from retrieval.tagging import TagSearch


def register_tag_routes(app: FastAPI, search: TagSearch, log_dirs: Sequence[Path | str], max_k: int = 200) -> None:
    """Add the ``/api/tags/*`` routes to ``app``, answering from ``search`` over ``log_dirs``."""
    logs = {Path(d).name: Path(d) for d in log_dirs}

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
    def series(
        log_id: Annotated[str, Query(description="a served log")],
        tag: Annotated[str, Query(description="an attribute or a composition, e.g. 'stopped & four_way'")],
        region: Annotated[str, Query(description="full, front, behind, around, intersection or crosswalk")] = "full",
        kappa: Annotated[float | None, Query(description="compose 1{V >= kappa} instead of values")] = None,
    ) -> dict[str, Any]:
        log_dir = log_dir_of(log_id)
        h, k = transform(kappa)
        try:
            ts, values = search.series(log_dir, tag, region, h, k)
        except TagError as exc:
            raise HTTPException(422, str(exc)) from None
        t0 = int(ts[0]) if ts.shape[0] else 0
        return {"log_id": log_id, "tag": tag, "region": region, "timestamps_ns": ts.tolist(),
                "time_s": [round((int(t) - t0) * 1e-9, 3) for t in ts], "values": [round(float(v), 4) for v in values]}

    @app.get("/api/tags/find", summary="Log spans where a compositional tag holds, best first")
    def find(
        tag: Annotated[str, Query(description="e.g. 'blocked_by & four_way'")],
        region: Annotated[str, Query(description="full, front, behind, around, intersection or crosswalk")] = "front",
        threshold: Annotated[float, Query(description="pooled value a frame must reach")] = 0.5,
        min_duration_s: Annotated[float, Query(description="shortest span kept")] = 0.5,
        k: Annotated[int, Query(description="number of spans")] = 20,
        log_id: Annotated[list[str] | None, Query(description="restrict to these logs")] = None,
        kappa: Annotated[float | None, Query(description="compose 1{V >= kappa} instead of values")] = None,
    ) -> dict[str, Any]:
        try:
            check_k(k, max_k)
        except InvalidKError as exc:
            raise HTTPException(422, str(exc)) from None
        dirs = [log_dir_of(lid) for lid in log_id] if log_id else list(logs.values())
        h, kap = transform(kappa)
        try:
            spans = search.find(dirs, tag, region, threshold, min_duration_s, k, h, kap)
        except TagError as exc:
            raise HTTPException(422, str(exc)) from None
        return {"tag": tag, "region": region, "threshold": threshold, "k": k,
                "results": [s.to_dict() for s in spans]}
