"""Freed memory is reused: large blocks come from malloc's heap and stay there when freed, in this
process and in the processes it starts."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from scenesearch_base.memory import malloc_tunables, retain_freed_memory

#: Allocates a 64 MiB array and frees it; prints malloc's statistics (mallinfo2) while it lives and after.
_ALLOCATE = """
import ctypes, json, sys
import numpy as np
from scenesearch_base.memory import retain_freed_memory

class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks",
                 "keepcost")]

libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = MallInfo2
if sys.argv[1] == "retain":
    assert retain_freed_memory()
x = np.ones(8 * 2**20)  # 64 MiB, above glibc's largest mmap threshold
live = libc.mallinfo2()
del x
freed = libc.mallinfo2()
print(json.dumps({"mapped_live": live.hblkhd, "heap_live": live.arena, "heap_freed": freed.arena}))
"""


def _malloc_figures(mode: str, tunables: str | None = None) -> dict[str, int]:
    env = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
    if tunables is not None:
        env["GLIBC_TUNABLES"] = tunables
    out = subprocess.run([sys.executable, "-c", _ALLOCATE, mode], capture_output=True, text=True, check=True,
                         env=env)
    figures: dict[str, int] = json.loads(out.stdout)
    return figures


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_large_blocks_come_from_the_heap_and_stay_there() -> None:
    size = 64 * 2**20
    default = _malloc_figures("default")
    assert default["mapped_live"] >= size  # a fresh mapping, unmapped when freed: the kernel zeroes it each time
    retained = _malloc_figures("retain")
    assert retained["mapped_live"] < size and retained["heap_live"] >= size
    assert retained["heap_freed"] >= size  # kept for the next allocation
    # A process started from one that called it (a Ray worker, a training process) does the same.
    inherited = _malloc_figures("default", malloc_tunables())
    assert inherited["mapped_live"] < size and inherited["heap_freed"] >= size


def test_tunables_keep_what_is_given() -> None:
    merged = malloc_tunables("glibc.malloc.arena_max=4:glibc.cpu.hwcaps=-AVX")
    pairs = dict(p.split("=", 1) for p in merged.split(":"))
    assert pairs["glibc.malloc.arena_max"] == "4" and pairs["glibc.cpu.hwcaps"] == "-AVX"
    assert pairs["glibc.malloc.mmap_max"] == "0"


def test_is_idempotent() -> None:
    first = retain_freed_memory()
    assert retain_freed_memory() is first
