"""Indexes with on-disk lists: built from ``.npy`` files in shards, merged, memory-mapped, checked."""

# D and I are FAISS's names for the (nq, k) score and id tables.
# ruff: noqa: E741

from __future__ import annotations

import pickle
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path

import faiss
import numpy as np
import pyarrow as pa
import pytest
from faiss.contrib.evaluation import knn_intersection_measure

from indexes import ClipIndex, IdError, IndexFileError, MemoryBudgetError, ReadOnlyIndexError, VectorIndex
from indexes.ondisk import (
    AddTask,
    MemoryBudgetWarning,
    OnDiskBuild,
    ShardResult,
    add_shard,
    build_on_disk,
    plan_on_disk,
)
from indexes.ondisk_lists import IVFDATA_FILE, LOCATIONS_FILE, read_ondisk_index
from indexes.ondisk_steps import merge_shards, train_index
from indexes.vector_files import VectorFiles
from indexes.vectors import Metric, prepare_vectors

N, D, NLIST = 20_000, 32, 64
BUDGET = 1 << 30


@pytest.fixture(scope="module")
def vectors(clustered: Callable[..., np.ndarray]) -> np.ndarray:
    """(N + 200, D): the collection, then held-out queries."""
    return clustered(N + 200, D, seed=11)


@pytest.fixture(scope="module")
def files(vectors: np.ndarray, tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """The collection in three files of unequal size."""
    folder = tmp_path_factory.mktemp("vectors")
    paths = []
    for i, (a, b) in enumerate([(0, 7_000), (7_000, 8_000), (8_000, N)]):
        paths.append(folder / f"part{i}.npy")
        np.save(paths[-1], vectors[a:b])
    return paths


@pytest.fixture(scope="module")
def built(files: list[Path], tmp_path_factory: pytest.TempPathFactory) -> OnDiskBuild:
    return build_on_disk(files, tmp_path_factory.mktemp("built") / "index", nlist=NLIST, memory_budget_bytes=BUDGET)


def unit(x: np.ndarray) -> np.ndarray:
    """Rows normalised exactly as the index does (a last-bit difference can move an SQ8 code a step)."""
    return prepare_vectors(x, None, Metric.COSINE)


def in_memory_twin(directory: Path, index: VectorIndex, xb: np.ndarray, ids: np.ndarray) -> faiss.Index:
    """The same trained quantizer and codec with empty in-memory lists, then ``xb`` added in file order."""
    twin = read_ondisk_index(directory / "index.faiss")
    ivf = faiss.extract_index_ivf(twin)
    lists = faiss.ArrayInvertedLists(ivf.nlist, ivf.code_size)
    ivf.replace_invlists(lists, True)
    lists.this.disown()  # the index owns it now
    twin.ntotal = ivf.ntotal = 0
    twin.add_with_ids(xb, ids)
    ivf.nprobe = index.search_knob[1]
    return twin


def test_recall_against_exact_search(built: OnDiskBuild, vectors: np.ndarray) -> None:
    index = VectorIndex.load(built.directory)
    xb, xq = unit(vectors[:N]), unit(vectors[N:])
    exact = faiss.IndexFlatIP(D)
    exact.add(xb)
    _, gt = exact.search(xq, 10)
    _, I = index.search(xq, 10)
    assert knn_intersection_measure(I, gt) >= 0.9
    assert built.tuning is not None and built.tuning["recall_at_k"] >= 0.9
    assert index.search_knob == ("nprobe", built.tuning["value"])
    # More lists probed never finds less.
    index.search_knob = NLIST
    _, I_all = index.search(xq, 10)
    assert knn_intersection_measure(I_all, gt) >= knn_intersection_measure(I, gt)


def test_merged_lists_search_like_an_in_memory_ivf(built: OnDiskBuild, vectors: np.ndarray) -> None:
    index = VectorIndex.load(built.directory)
    twin = in_memory_twin(built.directory, index, unit(vectors[:N]), np.arange(N))
    D_disk, I_disk = index.search(vectors[N:], 10)  # normalised inside, as unit() does
    D_mem, I_mem = twin.search(unit(vectors[N:]), 10)
    np.testing.assert_array_equal(I_disk, I_mem)
    np.testing.assert_array_equal(D_disk, D_mem)


def test_parts_merge_equals_one_in_memory_add(files: list[Path], vectors: np.ndarray, tmp_path: Path) -> None:
    """The pieces alone: shards added from the trained file and merged equal one in-memory add."""
    source = VectorFiles.open(files)
    plan = plan_on_disk(N, D, "l2", "PQ8", BUDGET, nlist=NLIST)
    trained = train_index(source, plan, Metric.L2, seed=3)
    faiss.write_index(trained, str(tmp_path / "trained.faiss"))
    tasks = [AddTask(i, tmp_path / "trained.faiss", span, tmp_path / f"s{i}.faiss", "l2", 1000)
             for i, span in enumerate(source.spans(4_000))]
    assert len(tasks) == 6  # 7000 → 2 spans, 1000 → 1, 12000 → 3
    results = [add_shard(t) for t in tasks]
    merged = merge_shards(faiss.read_index(str(tmp_path / "trained.faiss")), [r.path for r in results],
                          tmp_path / IVFDATA_FILE)
    reference = faiss.read_index(str(tmp_path / "trained.faiss"))
    reference.add_with_ids(vectors[:N], np.arange(N))
    for index in (merged, reference):
        faiss.extract_index_ivf(index).nprobe = 8
    D_disk, I_disk = merged.search(vectors[N:], 10)
    D_mem, I_mem = reference.search(vectors[N:], 10)
    np.testing.assert_array_equal(I_disk, I_mem)
    np.testing.assert_array_equal(D_disk, D_mem)


def test_two_level_kmeans_on_request(files: list[Path], vectors: np.ndarray, tmp_path: Path) -> None:
    build = build_on_disk(files, tmp_path / "index", nlist=NLIST, memory_budget_bytes=BUDGET, two_level_training=True)
    assert build.plan.factory == "IVF64,SQ8" and build.plan.two_level
    index = VectorIndex.load(tmp_path / "index")
    exact = faiss.IndexFlatIP(D)
    exact.add(unit(vectors[:N]))
    _, gt = exact.search(unit(vectors[N:]), 10)
    assert knn_intersection_measure(index.search(vectors[N:], 10)[1], gt) >= 0.9


def test_opens_memory_mapped_read_only_and_moves_as_a_folder(built: OnDiskBuild, vectors: np.ndarray,
                                                            tmp_path: Path) -> None:
    moved = tmp_path / "moved"
    shutil.copytree(built.directory, moved)
    index = VectorIndex.load(moved)
    assert index.on_disk and index.read_only and len(index) == N
    lists = faiss.downcast_InvertedLists(faiss.extract_index_ivf(index.faiss_index).invlists)
    assert isinstance(lists, faiss.OnDiskInvertedLists)
    assert Path(lists.filename) == (moved / IVFDATA_FILE).resolve()
    assert np.array_equal(index.ids, np.arange(N))
    # Stored vectors come back decoded from the mapped list data (SQ8: within a quantisation step).
    np.testing.assert_allclose(index.reconstruct([0, 7_500, N - 1]), unit(vectors[[0, 7_500, N - 1]]), atol=0.02)
    with pytest.raises(ReadOnlyIndexError, match="on disk"):
        index.add(vectors[:1])
    with pytest.raises(ReadOnlyIndexError):
        index.remove([0])
    # A filter small enough for exact search over the decoded subset.
    allowed = np.arange(100, 300)
    _, I = index.search(unit(vectors[N:N + 3]), 5, filter=allowed)
    assert np.isin(I, allowed).all()
    # Saved elsewhere, the lists come along.
    index.save(tmp_path / "saved")
    again = VectorIndex.load(tmp_path / "saved")
    np.testing.assert_array_equal(again.search(vectors[N:N + 5], 10)[1], index.search(vectors[N:N + 5], 10)[1])


def test_metadata_gives_a_clip_index(files: list[Path], vectors: np.ndarray, tmp_path: Path) -> None:
    meta = pa.table({"clip_id": [f"c{i}" for i in range(N)],
                     "category": pa.array(["car", "bus", "pedestrian", "car"] * (N // 4))})
    build = build_on_disk(files, tmp_path / "clips", nlist=NLIST, memory_budget_bytes=BUDGET, metadata=meta,
                          tune_recall=False)
    assert build.tuning is None
    clips = ClipIndex.load(tmp_path / "clips")
    hits = clips.search(vectors[N], 5, filter="category == bus")
    assert [h.metadata["category"] for h in hits.hits[0]] == ["bus"] * 5
    assert all(int(h.clip_id[1:]) % 4 == 1 for h in hits.hits[0])
    similar = clips.search_clip("c42", 3)
    assert "c42" not in [h.clip_id for h in similar.hits[0]]


def test_id_files_and_a_picklable_map(files: list[Path], vectors: np.ndarray, tmp_path: Path) -> None:
    """Given ids travel with their rows; tasks survive pickling (as they must to run on Ray)."""
    id_files = []
    offsets = [0, 7_000, 8_000, N]
    for i in range(len(files)):
        id_files.append(tmp_path / f"ids{i}.npy")
        np.save(id_files[-1], 10 * np.arange(offsets[i], offsets[i + 1], dtype=np.int64) + 5)
    seen: list[AddTask] = []

    def pickled_map(fn: Callable[[AddTask], ShardResult], tasks: Sequence[AddTask]) -> list[ShardResult]:
        seen.extend(tasks)
        return [pickle.loads(pickle.dumps(fn(pickle.loads(pickle.dumps(t))))) for t in reversed(tasks)]

    build = build_on_disk(files, tmp_path / "index", ids=id_files, nlist=NLIST, memory_budget_bytes=BUDGET,
                          workers=2, map_fn=pickled_map, tune_recall=False)
    assert build.shards == len(seen) >= 2 and all(t.threads >= 1 for t in seen)
    index = VectorIndex.load(tmp_path / "index")
    index.search_knob = NLIST
    _, I = index.search(vectors[:3], 1)
    np.testing.assert_array_equal(I[:, 0], [5, 15, 25])
    index.search_knob = 8
    twin = in_memory_twin(tmp_path / "index", index, unit(vectors[:N]), 10 * np.arange(N) + 5)
    np.testing.assert_array_equal(index.search(vectors[N:], 10)[1], twin.search(unit(vectors[N:]), 10)[1])


def test_adds_run_as_ray_tasks(ray_local: None, files: list[Path], vectors: np.ndarray, tmp_path: Path) -> None:
    import ray

    def ray_map(fn: Callable[[AddTask], ShardResult], tasks: Sequence[AddTask]) -> list[ShardResult]:
        remote = ray.remote(max_retries=2)(fn)
        return ray.get([remote.remote(t) for t in tasks])

    build = build_on_disk(files, tmp_path / "index", nlist=NLIST, memory_budget_bytes=BUDGET, workers=2,
                          map_fn=ray_map, tune_recall=False)
    assert build.shards >= 3  # one span per file at least
    index = VectorIndex.load(tmp_path / "index")
    index.search_knob = 8  # untuned nprobe=1 leaves some rows short, which search widens and FAISS pads
    twin = in_memory_twin(tmp_path / "index", index, unit(vectors[:N]), np.arange(N))
    np.testing.assert_array_equal(index.search(vectors[N:], 10)[1], twin.search(unit(vectors[N:]), 10)[1])


def test_memory_budget_is_checked_up_front() -> None:
    plan = plan_on_disk(10_000_000, 256, "cosine", "SQ8", 4 * 2**30, workers=2)
    # An exact coarse quantizer at any size; lists capped by k-means' cost, as many as asked for.
    assert plan.factory == "IVF4096,SQ8" and not plan.two_level
    assert plan_on_disk(10_000_000, 256, nlist=16384).factory == "IVF16384,SQ8"
    assert max(plan.estimated_bytes.values()) <= 4 * 2**30
    one = plan_on_disk(10_000_000, 256, "cosine", "SQ8", 4 * 2**30, workers=1)
    assert one.span_rows > plan.span_rows
    small = plan_on_disk(1_000_000, 256, "cosine", "SQ8", int(0.6 * 2**30), workers=1)
    assert small.train_points < one.train_points and small.notes
    with pytest.raises(MemoryBudgetError, match="merge phase"):
        plan_on_disk(100_000_000, 256, "cosine", "SQ8", 2 * 2**30)
    with pytest.raises(MemoryBudgetError, match="fewer workers"):
        plan_on_disk(1_000_000, 256, "cosine", "SQ8", 2**30, workers=8)


def test_measured_memory_is_reported(built: OnDiskBuild, files: list[Path], tmp_path: Path,
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    assert set(built.peak_memory_bytes) == {"train", "add", "add_task", "merge", "tune"}
    # Peaks are the whole process's anonymous memory: whatever this test process held before the build
    # (other tests' models, in a full run) counts too, so the bound is that plus the budget.
    from indexes.ondisk_plan import anon_rss_bytes

    held = anon_rss_bytes()
    assert all(0 < b < held + BUDGET for b in built.peak_memory_bytes.values()), built.peak_memory_bytes
    # A plan that forgets the process itself accepts a budget below what the process already uses:
    # the build finishes and warns with the phases measured above it.
    import indexes.ondisk_plan as ondisk_plan

    monkeypatch.setattr(ondisk_plan, "PROCESS_BYTES", 0)
    with pytest.warns(MemoryBudgetWarning, match="above the budget .* train"):
        build_on_disk(files, tmp_path / "index", nlist=NLIST, memory_budget_bytes=20 * 2**20, tune_recall=False)
    assert VectorIndex.load(tmp_path / "index").on_disk


# ---------------------------------------------------------------------- bad input


def test_missing_file_is_named(files: list[Path], tmp_path: Path) -> None:
    with pytest.raises(IndexFileError, match="nowhere.npy: missing"):
        build_on_disk([files[0], tmp_path / "nowhere.npy"], tmp_path / "index")
    assert not (tmp_path / "index").exists()


def test_mismatched_dimension_is_named(files: list[Path], tmp_path: Path) -> None:
    np.save(tmp_path / "wide.npy", np.ones((10, D + 1), np.float32))
    with pytest.raises(IndexFileError, match=r"wide.npy, field 'shape': has dimension 33, part0.npy has 32"):
        build_on_disk([files[0], tmp_path / "wide.npy"], tmp_path / "index")


@pytest.mark.parametrize("damage", ["garbage", "truncated", "ints"])
def test_unreadable_file_is_named(damage: str, files: list[Path], tmp_path: Path) -> None:
    bad = tmp_path / "bad.npy"
    if damage == "garbage":
        bad.write_bytes(b"not an array at all")
    elif damage == "truncated":
        bad.write_bytes(files[1].read_bytes()[:-100])
    else:
        np.save(bad, np.ones((10, D), np.int32))
    with pytest.raises(IndexFileError, match="bad.npy: ") as info:
        build_on_disk([files[0], bad], tmp_path / "index")
    assert {"garbage": "not a readable .npy", "truncated": "truncated", "ints": "2-D float"}[damage] in str(info.value)


def test_bad_row_is_named_with_its_file_and_row(vectors: np.ndarray, tmp_path: Path) -> None:
    x = vectors[:3_000].copy()
    x[2_345, 7] = np.nan
    np.save(tmp_path / "a.npy", vectors[3_000:6_000])
    np.save(tmp_path / "b.npy", x)
    with pytest.raises(IndexFileError, match=r"b.npy: row 2345: .*NaN"):
        build_on_disk([tmp_path / "a.npy", tmp_path / "b.npy"], tmp_path / "index", nlist=16, tune_recall=False)


def test_bad_id_files_are_named(files: list[Path], tmp_path: Path) -> None:
    np.save(tmp_path / "i0.npy", np.arange(7_000, dtype=np.int64))
    np.save(tmp_path / "i1.npy", np.arange(6_999, 7_999, dtype=np.int64))  # 6999 repeats
    with pytest.raises(IdError, match="ids repeat .*i1.npy.*: 6999"):
        build_on_disk(files[:2], tmp_path / "index", ids=[tmp_path / "i0.npy", tmp_path / "i1.npy"])
    np.save(tmp_path / "i1.npy", np.arange(7_000, 7_500, dtype=np.int64))
    with pytest.raises(IndexFileError, match=r"i1.npy: expected int64 ids of shape \(1000,\)"):
        build_on_disk(files[:2], tmp_path / "index", ids=[tmp_path / "i0.npy", tmp_path / "i1.npy"])


def test_damaged_list_data_is_found_on_open(built: OnDiskBuild, tmp_path: Path) -> None:
    copy = tmp_path / "copy"
    shutil.copytree(built.directory, copy)
    data = copy / IVFDATA_FILE
    raw = bytearray(data.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    data.write_bytes(bytes(raw))
    with pytest.raises(IndexFileError, match=f"{IVFDATA_FILE}: checksum differs"):
        VectorIndex.load(copy)
    (copy / LOCATIONS_FILE).unlink()
    with pytest.raises(IndexFileError, match=f"{LOCATIONS_FILE}: listed in the manifest but missing"):
        VectorIndex.load(copy)


def test_damaged_shard_is_named_before_merging(files: list[Path], tmp_path: Path) -> None:
    """A shard file changed between its task and the merge (a partial copy on a shared disk)."""
    def damaging_map(fn: Callable[[AddTask], ShardResult], tasks: Sequence[AddTask]) -> list[ShardResult]:
        results = [fn(t) for t in tasks]
        with results[1].path.open("r+b") as f:
            f.seek(200)
            f.write(b"\x00" * 16)
        return results

    with pytest.raises(IndexFileError, match=r"shard_00001.faiss: checksum differs"):
        build_on_disk(files, tmp_path / "index", nlist=NLIST, memory_budget_bytes=BUDGET, map_fn=damaging_map,
                      tune_recall=False)
    assert not (tmp_path / "index").exists()
    assert [p.name for p in tmp_path.iterdir()] == []  # no temporary folder or shard left behind
