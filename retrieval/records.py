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
            stamps = pq.ParquetFile(path).read(columns=["timestamp_ns"]).column("timestamp_ns")
        except (OSError, ValueError, KeyError):  # missing, unreadable or without the column
            continue
        if len(stamps):
            out[log_id] = LogSpan(int(stamps[0].as_py()), int(stamps[-1].as_py()))
    return out
