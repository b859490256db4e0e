"""An index beyond memory: 10M × 256 clustered float32 vectors (200k with ``quick``) in ``.npy`` files.

The vectors (10 GB at 10M) are generated deterministically, chunk by chunk, into ten files on disk,
from the same kind of clusters as ``bench_index`` (cluster centre + a point of a shared
16-dimensional subspace + noise, L2-normalised; 1,000 vectors a cluster). Then
:func:`indexes.build_on_disk` builds the default on-disk index (``SQ8`` codes) within a 4 GiB
budget, its add tasks on a local Ray runtime with two workers (:mod:`scenesearch_base.ray_runner`).

Figures:

* build time per phase (train, add, merge, tune) and the plan (factory, lists, training sample, shards);
* memory: the highest anonymous resident memory of each phase (driver and add tasks, each in its
  own process), against the budget and the plan's estimates; the driver's peak resident set
  (``VmHWM``, which also counts mapped files' pages); the anonymous memory of the opened index;
* the index's size on disk, and the time to open it (checksums verified) the first and a later time;
* recall@10 of held-out queries against exact search (brute force streamed over the files);
* single-query latency p50/p99 with the list data in the page cache (warm) and evicted from it
  (cold: ``posix_fadvise(DONTNEED)`` on the index's files only), and batch queries/s.

Baselines in the same run: exact search streamed over the files (batch queries/s from computing the
ground truth; single-query latency on a few queries), and the same index with its lists copied into
memory (an in-memory IVF with the same quantizer and codes: same answers, its latency and memory).

Run a chosen size with ``python -c "from benchmarks.bench_index_scale import measure; print(measure(1_000_000))"``;
the files go under ``$TMPDIR`` and are deleted at the end.
"""

# D and I are FAISS's names for the (nq, k) score and id tables.
# ruff: noqa: E741

from __future__ import annotations

import gc
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import faiss
import numpy as np
from faiss.contrib.evaluation import knn_intersection_measure
from faiss.contrib.exhaustive_search import knn_ground_truth
from numpy.lib import format as npy_format

from indexes import VectorIndex, build_on_disk, integrity
from indexes.ondisk import AddTask, ShardResult
from indexes.ondisk_lists import read_ondisk_index
from indexes.ondisk_plan import DEFAULT_MEMORY_BUDGET_BYTES
from indexes.vector_files import VectorFiles
from scenesearch_base.ray_runner import Execution, run_tasks

DIM = 256
K = 10
FILES = 10
POINTS_PER_CLUSTER = 1000
LATENT_DIM = 16
GENERATE_ROWS = 100_000


def _progress(message: str) -> None:
    print(f"  [index_scale] {time.strftime('%H:%M:%S')} {message}", flush=True)


