"""SHA-256 of files, hashed in parallel: how a stage recognises that a file it wrote is still intact.

``hashlib`` releases the GIL while it hashes, so threads hash several files at once.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

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


def file_checksums(folder: Path, names: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``{name: {"size_bytes", "sha256"}}`` of the files ``names`` in ``folder``: what a manifest records
    so that a reader can tell the files are still the ones written."""
    paths = [folder / name for name in names]
    return {name: {"size_bytes": p.stat().st_size, "sha256": digest}
            for name, p, digest in zip(names, paths, sha256_files(paths))}


def checksum_problem(folder: Path, listed: object, source: str) -> str | None:
    """Why the files that ``listed`` (a :func:`file_checksums` mapping read from ``source``) names in
    ``folder`` are not the ones written, or None when each has its size and SHA-256."""
    if not isinstance(listed, dict) or not listed:
        return f"{source} lists no checksums"
    names = []
    for name, entry in listed.items():
        file = folder / str(name)
        if not file.is_file():
            return f"{name} is missing"
        size, expected = file.stat().st_size, entry.get("size_bytes") if isinstance(entry, dict) else None
        if size != expected:
            return f"{name} is {size} bytes, {source} says {expected}"
        names.append(str(name))
    for name, digest in zip(names, sha256_files([folder / n for n in names])):
        if digest != listed[name].get("sha256"):
            return f"{name} differs from its checksum in {source}"
    return None
