"""An iterator's items produced in a background thread, a few ahead of their consumer.

Embedding clips alternates two kinds of work: assembling a batch (numpy, in Python) and running the
model on it (torch, which releases the GIL in its kernels). In one thread each waits for the other;
with the next batch assembled beside the model, the two overlap.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

#: Seconds between the producer's checks of whether its consumer stopped.
_POLL_S = 0.1


def read_ahead(items: Iterable[T], depth: int = 2) -> Iterator[T]:
    """The items of ``items`` in order, produced by a background thread up to ``depth`` ahead.

    An exception raised while producing is raised here, at the item it stopped. Closing this
    iterator before the end stops the producer after the item it is producing.
    """
    if depth < 1:
        raise ValueError(f"depth must be at least 1, got {depth}")
    done = object()
    ready: queue.Queue[tuple[object, BaseException | None]] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(entry: tuple[object, BaseException | None]) -> bool:
        while not stop.is_set():
            try:
                ready.put(entry, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for item in items:
                if not put((item, None)):
                    return
            put((done, None))
        except BaseException as exc:  # handed to the consumer, which raises it
            put((done, exc))

    producer = threading.Thread(target=produce, name="read-ahead", daemon=True)
    producer.start()
    try:
        while True:
            item, error = ready.get()
            if item is done:
                if error is not None:
                    raise error
                return
            yield item  # type: ignore[misc]
    finally:
        stop.set()
        producer.join()
