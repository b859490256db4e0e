"""On-disk layout of an index: a directory of files described by ``manifest.json``.

```
<dir>/manifest.json    format version, kind, dimension, metric, factory, count, per-file size+sha256
<dir>/index.faiss      the FAISS index (ids inside it are the caller's ids)
<dir>/ids.npy          live ids, sorted (int64)
<dir>/removed.npy      ids removed so far; never reused
<dir>/metadata.parquet clip metadata (ClipIndex only)
```

The manifest is written last, inside a temporary directory that is renamed onto the target, so a
reader sees either the previous complete index or the new one. :func:`resolve_dir` also accepts the
previous copy that :func:`common.atomic.atomic_directory` keeps aside during the instant between
its two renames, so a kill at any moment leaves a loadable index.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import faiss
import numpy as np

from common.atomic import atomic_directory
from indexes.errors import IndexFileError, ManifestError, UnsupportedFormatError, faiss_message

FORMAT_VERSION = 1
MANIFEST_NAME = "manifest.json"
_CHUNK_BYTES = 8 << 20


@dataclass(frozen=True)
class FileEntry:
    """One file of an index directory: its size and SHA-256."""

    size_bytes: int
    sha256: str


@dataclass(frozen=True)
class Manifest:
    """Contents of ``manifest.json``.

    Attributes:
        format_version: layout version; readers refuse newer ones.
        kind: ``vector_index``, ``clip_index`` or ``sharded_index``.
        dim: vector dimension.
        metric: :class:`indexes.vectors.Metric` value.
        factory: FAISS factory string (``sharded`` for a sharded index).
        count: number of live vectors.
        files: file name → size and checksum.
        extra: kind-specific fields (tuning, next id, shard names, …).
    """

    format_version: int
    kind: str
    dim: int
    metric: str
    factory: str
    count: int
    files: dict[str, FileEntry] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        payload = {
            "format_version": self.format_version, "kind": self.kind, "dim": self.dim,
            "metric": self.metric, "factory": self.factory, "count": self.count,
            "files": {name: {"size_bytes": e.size_bytes, "sha256": e.sha256} for name, e in self.files.items()},
            "extra": self.extra,
        }
        return json.dumps(payload, indent=2, sort_keys=True)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(_CHUNK_BYTES):
            h.update(chunk)
    return h.hexdigest()


@contextmanager
def writing_index_dir(target: Path | str, overwrite: bool = True) -> Iterator[Path]:
    """Yield a temporary directory; on success it replaces ``target`` in one rename.

    The caller writes its files and then :func:`write_manifest` (last); a crash at any moment leaves
    the previous index untouched.
    """
    with atomic_directory(target, overwrite=overwrite) as tmp:
        yield tmp


def write_manifest(directory: Path, kind: str, dim: int, metric: str, factory: str, count: int,
                   extra: dict[str, Any] | None = None) -> Manifest:
    """Checksum every file in ``directory`` (subdirectories hold their own manifests) and write the manifest."""
    files = {
        p.name: FileEntry(p.stat().st_size, sha256_file(p))
        for p in sorted(directory.iterdir()) if p.is_file() and p.name != MANIFEST_NAME
    }
    manifest = Manifest(FORMAT_VERSION, kind, dim, metric, factory, count, files, dict(extra or {}))
    (directory / MANIFEST_NAME).write_text(manifest.to_json())
    return manifest


def resolve_dir(directory: Path | str) -> Path:
    """The directory to read: ``directory``, or the previous copy kept aside during a save's swap."""
    directory = Path(directory)
    if (directory / MANIFEST_NAME).exists():
        return directory
    aside = directory.with_name(f".{directory.name}.old")
    if not directory.exists() and (aside / MANIFEST_NAME).exists():
        return aside
    if not directory.exists():
        raise IndexFileError(directory, "no index directory here")
    raise ManifestError(directory / MANIFEST_NAME, "missing; this is not a saved index (or its save never finished)")


