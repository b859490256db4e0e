"""Keep freed memory in the process instead of handing it back to the system at once.

glibc's malloc serves every block above 32 MiB (its largest mmap threshold) by a fresh ``mmap`` and
returns it with ``munmap`` when freed; it also gives the top of its heap back once more than
128 KiB of it is free. A batch of BEV clips is hundreds of MiB of tensors, allocated and freed at
every step, so each step maps fresh pages and the kernel zeroes every one on first touch. Embedding
on one core spent about a third of its time in the kernel this way (8.5 million page faults for
192 clips), and a Ray actor, whose tasks run on a thread of their own with its own malloc arena,
spent four fifths of it there.

:func:`retain_freed_memory` has malloc take every block from one heap (one arena for all threads,
no ``mmap``) and never trim that heap's freed top, so freed blocks are reused without the kernel:

- in this process, through ``mallopt`` (a trim threshold of -1 turns trimming off);
- in every process started from it afterwards (Ray's local workers, the training launcher's
  processes), through ``GLIBC_TUNABLES`` in the environment (:func:`malloc_tunables`), which glibc
  reads when a process starts; a joined Ray cluster's workers get it through the job's runtime
  environment (:func:`scenesearch_base.ray_cluster.ray_runtime`).

The command line's ``main`` and the benchmarks call it first; workers and launched processes get it
from their environment, not by calling it: a worker's task runs on a thread that already has its own
malloc arena, and ``mallopt`` then would forbid that arena's large mappings without moving the
thread to the main heap, which slows the embedding (``docs/research/ray-scale.md``).

A process keeps its peak memory until it exits, which is what a training run, an embedding worker
or a service does anyway. Results do not change: only where the bytes live does. Where malloc is
not glibc's (macOS, musl) nothing changes.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
from pathlib import Path

#: glibc's mallopt parameters (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_M_ARENA_MAX = -8
#: The same settings for processes started from this one (a trim threshold of SIZE_MAX: never trim).
_TUNABLES = {"glibc.malloc.arena_max": "1", "glibc.malloc.mmap_max": "0",
             "glibc.malloc.trim_threshold": str(2**64 - 1)}

_applied: bool | None = None


def malloc_tunables(current: str = "") -> str:
    """``GLIBC_TUNABLES`` with this module's malloc settings added to ``current``'s (which win)."""
    pairs = [p for p in current.split(":") if "=" in p]
    given = {p.split("=", 1)[0] for p in pairs}
    return ":".join([*pairs, *(f"{k}={v}" for k, v in _TUNABLES.items() if k not in given)])


def retain_freed_memory() -> bool:
    """Have this process's malloc, and that of the processes it starts from now on, reuse freed
    memory instead of returning it (idempotent).

    Returns whether this process's malloc was reconfigured (False where it is not glibc's). Large
    requests that the heap cannot grow for still fall back to ``mmap`` inside glibc, so no
    allocation fails for it.
    """
    global _applied
    if _applied is not None:
        return _applied
    _applied = False
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    # Threads started from now on share the main arena: a thread's own arena holds at most 64 MiB
    # heaps, so its larger blocks would be mapped afresh every time.
    _applied = all(mallopt(param, value) for param, value in
                   ((_M_ARENA_MAX, 1), (_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, -1)))
    os.environ["GLIBC_TUNABLES"] = malloc_tunables(os.environ.get("GLIBC_TUNABLES", ""))
    return _applied


class MemoryBudgetError(ValueError):
    """A step would need more memory than the machine has available; the message says what to lower."""


def available_memory_bytes() -> int | None:
    """Bytes this process may still allocate: the smaller of the system's available memory and what
    its cgroup's limit leaves; None where neither can be read (not Linux)."""
    found: list[int] = []
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    found.append(int(line.split()[1]) * 1024)
                    break
    except (OSError, ValueError):
        pass
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text(encoding="ascii").strip()
        used = Path("/sys/fs/cgroup/memory.current").read_text(encoding="ascii").strip()
        if limit != "max":
            found.append(max(0, int(limit) - int(used)))
    except (OSError, ValueError):
        pass
    return min(found) if found else None


def check_memory(need_bytes: int, what: str, lower: str) -> None:
    """Refuse a step that needs more than the available memory, before it allocates anything.

    Args:
        need_bytes: the step's estimate.
        what: the step, as the message names it (``rendering log L (F frames)``).
        lower: the options or config keys that shrink it.

    Raises:
        MemoryBudgetError: ``what`` needs about N GiB, M GiB are available; lower ``lower``.
    """
    available = available_memory_bytes()
    if available is None or need_bytes <= available:
        return
    gib = 1024**3
    raise MemoryBudgetError(f"{what} needs about {need_bytes / gib:.1f} GiB of memory, {available / gib:.1f} GiB "
                            f"are available; lower {lower}")
