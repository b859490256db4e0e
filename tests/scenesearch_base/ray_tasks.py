"""Tasks for the runner tests: they run in Ray workers, so they live in a module of their own,
sent by value (the workers cannot import the tests)."""

from __future__ import annotations

import os
from pathlib import Path


def crashing(item: str, marker_dir: str) -> str:
    """``dies-once`` kills its worker on the first attempt (a marker file says it was tried),
    ``dies-always`` on every attempt, ``bad`` is bad input, ``bug`` a programming error."""
    marker = Path(marker_dir) / f"{item}.tried"
    if item == "dies-once" and not marker.exists():
        marker.write_text("tried")
        os._exit(1)
    if item == "dies-always":
        with open(Path(marker_dir) / "attempts", "a") as fh:
            fh.write("x")
        os._exit(1)
    if item == "bad":
        raise ValueError("bad input: no such frame")
    if item == "bug":
        raise KeyError("oops")
    return f"{item}:{os.getpid()}"


def slow_first(item: int) -> int:
    """The earlier the item, the longer it takes: on Ray the later items end first."""
    import time

    time.sleep(0.05 * (4 - item) if item < 4 else 0.0)
    return item


def slow_zero(item: int) -> int:
    """Item 0 takes a second, the others no time: all of them could end while it runs."""
    import time

    time.sleep(1.0 if item == 0 else 0.0)
    return item
