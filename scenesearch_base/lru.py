"""A least-recently-used cache bounded by the total cost of its values (bytes, or a count).

Readers that pass over a fleet's logs keep per-log state (decoded blocks, a log's arrays, its tracks'
kinematics) for the next reads of the same log. Kept in a plain dict, that state grows with every log
read; here the least recently used values go once the budget is spent, so a pass over any number of
logs holds at most the budget, and a pass whose logs fit keeps every one.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class Lru(Generic[K, V]):
    """The most recently used values, up to ``capacity`` in total ``cost`` (thread-safe).

    Args:
        capacity: the budget, in the unit of ``cost``.
        cost: a value's share of the budget (default: 1, a count of values). A value costing more than
            the whole budget is not kept.
    """

    def __init__(self, capacity: int, cost: Callable[[V], int] = lambda _value: 1) -> None:
        self.capacity = int(capacity)
        self._cost = cost
        self._values: OrderedDict[K, tuple[V, int]] = OrderedDict()
        self.total = 0
        self._lock = threading.Lock()

    def get(self, key: K) -> V | None:
        """The value of ``key`` (now the most recently used), or None."""
        with self._lock:
            entry = self._values.get(key)
            if entry is None:
                return None
            self._values.move_to_end(key)
            return entry[0]

    def put(self, key: K, value: V) -> None:
        """Keep ``value`` under ``key`` (replacing a value there), evicting the least recently used."""
        cost = int(self._cost(value))
        with self._lock:
            old = self._values.pop(key, None)
            if old is not None:
                self.total -= old[1]
            if cost > self.capacity:
                return
            self._values[key] = (value, cost)
            self.total += cost
            while self.total > self.capacity:
                _, (_, evicted) = self._values.popitem(last=False)
                self.total -= evicted

    def clear(self) -> None:
        """Forget every value."""
        with self._lock:
            self._values.clear()
            self.total = 0

    def __len__(self) -> int:
        return len(self._values)

    def __contains__(self, key: object) -> bool:
        return key in self._values
