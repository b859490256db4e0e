import numpy as np

from indexes.tuning import Knob, recall_excluding_self, tune


def test_recall_drops_the_query_itself() -> None:
    exact = np.array([[7, 1, 2, 3], [8, 4, 5, 6]])
    found = np.array([[1, 7, 2, 9], [4, 5, 0, 6]])  # row 1 misses its own id 8
    r = recall_excluding_self(exact, found, np.array([7, 8]), k=3)
    # row 0: {1,2,3} vs {1,2,9} → 2/3; row 1: {4,5,6} vs {4,5,0} → 2/3
    assert r == 2 / 3


def test_tune_finds_the_smallest_value_reaching_the_target() -> None:
    k = 10
    nq = 50
    exact = np.arange(nq * (k + 1)).reshape(nq, k + 1)
    self_ids = exact[:, 0].copy()

    def search(kk: int, value: int) -> np.ndarray:
        # A fake index whose recall grows with the knob: value v finds min(v, k) true neighbours.
        hits = min(value, k)
        out = np.full((nq, kk), -1)
        out[:, 0] = self_ids
        out[:, 1:1 + hits] = exact[:, 1:1 + hits]
        return out

    result = tune(search, exact, self_ids, k, Knob.NPROBE, limit=64, target_recall=0.7)
    assert result.value == 7 and result.recall_at_k == 0.7
    assert [v for v, _ in result.curve][:4] == [1, 2, 4, 8]
    capped = tune(search, exact, self_ids, k, Knob.NPROBE, limit=5, target_recall=0.9)
    assert capped.value == 5 and capped.recall_at_k == 0.5  # best reachable, recorded honestly
    margin = tune(search, exact, self_ids, k, Knob.NPROBE, limit=64, target_recall=0.7, margin=0.1)
    assert margin.value == 8 and margin.target_recall == 0.7


def test_tune_stops_at_a_plateau() -> None:
    exact = np.arange(20 * 11).reshape(20, 11)

    def search(kk: int, value: int) -> np.ndarray:
        return exact[:, :kk].copy() * 0 - 1  # never finds anything

    result = tune(search, exact, exact[:, 0], 10, Knob.NPROBE, limit=4096, target_recall=0.95)
    assert result.recall_at_k == 0.0 and len(result.curve) < 6
