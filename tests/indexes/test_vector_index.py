# D and I are FAISS's names for the (nq, k) score and id tables.
# ruff: noqa: E741
from collections.abc import Callable

import faiss
import numpy as np
import pytest
from faiss.contrib.evaluation import check_ref_knn_with_draws, knn_intersection_measure

from indexes.errors import DimensionMismatchError, IdError, InvalidKError, VectorError
from indexes.factory import AutoConfig
from indexes.vector_index import VectorIndex

Data = tuple[np.ndarray, np.ndarray]
APPROX = ["HNSW16", "IVF32,Flat"]


def _unit(x: np.ndarray) -> np.ndarray:
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


def exact(xq: np.ndarray, xb: np.ndarray, k: int, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """Reference: brute force with FAISS's exact knn, normalising for cosine."""
    if metric == "cosine":
        xq, xb = _unit(xq), _unit(xb)
    m = faiss.METRIC_L2 if metric == "l2" else faiss.METRIC_INNER_PRODUCT
    return faiss.knn(xq, xb, k, metric=m)


@pytest.mark.parametrize("metric", ["cosine", "ip", "l2"])
def test_flat_matches_exact_search_with_ties_tolerated(data: Data, metric: str) -> None:
    xb, xq = data
    ids = np.arange(len(xb), dtype=np.int64) * 7 + 3  # the caller's ids, not row numbers
    index = VectorIndex.build(xb, ids, metric=metric, factory="Flat")
    k = 10
    D, I = index.search(xq, k)
    D_ref, I_ref = exact(xq, xb, k, metric)
    check_ref_knn_with_draws(D_ref, ids[I_ref], D, I, rtol=1e-4)
    assert index.recall_at_10 == 1.0


def test_duplicate_vectors_tie_tolerant(data: Data) -> None:
    xb, xq = data
    xb = np.concatenate([xb[:500], xb[:500]])  # every vector twice: exact ties everywhere
    index = VectorIndex.build(xb, factory="Flat")
    D, I = index.search(xq, 6)
    D_ref, I_ref = exact(xq, xb, 6, "cosine")
    check_ref_knn_with_draws(D_ref, I_ref, D, I, rtol=1e-4)


@pytest.mark.parametrize("factory", APPROX)
def test_approximate_indexes_reach_the_target_recall(data: Data, factory: str) -> None:
    xb, xq = data
    index = VectorIndex.build(xb, factory=factory, config=AutoConfig(target_recall=0.95, tune_queries=200))
    tuning = index.info["tuning"]
    assert tuning["knob"] in ("nprobe", "efSearch") and tuning["value"] == index.search_knob[1]
    assert tuning["recall_at_k"] >= 0.95
    _, I = index.search(xq, 10)
    _, I_ref = exact(xq, xb, 10, "cosine")
    assert knn_intersection_measure(I, I_ref) >= 0.9


def test_auto_picks_flat_for_small_collections(data: Data) -> None:
    index = VectorIndex.build(data[0])
    assert index.factory == "Flat" and "flat_max_n" in index.info["choice_reason"]


def test_auto_picks_hnsw_then_ivf_by_size(data: Data) -> None:
    xb, _ = data
    hnsw = VectorIndex.build(xb, config=AutoConfig(flat_max_n=1000, hnsw_m=8))
    assert hnsw.factory == "HNSW8"
    ivf = VectorIndex.build(xb, config=AutoConfig(flat_max_n=1000, hnsw_max_n=2000, ivf_min_lists=8))
    assert ivf.factory.startswith("IVF") and ivf.recall_at_10 is not None and ivf.recall_at_10 >= 0.95


def test_explicit_compressed_factory(data: Data) -> None:
    xb, xq = data
    index = VectorIndex.build(xb, factory="IVF16,PQ8x4", config=AutoConfig(tune_queries=100))
    _, I = index.search(xq, 10)
    assert index.factory == "IVF16,PQ8x4" and (I >= 0).all()
    assert 0.0 < index.info["tuning"]["recall_at_k"] <= 1.0


@pytest.mark.parametrize("factory", ["Flat", *APPROX])
def test_filter_returns_only_allowed_ids(data: Data, factory: str) -> None:
    xb, xq = data
    index = VectorIndex.build(xb, factory=factory)
    rng = np.random.default_rng(0)
    for n_allowed in (3, 40, 1500):
        allowed = np.sort(rng.choice(len(xb), n_allowed, replace=False))
        k = 10
        D, I = index.search(xq, k, filter=allowed)
        assert np.isin(I[I >= 0], allowed).all()
        # Even very selective filters come back full (padded only when fewer pass).
        assert ((I >= 0).sum(axis=1) == min(k, n_allowed)).all()
        if n_allowed < k:
            assert (I[:, n_allowed:] == -1).all() and np.isneginf(D[:, n_allowed:]).all()
        if factory == "Flat" or n_allowed <= 40:  # exact: compare against brute force on the subset
            D_ref, I_ref = exact(xq, xb[allowed], min(k, n_allowed), "cosine")
            check_ref_knn_with_draws(D_ref, allowed[I_ref], D[:, :n_allowed], I[:, :n_allowed], rtol=1e-4)


def test_filter_with_no_match_is_all_padding(data: Data) -> None:
    index = VectorIndex.build(data[0], factory="Flat")
    D, I = index.search(data[1], 5, filter=np.array([10**9]))
    assert (I == -1).all() and np.isneginf(D).all()


@pytest.mark.parametrize("factory", ["Flat", *APPROX])
def test_removed_ids_never_come_back(data: Data, factory: str) -> None:
    xb, xq = data
    index = VectorIndex.build(xb, factory=factory)
    _, I_before = index.search(xq, 20)
    gone = np.unique(I_before[:, :10])  # the best hits: the ones most likely to reappear
    assert index.remove(gone) == len(gone)
    assert len(index) == len(xb) - len(gone)
    _, I = index.search(xq, 20)
    assert not np.isin(I, gone).any() and (I >= 0).all()
    _, I = index.search(xq, 10, filter=np.concatenate([gone, [0, 1]]))
    assert not np.isin(I, gone).any()
    # Removed ids are never reused; new ids come after every id ever used.
    with pytest.raises(IdError, match="never reused"):
        index.add(xb[:1], [int(gone[0])])
    new = index.add(xb[:2])
    assert new.min() > max(len(xb) - 1, int(gone.max()))
    _, I = index.search(xb[:1], 1)
    assert I[0, 0] in (new[0], 0)


def test_remove_unknown_id_changes_nothing(data: Data) -> None:
    index = VectorIndex.build(data[0], factory="Flat")
    with pytest.raises(IdError, match="not in the index.*99999"):
        index.remove([1, 99999])
    assert len(index) == len(data[0]) and 1 in index


def test_add_checks_ids_and_dimension(data: Data) -> None:
    xb, _ = data
    index = VectorIndex.build(xb[:100], factory="Flat")
    with pytest.raises(IdError, match="already in the index.*5"):
        index.add(xb[:2], [5, 1000])
    with pytest.raises(DimensionMismatchError):
        index.add(np.ones((2, 31)))
    ids = index.add(xb[100:110], np.arange(500, 510))
    assert len(index) == 110 and list(ids) == list(range(500, 510))
    np.testing.assert_allclose(index.reconstruct([505])[0], _unit(xb[105:106])[0], rtol=1e-5)


def test_bad_queries_and_k(data: Data) -> None:
    xb, xq = data
    index = VectorIndex.build(xb[:50], factory="Flat")
    with pytest.raises(InvalidKError, match="positive"):
        index.search(xq, 0)
    with pytest.raises(InvalidKError, match="k=51.*50 vectors"):
        index.search(xq, 51)
    assert index.search(xq, 50)[1].shape == (len(xq), 50)
    bad = xq.copy()
    bad[4, 0] = np.nan
    with pytest.raises(VectorError, match="row 4"):
        index.search(bad, 5)
    with pytest.raises(DimensionMismatchError):
        index.search(np.ones((1, 8)), 5)


def test_build_rejects_bad_input(data: Data) -> None:
    xb, _ = data
    bad = xb[:20].copy()
    bad[13, 5] = np.inf
    with pytest.raises(VectorError, match="row 13"):
        VectorIndex.build(bad)
    with pytest.raises(IdError, match="duplicate"):
        VectorIndex.build(xb[:3], ids=[1, 2, 1])
    with pytest.raises(ValueError, match="factory"):
        VectorIndex.build(xb[:10], factory="NotAFactory")
    with pytest.raises(ValueError, match="cannot be trained"):
        VectorIndex.build(xb[:10], factory="IVF64,Flat")


def test_single_query_vector(data: Data) -> None:
    xb, xq = data
    index = VectorIndex.build(xb, factory="Flat")
    D1, I1 = index.search(xq[0], 5)
    D2, I2 = index.search(xq[:1], 5)
    np.testing.assert_array_equal(I1, I2)
    np.testing.assert_array_equal(D1, D2)


def test_retune_after_adds(clustered: Callable[..., np.ndarray]) -> None:
    x = clustered(3000, 16, seed=3)
    index = VectorIndex.build(x[:2000], factory="IVF32,Flat", config=AutoConfig(tune_queries=100))
    index.add(x[2000:])
    tuning = index.tune(target_recall=0.99, config=AutoConfig(tune_queries=100))
    assert tuning["target_recall"] == 0.99 and tuning["recall_at_k"] >= 0.99


def test_kinds_without_a_knob_still_measure_recall(data: Data, monkeypatch: pytest.MonkeyPatch) -> None:
    index = VectorIndex.build(data[0], factory="PQ8x4", config=AutoConfig(tune_queries=100))
    tuning = index.info["tuning"]
    assert tuning["knob"] == "none" and tuning["value"] == 0
    assert 0.0 < tuning["recall_at_k"] < 1.0  # lossy codes: measured, not assumed
    assert index.remove([3]) == 1 and 3 not in index  # flat codes delete in place
    # Flat PQ takes no selector: a filter falls back to exact search over the allowed vectors.
    monkeypatch.setattr("indexes.filtered_search.EXACT_FILTER_MAX", 0)
    _, I = index.search(data[1], 5, filter=np.arange(0, 3000, 2))
    assert (I % 2 == 0).all() and (I >= 0).all()


def test_small_searches_run_faiss_on_one_thread_and_restore_the_setting() -> None:
    from indexes.tuning import SMALL_BATCH_QUERIES, faiss_threads_for

    before = faiss.omp_get_max_threads()
    faiss.omp_set_num_threads(2)
    try:
        with faiss_threads_for(1):
            assert faiss.omp_get_max_threads() == 1
        assert faiss.omp_get_max_threads() == 2
        with faiss_threads_for(SMALL_BATCH_QUERIES):
            assert faiss.omp_get_max_threads() == 2
    finally:
        faiss.omp_set_num_threads(before)
