"""On-disk layout of an index: a directory of files described by ``manifest.json``.

```
<dir>/manifest.json    format version, kind, dimension, metric, factory, count, per-file size+sha256,
                       and the checksum of its own content
<dir>/index.faiss      the FAISS index (ids inside it are the caller's ids)
<dir>/ids.npy          live ids, sorted (int64)
<dir>/removed.npy      ids removed so far; never reused
<dir>/metadata.parquet clip metadata (ClipIndex only)
<dir>/.verified.json   files already verified (written on open; see :mod:`indexes.integrity`)
```

The manifest is written last, inside a temporary directory that is renamed onto the target, so a
reader sees either the previous complete index or the new one. A kill between the two renames of
that swap leaves the complete previous index aside (see :mod:`scenesearch_base.atomic`); :func:`reading_index_dir`
moves it back, so a kill at any moment leaves a loadable index, and holds off a concurrent save
while a loader reads. Loading checks every file against the manifest (:mod:`indexes.integrity`).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import faiss
import numpy as np

from indexes.errors import IndexFileError, ManifestError, UnsupportedFormatError, faiss_message
from indexes.integrity import FileEntry, check_seal, file_entries, parse_file_entries, seal
from scenesearch_base.atomic import atomic_directory, reading_directory

#: The layout version: the manifest holds the checksum of its own content. Other versions are refused.
FORMAT_VERSION = 2
MANIFEST_NAME = "manifest.json"


@dataclass(frozen=True)
class Manifest:
    """Contents of ``manifest.json``.

    Attributes:
        format_version: layout version; readers refuse other ones.
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
            "files": {name: e.to_json() for name, e in self.files.items()},
            "extra": self.extra,
        }
        return json.dumps(seal(json.loads(json.dumps(payload))), indent=2, sort_keys=True)


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
    names = [p.name for p in sorted(directory.iterdir())
             if p.is_file() and p.name != MANIFEST_NAME and not p.name.startswith(".")]
    manifest = Manifest(FORMAT_VERSION, kind, dim, metric, factory, count, file_entries(directory, names),
                        dict(extra or {}))
    (directory / MANIFEST_NAME).write_text(manifest.to_json())
    return manifest


def require_files(manifest: Manifest, directory: Path, names: tuple[str, ...]) -> None:
    """Refuse a manifest that does not list (hence would not verify) each of ``names``."""
    missing = [n for n in names if n not in manifest.files]
    if missing:
        raise ManifestError(directory / MANIFEST_NAME, f"does not list {', '.join(missing)}", field="files")


@contextmanager
def reading_index_dir(directory: Path | str) -> Iterator[Path]:
    """Yield the index directory to read at ``directory``, after recovering a save whose swap a kill
    interrupted; a concurrent save waits until the block has read it
    (:func:`scenesearch_base.atomic.reading_directory`).

    Raises:
        IndexFileError: nothing there.
        ManifestError: a directory without a manifest.
    """
    with reading_directory(Path(directory)) as d:
        if not (d / MANIFEST_NAME).exists():
            if not d.exists():
                raise IndexFileError(d, "no index directory here")
            raise ManifestError(d / MANIFEST_NAME, "missing; this is not a saved index (or its save never finished)")
        yield d


def read_manifest(directory: Path | str, expected_kind: str | None = None) -> Manifest:
    """Read and check ``manifest.json``: its fields and its own checksum.

    The files it lists are checked by :func:`indexes.integrity.verifying` while they load.

    Args:
        directory: an index directory (see :func:`reading_index_dir`).
        expected_kind: refuse a manifest of another kind.

    Raises:
        UnsupportedFormatError: written in another format version (newer or older).
        ManifestError: unreadable, missing fields, corrupt, or of the wrong kind.
    """
    path = Path(directory) / MANIFEST_NAME
    raw = read_json_manifest(path, expected_kind, FORMAT_VERSION)
    required = {"kind": str, "dim": int, "metric": str, "factory": str, "count": int, "files": dict}
    for key, typ in required.items():
        if not isinstance(raw.get(key), typ):
            raise ManifestError(path, f"missing or not a {typ.__name__}", field=key)
    files = parse_file_entries(raw["files"], path)
    extra = raw.get("extra", {})
    if not isinstance(extra, dict):
        raise ManifestError(path, "not an object", field="extra")
    return Manifest(raw["format_version"], raw["kind"], raw["dim"], raw["metric"], raw["factory"], raw["count"],
                    files, extra)


