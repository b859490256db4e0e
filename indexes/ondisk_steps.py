"""The steps of building an index with on-disk lists: train, add a shard, merge, tune.

:func:`add_shard` is the unit of parallel work: a plain function of a picklable :class:`AddTask`
(the trained index's file, a span of rows, the shard file to write), so that it can run in another
process or on another machine, e.g. as a Ray task. :mod:`indexes.ondisk` runs the steps in order.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import faiss
import numpy as np
from faiss.contrib.exhaustive_search import knn_ground_truth

from indexes.errors import IndexFileError, VectorError, faiss_message
from indexes.factory import AutoConfig
from indexes.ondisk_plan import OnDiskPlan, PeakMemory
from indexes.persistence import read_faiss_index
from indexes.tuning import Knob, TuningResult, knob_limit, search_parameters, set_knob, tune
from indexes.vector_files import RowSpan, VectorFiles, span_chunks
from indexes.vector_index import VectorIndex
from indexes.vectors import Metric, prepare_vectors
from scenesearch_base.atomic import atomic_path
from scenesearch_base.checksums import sha256_file

# ---------------------------------------------------------------------- reading prepared rows


def _prepare(x: np.ndarray, dim: int, metric: Metric, span: RowSpan) -> np.ndarray:
    """:func:`prepare_vectors` on rows of ``span``; a bad row is reported by file and row."""
    try:
        return prepare_vectors(x, dim, metric, "vectors")
    except VectorError as exc:
        row = "" if exc.row is None else f"row {span.start + exc.row}: "
        raise IndexFileError(span.vectors, f"{row}{exc.reason}") from None


def _prepare_rows(files: VectorFiles, rows: np.ndarray, metric: Metric) -> np.ndarray:
    """(M, d) prepared vectors at the ascending global ``rows`` (M,)."""
    x = files.read_global_rows(rows)
    try:
        return prepare_vectors(x, files.dim, metric, "vectors")
    except VectorError as exc:
        if exc.row is None:
            raise
        file_no, local = files.locate(rows[exc.row:exc.row + 1])
        raise IndexFileError(files.headers[int(file_no[0])].path, f"row {int(local[0])}: {exc.reason}") from None


def prepared_chunks(files: VectorFiles, metric: Metric, chunk_rows: int) -> Iterator[np.ndarray]:
    """Every vector of ``files`` in order, prepared for ``metric``, as (n, d) chunks of at most ``chunk_rows``."""
    for span, x in files.chunks(chunk_rows):
        yield _prepare(x, files.dim, metric, span)


# ---------------------------------------------------------------------- train


def train_index(files: VectorFiles, plan: OnDiskPlan, metric: Metric, seed: int) -> faiss.Index:
    """The trained, empty index of ``plan``, trained on a seeded sample of ``files``."""
    rng = np.random.default_rng(seed)
    n = plan.n
    rows = np.sort(rng.choice(n, size=plan.train_points, replace=False)) if plan.train_points < n else np.arange(n)
    x = _prepare_rows(files, rows, metric)
    index = faiss.index_factory(plan.dim, plan.factory, metric.faiss_metric)
    ivf = faiss.downcast_index(faiss.extract_index_ivf(index))
    if isinstance(ivf, faiss.IndexIVFPQ):
        # Polysemous training orders PQ codes for a Hamming pre-filter that these searches never
        # turn on; it takes most of PQ's training time.
        ivf.do_polysemous_training = False  # type: ignore[attr-defined]  # missing from the stubs
    try:
        if plan.two_level:
            _train_two_level(index, x, plan.nlist, metric, seed)
        else:
            index.train(x)
    except RuntimeError as exc:
        raise ValueError(f"factory {plan.factory!r} cannot be trained on {len(x)} vectors: "
                         f"{faiss_message(exc)}") from None
    return index


def _train_two_level(index: faiss.Index, x: np.ndarray, nlist: int, metric: Metric, seed: int) -> None:
    """Coarse centroids by two-level k-means, then the codec (as ``train_ivf_index_with_2level``,
    which only handles L2)."""
    if isinstance(index, faiss.IndexPreTransform):
        chain = index.chain  # a SWIG vector, typed as a list by the stubs
        for i in range(chain.size()):  # type: ignore[attr-defined]
            transform = chain.at(i)  # type: ignore[attr-defined]
            transform.train(x)
            x = transform.apply(x)
        _train_two_level(faiss.downcast_index(index.index), x, nlist, metric, seed)
        index.is_trained = True
        return
    ivf = faiss.extract_index_ivf(index)
    # Imported here: it imports scipy.sparse, a cost of every search's start-up that only a build needs.
    from faiss.contrib.clustering import two_level_clustering

    centroids, _ = two_level_clustering(x, math.isqrt(nlist), nlist, spherical=metric is not Metric.L2,
                                        seed=seed, min_points_per_centroid=1)
    ivf.quantizer.add(np.ascontiguousarray(centroids, dtype=np.float32))
    index.train(x)  # the quantizer holds nlist centroids already: this trains the codec only


# ---------------------------------------------------------------------- add


@dataclass(frozen=True)
class AddTask:
    """One shard to build: what :func:`add_shard` needs, picklable.

    Attributes:
        number: the shard's position (merge order).
        trained: file of the trained, empty index.
        span: the rows to add.
        out: the shard index file to write.
        metric: :class:`Metric` value (cosine rows are normalised).
        chunk_rows: rows read at a time.
        threads: FAISS threads in the task; 0 leaves FAISS's default.
    """

    number: int
    trained: Path
    span: RowSpan
    out: Path
    metric: str
    chunk_rows: int
    threads: int = 0


@dataclass(frozen=True)
class ShardResult:
    """What :func:`add_shard` wrote.

    Attributes:
        number: the task's number.
        path: the shard index file.
        count: vectors added.
        size_bytes: the file's size.
        sha256: its checksum (verified before merging).
        seconds: the task's wall time.
        peak_memory_bytes: the task process's highest anonymous memory during the task.
    """

    number: int
    path: Path
    count: int
    size_bytes: int
    sha256: str
    seconds: float
    peak_memory_bytes: int


def add_shard(task: AddTask) -> ShardResult:
    """Add the rows of ``task.span`` to a copy of the trained index and write it to ``task.out``.

    A plain function of its argument, so that it can run in another process or on another machine
    (e.g. ``ray.remote(add_shard)``), provided the files are reachable there.

    Raises:
        IndexFileError: a vector file unreadable, or a row with NaN/inf (or zero under cosine),
            naming the file and row.
    """
    start = time.perf_counter()
    if task.threads:
        faiss.omp_set_num_threads(task.threads)
    with PeakMemory() as peak:
        index = read_faiss_index(task.trained, mmap=False)
        metric = Metric(task.metric)
        for sub, x in span_chunks(task.span, task.chunk_rows):
            index.add_with_ids(_prepare(x, index.d, metric, sub), sub.read_ids())
        with atomic_path(task.out) as tmp:
            faiss.write_index(index, str(tmp))
        count = int(index.ntotal)
        del index
    return ShardResult(task.number, task.out, count, task.out.stat().st_size, sha256_file(task.out),
                       round(time.perf_counter() - start, 3), peak.peak_bytes)


# ---------------------------------------------------------------------- merge


def merge_shards(trained: faiss.Index, shard_paths: Sequence[Path], data_path: Path) -> faiss.Index:
    """Move the lists of every shard file into ``data_path``, an ``OnDiskInvertedLists`` file that
    ``trained`` (empty) then searches. Shards are read mapped, so they never need to fit in memory.

    Raises:
        IndexFileError: a shard file unreadable, or not built from the same trained index.
    """
    ivf = faiss.extract_index_ivf(trained)
    if trained.ntotal:
        raise ValueError("merge_shards needs an empty trained index")
    shards = [read_faiss_index(p, mmap=True) for p in shard_paths]
    for path, shard in zip(shard_paths, shards):
        s = faiss.try_extract_index_ivf(shard)
        if s is None or s.nlist != ivf.nlist or s.code_size != ivf.code_size or shard.d != trained.d:
            raise IndexFileError(path, f"is not a shard of this index (expected IVF with {ivf.nlist} lists of "
                                       f"{ivf.code_size}-byte codes, dimension {trained.d})")
    lists = faiss.OnDiskInvertedLists(ivf.nlist, ivf.code_size, str(data_path))
    pointers = faiss.InvertedListsPtrVector()  # type: ignore[attr-defined]  # missing from the stubs
    for shard in shards:
        pointers.push_back(faiss.extract_index_ivf(shard).invlists)
    ntotal = lists.merge_from_multiple(pointers.data(), pointers.size(), False)
    ivf.replace_invlists(lists, True)
    lists.this.disown()  # type: ignore[attr-defined]  # owned by the index now
    trained.ntotal = ivf.ntotal = ntotal
    # Unlike merge_ondisk, the shards keep owning their lists: deleting them unmaps the files.
    del pointers, shards
    return trained


# ---------------------------------------------------------------------- tune


def tune_on_files(index: VectorIndex, files: VectorFiles, ids: np.ndarray, metric: Metric, config: AutoConfig,
                  chunk_rows: int) -> TuningResult | None:
    """Tune ``nprobe`` to ``config.target_recall`` on held-out rows of ``files`` (see :mod:`indexes.tuning`).

    Args:
        index: the built index.
        files: its vectors.
        ids: (N,) the ids of ``files``' rows, in file order.
        metric: the index's metric.
        config: ``tune_queries``, ``tune_k``, ``target_recall``, ``tune_margin``, ``seed``.
        chunk_rows: rows read at a time for the exact search.
    """
    k = config.tune_k
    n = len(files)
    if n <= k + 1:
        return None
    rng = np.random.default_rng(config.seed + 1)
    rows = np.sort(rng.choice(n, size=min(config.tune_queries, n), replace=False))
    xq = _prepare_rows(files, rows, metric)
    _, exact_rows = knn_ground_truth(xq, prepared_chunks(files, metric, chunk_rows), k + 1, metric.faiss_metric)
    exact_ids = np.where(exact_rows >= 0, ids[np.maximum(exact_rows, 0)], -1)
    faiss_index = index.faiss_index

    def search(kk: int, value: int) -> np.ndarray:
        return np.asarray(faiss_index.search(xq, kk, params=search_parameters(faiss_index, None, value))[1])

    result = tune(search, exact_ids, ids[rows], k, Knob.NPROBE, knob_limit(faiss_index), config.target_recall,
                  start=1, margin=config.tune_margin)
    set_knob(faiss_index, result.value)
    return result
