"""Fault injection for the kill tests: a child process imports this and SIGKILLs itself at a chosen point.

Points of an atomic write or directory swap of ``target`` (see :mod:`scenesearch_base.atomic`):

* ``before_swap``: just before the previous directory is moved aside;
* ``between_renames``: after it was moved aside, before the new one is moved in;
* ``after_swap``: after the new one is in place, before the aside copy is removed;
* ``after_write:<suffix>``: right after ``faiss.write_index`` or ``numpy.save`` wrote a file whose
  name ends with ``<suffix>`` (a kill while the new files are being written).

Usage in the child::

    sys.path.insert(0, "<repo>/tests/scenesearch_base")
    import kill_points
    kill_points.install(target, point)
"""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any


def die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def install(target: Path | str, point: str) -> None:
    """Patch ``os.replace``, ``faiss.write_index`` and ``numpy.save`` to kill this process at ``point``."""
    target = Path(target)
    real_replace = os.replace

    def replace(src: Any, dst: Any) -> None:
        src, dst = Path(src), Path(dst)
        if point == "before_swap" and src == target:
            die()
        real_replace(src, dst)
        if (point == "between_renames" and src == target) or (point == "after_swap" and dst == target):
            die()

    os.replace = replace  # type: ignore[assignment]
    if not point.startswith("after_write:"):
        return
    suffix = point.split(":", 1)[1]
    import faiss
    import numpy as np

    real_write, real_save = faiss.write_index, np.save

    def write_index(index: Any, path: Any, *args: Any) -> None:
        real_write(index, path, *args)
        if str(path).endswith(suffix):
            die()

    def save(path: Any, arr: Any, *args: Any, **kwargs: Any) -> None:
        real_save(path, arr, *args, **kwargs)
        if str(path).endswith(suffix):
            die()

    faiss.write_index, np.save = write_index, save
