"""Checksums of index files, verified when an index opens, at little cost.

Every index directory lists its files in its manifest with their size and SHA-256, and the
manifest carries the SHA-256 of its own content (:data:`SEAL_FIELD`), so a flipped byte anywhere
in what a search reads is found before the first search. Sizes are always compared (that catches
truncation for free); checksums according to :class:`Verify`:

* ``cached`` (the default) hashes each file unless a *stamp* shows that this very file was hashed
  before: ``.verified.json`` beside the files records, per file, its device, inode, size,
  modification and change times (``st_ctime_ns``, which no program can set back) and the
  checksum found. Any write to a file changes its times, a copy changes its inode, and a rebuilt
  index is a new directory without a stamp, so each of these is hashed again. A stamp entry is
  trusted only when the file last changed at least :data:`STAMP_MARGIN_NS` before the hashing
  began (the "racy" rule of git's index: file times are coarse, so a change in the same tick as
  the hashing could otherwise go unseen). Bit rot on the disk that changes no time is only found
  by ``full``. Where the directory is read-only, no stamp is written and every open hashes.
* ``full`` hashes every byte on every open.
* ``off`` compares sizes only, and says so with an :class:`IntegrityWarning`.

Cost: SHA-256 is fast on CPUs with SHA extensions (most x86 and ARM server CPUs;
``docs/research/index-integrity.md``). Hashing runs in background threads (``hashlib`` releases the
GIL) while the loader parses the same files, so a first open takes about as long as the slower of the
two rather than their sum, and a stamped open costs a ``stat`` per file; ``benchmarks/bench_index.py``
measures both at 1M clips.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import warnings
from collections.abc import Iterator, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from indexes.errors import IndexFileError, ManifestError
from scenesearch_base.atomic import atomic_write_text
from scenesearch_base.checksums import hash_threads, sha256_file, sha256_files

STAMP_NAME = ".verified.json"
SEAL_FIELD = "content_sha256"
#: A stamp entry is trusted only for files unchanged since this long before their hashing began.
STAMP_MARGIN_NS = 2_000_000_000
_STAMP_VERSION = 1


class Verify(StrEnum):
    """How an index checks its files' checksums when it opens (see the module docstring)."""

    CACHED = "cached"
    FULL = "full"
    OFF = "off"


VerifyLike = Verify | str | bool


def as_verify(value: VerifyLike) -> Verify:
    """``True`` → ``full``, ``False`` → ``off``, or a :class:`Verify` value."""
    if isinstance(value, bool):
        return Verify.FULL if value else Verify.OFF
    try:
        return Verify(value)
    except ValueError:
        raise ValueError(f"verify must be one of {', '.join(v.value for v in Verify)}, got {value!r}") from None


class IntegrityWarning(UserWarning):
    """Checksums were not verified: skipped on request."""


@dataclass(frozen=True)
class FileEntry:
    """One file of an index directory: its size and SHA-256."""

    size_bytes: int
    sha256: str

    def to_json(self) -> dict[str, Any]:
        return {"size_bytes": self.size_bytes, "sha256": self.sha256}


def file_entries(directory: Path, names: list[str]) -> dict[str, FileEntry]:
    """Size and SHA-256 of ``directory / name`` for each of ``names``, hashed in parallel."""
    paths = [directory / n for n in names]
    return {n: FileEntry(p.stat().st_size, h) for n, p, h in zip(names, paths, sha256_files(paths))}


def parse_file_entries(raw: object, path: Path, field: str = "files") -> dict[str, FileEntry]:
    """The ``{name: {size_bytes, sha256}}`` object of a manifest, checked."""
    if not isinstance(raw, dict):
        raise ManifestError(path, "missing or not an object", field=field)
    out = {}
    for name, entry in raw.items():
        try:
            size, digest = int(entry["size_bytes"]), str(entry["sha256"])
        except (KeyError, TypeError, ValueError):
            raise ManifestError(path, f"bad entry for {name!r}", field=field) from None
        if ".." in Path(name).parts or Path(name).is_absolute():
            raise ManifestError(path, f"names a file outside the index: {name!r}", field=field)
        out[str(name)] = FileEntry(size, digest)
    return out


# ---------------------------------------------------------------------- manifests' own checksum


def _content_digest(payload: Mapping[str, Any]) -> str:
    body = {k: v for k, v in payload.items() if k != SEAL_FIELD}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def seal(payload: Mapping[str, Any]) -> dict[str, Any]:
    """``payload`` with :data:`SEAL_FIELD`: the SHA-256 of the rest of its content (key order and spacing aside)."""
    return {**{k: v for k, v in payload.items() if k != SEAL_FIELD}, SEAL_FIELD: _content_digest(payload)}


def check_seal(raw: Mapping[str, Any], path: Path) -> None:
    """Compare a manifest's content with its :data:`SEAL_FIELD`.

    Raises:
        ManifestError: the content differs, or the field is absent.
    """
    stored = raw.get(SEAL_FIELD)
    if stored is None:
        raise ManifestError(path, "missing; the manifest cannot be checked", field=SEAL_FIELD)
    if stored != _content_digest(raw):
        raise ManifestError(path, "the manifest's content differs from its checksum (corrupt or edited); "
                                  "rebuild the index", field=SEAL_FIELD)


