"""The plain-text results table the CLI prints: short ids, scores, time in log, captions object first."""

from __future__ import annotations

from collections.abc import Mapping

from retrieval.records import LogSpan, SearchResult, time_in_log
from retrieval.short_ids import ShortIds


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
        ids = ShortIds.of_results(results, spans).readable_ids(results)
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
