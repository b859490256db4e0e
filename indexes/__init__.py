"""FAISS index choice, build, search with filters, and persistence; id ↔ clip mapping and metadata.

* :class:`VectorIndex` — vectors with the caller's int64 ids (build/search/add/remove/save/load);
* :class:`ShardedIndex` — the same API over several shards;
* :class:`ClipIndex` — vectors plus clip metadata, searched with filters such as
  ``category in {car, truck} and tags contains "left:approach"``;
* :func:`build_on_disk` — a collection larger than memory, from ``.npy`` files, built in parallel
  shards within a memory budget and merged into one index whose lists stay on disk.

Typical use::

    index = ClipIndex.build(embeddings, [{"clip_id": ..., "log_id": ..., "category": ..., "tags": [...]}, ...])
    result = index.search(text_embedding, k=10, filter="category in {car, truck} and time_of_day == night")
    for hit in result.hits[0]:
        print(hit.clip_id, hit.score, hit.metadata["log_id"])
    index.save("out/index")          # atomic; ClipIndex.load("out/index", mmap=True) maps IVF lists
"""

from indexes.clip_index import ClipIndex, Hit, IndexHits
from indexes.errors import (
    DimensionMismatchError,
    FilterError,
    IdError,
    IndexesError,
    IndexFileError,
    InvalidKError,
    ManifestError,
    MemoryBudgetError,
    MetadataError,
    ReadOnlyIndexError,
    UnsupportedFormatError,
    VectorError,
)
from indexes.factory import AutoConfig, FactoryChoice, choose_factory
from indexes.metadata import MetadataStore
from indexes.ondisk import MemoryBudgetWarning, OnDiskBuild, OnDiskPlan, build_on_disk, plan_on_disk
from indexes.sharded import ShardedIndex
from indexes.vector_index import VectorIndex
from indexes.vectors import Metric

__all__ = [
    "AutoConfig",
    "ClipIndex",
    "DimensionMismatchError",
    "FactoryChoice",
    "FilterError",
    "Hit",
    "IdError",
    "IndexFileError",
    "IndexHits",
    "IndexesError",
    "InvalidKError",
    "ManifestError",
    "MemoryBudgetError",
    "MemoryBudgetWarning",
    "MetadataError",
    "MetadataStore",
    "Metric",
    "OnDiskBuild",
    "OnDiskPlan",
    "ReadOnlyIndexError",
    "ShardedIndex",
    "UnsupportedFormatError",
    "VectorError",
    "VectorIndex",
    "build_on_disk",
    "choose_factory",
    "plan_on_disk",
]
