"""Indexes larger than memory: train on a sample, add in parallel shards, merge into lists on disk.

:func:`build_on_disk` turns vectors in ``.npy`` files (:mod:`indexes.vector_files`) into one saved
index whose inverted lists stay on disk and are memory-mapped by searches
(:mod:`indexes.ondisk_lists`). It opens like any index — ``VectorIndex.load`` (or ``ClipIndex.load``
when metadata was given), checksums verified — and searches with ``nprobe`` like an in-memory IVF
index, with the same results (the lists hold the same codes in the same order).

1. **Plan** (:func:`plan_on_disk`): the factory ``IVF{K},{codec}`` (K as for in-memory indexes,
   with an exact coarse quantizer), the training sample, and how many rows each add task and each
   read takes, all fitted to the memory budget; the build is refused up front when a phase cannot
   fit (:class:`~indexes.errors.MemoryBudgetError`, listing each phase's estimate).
2. **Train** the coarse quantizer (k-means) and the codec (``SQ8``, ``PQ{M}``, …) on a seeded
   sample read from the files.
3. **Add** (:func:`add_shard`): each task reads the trained index from its file and a span of rows,
   and writes a shard index file. It is a plain function of picklable arguments, so ``map_fn`` may
   run the tasks anywhere, e.g. as Ray tasks; the default runs them here, one after the other.
4. **Merge** the shards' lists into ``index.ivfdata`` with FAISS's ``OnDiskInvertedLists``
   (``merge_from_multiple``, as ``faiss.contrib.ondisk.merge_ondisk``), reading the shards mapped.
5. **Tune** ``nprobe`` to the target recall@10 on held-out rows against exact search streamed over
   the files (:func:`faiss.contrib.exhaustive_search.knn_ground_truth`).

Everything is written inside the index's temporary directory, which replaces the target in one
rename when done (:mod:`indexes.persistence`); the shard files are deleted before that.

**Memory** is planned and measured as :mod:`indexes.ondisk_plan` says.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import faiss
import numpy as np
import pyarrow as pa

from indexes.clip_index import KIND as CLIP_KIND
from indexes.clip_index import METADATA_FILE
from indexes.errors import IndexesError, IndexFileError
from indexes.factory import AutoConfig
from indexes.integrity import FileEntry, verify_files
from indexes.metadata import MetadataStore
from indexes.ondisk_lists import IVFDATA_FILE, LOCATIONS_FILE, ON_DISK, list_locations, write_ondisk_index
from indexes.ondisk_plan import (
    DEFAULT_CODEC,
    DEFAULT_MEMORY_BUDGET_BYTES,
    MemoryBudgetWarning,
    OnDiskPlan,
    PeakMemory,
    plan_on_disk,
)
from indexes.ondisk_steps import AddTask, ShardResult, add_shard, merge_shards, train_index, tune_on_files
from indexes.persistence import write_manifest, writing_index_dir
from indexes.vector_files import VectorFiles
from indexes.vector_index import IDS_FILE, INDEX_FILE, KIND, REMOVED_FILE, TOMBSTONES_FILE, VectorIndex
from indexes.vectors import Metric, as_metric

__all__ = ["AddTask", "MapFn", "MemoryBudgetWarning", "OnDiskBuild", "OnDiskPlan", "ShardResult", "add_shard",
           "build_on_disk", "plan_on_disk"]

AddFn = Callable[[AddTask], ShardResult]
#: ``map_fn(add_shard, tasks)`` → one result per task, in any order (e.g. a Ray map, an executor's map).
MapFn = Callable[[AddFn, Sequence[AddTask]], Iterable[ShardResult]]


@dataclass(frozen=True)
class OnDiskBuild:
    """What :func:`build_on_disk` did.

    Attributes:
        directory: the saved index (open it with ``VectorIndex.load``, or ``ClipIndex.load`` with metadata).
        count: vectors indexed.
        plan: the plan followed.
        seconds: wall time per phase (``train``, ``add``, ``merge``, ``tune``, ``save``).
        peak_memory_bytes: highest anonymous memory per phase in this process; ``add_task`` is the
            highest of any add task in its own process.
        size_bytes: the index's files on disk.
        shards: add tasks run.
        tuning: the tuning record, or None.
    """

    directory: Path
    count: int
    plan: OnDiskPlan
    seconds: dict[str, float]
    peak_memory_bytes: dict[str, int]
    size_bytes: int
    shards: int
    tuning: dict[str, Any] | None

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["directory"] = str(self.directory)
        out["plan"] = self.plan.to_dict()
        return out


def build_on_disk(vectors: Sequence[Path | str] | VectorFiles, directory: Path | str, *,
                  ids: Sequence[Path | str] | None = None, metric: Metric | str = "cosine",
                  codec: str = DEFAULT_CODEC, nlist: int | None = None,
                  memory_budget_bytes: int = DEFAULT_MEMORY_BUDGET_BYTES, workers: int = 1,
                  map_fn: MapFn | None = None, work_dir: Path | str | None = None,
                  config: AutoConfig | None = None, tune_recall: bool = True,
                  metadata: pa.Table | None = None, overwrite: bool = True,
                  two_level_training: bool = False) -> OnDiskBuild:
    """Build an index with on-disk lists from vectors in ``.npy`` files (see the module docstring).

    Args:
        vectors: (n_i, d) float ``.npy`` files, or :class:`VectorFiles` already opened.
        directory: where the index is saved (replaced atomically).
        ids: one (n_i,) int64 ``.npy`` file per vector file; None: ids 0 … N−1 in file order.
        metric: ``cosine`` (rows normalised), ``ip`` or ``l2``.
        codec: see :func:`plan_on_disk`.
        nlist: number of lists; see :func:`plan_on_disk`.
        memory_budget_bytes: see :func:`plan_on_disk`.
        workers: add tasks running at once (``map_fn`` decides where they run).
        map_fn: ``map_fn(add_shard, tasks)`` runs the add tasks, e.g. on Ray; by default they run
            here, one after the other. Tasks read the vector files and write into the work folder,
            so both must be reachable wherever they run.
        work_dir: folder for the trained index and the shard files (a shared file system when
            tasks run on other machines); by default inside the index's temporary directory.
        config: list-count rule, training sample, tuning target and seed.
        tune_recall: tune ``nprobe`` to ``config.target_recall``; otherwise ``nprobe`` stays 1.
        metadata: a table of N rows in file order, each with a unique ``clip_id``: the result is a
            ``ClipIndex`` directory.
        overwrite: replace an existing index at ``directory``.
        two_level_training: see ``two_level`` of :func:`plan_on_disk`.

    Raises:
        IndexFileError: a vector or id file missing, truncated, of another dimension, or with a
            bad row (naming the file and row); a shard file damaged before the merge.
        IdError: ids negative or repeated across the files.
        MemoryBudgetError: the build cannot fit the budget (nothing is read beyond headers).
        MetadataError: metadata rows that do not match the vectors.
    """
    config = config or AutoConfig()
    metric = as_metric(metric)
    files = vectors if isinstance(vectors, VectorFiles) else VectorFiles.open(vectors, ids)
    plan = plan_on_disk(len(files), files.dim, metric, codec, memory_budget_bytes, workers, nlist, config,
                        two_level_training)
    all_ids = files.all_ids()
    store = None if metadata is None else MetadataStore.from_rows(metadata, all_ids)  # checked before any work
    seconds: dict[str, float] = {}
    peaks: dict[str, int] = {}
    target = Path(directory)
    with writing_index_dir(target, overwrite=overwrite) as tmp:
        own_work = work_dir is None
        work = tmp / ".work" if own_work else Path(tempfile.mkdtemp(prefix=f".{target.name}.build.", dir=work_dir))
        work.mkdir(exist_ok=True)
        try:
            t = time.perf_counter()
            with PeakMemory() as peak:
                trained = train_index(files, plan, metric, config.seed)
                trained_path = work / "trained.faiss"
                faiss.write_index(trained, str(trained_path))
            seconds["train"], peaks["train"] = time.perf_counter() - t, peak.peak_bytes

            t = time.perf_counter()
            threads = max(1, (os.cpu_count() or 1) // workers) if map_fn is not None else 0
            tasks = [AddTask(i, trained_path, span, work / f"shard_{i:05d}.faiss", metric.value, plan.chunk_rows,
                             threads) for i, span in enumerate(files.spans(plan.span_rows))]
            with PeakMemory() as peak:
                results = _run_adds(tasks, map_fn)
            seconds["add"], peaks["add"] = time.perf_counter() - t, peak.peak_bytes
            peaks["add_task"] = max(r.peak_memory_bytes for r in results)

            t = time.perf_counter()
            with PeakMemory() as peak:
                verify_files(work, {r.path.name: FileEntry(r.size_bytes, r.sha256) for r in results})
                index = merge_shards(trained, [r.path for r in results], tmp / IVFDATA_FILE)
                for r in results:
                    r.path.unlink()
                stored_ids, locations = list_locations(index)
                if len(stored_ids) != len(all_ids) or not np.array_equal(stored_ids, np.sort(all_ids)):
                    raise IndexesError(f"the merged lists hold {len(stored_ids)} vectors, the files {len(all_ids)}; "
                                       "a shard is missing or was built from other files")
                np.save(tmp / IDS_FILE, stored_ids)
                np.save(tmp / LOCATIONS_FILE, locations)
                del stored_ids, locations
                np.save(tmp / REMOVED_FILE, np.empty(0, np.int64))
                np.save(tmp / TOMBSTONES_FILE, np.empty(0, np.int64))
                write_ondisk_index(index, tmp / INDEX_FILE)
                del index, trained
            seconds["merge"], peaks["merge"] = time.perf_counter() - t, peak.peak_bytes

            t = time.perf_counter()
            with PeakMemory() as peak:
                # Opened the way every reader opens it, so tuning measures what searches will get.
                built = VectorIndex.from_files(tmp, files.dim, metric.value, plan.factory, len(files),
                                               {"storage": ON_DISK}, mmap=True)
                tuning = tune_on_files(built, files, all_ids, metric, config, plan.chunk_rows) if tune_recall else None
            seconds["tune"], peaks["tune"] = time.perf_counter() - t, peak.peak_bytes
        finally:
            shutil.rmtree(work, ignore_errors=True)

        t = time.perf_counter()
        built.info.update(train_points=plan.train_points, on_disk_plan=plan.to_dict())
        if tuning is not None:
            built.info["tuning"] = tuning.to_dict()
        extra = built.manifest_fields()
        kind = KIND
        if store is not None:
            store.write(tmp / METADATA_FILE)
            extra["metadata_fields"] = store.fields
            kind = CLIP_KIND
        write_manifest(tmp, kind, files.dim, metric.value, plan.factory, len(files), extra)
        size = sum(p.stat().st_size for p in tmp.iterdir() if p.is_file())
        seconds["save"] = time.perf_counter() - t
    # The add tasks run at once, each in its own process (or all in this one, without map_fn).
    measured = {**peaks, "add_task": peaks["add_task"] * (workers if map_fn is not None else 1)}
    over = {phase: b for phase, b in measured.items() if b > plan.memory_budget_bytes}
    if over:
        warnings.warn(f"{target}: measured memory above the budget of {plan.memory_budget_bytes / 2**30:.2f} GiB in "
                      + ", ".join(f"{p} ({b / 2**30:.2f} GiB)" for p, b in over.items()), MemoryBudgetWarning,
                      stacklevel=2)
    return OnDiskBuild(target, len(files), plan, {k: round(v, 3) for k, v in seconds.items()}, peaks, size,
                       len(tasks), None if tuning is None else tuning.to_dict())


def _run_adds(tasks: list[AddTask], map_fn: MapFn | None) -> list[ShardResult]:
    """Run every task; results in task order, checked to be one per task."""
    results = [add_shard(t) for t in tasks] if map_fn is None else list(map_fn(add_shard, tasks))
    by_number = {r.number: r for r in results}
    missing = [t for t in tasks if t.number not in by_number]
    if missing:
        raise IndexesError(f"{len(missing)} of {len(tasks)} add tasks returned no shard (first: rows "
                           f"{missing[0].span.start}…{missing[0].span.stop - 1} of {missing[0].span.vectors})")
    for t in tasks:
        r = by_number[t.number]
        if r.count != len(t.span):
            raise IndexFileError(r.path, f"holds {r.count} vectors, its task added {len(t.span)}")
    return [by_number[t.number] for t in tasks]
