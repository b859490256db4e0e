# D and I are FAISS's names for the (nq, k) score and id tables.
# ruff: noqa: E741
from pathlib import Path

import numpy as np
import pytest
from faiss.contrib.evaluation import check_ref_knn_with_draws

from indexes.errors import IdError, ManifestError
from indexes.sharded import ShardedIndex, merge_results
from indexes.vector_index import VectorIndex
from indexes.vectors import Metric

Data = tuple[np.ndarray, np.ndarray]


def test_flat_shards_match_one_flat_index(data: Data) -> None:
    xb, xq = data
    single = VectorIndex.build(xb, factory="Flat")
    sharded = ShardedIndex.build(xb, factory="Flat", shard_size=700)
    assert len(sharded.shards) == 5 and len(sharded) == len(xb)
    D1, I1 = single.search(xq, 10)
    D2, I2 = sharded.search(xq, 10)
    check_ref_knn_with_draws(D1, I1, D2, I2, rtol=1e-5)
    allowed = np.arange(0, len(xb), 13)
    D1, I1 = single.search(xq, 10, filter=allowed)
    D2, I2 = sharded.search(xq, 10, filter=allowed)
    check_ref_knn_with_draws(D1, I1, D2, I2, rtol=1e-5)


def test_ivf_shards_share_training_and_tuning(data: Data) -> None:
    xb, _ = data
    sharded = ShardedIndex.build(xb, factory="IVF16,Flat", shard_size=1000)
    knobs = {s.search_knob for s in sharded.shards}
    assert len(knobs) == 1 and sharded.recall_at_10 is not None and sharded.recall_at_10 >= 0.95


def test_add_opens_new_shards_and_remove_routes(data: Data) -> None:
    xb, xq = data
    sharded = ShardedIndex.build(xb[:1000], factory="Flat", shard_size=600)
    ids = sharded.add(xb[1000:1500])
    assert ids[0] == 1000 and len(sharded.shards) == 3 and len(sharded.shards[-1]) == 300
    gone = np.array([5, 700, 1200])
    assert sharded.remove(gone) == 3
    _, I = sharded.search(np.concatenate([xb[gone], xq]), 10)
    assert not np.isin(I, gone).any()
    with pytest.raises(IdError, match="already used"):
        sharded.add(xb[:1], [700])
    with pytest.raises(IdError, match="not in the index"):
        sharded.remove([99999])


def test_round_trip(tmp_path: Path, data: Data) -> None:
    xb, xq = data
    sharded = ShardedIndex.build(xb, factory="IVF16,Flat", shard_size=1200)
    sharded.remove([1, 2, 3])
    sharded.save(tmp_path / "s")
    loaded = ShardedIndex.load(tmp_path / "s")
    np.testing.assert_array_equal(loaded.search(xq, 10)[1], sharded.search(xq, 10)[1])
    mapped = ShardedIndex.load(tmp_path / "s", mmap=True)
    np.testing.assert_array_equal(mapped.search(xq, 10)[1], sharded.search(xq, 10)[1])
    np.testing.assert_allclose(loaded.reconstruct([10, 2000]), sharded.reconstruct([10, 2000]))
    # A damaged shard manifest is caught through the top manifest's checksum.
    (tmp_path / "s" / "shard_0001" / "manifest.json").write_text("{}")
    with pytest.raises(ManifestError):
        ShardedIndex.load(tmp_path / "s")


def test_from_separately_built_shards(data: Data) -> None:
    xb, xq = data
    a = VectorIndex.build(xb[:1500], factory="Flat")
    b = VectorIndex.build(xb[1500:], np.arange(1500, len(xb)), factory="Flat")
    combined = ShardedIndex.from_shards([a, b])
    D1, I1 = VectorIndex.build(xb, factory="Flat").search(xq, 5)
    D2, I2 = combined.search(xq, 5)
    check_ref_knn_with_draws(D1, I1, D2, I2, rtol=1e-5)
    with pytest.raises(IdError, match="more than one shard"):
        ShardedIndex.from_shards([a, a])


def test_merge_pads_and_orders() -> None:
    D = [np.array([[0.9, 0.1]], np.float32), np.array([[0.5, -np.inf]], np.float32)]
    I = [np.array([[4, 7]]), np.array([[9, -1]])]
    D_m, I_m = merge_results(D, I, 4, Metric.COSINE)
    assert I_m.tolist() == [[4, 9, 7, -1]] and np.isneginf(D_m[0, 3])
    D_m, I_m = merge_results([np.array([[3.0, 1.0]], np.float32)], [np.array([[1, 2]])], 2, Metric.L2)
    assert I_m.tolist() == [[2, 1]]
