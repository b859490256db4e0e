"""SHA-256 of files, hashed in parallel: how a stage recognises that a file it wrote is still intact.

``hashlib`` releases the GIL while it hashes, so threads hash several files at once.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

_MAX_THREADS = 8


def sha256_file(path: Path) -> str:
    """The hex SHA-256 of the file at ``path``."""
    with path.open("rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def hash_threads(n_files: int) -> int:
    """Threads that hash ``n_files`` files: one per file, at most one per core (and 8)."""
    return max(1, min(n_files, os.cpu_count() or 1, _MAX_THREADS))


def sha256_files(paths: Sequence[Path]) -> list[str]:
    """The hex SHA-256 of each file of ``paths``, in order, hashed in parallel."""
    if len(paths) <= 1:
        return [sha256_file(p) for p in paths]
    with ThreadPoolExecutor(max_workers=hash_threads(len(paths))) as pool:
        return list(pool.map(sha256_file, paths))
