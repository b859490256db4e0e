"""A query's arguments, checked once where the query is built, and index hits → result records.

Every search entry point (:class:`retrieval.SceneSearch`, :class:`retrieval.captions_search.CaptionSearch`,
and through them the CLI and the HTTP service) builds a :class:`Query` with :func:`build_query` before
any work: ``k`` and the filter are checked there, with one error style naming the parameter, and the
layers below (:func:`hits_to_results`, :mod:`indexes`) take the query as it is.

The query sentence has one check too, :func:`check_query` (its text by :func:`check_text`): at most
:data:`MAX_QUERY_CHARS` characters, no control character but tab, line feed and carriage return, and
nothing that is not text (a lone surrogate, which is what Python makes of bytes that are not UTF-8 in
a command-line argument). The CLI, the Python API and the HTTP service all call it, so a query one of
them refuses is refused by the others with the same rule.

The index packages load on first use, so that reading :data:`MAX_QUERY_CHARS` (the service's default
limit, read when the CLI builds its options) stays light.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from retrieval.errors import EmptyQueryError, FilterSyntaxError, InvalidKError, NoCameraError, RetrievalError
from retrieval.records import SearchResult

if TYPE_CHECKING:
    from indexes.clip_index import ClipIndex
    from indexes.filters import Condition, FilterSpec
    from indexes.metadata import MetadataStore

#: The most results one query may ask for (the service lowers it with its own limit).
MAX_K = 10_000
#: The longest query sentence, in characters, that any entry point takes (the service may lower it).
MAX_QUERY_CHARS = 500

#: What a query may not hold: control characters other than tab, line feed and carriage return (C0,
#: DEL and C1), and surrogates (never text on their own; the escapes of bytes that are not UTF-8).
_NOT_TEXT = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\ud800-\udfff]")


class QueryTooLongError(RetrievalError):
    """A query (or another text parameter) longer than its limit."""

    def __init__(self, name: str, length: int, limit: int) -> None:
        self.length, self.limit = length, limit
        super().__init__(f"{name} is {length} characters; the limit is {limit}")


class QueryTextError(RetrievalError):
    """A query (or another text parameter) holding a control character or bytes that are not UTF-8 text."""


def check_text(value: str, name: str = "query", max_chars: int = MAX_QUERY_CHARS) -> str:
    """``value`` when a query may hold it: at most ``max_chars`` characters, no control character
    but tab, line feed and carriage return, no surrogate; ``name`` (``"parameter 'q'"``) starts the message.

    Raises:
        QueryTooLongError: more than ``max_chars`` characters.
        QueryTextError: a control character or a surrogate; the message says which and where.
    """
    if len(value) > max_chars:
        raise QueryTooLongError(name, len(value), max_chars)
    bad = _NOT_TEXT.search(value)
    if bad is None:
        return value
    code = ord(bad.group())
    if 0xDC80 <= code <= 0xDCFF:  # Python's escape of an undecodable byte (surrogateescape)
        raise QueryTextError(f"{name} is not valid UTF-8: byte 0x{code - 0xDC00:02x} at character {bad.start()}")
    if 0xD800 <= code <= 0xDFFF:
        raise QueryTextError(f"{name} is not valid text: lone surrogate U+{code:04X} at character {bad.start()}")
    raise QueryTextError(f"{name} holds the control character U+{code:04X} at character {bad.start()}; "
                         "a query is text (tabs and line breaks aside)")


def check_query(query: object, name: str = "query", max_chars: int = MAX_QUERY_CHARS) -> str:
    """The query sentence without surrounding blanks, checked by :func:`check_text`.

    Raises:
        EmptyQueryError: not a string, or nothing but blanks.
        QueryTooLongError, QueryTextError: see :func:`check_text`.
    """
    if not isinstance(query, str) or not query.strip():
        raise EmptyQueryError()
    return check_text(query, name, max_chars).strip()


@dataclass(frozen=True)
class Query:
    """The checked ``k`` and filter of one search.

    Attributes:
        k: results to ask for, 0 … the items the search can return (0 only when it can return none).
        filters: the filter's conditions, each naming a metadata field with a value of its type and an
            operator it takes; None without a filter.
    """

    k: int
    filters: tuple[Condition, ...] | None


def build_query(k: object, filters: FilterSpec, metadata: MetadataStore, size: int, max_k: int = MAX_K,
                view: str | None = None) -> Query:
    """Check ``k`` and ``filters`` against the searched ``metadata``; the only place either is checked.

    Args:
        k: results wanted, an integer in 1 … ``max_k``; more than ``size`` gives ``size``.
        filters: ``{"category": "car"}``, ``{"category": ["car", "bus"]}``, a filter string
            (``"category in {car, bus} and tags contains 'left:approach'"``, see :mod:`indexes.filters`),
            conditions, or None.
        metadata: the rows searched; filters may name its fields except ``id``.
        size: how many items the search can return.
        max_k: the most results a query may ask for.
        view: the clip embedding searched. ``camera`` keeps to the clips the camera saw (``has_camera``,
            where the index records it): a clip without camera frames has no camera embedding worth
            ranking (the tower ran on blank frames), and the evaluation's camera figures leave such
            clips out for that reason.

    Raises:
        InvalidKError: ``k`` is not an integer in 1 … ``max_k``.
        FilterSyntaxError: the filter cannot be read, names an unknown field, or holds a value or an
            operator its field does not take (the message lists the valid fields).
    """
    from indexes.filters import Condition, Op

    checked = _checked_filters(filters, metadata)
    if view == "camera" and "has_camera" in metadata.fields:
        checked = (*(checked or ()), Condition("has_camera", Op.EQ, True))
    return Query(min(check_k(k, max_k), size), checked)


def check_camera_clip(row: dict[str, Any], view: str) -> None:
    """Raise :class:`NoCameraError` when ``view`` is the camera and the indexed clip ``row`` has none."""
    if view == "camera" and row.get("has_camera") is False:
        raise NoCameraError(str(row.get("clip_id")))


def check_k(k: object, max_k: int = MAX_K) -> int:
    """``k`` as an int; raises :class:`InvalidKError` unless it is an integer in 1 … ``max_k``."""
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 1 <= int(k) <= max_k:
        raise InvalidKError(k, max_k)
    return int(k)


def _checked_filters(filters: FilterSpec, metadata: MetadataStore) -> tuple[Condition, ...] | None:
    from indexes.errors import FilterError
    from indexes.filters import check, conditions_of

    if filters is None:
        return None
    valid = [f for f in metadata.fields if f != "id"]
    try:
        conditions = conditions_of(filters)
        unknown = [c.field for c in conditions if c.field not in valid]
        if unknown:
            raise FilterSyntaxError(f"unknown filter field {unknown[0]!r}; valid fields: {', '.join(valid)}")
        check(conditions, metadata.table.schema, filters if isinstance(filters, str) else None)
    except FilterError as exc:
        raise FilterSyntaxError(f"{exc}; valid fields: {', '.join(valid)}") from None
    _check_categorical_values(conditions, metadata)
    return tuple(conditions)


#: A text field with at most this many distinct values is a vocabulary (split, category, weather): a
#: value outside it is a typo, refused with the values it holds, rather than answered with nothing.
MAX_VOCABULARY = 50


def _check_categorical_values(conditions: Sequence[Condition], metadata: MetadataStore) -> None:
    import pyarrow as pa

    from indexes.filters import Op

    for c in conditions:
        if c.op not in (Op.EQ, Op.IN) or not pa.types.is_string(metadata.table.schema.field(c.field).type):
            continue
        present = metadata.distinct(c.field, MAX_VOCABULARY)  # computed once per index, not per query
        if present is None:
            continue
        wanted = c.value if c.op is Op.IN else (c.value,)
        absent = [v for v in wanted if v not in present]
        if absent and len(absent) == len(wanted):
            values = ", ".join(sorted(str(v) for v in present if v is not None))
            raise FilterSyntaxError(f"filter field {c.field!r}: no clip has the value {absent[0]!r}; its values: "
                                    f"{values}")


def parse_cli_filters(items: Sequence[str] | None) -> FilterSpec:
    """``["category=car", "time_of_day=night,dusk"]`` → ``{"category": "car", "time_of_day": [...]}``.

    An item without a single ``=`` (e.g. ``start_ns >= 5``) is passed through in the filter language.
    Checking the result is :func:`build_query`'s job.

    Raises:
        FilterSyntaxError: an item ``FIELD=VALUE`` with an empty side.
    """
    if not items:
        return None
    simple: dict[str, Any] = {}
    expressions: list[str] = []
    for item in items:
        if "=" in item and not any(op in item for op in ("==", "!=", "<=", ">=")) and item.count("=") == 1:
            key, value = (s.strip() for s in item.split("=", 1))
            if not key or not value:
                raise FilterSyntaxError(f"--filter {item!r}: expected FIELD=VALUE, e.g. category=car")
            simple[key] = value.split(",") if "," in value else value
        else:
            expressions.append(item)
    if not expressions:
        return simple
    parts = [f"{k} in {{{', '.join(repr(x) for x in v)}}}" if isinstance(v, list) else f"{k} == {v!r}"
             for k, v in simple.items()]
    return " and ".join(parts + expressions)


def hits_to_results(index: ClipIndex, xq: np.ndarray, query: Query, view: str, base_dir: Path | None,
                    exclude_clip: str | None = None, exclude: Sequence[str] = ()) -> list[SearchResult]:
    """Search ``index`` with one query vector (1, D), or from ``exclude_clip``'s own vector leaving out
    it and the clips ``exclude`` names, and turn the hits into records."""
    if query.k == 0:
        return []
    if exclude_clip is not None:
        found = index.search_clip(exclude_clip, query.k, query.filters, exclude=exclude)
    else:
        found = index.search(xq, query.k, query.filters)
    return [SearchResult.from_row(rank, hit.metadata, hit.score, view, preview_of(hit.metadata, base_dir))
            for rank, hit in enumerate(found.hits[0], start=1)]


def moment_of(index: ClipIndex, row: Mapping[str, Any]) -> list[str]:
    """The clip ids of ``row``'s moment: the clips of its log whose windows share an instant with its own
    (first and last timestamps included, as :func:`retrieval.clip_neighbours.same_moment` reads them),
    itself included."""
    window = {"log_id": row["log_id"], "start_ns": {"<=": int(row["end_ns"])}, "end_ns": {">=": int(row["start_ns"])}}
    return index.metadata.clip_ids(index.select(window))


def preview_of(row: dict[str, Any], base_dir: Path | None) -> str | None:
    """The absolute preview path of a metadata row (relative ones are under ``base_dir``), or None."""
    rel = row.get("preview_path")
    if not rel:
        return None
    path = Path(rel)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    return str(path)
