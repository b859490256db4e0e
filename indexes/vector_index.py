"""``VectorIndex``: a FAISS index that keeps the caller's int64 ids, filters, removes and persists.

FAISS stores vectors and int64 ids; this class owns everything around them:

* ids — the caller's ids live inside the FAISS index (IVF lists natively, other kinds through
  ``IndexIDMap2``), the set of live ids is kept sorted beside it, and removed ids are never reused;
* filtering inside the search through FAISS ID selectors, with an exact fallback when a filter is
  so selective that the approximate search would come back short (:mod:`indexes.filtered_search`);
* removal: in place where FAISS supports it (Flat, IVF); for HNSW, which cannot delete, removed
  ids become tombstones excluded by a selector on every search;
* saving and loading its files, checked against the manifest.

The trained empty index comes from :mod:`indexes.building` (``factory="auto"`` picks the kind, see
:mod:`indexes.factory`), ``nprobe``/``efSearch`` are tuned to a target recall by
:mod:`indexes.tuning`, and the directory layout is :mod:`indexes.persistence`'s. What stays here keeps
the id bookkeeping (live, removed, tombstoned ids) true to the FAISS index.

Search results follow FAISS: ``D`` and ``I`` are (nq, k); ``I`` holds the caller's ids, sorted by
closeness; where fewer than k vectors qualify, ``I`` is −1 and ``D`` is −inf (similarity metrics) or
+inf (L2).
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from pathlib import Path
from typing import Any

import faiss
import numpy as np

from indexes.building import IdsLike, prepare_build
from indexes.errors import IdError, IndexesError, InvalidKError, ManifestError, ReadOnlyIndexError, faiss_message
from indexes.factory import AutoConfig
from indexes.filtered_search import filtered_search
from indexes.integrity import Verify, VerifyLike, verifying
from indexes.ondisk_lists import (
    IVFDATA_FILE,
    LOCATIONS_FILE,
    ON_DISK,
    CodeLocator,
    read_ondisk_index,
    write_ondisk_index,
)
from indexes.persistence import (
    load_ids,
    read_faiss_index,
    read_manifest,
    reading_index_dir,
    require_files,
    write_manifest,
    writing_index_dir,
)
from indexes.tuning import (
    get_knob,
    knob_of,
    set_knob,
    tune_index,
    unwrap,
)
from indexes.vectors import Metric, as_metric, prepare_ids, prepare_vectors

KIND = "vector_index"
INDEX_FILE = "index.faiss"
IDS_FILE = "ids.npy"
REMOVED_FILE = "removed.npy"
TOMBSTONES_FILE = "tombstones.npy"
FILES = (INDEX_FILE, IDS_FILE, REMOVED_FILE, TOMBSTONES_FILE)
#: Files an index with on-disk inverted lists has besides :data:`FILES` (see :mod:`indexes.ondisk_lists`).
ON_DISK_FILES = (IVFDATA_FILE, LOCATIONS_FILE)



class VectorIndex:
    """Vectors with the caller's int64 ids; see the module docstring.

    Build with :meth:`build` or :meth:`load`, not the constructor.
    """

    def __init__(self, index: faiss.Index, metric: Metric, factory: str, ids: np.ndarray,
                 removed: np.ndarray, tombstones: np.ndarray, info: dict[str, Any] | None = None,
                 read_only: bool = False, locator: CodeLocator | None = None) -> None:
        self._index = index
        self._dim = int(index.d)  # cached: reading a SWIG attribute costs microseconds per query
        self.metric = metric
        self.factory = factory
        self._ids = np.sort(np.asarray(ids, dtype=np.int64))
        self._removed = np.sort(np.asarray(removed, dtype=np.int64))
        self._tombstones = np.sort(np.asarray(tombstones, dtype=np.int64))
        self.info: dict[str, Any] = dict(info or {})
        self.read_only = read_only or locator is not None
        # Set for an index whose inverted lists stay on disk: stored vectors are decoded from there.
        self._locator = locator
        self._knob = knob_of(index)
        inner = unwrap(index)
        self._is_ivf = faiss.try_extract_index_ivf(inner) is not None
        # FAISS deletes in place from IVF lists and flat code arrays; graphs (HNSW) cannot.
        self._native_remove = self._is_ivf or isinstance(inner, faiss.IndexFlatCodes)

    # ------------------------------------------------------------------ building

    @classmethod
    def build(cls, xb: np.ndarray, ids: IdsLike | None = None, metric: Metric | str = "cosine",
              factory: str = "auto", memory_budget_bytes: int | None = None,
              config: AutoConfig | None = None, tune_recall: bool = True) -> VectorIndex:
        """Build an index over ``xb``.

        Args:
            xb: (N, d) vectors; copied, never modified.
            ids: (N,) unique int64 ids ≥ 0; ``0 … N-1`` when None.
            metric: ``cosine`` (inner product on L2-normalised vectors), ``ip`` or ``l2``.
            factory: ``auto`` (see :func:`indexes.factory.choose_factory`) or any FAISS factory string.
            memory_budget_bytes: memory the index may take; guides ``auto``.
            config: thresholds of the automatic choice and of tuning.
            tune_recall: tune ``nprobe``/``efSearch`` to ``config.target_recall`` after building.

        Raises:
            VectorError, DimensionMismatchError, IdError: bad vectors or ids (naming the row / ids).
            ValueError: an unknown metric or a factory string FAISS rejects.
        """
        config = config or AutoConfig()
        metric = as_metric(metric)
        x, id_arr, factory, index, info = prepare_build(xb, ids, metric, factory, memory_budget_bytes, config)
        n = x.shape[0]
        if n:
            index.add_with_ids(x, id_arr)
        out = cls(index, metric, factory, id_arr, np.empty(0, np.int64), np.empty(0, np.int64), info)
        if tune_recall:
            out.tune_on(x, id_arr, config)
        return out

    @classmethod
    def from_trained(cls, template: faiss.Index, metric: Metric, factory: str, x: np.ndarray,
                     ids: np.ndarray, info: dict[str, Any] | None = None) -> VectorIndex:
        """An index of already prepared vectors ``x`` (N, d) with ``ids`` (N,), in a copy of the
        trained, empty ``template`` (shards share one training)."""
        index = faiss.clone_index(template)
        if len(x):
            index.add_with_ids(x, ids)
        return cls(index, metric, factory, ids, np.empty(0, np.int64), np.empty(0, np.int64), info)

    def tune(self, target_recall: float | None = None, config: AutoConfig | None = None) -> dict[str, Any]:
        """Re-tune ``nprobe``/``efSearch`` on a sample of the vectors now in the index.

        Returns the tuning record, also kept in ``info["tuning"]`` and saved in the manifest.

        Raises:
            IndexesError: the index keeps its lists on disk (it is tuned while it is built, see
                :func:`indexes.ondisk.build_on_disk`; set :attr:`search_knob` to change it).
        """
        if self._locator is not None:
            # Tuning here decodes every vector into memory, which an on-disk collection may not fit.
            raise IndexesError("an index with on-disk lists is tuned while it is built (build_on_disk(..., "
                               "tune_recall=True)); set search_knob to change nprobe")
        config = config or AutoConfig()
        if target_recall is not None:
            config = dataclasses.replace(config, target_recall=target_recall)
        rng = np.random.default_rng(config.seed)
        n_q = min(config.tune_queries, len(self))
        sample_ids = np.sort(rng.choice(self._ids, size=n_q, replace=False))
        # Ground truth over the whole collection needs every vector; tune against the index's own
        # reconstruction so that compressed codes are judged on what they can find.
        xb = self.reconstruct(self._ids)
        self.tune_on(xb, self._ids, config, query_ids=sample_ids)
        return dict(self.info.get("tuning", {}))

    def tune_on(self, x: np.ndarray, ids: np.ndarray, config: AutoConfig,
                 query_ids: np.ndarray | None = None) -> None:
        """Tune the knob with held-out queries drawn from ``x`` (rows labelled ``ids``); see :func:`tune_index`."""
        self.info["tuning"] = tune_index(self._index, self.metric, x, ids, config, query_ids).to_dict()

    # ------------------------------------------------------------------ properties

    def __len__(self) -> int:
        return len(self._ids)

    @property
    def dim(self) -> int:
        return self._dim

    @property
    def ids(self) -> np.ndarray:
        """(N,) live ids, sorted; a copy."""
        return self._ids.copy()

    @property
    def removed_ids(self) -> np.ndarray:
        """(M,) ids removed so far, sorted; a copy. They are never accepted again."""
        return self._removed.copy()

    @property
    def on_disk(self) -> bool:
        """Whether the inverted lists stay on disk (memory-mapped; the index is then read-only)."""
        return self._locator is not None

    @property
    def faiss_index(self) -> faiss.Index:
        """The underlying FAISS index (ids inside are the caller's ids; tombstones still present)."""
        return self._index

    @property
    def search_knob(self) -> tuple[str, int]:
        """``("nprobe" | "efSearch" | "none", value)``."""
        return self._knob.value, get_knob(self._index)

    @search_knob.setter
    def search_knob(self, value: int) -> None:
        set_knob(self._index, value)

    @property
    def recall_at_10(self) -> float | None:
        """Recall@10 measured when the index was tuned, or None."""
        tuning = self.info.get("tuning")
        return None if tuning is None or tuning["recall_at_k"] is None else float(tuning["recall_at_k"])

    def __contains__(self, id_: object) -> bool:
        if not isinstance(id_, int | np.integer):
            return False
        pos = np.searchsorted(self._ids, id_)
        return bool(pos < len(self._ids) and self._ids[pos] == id_)

    def __repr__(self) -> str:
        knob, value = self.search_knob
        return (f"VectorIndex(n={len(self)}, dim={self.dim}, metric={self.metric.value}, "
                f"factory={self.factory!r}, {knob}={value})")

    # ------------------------------------------------------------------ search

    def search(self, xq: np.ndarray, k: int, filter: IdsLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The k nearest vectors to each query (:func:`indexes.filtered_search.filtered_search`).

        Args:
            xq: (nq, d) or (d,) queries.
            k: results per query, 1 … ``len(self)``.
            filter: (M,) ids allowed in the results, or None for all. Ids not in the index are
                ignored. When fewer than k ids pass, rows are padded with −1.

        Returns:
            D: (nq, k) float32 scores (similarity for cosine/ip, squared distance for l2).
            I: (nq, k) int64 ids, −1 where fewer than k results exist.

        Raises:
            InvalidKError: ``k <= 0`` or ``k > len(self)``.
            VectorError, DimensionMismatchError: bad queries (naming the row).
        """
        x = prepare_vectors(xq, self.dim, self.metric, "queries")
        check_k(k, len(self))
        allowed = None if filter is None else self._allowed(filter)
        return filtered_search(self._index, self.metric, self.factory, self._knob, self._ids, self._tombstones,
                               self.reconstruct, x, k, allowed)

    def _allowed(self, filter: IdsLike) -> np.ndarray:
        wanted = np.unique(np.asarray(filter, dtype=np.int64))
        return np.intersect1d(wanted, self._ids, assume_unique=True)

    def reconstruct(self, ids: IdsLike) -> np.ndarray:
        """(M, d) stored vectors (normalised under cosine; approximate for compressed codes).

        Raises:
            IdError: an id is not in the index.
        """
        arr = np.atleast_1d(np.asarray(ids, dtype=np.int64))
        missing = arr[~np.isin(arr, self._ids)]
        if len(missing):
            raise IdError("ids not in the index", missing.tolist())
        if len(arr) == 0:
            return np.empty((0, self.dim), dtype=np.float32)
        if self._locator is not None:
            return self._locator.reconstruct(np.searchsorted(self._ids, arr))
        try:
            return np.asarray(self._index.reconstruct_batch(arr), dtype=np.float32)
        except RuntimeError as exc:
            raise IndexesError(f"factory {self.factory!r} cannot return stored vectors: "
                               f"{faiss_message(exc)}") from None

    # ------------------------------------------------------------------ changes

    def add(self, xb: np.ndarray, ids: IdsLike | None = None) -> np.ndarray:
        """Add vectors; returns their (N,) ids (new ones after every id ever used when None).

        Raises:
            ReadOnlyIndexError: the index was loaded memory-mapped.
            IdError: ids already present, removed earlier, negative or duplicated.
        """
        self._check_writable()
        x = prepare_vectors(xb, self.dim, self.metric, "xb")
        id_arr = prepare_ids(None if ids is None else np.asarray(ids), len(x), start=self.next_id)
        present = id_arr[np.isin(id_arr, self._ids)]
        if len(present):
            raise IdError("ids already in the index", present.tolist())
        reused = id_arr[np.isin(id_arr, self._removed)]
        if len(reused):
            raise IdError("ids were removed earlier and are never reused", reused.tolist())
        if len(x):
            self._index.add_with_ids(x, id_arr)
            self._ids = np.union1d(self._ids, id_arr)
        return id_arr

    def remove(self, ids: IdsLike) -> int:
        """Remove vectors by id; returns how many were removed. Their ids are never reused.

        Raises:
            ReadOnlyIndexError: the index was loaded memory-mapped.
            IdError: an id is not in the index (nothing is removed then).
        """
        self._check_writable()
        arr = np.unique(np.atleast_1d(np.asarray(ids, dtype=np.int64)))
        unknown = arr[~np.isin(arr, self._ids, assume_unique=True)]
        if len(unknown):
            raise IdError("cannot remove ids that are not in the index", unknown.tolist())
        if len(arr) == 0:
            return 0
        if self._native_remove:
            # An IVF index with a hash-table id map removes only through an explicit id array.
            sel = faiss.IDSelectorArray(arr) if self._is_ivf else faiss.IDSelectorBatch(arr)
            n_removed = int(self._index.remove_ids(sel))
            if n_removed != len(arr):
                raise IndexesError(f"FAISS removed {n_removed} vectors, expected {len(arr)}")
        else:
            self._tombstones = np.union1d(self._tombstones, arr)
        self._ids = np.setdiff1d(self._ids, arr, assume_unique=True)
        self._removed = np.union1d(self._removed, arr)
        return len(arr)

    @property
    def next_id(self) -> int:
        """The id :meth:`add` gives next: one past every id ever used."""
        last = max(int(self._ids[-1]) if len(self._ids) else -1,
                   int(self._removed[-1]) if len(self._removed) else -1)
        return last + 1

    def _check_writable(self) -> None:
        if self._locator is not None:
            raise ReadOnlyIndexError("this index keeps its lists on disk and is read-only; build it again with "
                                     "the new vectors, or serve them beside it (ShardedIndex.from_shards)")
        if self.read_only:
            raise ReadOnlyIndexError("this index was loaded memory-mapped and is read-only; "
                                     "load it with mmap=False to change it")

    # ------------------------------------------------------------------ persistence

    def save(self, directory: Path | str, overwrite: bool = True) -> None:
        """Write the index to ``directory`` atomically (see :mod:`indexes.persistence`)."""
        with writing_index_dir(directory, overwrite=overwrite) as tmp:
            extra = self.write_files(tmp)
            write_manifest(tmp, KIND, self.dim, self.metric.value, self.factory, len(self), extra)

    def write_files(self, directory: Path) -> dict[str, Any]:
        """Write the index's files into an existing ``directory``; returns the manifest's extra fields."""
        if self._locator is not None:
            # The lists stay in their file: link it (or copy it, across file systems) beside the new index.
            for source in self._locator.files:
                link_or_copy(source, directory / source.name)
            write_ondisk_index(self._index, directory / INDEX_FILE)
        else:
            faiss.write_index(self._index, str(directory / INDEX_FILE))
        np.save(directory / IDS_FILE, self._ids)
        np.save(directory / REMOVED_FILE, self._removed)
        np.save(directory / TOMBSTONES_FILE, self._tombstones)
        return self.manifest_fields()

    def manifest_fields(self) -> dict[str, Any]:
        """The manifest's extra fields for this index's files (:meth:`from_files` reads them back)."""
        knob, value = self.search_knob
        extra: dict[str, Any] = {"info": self.info, "knob": knob, "knob_value": value,
                                 "tombstones": len(self._tombstones)}
        if self._locator is not None:
            extra["storage"] = ON_DISK
        return extra

    @classmethod
    def load(cls, directory: Path | str, mmap: bool = False, verify: VerifyLike = Verify.CACHED) -> VectorIndex:
        """Load an index saved by :meth:`save`.

        Args:
            directory: the saved directory.
            mmap: map IVF lists (and flat codes) from disk instead of reading them; the index is
                then read-only and pages in on demand.
            verify: file checksums: ``cached`` (hash files not verified before), ``full`` or
                ``off`` (warns); see :mod:`indexes.integrity`. Sizes are always checked. With
                ``mmap`` the first verified open still reads every byte once.

        Raises:
            UnsupportedFormatError: the manifest is from a newer format version.
            ManifestError, IndexFileError: missing, truncated, corrupt or inconsistent files.
        """
        with reading_index_dir(directory) as d:
            manifest = read_manifest(d, KIND)
            require_files(manifest, d, files_of(manifest.extra))
            with verifying(d, manifest.files, verify):
                return cls.from_files(d, manifest.dim, manifest.metric, manifest.factory, manifest.count,
                                      manifest.extra, mmap)

    @classmethod
    def from_files(cls, d: Path, dim: int, metric_name: str, factory: str, count: int,
                   extra: dict[str, Any], mmap: bool) -> VectorIndex:
        """Read the files :meth:`write_files` wrote and check them against the manifest's fields."""
        manifest_path = d / "manifest.json"
        try:
            metric = Metric(metric_name)
        except ValueError:
            raise ManifestError(manifest_path, f"unknown metric {metric_name!r}", field="metric") from None
        on_disk = extra.get("storage") == ON_DISK
        index = read_ondisk_index(d / INDEX_FILE) if on_disk else read_faiss_index(d / INDEX_FILE, mmap)
        ids = load_ids(d / IDS_FILE)
        removed = load_ids(d / REMOVED_FILE)
        tombstones = load_ids(d / TOMBSTONES_FILE)
        if index.d != dim:
            raise ManifestError(manifest_path, f"says dimension {dim}, {INDEX_FILE} has {index.d}", field="dim")
        if index.metric_type != metric.faiss_metric:
            raise ManifestError(manifest_path, f"says metric {metric.value}, {INDEX_FILE} disagrees",
                                field="metric")
        if len(ids) != count or index.ntotal != count + len(tombstones):
            raise ManifestError(manifest_path, f"says {count} vectors, {IDS_FILE} has {len(ids)} and "
                                f"{INDEX_FILE} {index.ntotal} (with {len(tombstones)} tombstones)", field="count")
        locator = CodeLocator(d, index, count) if on_disk else None
        out = cls(index, metric, factory, ids, removed, tombstones, extra.get("info"), read_only=mmap, locator=locator)
        if extra.get("knob") == out._knob.value and extra.get("knob_value"):
            set_knob(index, int(extra["knob_value"]))
        return out


def files_of(extra: dict[str, Any]) -> tuple[str, ...]:
    """The files a manifest with these extra fields must list: :data:`FILES`, plus the on-disk lists'."""
    return FILES + ON_DISK_FILES if extra.get("storage") == ON_DISK else FILES


def link_or_copy(source: Path, target: Path) -> None:
    """Hard-link ``source`` to ``target`` (instant; both names are only ever read), or copy it."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copyfile(source, target)


def check_k(k: int, size: int) -> None:
    if not isinstance(k, int | np.integer) or k <= 0 or k > size:
        raise InvalidKError(int(k), size)
