"""Typed records returned by :class:`retrieval.SceneSearch` and :mod:`retrieval.captions_search`."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class SearchResult:
    """One retrieved moment: an object of a log over a time window.

    Attributes:
        rank: 1-based position in the result list.
        clip_id: ``f"{log_id}:{track_id}:{start_ns}"`` (the clip's stable id; caption rows use the same form).
        log_id: the log the moment comes from.
        track_id: the object's track (``ego`` for the host vehicle's own caption rows).
        category: the object's category (``car``, ``pedestrian``, …).
        start_ns: first timestamp of the window, nanoseconds.
        end_ns: last timestamp of the window, nanoseconds.
        caption: the rule caption of the moment (canonical form).
        tags: the unified tag sequence, e.g. ``("left:approach", "host:constant")``.
        score: similarity to the query; higher is closer (cosine of normalised embeddings).
        preview_path: absolute path of the moment's preview animation, or None when there is none.
        view: which embedding answered: ``fused``, ``camera``, ``bev`` or ``captions``.
    """

    rank: int
    clip_id: str
    log_id: str
    track_id: str
    category: str
    start_ns: int
    end_ns: int
    caption: str
    tags: tuple[str, ...]
    score: float
    preview_path: str | None
    view: str

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["tags"] = list(self.tags)
        return out

    @staticmethod
    def from_row(rank: int, row: Mapping[str, Any], score: float, view: str,
                 preview_path: str | None) -> SearchResult:
        """A result from a metadata row (a dict with the clip table's columns)."""
        return SearchResult(
            rank=rank,
            clip_id=str(row["clip_id"]),
            log_id=str(row.get("log_id", "")),
            track_id=str(row.get("track_id", "")),
            category=str(row.get("category", "")),
            start_ns=int(row.get("start_ns") or 0),
            end_ns=int(row.get("end_ns") or 0),
            caption=str(row.get("caption") or ""),
            tags=tuple(str(t) for t in (row.get("tags") or ())),
            score=float(score),
            preview_path=preview_path,
            view=view,
        )


@dataclass(frozen=True)
class LogSpan:
    """The time a log covers: its first and last frame's timestamps, nanoseconds."""

    first_ns: int
    last_ns: int

    @property
    def duration_s(self) -> float:
        return (self.last_ns - self.first_ns) / 1e9


@dataclass(frozen=True)
class TimeInLog:
    """When a moment happens in its log: seconds from the log's first frame, and the log's length.

    ``str()`` gives what the page, the CLI and the API show: ``12.4–15.9 s of 20 s``.
    """

    start_s: float
    end_s: float
    log_s: float

    def __str__(self) -> str:
        whole = abs(self.log_s - round(self.log_s)) < 0.05
        return f"{self.start_s:.1f}–{self.end_s:.1f} s of {self.log_s:.0f} s" if whole else \
            f"{self.start_s:.1f}–{self.end_s:.1f} s of {self.log_s:.1f} s"

    def to_dict(self) -> dict[str, Any]:
        return {"start_s": round(self.start_s, 2), "end_s": round(self.end_s, 2), "log_s": round(self.log_s, 2),
                "text": str(self)}


def time_in_log(result: SearchResult, span: LogSpan) -> TimeInLog:
    """When ``result`` happens within its log, whose time ``span`` covers."""
    return TimeInLog((result.start_ns - span.first_ns) / 1e9, (result.end_ns - span.first_ns) / 1e9, span.duration_s)


def read_log_spans(clips_dir: Path | str, log_ids: Iterable[str]) -> dict[str, LogSpan]:
    """The time span of each of ``log_ids`` from its rendered frames (``CLIPS_DIR/logs/<log_id>/frames.parquet``,
    one small column read per log); logs without that file are left out."""
    import pyarrow.parquet as pq

    from encoders.clips.layout import FRAMES_FILE, rendered_log_dir

    out: dict[str, LogSpan] = {}
    for log_id in dict.fromkeys(log_ids):
        path = rendered_log_dir(clips_dir, log_id) / FRAMES_FILE
        try:
            stamps = pq.read_table(path, columns=["timestamp_ns"]).column("timestamp_ns")
        except (OSError, ValueError, KeyError):  # missing, unreadable or without the column
            continue
        if len(stamps):
            out[log_id] = LogSpan(int(stamps[0].as_py()), int(stamps[-1].as_py()))
    return out


def format_table(results: list[SearchResult], width: int | None = None, ids: Mapping[str, str] | None = None,
                 spans: Mapping[str, LogSpan] | None = None) -> str:
    """Results as a plain-text table that fits ``width`` columns (what the CLI prints by default).

    Each result takes one line of fields (rank, short id, score, category, when it happens in its log)
    and below it, indented, its caption in full, wrapped rather than cut, with the object's sentence
    first: every rule caption opens with the ego's sentence, which says least about the object
    (:func:`captioning.text.caption_halves`).

    Args:
        results: the ranked results.
        width: the line length (default: the terminal's width, ``COLUMNS`` where set).
        ids: clip id → the short id to show (:meth:`retrieval.short_ids.ShortIds.readable_ids` of the
            index, which ``similar`` reads back); default: the readable form of these results alone, the
            logs' starts taken from ``spans``.
        spans: log id → the log's time span, for the time within the log; without it the duration shows.
    """
    import shutil
    import textwrap

    if not results:
        return "(no results)"
    width = width or shutil.get_terminal_size().columns
    if ids is None:
        from retrieval.short_ids import ShortIds

        given = dict(spans or {})
        short = ShortIds([r.clip_id for r in results], [r.log_id for r in results], [r.track_id for r in results],
                         [r.start_ns for r in results], [r.end_ns for r in results],
                         read_spans=lambda logs: {lg: given[lg] for lg in logs if lg in given})
        ids = short.readable_ids(r.clip_id for r in results)
    header: tuple[str, ...] = ("#", "id", "score", "category", "time in log" if spans is not None else "duration")
    rows = []
    for r in results:
        span = spans.get(r.log_id) if spans is not None else None
        when = str(time_in_log(r, span)) if span is not None else f"{r.duration_s:.1f} s"
        rows.append((str(r.rank), ids.get(r.clip_id, r.clip_id), f"{r.score:.3f}", r.category, when))
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(header)]
    # Too narrow for every field on one line: the time opens the caption's lines instead.
    time_below = sum(widths) + 2 * (len(widths) - 1) > width
    if time_below:
        header, widths = header[:-1], widths[:-1]
    indent = " " * (widths[0] + 2)
    text_width = max(len(indent) + 20, width)  # textwrap counts the indent in the width
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths)).rstrip(),
             f"{indent}{'time: ' if time_below else ''}caption"]
    lines.append("  ".join("-" * w for w in widths))
    for r, row in zip(results, rows):
        lines.append("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip())
        text = object_first(r.caption) or "(no caption)"
        lines.extend(textwrap.wrap(f"{row[-1]}: {text}" if time_below else text, text_width, initial_indent=indent,
                                   subsequent_indent=indent, break_on_hyphens=False))
    return "\n".join(lines)


def object_first(caption: str) -> str:
    """The caption with the object's sentence before the ego's (unchanged when it has no object sentence)."""
    from captioning.text import caption_halves

    host, obj = caption_halves(caption)
    return f"{obj} {host}" if host and obj else caption