class Clusters:
    """The distribution of ``bench_index.clustered_data``, drawn chunk by chunk with per-chunk seeds."""

    def __init__(self, n: int, seed: int = 0, latent_scale: float = 0.6, noise: float = 0.2) -> None:
        rng = np.random.default_rng([seed, 0])
        self.n_clusters = max(1, n // POINTS_PER_CLUSTER)
        self.centres = rng.standard_normal((self.n_clusters, DIM), dtype=np.float32)
        self.basis = (rng.standard_normal((LATENT_DIM, DIM), dtype=np.float32) / np.sqrt(LATENT_DIM)).astype(
            np.float32)
        self.seed, self.latent_scale, self.noise = seed, latent_scale, noise

    def draw(self, m: int, stream: int) -> np.ndarray:
        """(m, DIM) unit vectors; the same ``stream`` number always gives the same rows."""
        rng = np.random.default_rng([self.seed, 1, stream])
        c = rng.integers(0, self.n_clusters, m)
        z = self.latent_scale * rng.standard_normal((m, LATENT_DIM), dtype=np.float32)
        out = self.centres[c] + z @ self.basis + self.noise * rng.standard_normal((m, DIM), dtype=np.float32)
        out /= np.linalg.norm(out, axis=1, keepdims=True)
        return out


def write_files(clusters: Clusters, n: int, folder: Path) -> list[Path]:
    """``FILES`` ``.npy`` files holding n rows together, written chunk by chunk (never all in memory)."""
    bounds = np.linspace(0, n, FILES + 1).astype(np.int64)
    paths = []
    stream = 0
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        path = folder / f"vectors_{i:02d}.npy"
        with path.open("wb") as f:
            npy_format.write_array_header_1_0(f, {"descr": "<f4", "fortran_order": False, "shape": (int(b - a), DIM)})
            for start in range(int(a), int(b), GENERATE_ROWS):
                f.write(clusters.draw(min(GENERATE_ROWS, int(b) - start), stream).tobytes())
                stream += 1
        paths.append(path)
    return paths


def ray_map(workers: int) -> Callable[[Callable[[AddTask], ShardResult], Sequence[AddTask]], Iterable[ShardResult]]:
    """Run add tasks with :func:`scenesearch_base.ray_runner.run_tasks` on a local Ray runtime of ``workers`` CPUs."""
    def map_fn(fn: Callable[[AddTask], ShardResult], tasks: Sequence[AddTask]) -> list[ShardResult]:
        report = run_tasks(fn, tasks, Execution(workers=workers, progress=False),
                           labels=[f"rows {t.span.start}-{t.span.stop} of {t.span.vectors.name}" for t in tasks],
                           noun="shard")
        if report.problems():
            raise RuntimeError("; ".join(report.problems()))
        return report.values

    return map_fn


def status_bytes(field: str) -> int:
    """A memory figure of this process from ``/proc/self/status`` (``VmHWM``, ``RssAnon``, ``RssFile``)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) * 1024
    return 0


def evict(paths: Iterable[Path]) -> None:
    """Drop these files' pages from the page cache (pages that no process maps)."""
    for path in paths:
        fd = os.open(path, os.O_RDONLY)
        try:
            os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
        finally:
            os.close(fd)


def in_memory_copy(directory: Path) -> faiss.Index:
    """The saved index with its lists copied into memory: the same quantizer, codes and order."""
    index = read_ondisk_index(directory / "index.faiss")
    ivf = faiss.extract_index_ivf(index)
    lists = faiss.ArrayInvertedLists(ivf.nlist, ivf.code_size)
    ivf.invlists.copy_subset_to(lists, faiss.InvertedLists.SUBSET_TYPE_INVLIST, 0, ivf.nlist)
    ivf.replace_invlists(lists, True)
    lists.this.disown()  # owned by the index now
    return index


def exact_latencies(files: VectorFiles, xq: np.ndarray, chunk_rows: int) -> dict[str, Any]:
    """Single-query latency of exact search streamed over the files, one query after the other."""
    lat = []
    for q in xq:
        t = time.perf_counter()
        knn_ground_truth(q[None, :], (x for _, x in files.chunks(chunk_rows)), K, faiss.METRIC_INNER_PRODUCT)
        lat.append(time.perf_counter() - t)
    ms = np.array(lat) * 1e3
    return {"single_p50_ms": round(float(np.percentile(ms, 50)), 1),
            "single_p99_ms": round(float(np.percentile(ms, 99)), 1), "queries": len(xq)}


#: How :func:`search_process` searches: through ``VectorIndex`` (what users call), the same index
#: through FAISS alone, or FAISS over a copy of the lists in memory.
MODES = ("on_disk", "on_disk_faiss", "in_memory")


def search_process(directory: str, queries: str, mode: str, nprobe: str, warm: str) -> dict[str, Any]:
    """Open the index in ``mode`` in this (fresh) process, search each query alone, then all at once.

    Runs in a process of its own so that its memory figures are the index's alone. With ``warm``
    ``"1"`` every query is searched once before timing; otherwise the first pass is timed (cold
    when the caller evicted the files).
    """
    xq = np.load(queries)
    faiss.omp_set_num_threads(1)  # VectorIndex.search does so for single queries: the same for all
    anon0, file0 = status_bytes("RssAnon"), status_bytes("RssFile")
    t = time.perf_counter()
    if mode == "on_disk":
        vector_index = VectorIndex.load(directory)
        vector_index.search_knob = int(nprobe)

        def search(x: np.ndarray) -> np.ndarray:
            return vector_index.search(x, K)[1]
    else:
        index = read_ondisk_index(Path(directory) / "index.faiss") if mode == "on_disk_faiss" else \
            in_memory_copy(Path(directory))
        faiss.extract_index_ivf(index).nprobe = int(nprobe)

        def search(x: np.ndarray) -> np.ndarray:
            return np.asarray(index.search(x, K)[1])
    open_s = time.perf_counter() - t
    opened_anon = status_bytes("RssAnon") - anon0
    if warm == "1":
        for q in xq:
            search(q[None, :])
    lat = []
    for q in xq:
        t = time.perf_counter()
        search(q[None, :])
        lat.append(time.perf_counter() - t)
    faiss.omp_set_num_threads(os.cpu_count() or 1)
    t = time.perf_counter()
    I = search(xq)
    batch_s = time.perf_counter() - t
    np.save(Path(queries).with_name(f"found_{mode}.npy"), I)
    ms = np.array(lat) * 1e3
    return {"open_s": round(open_s, 3), "single_p50_ms": round(float(np.percentile(ms, 50)), 3),
            "single_p99_ms": round(float(np.percentile(ms, 99)), 3), "queries": len(xq),
            "batch_qps": round(len(xq) / batch_s, 1), "anon_after_open_bytes": opened_anon,
            "anon_bytes": status_bytes("RssAnon") - anon0, "file_pages_bytes": status_bytes("RssFile") - file0}


def in_fresh_process(directory: Path, queries: Path, mode: str, nprobe: int, warm: bool) -> dict[str, Any]:
    code = ("import json, sys; from benchmarks.bench_index_scale import search_process; "
            "print(json.dumps(search_process(*sys.argv[1:])))")
    done = subprocess.run([sys.executable, "-c", code, str(directory), str(queries), mode, str(nprobe),
                           "1" if warm else "0"], capture_output=True, text=True, check=False,
                          cwd=Path(__file__).resolve().parents[1])
    if done.returncode:
        raise RuntimeError(f"search process ({mode}) failed: {done.stderr[-2000:]}")
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def measure(n: int, nq: int = 500, n_exact_single: int = 3, workers: int = 2,
            memory_budget_bytes: int = DEFAULT_MEMORY_BUDGET_BYTES) -> dict[str, Any]:
    """Every figure of the module docstring for n vectors."""
    root = Path(tempfile.mkdtemp(prefix="bench_index_scale."))
    out: dict[str, Any] = {"n": n, "dim": DIM, "k": K, "nq": nq, "files": FILES, "workers": workers,
                           "memory_budget_bytes": memory_budget_bytes, "threads": faiss.omp_get_max_threads()}
    try:
        clusters = Clusters(n)
        _progress(f"writing {n} x {DIM} vectors to {FILES} files")
        t = time.perf_counter()
        paths = write_files(clusters, n, root)
        out["generate_s"] = round(time.perf_counter() - t, 1)
        out["vectors_bytes"] = sum(p.stat().st_size for p in paths)
        xq = clusters.draw(nq, stream=10**9)  # held out: a stream no file used

        _progress("exact search over the files (ground truth)")
        files = VectorFiles.open(paths)
        chunk = 65_536
        t = time.perf_counter()
        _, gt = knn_ground_truth(xq, (x for _, x in files.chunks(chunk)), K, faiss.METRIC_INNER_PRODUCT)
        exact_s = time.perf_counter() - t
        exact: dict[str, Any] = {"batch_qps": round(nq / exact_s, 2), "batch_s": round(exact_s, 1)}
        exact.update(exact_latencies(files, xq[:n_exact_single], chunk))
        out["exact_streamed"] = exact

        _progress(f"build_on_disk, add on Ray with {workers} workers")
        gc.collect()
        t = time.perf_counter()
        build = build_on_disk(paths, root / "index", memory_budget_bytes=memory_budget_bytes, workers=workers,
                              map_fn=ray_map(workers))
        total_s = time.perf_counter() - t
        plan = build.plan
        out["build"] = {
            "factory": plan.factory, "nlist": plan.nlist,
            "train_points": plan.train_points, "shards": build.shards, "span_rows": plan.span_rows,
            "seconds": build.seconds, "total_s": round(total_s, 1),
            "tuned_nprobe": build.tuning["value"] if build.tuning else None,
            "tuned_recall_at_10": build.tuning["recall_at_k"] if build.tuning else None,
        }
        out["memory"] = {
            "peak_anon_bytes": build.peak_memory_bytes,
            "estimated_bytes": plan.estimated_bytes,
            # Add tasks run at once, each in its own process.
            "add_all_tasks_bytes": workers * build.peak_memory_bytes["add_task"],
            "within_budget": max(max(v for k, v in build.peak_memory_bytes.items() if k != "add_task"),
                                 workers * build.peak_memory_bytes["add_task"]) <= memory_budget_bytes,
            "driver_vm_hwm_bytes": status_bytes("VmHWM"),
        }
        out["size_on_disk_bytes"] = build.size_bytes
        out["size_over_raw_vectors"] = round(build.size_bytes / out["vectors_bytes"], 3)

        directory = root / "index"
        # Files younger than the stamp margin are hashed at every open (see indexes.integrity), which
        # would read the list data back into the page cache before the cold measurement.
        time.sleep(integrity.STAMP_MARGIN_NS / 1e9 + 0.1)
        queries = root / "queries.npy"
        np.save(queries, xq)
        nprobe = build.tuning["value"] if build.tuning else 1
        searches: dict[str, Any] = {}
        found: dict[str, np.ndarray] = {}

        def search(name: str, mode: str, warm: bool) -> None:
            _progress(f"searches: {name}")
            searches[name] = in_fresh_process(directory, queries, mode, nprobe, warm)
            found[name] = np.load(queries.with_name(f"found_{mode}.npy"))
            searches[name]["recall_at_10"] = round(float(knn_intersection_measure(found[name], gt)), 4)

        # The first open hashes every file (and writes the stamp that later opens trust).
        search("on_disk_first_open", "on_disk", warm=True)
        for mode in MODES:
            search(mode, mode, warm=True)
        evict(p for p in directory.iterdir() if p.is_file())
        search("on_disk_cold", "on_disk", warm=False)
        out["searches"] = searches
        same = np.array_equal(found["on_disk"], found["in_memory"])
        on_disk, in_memory = searches["on_disk"], searches["in_memory"]
        out["on_disk_same_answers_as_in_memory"] = same
        out["on_disk_p50_over_in_memory"] = round(on_disk["single_p50_ms"] / in_memory["single_p50_ms"], 2)
        out["on_disk_faiss_p50_over_in_memory"] = round(
            searches["on_disk_faiss"]["single_p50_ms"] / in_memory["single_p50_ms"], 2)
        out["exact_p50_over_on_disk"] = round(exact["single_p50_ms"] / on_disk["single_p50_ms"], 1)
        out["on_disk_anon_over_in_memory"] = round(on_disk["anon_after_open_bytes"]
                                                   / max(in_memory["anon_after_open_bytes"], 1), 3)
        return out
    finally:
        shutil.rmtree(root, ignore_errors=True)


def run(quick: bool) -> dict[str, Any]:
    return measure(200_000, nq=200) if quick else measure(10_000_000)
