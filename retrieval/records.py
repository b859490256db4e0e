"""Typed records returned by :class:`retrieval.SceneSearch` and :mod:`retrieval.captions_search`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
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


def format_table(results: list[SearchResult], max_caption_chars: int = 72) -> str:
    """Results as an aligned plain-text table (what the CLI prints by default); clip ids in full."""
    if not results:
        return "(no results)"
    header = ("#", "score", "category", "dur_s", "caption", "clip_id")
    rows = []
    for r in results:
        caption = r.caption if len(r.caption) <= max_caption_chars else r.caption[: max_caption_chars - 1] + "…"
        rows.append((str(r.rank), f"{r.score:.3f}", r.category, f"{r.duration_s:.1f}", caption, r.clip_id))
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(header)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths)).rstrip()]
    lines.append("  ".join("-" * w for w in widths))
    lines.extend("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in rows)
    return "\n".join(lines)
