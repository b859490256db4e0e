"""The service's answers about results: each result's JSON, pages of a search, "more like this" without the
query's own track, the preview drawn for a scenario query, and what is computed once per index.

:class:`ResultContext` holds what the service computes once for the index it serves (the logs' time
spans, the field summary, the embedding map, the calibrations, the clip table of on-demand previews)
and computes each of them when first asked.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from indexes.filters import Condition, FilterSpec, Op
from indexes.metadata import MetadataStore
from retrieval.errors import UnknownClipError, UnknownViewError
from retrieval.querying import build_query, check_camera_clip, hits_to_results, moment_of
from retrieval.records import LogSpan, SearchResult, read_log_spans, time_in_log
from retrieval.scenario_search import ScenarioMatch
from retrieval.scenesearch import SceneSearch
from retrieval.service.explain import (
    SCORE_SCALES,
    Calibration,
    Calibrations,
    calibrate,
    explain_result,
    suggestion,
)
from retrieval.service.overview import embedding_map, examples, field_summary, log_spans_from_clips
from scenesearch_base.lru import Lru

#: On-demand previews kept in memory (bytes), most recently used first.
PREVIEW_CACHE_ENTRIES = 64


def preview_query(referred: Sequence[str], related: Sequence[str]) -> str:
    """The query string of a preview drawn for a scenario query (empty when nothing is to be marked)."""
    from urllib.parse import urlencode

    params = {k: ",".join(v) for k, v in (("referred", referred), ("related", related)) if v}
    return "?" + urlencode(params) if params else ""


def ranked_prefix(fetch: Callable[[int], list[SearchResult]], end: int, total: int) -> list[SearchResult]:
    """The first results up to at least ``end`` in one fixed order, whatever ``k`` a page asks for.

    ``fetch(n)`` gives a search's best ``n``; moments with equal scores (many share a caption) may come in any
    order, and a different ``n`` may cut a group of equal scores elsewhere. So the prefix is fetched until it
    holds the whole group of the score at ``end``, then ordered by score and clip id and ranked anew: a
    page is always the same slice of one ranking.
    """
    n = max(end, 1)
    results = fetch(n)
    while len(results) == n and n < total and len(results) >= end and results[-1].score == results[end - 1].score:
        n = min(total, 2 * n)
        results = fetch(n)
    ordered = sorted(results, key=lambda r: (-r.score, r.clip_id))
    return [replace(r, rank=i) for i, r in enumerate(ordered, start=1)]


class ResultContext:
    """What the service knows about the index it serves beyond a single search (see the module docstring)."""

    def __init__(self, search: SceneSearch) -> None:
        self.search = search
        self.calibrations = Calibrations()
        self._lock = threading.Lock()
        self._spans: dict[str, LogSpan] | None = None
        self._summary: dict[str, Any] | None = None
        self._maps: dict[str, dict[str, Any]] = {}
        self._clip_table: pa.Table | None = None
        self._clips_config: Any = None
        self._previews: Lru[tuple[str, tuple[str, ...], tuple[str, ...]], bytes] = Lru(PREVIEW_CACHE_ENTRIES)
        self._render_lock = threading.Lock()
        self._drawable: dict[str, bool] = {}  # log id → whether the clips folder holds its rendered frames
        self._clips_readable: bool | None = None  # whether the clips folder is of a format this release reads

    @property
    def metadata(self) -> MetadataStore:
        return self.search.views[next(iter(self.search.views))].metadata

    # ------------------------------------------------------------------ per result

    def spans(self) -> dict[str, LogSpan]:
        """Each log's time span: from its rendered frames, else from its indexed moments."""
        with self._lock:
            if self._spans is None:
                table = self.metadata.table
                spans = log_spans_from_clips(table)
                spans.update(read_log_spans(self.search.clips_dir, list(spans)))
                self._spans = spans
            return self._spans

    def result_json(self, result: SearchResult, match: ScenarioMatch | None = None,
                    query: str | None = None) -> dict[str, Any]:
        """A result as the API answers it: the record, its preview's URL (marking the tracks a scenario
        program refers to and relates to), its time in the log, its object sentence and tags in words."""
        out = result.to_dict()
        out.pop("preview_path", None)  # a server path: the page uses the preview URL instead
        drawable = bool(result.preview_path) or self.drawable(result.log_id)
        out["preview_url"] = f"/api/clips/{result.clip_id}/preview" if drawable else None
        out["duration_s"] = round(result.duration_s, 2)
        span = self.spans().get(result.log_id)
        out["time_in_log"] = time_in_log(result, span).to_dict() if span is not None else None
        out.update(explain_result(query, result))
        if match is not None and match.fallback is None:  # the objects the program refers to and relates to
            out.update(match.result_fields(result.clip_id))
            others, related = match.preview_marks(result.clip_id, result.track_id)
            if out["preview_url"] and (others or related):
                out["preview_url"] += preview_query(others, related)
        return out

    # ------------------------------------------------------------------ pages

    def total(self, metadata: MetadataStore, filters: FilterSpec, view: str | None,
              within: Sequence[str] | None = None) -> int:
        """How many moments of ``metadata`` pass ``filters`` (and the view's own condition), within ``within``."""
        checked = build_query(1, filters, metadata, len(metadata), view=view)
        conditions = list(checked.filters or ())
        if within is not None:
            conditions.append(Condition("clip_id", Op.IN, tuple(within)))
        return len(metadata) if not conditions else len(metadata.select(conditions))

    def similar(self, clip_id: str, k: int, filters: FilterSpec, view: str, max_k: int, other_moments: bool,
                same_track: bool) -> list[SearchResult]:
        """The k clips most like ``clip_id``, leaving out the clip itself, its track's other windows unless
        ``same_track``, and the other objects of its moment when ``other_moments``."""
        if view not in self.search.views:
            raise UnknownViewError(view, list(self.search.views))
        index = self.search.views[view]
        if clip_id not in index:
            raise UnknownClipError(clip_id, index.metadata.table.column("clip_id").slice(0, 3).to_pylist())
        row = index.get(clip_id)
        check_camera_clip(row, view)
        exclude: list[str] = []
        if not same_track:
            exclude += index.metadata.clip_ids(index.select({"log_id": str(row["log_id"]),
                                                             "track_id": str(row["track_id"])}))
        if other_moments:
            exclude += moment_of(index, row)
        checked = build_query(k, filters, index.metadata, len(index) - 1, max_k, view)
        return hits_to_results(index, np.zeros((1, index.dim), np.float32), checked, view, self.search.clips_dir,
                               exclude_clip=clip_id, exclude=list(dict.fromkeys(exclude)))

    # ------------------------------------------------------------------ explanations

    def confidence(self, mode: str, view: str, weight: float, results: list[SearchResult]) -> dict[str, Any] | None:
        """Whether the best of ``results`` is weak for ``mode`` (:mod:`retrieval.service.explain`); None when
        the index has no validation clips to calibrate on."""
        s = self.search
        big = len(s)

        def rank(query: str, k: int, conditions: list[Condition]) -> list[SearchResult]:
            if mode == "captions":
                return s.search_captions(query, k=k, filters=conditions, max_k=big)
            if mode == "hybrid":
                return s.search_hybrid(query, k=k, filters=conditions, view=view, weight=weight, max_k=big)
            return s.search_text(query, k=k, filters=conditions, view=view, max_k=big)

        def measure() -> Calibration | None:
            metadata = s.captions.metadata if mode == "captions" else s.views[view].metadata
            if "split" not in metadata.fields:
                return None
            rows = metadata.table.select(["clip_id", "caption", "split"]).to_pylist()
            return calibrate(mode, rows, rank)

        key = (mode, None if mode == "captions" else view, round(weight, 4) if mode == "hybrid" else None)
        calibration = self.calibrations.get(key, measure)
        if calibration is None:
            return None
        return calibration.judge(results[0].score if results else None)

    def suggest(self, query: str, unused: Sequence[str]) -> dict[str, Any] | None:
        """The words of ``query`` its program leaves unused and a phrasing the index knows."""
        s = self.search
        return suggestion(query, unused, lambda q: s.search_captions(q, k=5), s.captions.encoder)

    @staticmethod
    def score_scale(mode: str) -> str:
        return SCORE_SCALES[mode]

    # ------------------------------------------------------------------ once per index

    def summary(self, selects: Callable[[str], bool]) -> dict[str, Any]:
        """:func:`field_summary` of the index and its example queries."""
        with self._lock:
            if self._summary is None:
                table = self.metadata.table
                self._summary = {**field_summary(table), "examples": examples(table, selects)}
            return self._summary

    def embedding_map(self, view: str) -> dict[str, Any]:
        """The embedding map of ``view`` (:func:`retrieval.service.overview.embedding_map`), computed once."""
        if view not in self.search.views:
            raise UnknownViewError(view, list(self.search.views))
        with self._lock:
            if view not in self._maps:
                table, x = self.search.embeddings(view)
                self._maps[view] = {"view": view, **embedding_map(table, x)}
            return self._maps[view]

    # ------------------------------------------------------------------ previews

    def drawable(self, log_id: str) -> bool:
        """Whether previews of the log's clips can be drawn: the clips folder holds its rendered frames."""
        from encoders.clips.layout import read_manifest, rendered_log_dir

        with self._lock:
            if self._clips_readable is None:  # a folder of another format cannot be drawn from
                try:
                    read_manifest(self.search.clips_dir)
                    self._clips_readable = True
                except (OSError, ValueError):
                    self._clips_readable = False
            if log_id not in self._drawable:
                self._drawable[log_id] = self._clips_readable and rendered_log_dir(self.search.clips_dir,
                                                                                   log_id).is_dir()
            return self._drawable[log_id]

    def drawn_preview(self, clip_id: str, referred: Sequence[str], related: Sequence[str]) -> bytes | None:
        """The clip's preview with these marks if it was drawn before and is still kept, else None."""
        return self._previews.get((clip_id, tuple(referred), tuple(related)))

    def preview(self, clip_id: str, referred: Sequence[str], related: Sequence[str]) -> bytes | None:
        """The clip's preview drawn from the clips folder's rendered arrays, marking ``referred`` and
        ``related`` tracks; None when those are not at hand (the caller serves the stored preview, if any).
        Drawn previews are kept, the latest :data:`PREVIEW_CACHE_ENTRIES`."""
        kept = self.drawn_preview(clip_id, referred, related)  # drawn by a request queued before this one
        if kept is not None:
            return kept
        import pyarrow.compute as pc

        from encoders.clips.config import ClipsConfig
        from encoders.clips.layout import read_clip_table, read_manifest
        from encoders.clips.preview import preview_gif

        clips_dir = Path(self.search.clips_dir)
        with self._render_lock:  # one at a time: a page asks for a dozen at once
            try:
                if self._clip_table is None:  # kept in Arrow: one row becomes Python per drawing
                    self._clip_table = read_clip_table(clips_dir)
                    self._clips_config = ClipsConfig.from_dict(read_manifest(clips_dir).get("config", {}))
                rows = self._clip_table.filter(pc.equal(self._clip_table.column("clip_id"), clip_id)).to_pylist()
                if not rows or not self.drawable(str(rows[0]["log_id"])):
                    return None
                row = rows[0]
                data = preview_gif(clips_dir, row, self._clips_config, referred=referred, related=related)
            except (OSError, ValueError, KeyError):
                return None
        self._previews.put((clip_id, tuple(referred), tuple(related)), data)
        return data
