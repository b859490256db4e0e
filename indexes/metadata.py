"""Clip metadata beside the vectors: one Parquet table keyed by the vectors' int64 ids.

Columns: ``id`` (int64, unique, ascending), ``clip_id`` (string, unique), then any clip metadata —
``log_id``, ``category``, ``start_ns``/``end_ns``, ``time_of_day``, ``appearance``, list<string>
``tags`` … Filters (:mod:`indexes.filters`) run over this table and yield the ids that FAISS may
return.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeAlias

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from indexes.errors import IdError, IndexFileError, MetadataError
from indexes.filters import FilterSpec, compile_mask
from scenesearch_base.arrow_numpy import from_numpy, is_string, to_numpy

ID = "id"
CLIP_ID = "clip_id"
Rows: TypeAlias = pa.Table | Sequence[Mapping[str, Any]]


class MetadataStore:
    """The metadata table; rows sorted by ``id``. Changes return nothing and replace the table."""

    def __init__(self, table: pa.Table, source: str = "metadata") -> None:
        _validate(table, source)
        self._table = table.combine_chunks()
        self._ids = np.asarray(to_numpy(self._table.column(ID)), dtype=np.int64)
        self._clip_pos: dict[str, int] | None = None
        self._distinct: dict[str, frozenset[Any] | None] = {}

    @classmethod
    def from_rows(cls, rows: Rows, ids: np.ndarray) -> MetadataStore:
        """Store for ``rows`` (dicts or a table with a ``clip_id`` column) labelled by ``ids`` (N,)."""
        table = rows_to_table(rows)
        if table.num_rows != len(ids):
            raise MetadataError(f"{table.num_rows} metadata rows for {len(ids)} vectors")
        if ID in table.column_names:
            table = table.drop_columns([ID])
        table = table.add_column(0, ID, pa.array(np.asarray(ids, dtype=np.int64)))
        order = np.argsort(np.asarray(ids), kind="stable")
        return cls(table.take(pa.array(order)))

    # ------------------------------------------------------------------ reading

    @property
    def table(self) -> pa.Table:
        return self._table

    @property
    def fields(self) -> list[str]:
        return list(self._table.column_names)

    @property
    def ids(self) -> np.ndarray:
        """(N,) ids, ascending; a copy."""
        return self._ids.copy()

    def __len__(self) -> int:
        return int(self._table.num_rows)

    def select(self, spec: FilterSpec) -> np.ndarray:
        """(M,) ids of the rows matching the filter, ascending."""
        return self._ids[compile_mask(self._table, spec)]

    def positions(self, ids: np.ndarray) -> np.ndarray:
        """(M,) row positions of ``ids``; raises :class:`IdError` for unknown ids."""
        arr = np.asarray(ids, dtype=np.int64)
        pos = np.searchsorted(self._ids, arr)
        pos_c = np.minimum(pos, max(len(self._ids) - 1, 0))
        bad = (pos >= len(self._ids)) | (self._ids[pos_c] != arr) if len(self._ids) else np.ones(len(arr), bool)
        if bad.any():
            raise IdError("ids have no metadata row", arr[bad].tolist())
        return pos_c

    def rows(self, ids: np.ndarray) -> list[dict[str, Any]]:
        """Metadata rows (as dicts) of ``ids`` (M,), in that order."""
        return self._table.take(from_numpy(self.positions(ids))).to_pylist()

    def clip_ids(self, ids: np.ndarray) -> list[str]:
        return self._table.column(CLIP_ID).take(from_numpy(self.positions(ids))).to_pylist()

    def distinct(self, field: str, limit: int) -> frozenset[Any] | None:
        """The distinct values of a column when it holds at most ``limit`` of them, else None; computed
        once per store (filters check a vocabulary's values against them)."""
        if field not in self._distinct:
            values = pc.unique(self._table.column(field))
            self._distinct[field] = frozenset(values.to_pylist()) if len(values) <= limit else None
        return self._distinct[field]

    def ids_of(self, clip_ids: Sequence[str]) -> np.ndarray:
        """(M,) ids of ``clip_ids``; raises :class:`MetadataError` listing unknown clip ids."""
        if self._clip_pos is None:
            self._clip_pos = {c: i for i, c in enumerate(self._table.column(CLIP_ID).to_pylist())}
        unknown = [c for c in clip_ids if c not in self._clip_pos]
        if unknown:
            raise MetadataError(f"unknown clip ids: {unknown[:10]}", field=CLIP_ID)
        return self._ids[[self._clip_pos[c] for c in clip_ids]] if clip_ids else np.empty(0, np.int64)

    # ------------------------------------------------------------------ changing

    def append(self, rows: Rows, ids: np.ndarray) -> None:
        new = MetadataStore.from_rows(rows, ids).table
        try:
            table = pa.concat_tables([self._table, new], promote_options="permissive")
        except (pa.ArrowInvalid, pa.ArrowTypeError) as exc:
            raise MetadataError(f"new rows do not match the existing columns: {exc}") from None
        order = np.argsort(np.asarray(table.column(ID).to_numpy()), kind="stable")
        store = MetadataStore(table.take(pa.array(order)))
        self._table, self._ids, self._clip_pos, self._distinct = store._table, store._ids, None, {}

    def remove(self, ids: np.ndarray) -> None:
        keep = ~np.isin(self._ids, np.asarray(ids, dtype=np.int64))
        self._table = self._table.filter(pa.array(keep))
        self._ids = self._ids[keep]
        self._clip_pos, self._distinct = None, {}

    # ------------------------------------------------------------------ files

    def write(self, path: Path) -> None:
        pq.write_table(self._table, path)

    @classmethod
    def read(cls, path: Path) -> MetadataStore:
        try:
            table = pq.ParquetFile(path).read()  # not read_table: it imports pyarrow.dataset, a cost of every search
        except (OSError, pa.ArrowInvalid) as exc:
            raise IndexFileError(path, f"unreadable Parquet: {exc}") from None
        return cls(table, source=str(path))


def rows_to_table(rows: Rows) -> pa.Table:
    """A table from dict rows (checked for ``clip_id``) or an existing table."""
    if isinstance(rows, pa.Table):
        return rows
    rows_list: list[Any] = list(rows)
    for i, row in enumerate(rows_list):
        if not isinstance(row, Mapping):
            raise MetadataError(f"expected a dict, got {type(row).__name__}", row=i)
        if not isinstance(row.get(CLIP_ID), str) or not row.get(CLIP_ID):
            raise MetadataError("missing or empty clip id", row=i, field=CLIP_ID)
    try:
        return pa.Table.from_pylist(rows_list)
    except (pa.ArrowInvalid, pa.ArrowTypeError) as exc:
        raise MetadataError(f"rows do not form a table: {exc}") from None


def _validate(table: pa.Table, source: str) -> None:
    for name in (ID, CLIP_ID):
        if name not in table.column_names:
            raise MetadataError(f"{source}: the column is missing", field=name)
    if not pa.types.is_integer(table.schema.field(ID).type):
        raise MetadataError(f"{source}: ids must be integers", field=ID)
    clip = table.column(CLIP_ID)
    if not is_string(clip.type):
        raise MetadataError(f"{source}: clip ids must be strings, got {clip.type}", field=CLIP_ID)
    if clip.null_count:
        row = int(np.flatnonzero(np.asarray(pc.is_null(clip)))[0])
        raise MetadataError(f"{source}: missing clip id", row=row, field=CLIP_ID)
    counts = pc.value_counts(clip)
    repeated = np.flatnonzero(to_numpy(counts.field("counts")) > 1)
    if repeated.size:
        dup = counts.field("values").take(from_numpy(repeated)).to_pylist()
        first = clip.to_pylist().index(dup[0])
        raise MetadataError(f"{source}: duplicate clip ids {dup[:10]}", row=first, field=CLIP_ID)
    ids = to_numpy(table.column(ID))
    if len(ids) > 1 and not (np.diff(ids) > 0).all():
        raise MetadataError(f"{source}: ids must be unique and ascending", field=ID)
