"""Whole processes measured as a user runs them: wall time, CPU time and peak memory."""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

#: The repository root: commands run from it, as ``python -m retrieval.cli`` needs.
ROOT = Path(__file__).resolve().parent.parent


def measure_process(argv: Sequence[str], env: Mapping[str, str] | None = None) -> tuple[float, float, float]:
    """Wall seconds, CPU seconds (user + system, of the process and its children) and peak resident MiB
    of one process; its standard output is discarded.

    Raises:
        RuntimeError: the process failed; the message holds the end of its standard error.
    """
    start = time.perf_counter()
    proc = subprocess.Popen(list(argv), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env=None if env is None else dict(env), cwd=ROOT)
    assert proc.stderr is not None
    err = proc.stderr.read().decode(errors="replace")  # read while it runs: a full pipe would block it
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.stderr.close()
    if status:
        raise RuntimeError(f"{' '.join(argv)} failed ({status}): {err[-500:]}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


def run_checked(argv: Sequence[str], env: Mapping[str, str] | None = None) -> None:
    """Run a preparation step; raise with its standard error if it fails."""
    result = subprocess.run(list(argv), capture_output=True, cwd=ROOT, env=None if env is None else dict(env))
    if result.returncode:
        raise RuntimeError(f"{' '.join(argv)} failed ({result.returncode}): "
                           f"{result.stderr.decode(errors='replace')[-500:]}")