def read_manifest(directory: Path | str, expected_kind: str | None = None, verify: bool = True) -> Manifest:
    """Read and check ``manifest.json`` and the files it lists.

    Args:
        directory: an index directory (see :func:`resolve_dir`).
        expected_kind: refuse a manifest of another kind.
        verify: compare SHA-256 checksums (reads every byte); sizes are always compared, which
            catches truncated files cheaply.

    Raises:
        UnsupportedFormatError: written by a newer format version.
        ManifestError: unreadable, missing fields, or wrong kind.
        IndexFileError: a listed file is missing, truncated or fails its checksum.
    """
    directory = Path(directory)
    path = directory / MANIFEST_NAME
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        raise ManifestError(path, "missing") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ManifestError(path, f"unreadable: {exc}") from None
    if not isinstance(raw, dict):
        raise ManifestError(path, "expected a JSON object")
    version = raw.get("format_version")
    if not isinstance(version, int):
        raise ManifestError(path, "missing or non-integer", field="format_version")
    if version > FORMAT_VERSION:
        raise UnsupportedFormatError(
            path, f"format version {version} is newer than the supported version {FORMAT_VERSION}; "
            "upgrade scenesearch to read it", field="format_version")
    required = {"kind": str, "dim": int, "metric": str, "factory": str, "count": int, "files": dict}
    for key, typ in required.items():
        if not isinstance(raw.get(key), typ):
            raise ManifestError(path, f"missing or not a {typ.__name__}", field=key)
    if expected_kind is not None and raw["kind"] != expected_kind:
        raise ManifestError(path, f"holds a {raw['kind']!r}, expected a {expected_kind!r}", field="kind")
    files: dict[str, FileEntry] = {}
    for name, entry in raw["files"].items():
        try:
            files[name] = FileEntry(int(entry["size_bytes"]), str(entry["sha256"]))
        except (KeyError, TypeError, ValueError):
            raise ManifestError(path, f"bad entry for {name!r}", field="files") from None
    for name, entry in files.items():
        file = directory / name
        if not file.is_file():
            raise IndexFileError(file, "listed in the manifest but missing")
        size = file.stat().st_size
        if size != entry.size_bytes:
            raise IndexFileError(file, f"is {size} bytes, the manifest says {entry.size_bytes} "
                                       "(truncated or overwritten)")
        if verify and sha256_file(file) != entry.sha256:
            raise IndexFileError(file, "checksum differs from the manifest (corrupt file)")
    extra = raw.get("extra", {})
    if not isinstance(extra, dict):
        raise ManifestError(path, "not an object", field="extra")
    return Manifest(version, raw["kind"], raw["dim"], raw["metric"], raw["factory"], raw["count"], files, extra)


def read_faiss_index(path: Path, mmap: bool) -> faiss.Index:
    """Read a FAISS file, memory-mapped on request, turning FAISS's errors into :class:`IndexFileError`."""
    # The returned objects are already of their concrete type; downcasting them again would create
    # a second Python owner-less proxy and is never needed.
    flags = (faiss.IO_FLAG_MMAP | faiss.IO_FLAG_MMAP_IFC | faiss.IO_FLAG_READ_ONLY) if mmap else 0
    try:
        index = faiss.read_index(str(path), flags)
    except RuntimeError as exc:
        if mmap:
            # Kinds FAISS cannot map (e.g. graphs) are read into memory; they stay read-only.
            try:
                return faiss.read_index(str(path))
            except RuntimeError:
                pass
        raise IndexFileError(path, f"FAISS cannot read it (truncated or corrupt?): {faiss_message(exc)}") from None
    return index


def load_ids(path: Path) -> np.ndarray:
    """The (N,) int64 ids saved in ``path`` (``.npy``)."""
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise IndexFileError(path, f"unreadable: {exc}") from None
    if arr.ndim != 1 or arr.dtype != np.int64:
        raise IndexFileError(path, f"expected a 1-D int64 array, got {arr.dtype} {arr.shape}")
    return np.asarray(arr)