# ---------------------------------------------------------------------- verifying files


def check_sizes(directory: Path, entries: Mapping[str, FileEntry]) -> None:
    """Every listed file exists with its listed size (cheap: catches missing and truncated files)."""
    for name, entry in entries.items():
        file = directory / name
        if not file.is_file():
            raise IndexFileError(file, "listed in the manifest but missing")
        size = file.stat().st_size
        if size != entry.size_bytes:
            raise IndexFileError(file, f"is {size} bytes, the manifest says {entry.size_bytes} "
                                       "(truncated or overwritten)")


def _identity(st: os.stat_result) -> list[int]:
    return [st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns]


def _read_stamp(directory: Path) -> dict[str, list[Any]]:
    try:
        raw = json.loads((directory / STAMP_NAME).read_text())
    except (OSError, ValueError):
        return {}  # no stamp, or a damaged one: hash everything
    if not isinstance(raw, dict) or raw.get("version") != _STAMP_VERSION or not isinstance(raw.get("files"), dict):
        return {}
    return {str(k): v for k, v in raw["files"].items() if isinstance(v, list) and len(v) == 7}


def _trusted(record: list[Any] | None, st: os.stat_result, sha256: str) -> bool:
    if record is None:
        return False
    *identity, digest, hashed_from_ns = record
    return bool(identity == _identity(st) and digest == sha256
                and isinstance(hashed_from_ns, int) and st.st_ctime_ns < hashed_from_ns - STAMP_MARGIN_NS)


class PendingVerification:
    """Checksums of a directory's files being computed in background threads; :meth:`wait` reports the outcome."""

    def __init__(self, directory: Path, entries: Mapping[str, FileEntry], mode: Verify) -> None:
        self.directory = directory
        self.mode = mode
        self._entries = dict(entries)
        self._stamp = _read_stamp(directory) if mode is Verify.CACHED else {}
        self._records: dict[str, list[Any]] = {}
        self._jobs: dict[str, tuple[Future[str], os.stat_result, int]] = {}
        self._pool: ThreadPoolExecutor | None = None
        todo = []
        for name, entry in self._entries.items():
            st = (directory / name).stat()
            if _trusted(self._stamp.get(name), st, entry.sha256):
                self._records[name] = self._stamp[name]
            else:
                todo.append((name, st))
        #: Files hashed by this verification (the others were trusted from the stamp).
        self.hashed = [name for name, _ in todo]
        if todo:
            self._pool = ThreadPoolExecutor(max_workers=hash_threads(len(todo)), thread_name_prefix="verify")
            for name, st in todo:
                started_ns = time.time_ns()
                self._jobs[name] = (self._pool.submit(sha256_file, directory / name), st, started_ns)
            self._pool.shutdown(wait=False)

    def failure(self) -> IndexFileError | None:
        """Wait for the hashing; the first file whose checksum differs from the manifest, if any."""
        for name, (job, st, started_ns) in self._jobs.items():
            path = self.directory / name
            try:
                digest = job.result()
            except OSError as exc:
                return IndexFileError(path, f"unreadable while verifying its checksum: {exc}")
            if digest != self._entries[name].sha256:
                return IndexFileError(path, "checksum differs from the manifest (corrupt or modified file); "
                                            "rebuild the index")
            self._records[name] = [*_identity(st), digest, started_ns]
        return None

    def wait(self) -> None:
        """Wait for the hashing; write the stamp on success.

        Raises:
            IndexFileError: a file's checksum differs from the manifest (naming the file).
        """
        error = self.failure()
        if error is not None:
            raise error
        if self.hashed and self.mode is not Verify.OFF:
            self._write_stamp()

    def _write_stamp(self) -> None:
        payload = {"version": _STAMP_VERSION, "files": self._records}
        # A read-only index directory simply gets no stamp: the next open hashes again.
        with suppress(OSError):
            atomic_write_text(self.directory / STAMP_NAME, json.dumps(payload, separators=(",", ":")))


@contextmanager
def verifying(directory: Path, entries: Mapping[str, FileEntry], verify: VerifyLike) -> Iterator[None]:
    """Check sizes now, then hash the files while the body loads them; raise at exit if one is corrupt.

    When the body fails (a corrupt file often fails to parse too), a checksum failure is raised
    in its place, since it says more plainly what is wrong.

    Raises:
        IndexFileError: a file is missing, truncated, or fails its checksum (naming the file).
    """
    mode = as_verify(verify)
    check_sizes(directory, entries)
    if mode is Verify.OFF:
        warnings.warn(f"{directory}: checksums not verified (verify='off'); only file sizes were checked",
                      IntegrityWarning, stacklevel=3)
        yield
        return
    pending = PendingVerification(directory, entries, mode)
    try:
        yield
    except Exception as exc:
        error = pending.failure()
        if error is not None:
            raise error from exc
        raise
    pending.wait()


def verify_files(directory: Path, entries: Mapping[str, FileEntry], verify: VerifyLike = Verify.CACHED) -> None:
    """Check ``entries`` (relative path → size and SHA-256) under ``directory``; see :func:`verifying`."""
    with verifying(directory, entries, verify):
        pass
