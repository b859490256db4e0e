"""Items read ahead in a thread arrive in order; errors and early stops reach both sides."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from scenesearch_base.read_ahead import read_ahead


def test_items_arrive_in_order_whatever_the_depth() -> None:
    for depth in (1, 2, 5):
        assert list(read_ahead(range(20), depth)) == list(range(20))
    assert list(read_ahead([])) == []


def test_an_error_while_producing_is_raised_at_the_item_it_stopped() -> None:
    def failing() -> Iterator[int]:
        yield 0
        yield 1
        raise KeyError("bad row")

    got = []
    with pytest.raises(KeyError, match="bad row"):
        for item in read_ahead(failing()):
            got.append(item)
    assert got == [0, 1]


def test_stopping_early_stops_the_producer() -> None:
    produced = []
    threads_before = threading.active_count()

    def endless() -> Iterator[int]:
        i = 0
        while True:
            produced.append(i)
            yield i
            i += 1

    items = read_ahead(endless(), depth=2)
    assert [next(items) for _ in range(3)] == [0, 1, 2]
    items.close()  # joins the producer
    assert threading.active_count() == threads_before
    assert len(produced) <= 3 + 2 + 1  # what was taken, the queue's depth, the one being put


def test_depth_below_one_is_refused() -> None:
    with pytest.raises(ValueError, match="depth must be at least 1"):
        next(read_ahead([1], depth=0))
