"""Idle OpenMP threads wait briefly, then sleep, instead of spinning for long.

torch (and faiss) run their parallel loops on a GNU OpenMP thread pool. After each loop, libgomp's
idle threads spin for ``GOMP_SPINCOUNT`` checks (300,000 by default) before they sleep, so every
gap between two loops (assembling the next batch of clips, Python between a model's layers) burns
a whole core while the main thread works alone. With 10,000 checks, the threads still catch the
next loop of a running model, and sleep through the gaps: less CPU for the same wall time
(docs/research/ingest-profile.md, "Cheaper blocks, reads and idle threads"). Results do not change:
only how threads wait does.

libgomp reads the setting once, when it is loaded (with torch's first import), so the command
line's ``main`` and the benchmarks call :func:`shorten_thread_spin` first; the processes they
start (Ray's workers, the training launcher's, the data loaders') inherit it from the environment,
and a joined Ray cluster's workers get it through the job's runtime environment
(:func:`scenesearch_base.ray_cluster.ray_runtime`). A value already in the environment is kept.
"""

from __future__ import annotations

import os
import sys

#: Checks an idle OpenMP thread spins before it sleeps.
SPIN_COUNT = 10_000
#: The libgomp setting that says so.
SPIN_VARIABLE = "GOMP_SPINCOUNT"


def thread_spin_env() -> dict[str, str]:
    """The environment entry that shortens the spin (the environment's own value when it has one)."""
    return {SPIN_VARIABLE: os.environ.get(SPIN_VARIABLE, str(SPIN_COUNT))}


def shorten_thread_spin() -> bool:
    """Set :data:`SPIN_VARIABLE` for this process and those it starts, unless the environment sets it.

    Returns whether it takes effect in this process: not when torch, which loads libgomp, is
    imported already (its threads keep the spin they read then; processes started later still get
    the shorter one).
    """
    os.environ.update(thread_spin_env())
    return "torch" not in sys.modules
