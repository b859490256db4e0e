"""``ClipIndex``: clip embeddings plus their metadata, searched by vector with metadata filters.

This is what retrieval uses: text → clip (``search``) and clip → clip (``search_clip``). Ids are
row numbers at build time and grow on ``add``; removed ids are never reused, so an id seen once
always means the same clip.

Saved as one directory: the :class:`~indexes.vector_index.VectorIndex` files, ``metadata.parquet``
and a single ``manifest.json`` covering all of them.
"""

# D and I are FAISS's names for the (nq, k) score and id tables.
# ruff: noqa: E741

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from indexes.errors import ManifestError, MetadataError
from indexes.factory import AutoConfig
from indexes.filters import FilterSpec
from indexes.integrity import Verify, VerifyLike, verifying
from indexes.metadata import CLIP_ID, MetadataStore, Rows, rows_to_table
from indexes.persistence import read_manifest, reading_index_dir, require_files, write_manifest, writing_index_dir
from indexes.vector_index import VectorIndex, check_k, files_of
from indexes.vectors import Metric

KIND = "clip_index"
METADATA_FILE = "metadata.parquet"


@dataclass(frozen=True)
class Hit:
    """One search result.

    Attributes:
        clip_id: the clip.
        score: cosine / inner product (higher is closer) or squared L2 distance (lower is closer).
        id: the clip's int64 id in the index.
        metadata: the clip's metadata row (without ``id``).
    """

    clip_id: str
    score: float
    id: int
    metadata: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class IndexHits:
    """What the index found for a batch of queries (retrieval turns each hit into a user-facing result).

    Attributes:
        D: (nq, k) scores, −inf / +inf where fewer than k clips qualify.
        I: (nq, k) int64 ids, −1 where fewer than k clips qualify.
        hits: per query, the hits in order (padding left out, so a list may hold fewer than k).
    """

    D: np.ndarray
    I: np.ndarray
    hits: list[list[Hit]]


