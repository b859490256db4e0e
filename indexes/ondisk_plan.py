"""Fitting the build of an index with on-disk lists to a memory budget, and measuring memory.

The budget bounds the anonymous memory of the build's processes (what the kernel cannot take
back), estimated per phase: the driver's training, merge and tuning each alone, and the
``workers`` add tasks together, each with a ``1/workers`` share. Each task holds one shard's codes
and ids (twice, as FAISS grows its arrays) plus one chunk of rows read. The list data and the shard
files pass through the page cache, which the kernel reclaims; they are not counted.
:func:`plan_on_disk` refuses a build up front when a phase cannot fit
(:class:`~indexes.errors.MemoryBudgetError`, listing each phase's estimate); :class:`PeakMemory`
samples what a phase really used, so that the build can report it and warn
(:class:`MemoryBudgetWarning`) when the estimate was too low.
"""

from __future__ import annotations

import math
import threading
from dataclasses import asdict, dataclass, field
from typing import Any

import faiss

from indexes.errors import MemoryBudgetError, faiss_message
from indexes.factory import AutoConfig, ivf_lists, train_points
from indexes.vectors import Metric, as_metric

DEFAULT_MEMORY_BUDGET_BYTES = 4 * 2**30
#: Interpreter, NumPy, FAISS and their buffers in one process, before any data.
PROCESS_BYTES = 256 * 2**20
#: Rows read at a time: about this many bytes of float32.
CHUNK_BYTES = 64 * 2**20
#: A training sample is held as read, as prepared, and as k-means' and the codec's working copies.
TRAIN_COPIES = 3.5
#: While merging, per vector: ids and list locations (24 bytes) gathered, sorted (24 more) and the
#: sort order (8), plus the collection's ids in file order and sorted (16), kept for checks and tuning.
MERGE_BYTES_PER_VECTOR = 72
#: Opening the result: ``ids.npy`` read and sorted.
OPEN_BYTES_PER_VECTOR = 16
DEFAULT_CODEC = "SQ8"
#: Fewest rows an add task must be able to hold; smaller shards make the merge read many small files.
MIN_SPAN_ROWS = 10_000
#: Most lists chosen by default. k-means on 39 training points per list costs 39·K² distance
#: computations an iteration (16384 lists: 16 times as long as 4096; docs/research/index-beyond-memory.md),
#: and each vector added costs K dot products. Pass ``nlist`` for more.
MAX_DEFAULT_LISTS = 4096


class MemoryBudgetWarning(UserWarning):
    """A build phase was measured above the memory budget (the estimate was too low for this data)."""


# ---------------------------------------------------------------------- memory