def read_json_manifest(path: Path, kind: str | None, version: int) -> dict[str, Any]:
    """Parse a manifest file: a JSON object of ``kind`` whose ``format_version`` is ``version`` and
    whose content matches its own checksum.

    Raises:
        ManifestError: missing, unreadable, not an object, of another kind, or corrupt.
        UnsupportedFormatError: another format version: a newer one (upgrade scenesearch) or an older
            one (build the index again).
    """
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        raise ManifestError(path, "missing") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ManifestError(path, f"unreadable: {exc}") from None
    if not isinstance(raw, dict):
        raise ManifestError(path, "expected a JSON object")
    found = raw.get("format_version")
    if not isinstance(found, int):
        raise ManifestError(path, "missing or non-integer", field="format_version")
    if found > version:
        raise UnsupportedFormatError(
            path, f"format version {found} is newer than the supported version {version}; "
            "upgrade scenesearch to read it", field="format_version")
    if found < version:
        raise UnsupportedFormatError(
            path, f"format version {found} was built by an older version of scenesearch (this one reads "
            f"{version}): build it again", field="format_version")
    if kind is not None and raw.get("kind") != kind:
        raise ManifestError(path, f"holds a {raw.get('kind')!r}, expected a {kind!r}", field="kind")
    check_seal(raw, path)
    return raw


def read_faiss_index(path: Path, mmap: bool) -> faiss.Index:
    """Read a FAISS file, memory-mapped on request, turning FAISS's errors into :class:`IndexFileError`."""
    # The returned objects are already of their concrete type; downcasting them again would create
    # a second Python owner-less proxy and is never needed.
    if not mmap:
        attempts = [0]
    else:
        # Flat codes map with IO_FLAG_MMAP_IFC; IVF lists only with IO_FLAG_MMAP alone (FAISS refuses
        # the pair for them); kinds FAISS cannot map (e.g. graphs) are read into memory, read-only.
        read_only = faiss.IO_FLAG_READ_ONLY
        attempts = [faiss.IO_FLAG_MMAP | faiss.IO_FLAG_MMAP_IFC | read_only, faiss.IO_FLAG_MMAP | read_only, 0]
    for flags in attempts:
        try:
            return faiss.read_index(str(path), flags)
        except RuntimeError as exc:
            error = exc
    raise IndexFileError(path, f"FAISS cannot read it (truncated or corrupt?): {faiss_message(error)}") from None


def load_array(path: Path, dtype: type | np.dtype[Any], shape: tuple[int | str, ...]) -> np.ndarray:
    """Read a ``.npy`` file and check it: ``dtype`` and ``shape`` (a name such as ``"N"`` for any length).

    Raises:
        IndexFileError: missing, unreadable, or another dtype or shape (naming what was expected).
    """
    want = np.dtype(dtype)
    expected = f"a {want.name} array of shape ({', '.join(str(s) for s in shape)}{',' if len(shape) == 1 else ''})"
    try:
        arr = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise IndexFileError(path, f"missing; expected {expected}") from None
    except (OSError, ValueError, EOFError) as exc:
        raise IndexFileError(path, f"not a readable .npy file ({exc}); expected {expected}") from None
    if not isinstance(arr, np.ndarray) or arr.dtype != want or arr.ndim != len(shape) or any(
            isinstance(s, int) and s != n for s, n in zip(shape, arr.shape)):
        got = f"{arr.dtype} {arr.shape}" if isinstance(arr, np.ndarray) else type(arr).__name__
        raise IndexFileError(path, f"expected {expected}, got {got}")
    return arr


def load_ids(path: Path) -> np.ndarray:
    """The (N,) int64 ids saved in ``path`` (``.npy``)."""
    return load_array(path, np.int64, ("N",))