class ClipIndex:
    """A :class:`VectorIndex` whose ids are tied to clip ids and metadata rows."""

    def __init__(self, vectors: VectorIndex, metadata: MetadataStore) -> None:
        if not np.array_equal(vectors.ids, metadata.ids):
            raise MetadataError(f"the metadata holds {len(metadata)} ids that differ from the "
                                f"{len(vectors)} ids of the vectors")
        self.vectors = vectors
        self.metadata = metadata

    @classmethod
    def build(cls, xb: np.ndarray, metadata: Rows, metric: Metric | str = "cosine", factory: str = "auto",
              memory_budget_bytes: int | None = None, config: AutoConfig | None = None) -> ClipIndex:
        """Index ``xb`` (N, d) with ``metadata``: N dicts or a table, each with a unique ``clip_id``.

        Row i gets id i.
        """
        table = rows_to_table(metadata)
        n = len(np.asarray(xb)) if np.asarray(xb).ndim == 2 else 1
        if table.num_rows != n:
            raise MetadataError(f"{table.num_rows} metadata rows for {n} vectors")
        ids = np.arange(n, dtype=np.int64)
        store = MetadataStore.from_rows(table, ids)  # validates clip ids before the costly build
        vectors = VectorIndex.build(xb, ids, metric, factory, memory_budget_bytes, config)
        return cls(vectors, store)

    # ------------------------------------------------------------------ reading

    def __len__(self) -> int:
        return len(self.vectors)

    @property
    def dim(self) -> int:
        return self.vectors.dim

    @property
    def metric(self) -> Metric:
        return self.vectors.metric

    @property
    def fields(self) -> list[str]:
        """Metadata fields that filters may name."""
        return self.metadata.fields

    def __contains__(self, clip_id: object) -> bool:
        if not isinstance(clip_id, str):
            return False
        try:
            self.metadata.ids_of([clip_id])
        except MetadataError:
            return False
        return True

    def get(self, clip_id: str) -> dict[str, Any]:
        """The metadata row of ``clip_id`` (with its ``id``)."""
        return self.metadata.rows(self.metadata.ids_of([clip_id]))[0]

    def reconstruct(self, clip_ids: str | Sequence[str]) -> np.ndarray:
        """(M, d) stored vectors of ``clip_ids`` ((d,) for a single clip id)."""
        single = isinstance(clip_ids, str)
        names = [clip_ids] if isinstance(clip_ids, str) else list(clip_ids)
        x = self.vectors.reconstruct(self.metadata.ids_of(names))
        return x[0] if single else x

    def select(self, filter: FilterSpec) -> np.ndarray:
        """(M,) ids whose metadata matches ``filter``."""
        return self.metadata.select(filter)

    # ------------------------------------------------------------------ search

    def search(self, xq: np.ndarray, k: int, filter: FilterSpec = None) -> IndexHits:
        """The k closest clips to each query among those matching ``filter``.

        Args:
            xq: (nq, d) or (d,) query vectors.
            k: results per query, 1 … ``len(self)``; fewer come back (padded with −1 in ``I``)
                when fewer clips match the filter.
            filter: a filter string, dict or conditions (see :mod:`indexes.filters`), or None.

        Raises:
            InvalidKError: ``k <= 0`` or ``k > len(self)`` (checked by :meth:`VectorIndex.search`).
            FilterError: an unknown field or a value of the wrong type.
        """
        allowed = None if filter is None else self.metadata.select(filter)
        D, I = self.vectors.search(xq, k, allowed)
        return IndexHits(D, I, self._hits(D, I))

    def search_clip(self, clip_id: str, k: int, filter: FilterSpec = None,
                    exclude_self: bool = True, exclude: Sequence[str] = ()) -> IndexHits:
        """Clips closest to ``clip_id``'s own vector (clip → clip); the clip itself left out by default,
        and the clips ``exclude`` names (ids the index does not hold are ignored). As with a filter,
        fewer than k come back when fewer are left (``D`` and ``I`` padded as :class:`IndexHits` says).

        Raises:
            TypeError: ``exclude`` is a single string rather than a sequence of clip ids.
        """
        if isinstance(exclude, str):
            raise TypeError(f"exclude takes a sequence of clip ids, got the string {exclude!r}")
        x = self.reconstruct(clip_id)[None, :]
        names = [*exclude, clip_id] if exclude_self else list(exclude)
        left_out = self.metadata.ids_of([c for c in dict.fromkeys(names) if c in self])  # (M,)
        if not len(left_out):
            return self.search(x, k, filter)
        check_k(k, len(self) - 1 if exclude_self else len(self))
        if filter is None:
            # A few more results than asked, then drop the ones left out: cheaper than an "everything but
            # these" filter.
            D, I = self.vectors.search(x, min(k + len(left_out), len(self)))
            keep = np.flatnonzero(~np.isin(I[0], left_out))[:k]
            pad = k - len(keep)
            D = np.pad(D[:, keep], ((0, 0), (0, pad)), constant_values=self.vectors.metric.missing_score)
            I = np.pad(I[:, keep], ((0, 0), (0, pad)), constant_values=-1)
        else:
            allowed = self.metadata.select(filter)
            D, I = self.vectors.search(x, k, allowed[~np.isin(allowed, left_out)])
        return IndexHits(D, I, self._hits(D, I))

    def _hits(self, D: np.ndarray, I: np.ndarray) -> list[list[Hit]]:
        valid = I >= 0
        flat_ids = I[valid]
        rows = self.metadata.rows(flat_ids) if len(flat_ids) else []
        out: list[list[Hit]] = []
        it = iter(rows)
        for q in range(len(I)):
            hits = []
            for j in np.flatnonzero(valid[q]):
                row = dict(next(it))
                row.pop("id", None)
                hits.append(Hit(str(row[CLIP_ID]), float(D[q, j]), int(I[q, j]), row))
            out.append(hits)
        return out

    # ------------------------------------------------------------------ changes

    def add(self, xb: np.ndarray, metadata: Rows) -> np.ndarray:
        """Add clips; returns their new (N,) ids (after every id ever used)."""
        table = rows_to_table(metadata)
        clashes = [c for c in table.column(CLIP_ID).to_pylist() if c in self]
        if clashes:
            raise MetadataError(f"clip ids already in the index: {clashes[:10]}", field=CLIP_ID)
        n = table.num_rows
        ids = np.arange(self.vectors.next_id, self.vectors.next_id + n, dtype=np.int64)
        # Validate the rows first: a failure must leave both halves unchanged.
        MetadataStore.from_rows(table, ids)
        self.vectors.add(xb, ids)
        try:
            self.metadata.append(table, ids)
        except MetadataError:
            self.vectors.remove(ids)
            raise
        return ids

    def remove(self, clip_ids: Sequence[str]) -> int:
        """Remove clips by clip id; returns how many were removed."""
        ids = self.metadata.ids_of(list(clip_ids))
        n = self.vectors.remove(ids)
        self.metadata.remove(ids)
        return n

    # ------------------------------------------------------------------ persistence

    def save(self, directory: Path | str, overwrite: bool = True) -> None:
        """Write vectors, metadata and one manifest to ``directory`` atomically."""
        with writing_index_dir(directory, overwrite=overwrite) as tmp:
            extra = self.vectors.write_files(tmp)
            self.metadata.write(tmp / METADATA_FILE)
            extra["metadata_fields"] = self.metadata.fields
            write_manifest(tmp, KIND, self.dim, self.metric.value, self.vectors.factory, len(self), extra)

    @classmethod
    def load(cls, directory: Path | str, mmap: bool = False, verify: VerifyLike = Verify.CACHED) -> ClipIndex:
        """Load a directory written by :meth:`save`; see :meth:`VectorIndex.load` for the arguments."""
        with reading_index_dir(directory) as d:
            m = read_manifest(d, KIND)
            require_files(m, d, (*files_of(m.extra), METADATA_FILE))
            with verifying(d, m.files, verify):
                vectors = VectorIndex.from_files(d, m.dim, m.metric, m.factory, m.count, m.extra, mmap)
                metadata = MetadataStore.read(d / METADATA_FILE)
        if not np.array_equal(vectors.ids, metadata.ids):
            raise ManifestError(d / METADATA_FILE, "its ids differ from the index's ids", field="id")
        return cls(vectors, metadata)
