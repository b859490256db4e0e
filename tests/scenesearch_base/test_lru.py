"""The cost-bounded LRU cache: least recently used values go first, the budget is never exceeded."""

from __future__ import annotations

import numpy as np

from scenesearch_base.lru import Lru


def test_values_stay_within_their_budget_least_recently_used_first() -> None:
    cache: Lru[tuple[str, int], np.ndarray] = Lru(1000, lambda value: value.nbytes)
    for b in range(10):
        cache.put(("f", b), np.zeros(300, np.uint8))
    assert cache.get(("f", 9)) is not None and cache.get(("f", 0)) is None  # the oldest went first
    assert len(cache) == 3 and cache.total == 900  # 3 × 300 bytes ≤ 1000
    assert cache.get(("f", 7)) is not None  # used again: now the most recent
    cache.put(("f", 10), np.zeros(300, np.uint8))
    assert ("f", 7) in cache and ("f", 8) not in cache
    cache.put(("big", 0), np.zeros(2000, np.uint8))  # larger than the whole budget: not kept
    assert cache.get(("big", 0)) is None and cache.total == 900


def test_a_value_put_again_replaces_the_old_one_and_its_cost() -> None:
    cache: Lru[str, list[int]] = Lru(10, len)
    cache.put("a", [1] * 4)
    cache.put("a", [2] * 6)
    assert cache.get("a") == [2] * 6 and cache.total == 6
    cache.put("a", [3] * 20)  # too large: the key is left empty, not holding the old value
    assert cache.get("a") is None and cache.total == 0


def test_without_a_cost_it_counts_values() -> None:
    cache: Lru[int, str] = Lru(2)
    for i in range(5):
        cache.put(i, str(i))
    assert len(cache) == 2 and cache.get(3) == "3" and cache.get(4) == "4"
    cache.clear()
    assert len(cache) == 0 and cache.total == 0 and cache.get(4) is None
