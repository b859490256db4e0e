"""Argument checks and index hits → result records, shared by every search entry point."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from indexes.clip_index import ClipIndex
from indexes.errors import FilterError
from indexes.errors import InvalidKError as IndexInvalidKError
from indexes.filters import FilterSpec
from retrieval.errors import EmptyQueryError, FilterSyntaxError, InvalidKError
from retrieval.records import SearchResult


def check_query(query: object) -> str:
    if not isinstance(query, str) or not query.strip():
        raise EmptyQueryError()
    return query.strip()


#: The most results one query may ask for.
MAX_K = 10_000


def check_k(k: object, size: int) -> int:
    """``k`` as an int, at most ``size`` (the items that can be returned).

    Raises:
        InvalidKError: ``k`` is not an integer in 1 … ``MAX_K``.
    """
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 1 <= int(k) <= MAX_K:
        raise InvalidKError(k, MAX_K)
    return min(int(k), size)


def check_filters(index: ClipIndex, filters: FilterSpec) -> FilterSpec:
    """Reject unknown fields with the list of valid ones; other errors come from the filter language."""
    if filters is None or isinstance(filters, str):
        return filters
    if isinstance(filters, dict):
        valid = [f for f in index.fields if f != "id"]
        unknown = [f for f in filters if f not in valid]
        if unknown:
            raise FilterSyntaxError(f"unknown filter field {unknown[0]!r}; valid fields: {', '.join(valid)}")
    return filters


def hits_to_results(index: ClipIndex, xq: np.ndarray, k: int, filters: FilterSpec, view: str,
                    base_dir: Path | None, exclude_clip: str | None = None) -> list[SearchResult]:
    """Search ``index`` with one query vector (1, D) and turn the hits into records."""
    filters = check_filters(index, filters)
    try:
        if exclude_clip is not None:
            found = index.search_clip(exclude_clip, k, filters)
        else:
            found = index.search(xq, k, filters)
    except FilterError as exc:
        valid = ", ".join(f for f in index.fields if f != "id")
        message = str(exc)
        raise FilterSyntaxError(message if "valid fields" in message else f"{message}; valid fields: {valid}") \
            from None
    except IndexInvalidKError:
        raise InvalidKError(k, MAX_K) from None
    results = []
    for rank, hit in enumerate(found.hits[0], start=1):
        results.append(SearchResult.from_row(rank, hit.metadata, hit.score, view,
                                             preview_of(hit.metadata, base_dir)))
    return results


def preview_of(row: dict[str, Any], base_dir: Path | None) -> str | None:
    rel = row.get("preview_path")
    if not rel:
        return None
    path = Path(rel)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    return str(path)
