"""Caption log folders and search their captions in one call: rule-caption search on any log with
tracks, real AV2 logs without sensors included (:class:`retrieval.captions_search.CaptionSearch`).

>>> search_logs(["logs/7fab2350-…"], "a car in the left lane approaches", k=5)
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from indexes.filters import FilterSpec
from retrieval.captions_search import CaptionSearch, Skipped, TextEncoder
from retrieval.records import SearchResult


def caption_logs(log_dirs: Sequence[Path | str], config: Any = None) -> tuple[pa.Table, list[Skipped]]:
    """Caption log folders with ``captioning.caption_logs``; the caption table and the skipped logs.

    Raises:
        ValueError: no log gave a caption (the message lists why each was skipped).
    """
    import captioning
    from captioning.tables import captions_to_table

    batch = captioning.caption_logs([Path(d) for d in log_dirs], config)
    skipped = [Skipped(str(k), v) for k, v in batch.skipped_logs.items()]
    captions = [c for r in batch.results for c in r.captions]
    if not captions:
        reasons = "; ".join(f"{s.item}: {s.reason}" for s in skipped) or "the logs have no tracks to caption"
        raise ValueError(f"no log gave captions ({reasons})")
    return captions_to_table(captions), skipped


def search_logs(log_dirs: Sequence[Path | str], query: str, k: int = 10, filters: FilterSpec = None,
                encoder: TextEncoder | None = None) -> list[SearchResult]:
    """Caption ``log_dirs`` and search their captions for ``query`` in one call (tracks only)."""
    table, _ = caption_logs(log_dirs)
    search = CaptionSearch.build(table, encoder=encoder)
    return search.search(query, k=min(k, len(search)), filters=filters)