def anon_rss_bytes() -> int:
    """Anonymous resident memory of this process (``RssAnon``); the whole resident set where that is unknown."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("RssAnon:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    import resource

    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


class PeakMemory:
    """Highest :func:`anon_rss_bytes` while the block runs, sampled every ``interval_s`` by a thread."""

    def __init__(self, interval_s: float = 0.02) -> None:
        self.interval_s = interval_s
        self.peak_bytes = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="peak-memory", daemon=True)

    def _watch(self) -> None:
        while not self._stop.is_set():
            self.peak_bytes = max(self.peak_bytes, anon_rss_bytes())
            self._stop.wait(self.interval_s)

    def __enter__(self) -> PeakMemory:
        self.peak_bytes = anon_rss_bytes()
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.peak_bytes = max(self.peak_bytes, anon_rss_bytes())


# ---------------------------------------------------------------------- plan


@dataclass(frozen=True)
class OnDiskPlan:
    """How a collection is built within a memory budget (see :func:`plan_on_disk`).

    Attributes:
        n: vectors in the collection.
        dim: their dimension.
        factory: FAISS factory string ``IVF{K}[_HNSW32],{codec}``.
        nlist: K, the number of inverted lists.
        code_bytes: bytes stored per vector in the lists (plus its 8-byte id).
        two_level: train the coarse quantizer with two-level k-means (see :func:`plan_on_disk`).
        train_points: vectors in the training sample.
        span_rows: most rows one add task indexes (one shard).
        chunk_rows: rows read at a time.
        workers: add tasks running at once.
        memory_budget_bytes: the budget.
        estimated_bytes: per phase (``train``, ``add`` for all tasks together, ``merge``, ``tune``,
            ``search``), the expected peak anonymous memory.
        notes: choices the budget forced.
    """

    n: int
    dim: int
    factory: str
    nlist: int
    code_bytes: int
    two_level: bool
    train_points: int
    span_rows: int
    chunk_rows: int
    workers: int
    memory_budget_bytes: int
    estimated_bytes: dict[str, int] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["notes"] = list(self.notes)
        return out


def trained_bytes(factory: str, nlist: int, dim: int, metric: Metric, code_bytes: int) -> int:
    """Memory of the trained, empty index: centroids, codec tables, transforms."""
    total = nlist * dim * 4
    total += 256 * dim * 4  # PQ centroids or scalar ranges, whichever the codec has
    if "OPQ" in factory or "PCA" in factory:
        total += dim * dim * 4
    if metric is Metric.L2 and ",PQ" in factory:
        # IVF-PQ under L2 precomputes a table per list (FAISS caps it at 2 GB).
        total += min(nlist * code_bytes * 256 * 4, 2 * 2**30)
    return total


def plan_on_disk(n: int, dim: int, metric: Metric | str = "cosine", codec: str = DEFAULT_CODEC,
                 memory_budget_bytes: int = DEFAULT_MEMORY_BUDGET_BYTES, workers: int = 1,
                 nlist: int | None = None, config: AutoConfig | None = None, two_level: bool = False) -> OnDiskPlan:
    """Fit the build of ``n`` vectors of dimension ``dim`` to ``memory_budget_bytes`` (module docstring).

    Args:
        n: vectors in the collection.
        dim: their dimension.
        metric: ``cosine``, ``ip`` or ``l2``.
        codec: how the lists store vectors: ``SQ8`` (1 byte a dimension, recall close to the raw
            vectors), ``PQ{M}`` (M bytes, lower recall), ``Flat`` (raw float32), or any FAISS IVF codec.
        memory_budget_bytes: anonymous memory the build may use on this machine.
        workers: add tasks running at once; each gets a ``1/workers`` share of the budget.
        nlist: number of inverted lists; by default as for in-memory indexes
            (:func:`indexes.factory.ivf_lists`: about 4·√n), at most :data:`MAX_DEFAULT_LISTS`.
            Each vector added costs ``nlist`` dot products (the coarse assignment).
        config: list-count rule, training sample size, tuning target and seed.
        two_level: train the coarse quantizer by two-level k-means (√K clusters, each split in
            proportion to its size): about √K times cheaper than k-means, for many lists. Off by
            default: on clustered data whose clusters vary along shared directions it cut clusters
            across lists, at a recall@10 well below k-means' (``docs/research/index-beyond-memory.md``).

    Raises:
        MemoryBudgetError: a phase cannot fit the budget (the message lists each phase's estimate).
        ValueError: a codec FAISS rejects, too few vectors for the lists, or fewer than one worker.
    """
    config = config or AutoConfig()
    metric = as_metric(metric)
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    k = int(nlist) if nlist is not None else min(ivf_lists(n, config), MAX_DEFAULT_LISTS)
    if k < 1 or n < k:
        raise ValueError(f"{n} vectors cannot fill {k} inverted lists; give fewer lists (nlist) or more vectors")
    # The coarse quantizer is exact (flat), never a graph: FAISS's HNSW quantizer, which in-memory
    # indexes use from 2^14 lists, sent about half of the vectors of clustered data to another list than
    # their nearest one at its default search depth, and recall@10 stayed low at any nprobe
    # (docs/research/index-beyond-memory.md). Flat assignment costs more per vector but is spread over
    # the workers.
    factory = f"IVF{k},{codec}"
    try:
        probe = faiss.index_factory(dim, factory, metric.faiss_metric)
    except RuntimeError as exc:
        raise ValueError(f"FAISS rejects codec {codec!r} (factory {factory!r}): {faiss_message(exc)}") from None
    ivf = faiss.try_extract_index_ivf(probe)
    if ivf is None:
        raise ValueError(f"factory {factory!r} is not an IVF index")
    code_bytes = int(ivf.code_size)
    base = PROCESS_BYTES + trained_bytes(factory, k, dim, metric, code_bytes)
    budget = int(memory_budget_bytes)
    notes = []

    wanted = train_points(factory, n, config)
    fits = int((budget - base - k * dim * 4) // (dim * 4 * TRAIN_COPIES))
    # k-means needs a few points per centroid to be worth anything; FAISS asks for 39.
    least = min(n, 8 * k)
    n_train = min(wanted, fits)
    if n_train < wanted:
        notes.append(f"training sample capped at {n_train} vectors (wanted {wanted}) by the budget")

    chunk_rows = int(max(256, min(CHUNK_BYTES // (dim * 4), n)))
    per_task = budget // workers - base - 4 * chunk_rows * dim * 4
    fit_rows = int(per_task // (2 * (code_bytes + 8))) if per_task > 0 else 0
    # Every worker gets a span when there are enough rows; smaller spans only add merge inputs.
    span_rows = max(1, min(fit_rows, math.ceil(n / workers)))
    chunk_rows = min(chunk_rows, span_rows)

    estimates = {
        "train": int(base + k * dim * 4 + n_train * dim * 4 * TRAIN_COPIES),
        "add": int(workers * (base + 4 * chunk_rows * dim * 4 + 2 * span_rows * (code_bytes + 8))),
        "merge": base + MERGE_BYTES_PER_VECTOR * n,
        # The opened index, the files' ids, and chunks as read, prepared, copied into the exact
        # index and compared with the queries.
        "tune": base + (OPEN_BYTES_PER_VECTOR + 16) * n + 5 * chunk_rows * dim * 4,
        "search": base + OPEN_BYTES_PER_VECTOR * n,
    }
    problems = []
    if n_train < least:
        problems.append(f"training needs at least {least} vectors ({least * dim * 4 * TRAIN_COPIES / 2**30:.2f} GiB)")
    if fit_rows < min(n, MIN_SPAN_ROWS):
        problems.append(f"each of {workers} add task(s) gets {budget // workers / 2**30:.2f} GiB, too little "
                        f"for the trained index and one chunk; use fewer workers")
    problems += [f"the {phase} phase needs about {est / 2**30:.2f} GiB" for phase, est in estimates.items()
                 if phase not in ("train", "add") and est > budget]
    if problems:
        listed = ", ".join(f"{p} {e / 2**30:.2f}" for p, e in estimates.items())
        raise MemoryBudgetError(
            f"{n} vectors of dimension {dim} as {factory!r} do not fit a budget of {budget / 2**30:.2f} GiB: "
            f"{'; '.join(problems)} (estimates in GiB: {listed})")
    return OnDiskPlan(n, dim, factory, k, code_bytes, two_level, int(n_train), int(span_rows), int(chunk_rows),
                      int(workers), budget, estimates, tuple(notes))
