"""Atomic file writes: write to a temporary name beside the target, then rename.

A reader never sees a half-written file; a crash leaves either the old file or the new one.

**Temporary names** are ``.NAME.<pid>@<machine>.<random>.tmp<suffix>`` beside the target NAME, where
``<machine>`` is 8 hex digits of the host name, boot id and PID namespace. A write killed before
its rename leaves such an entry behind; the next atomic write into the same folder removes it when
its writer is gone:

* an entry of this machine is stale when no process with its pid is alive. A live writer's
  entries are never touched, so concurrent writers into one folder are safe; a reused pid only
  delays the cleanup.
* an entry of another machine (a shared network folder, another container, or before a reboot),
  or one written by an older version without a pid, is stale once unmodified for
  :data:`STALE_AFTER_S` (a day): its pid means nothing here, and no write lasts that long.

A process sweeps a folder at most every :data:`SWEEP_INTERVAL_S`, so writing many files into one
folder does not list it each time.

**Directory swaps** (:func:`atomic_directory` with ``overwrite``) rename the previous directory
aside to ``.NAME.old``, then the new one onto NAME. A kill between the two renames leaves the
complete previous directory aside and nothing at NAME: :func:`recover_directory` (called by
readers) and the next :func:`atomic_directory` of NAME move it back. The swap holds an exclusive
``flock`` on the parent folder, so that a reader never takes a swap in progress for a killed one;
the lock is released by the kernel when its holder dies.

**Reading a directory** that another process may replace at any moment: :func:`reading_directory`
holds a shared ``flock`` on the parent folder while the caller reads its files, so a swap waits for
the read to finish and a read never mixes files of two versions, nor finds one gone half way.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import os
import re
import secrets
import shutil
import socket
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

#: mkstemp/mkdtemp create private (0600/0700) entries; published files get the usual permissions.
_FILE_MODE = 0o666
_DIR_MODE = 0o777

#: Temporary entries of another machine (or without a pid) older than this are removed.
STALE_AFTER_S = 24 * 3600.0
#: A process lists a folder for stale entries at most this often.
SWEEP_INTERVAL_S = 60.0

# mkstemp's random part is 8 characters of [a-z0-9_]; ours is 8 hex digits.
_TEMP_RE = re.compile(r"^\..+?\.(?:(?P<pid>\d+)@(?P<machine>[0-9a-f]{8})\.)?[a-z0-9_]{8}\.tmp")
_last_sweep: dict[str, float] = {}


class OutputPathError(OSError):
    """An output path that cannot be written; the message names the path the caller gave, never a temporary one."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path = path


def check_output_file(target: Path | str) -> None:
    """Refuse a file output that cannot be written, before the work that would produce it.

    Raises:
        OutputPathError: ``target`` is a folder or a device (renaming onto it would replace it), or a
            part of its parent path is a file.
    """
    target = Path(target)
    if target.exists() and not target.is_file():
        raise OutputPathError(target, "exists and is not a regular file (a folder or a device); give a file path")
    for folder in target.parents:
        if folder.exists():
            if not folder.is_dir():
                raise OutputPathError(target, f"{folder} is a file, not a folder")
            if not os.access(folder, os.W_OK | os.X_OK):
                raise OutputPathError(target, f"{folder} cannot be written")
            break


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@functools.cache
def machine_tag() -> str:
    """8 hex digits naming this machine, boot and PID namespace: where a pid in a temporary name means something."""
    parts = [socket.gethostname()]
    with contextlib.suppress(OSError):
        parts.append(Path("/proc/sys/kernel/random/boot_id").read_text().strip())
    with contextlib.suppress(OSError):
        parts.append(os.readlink("/proc/self/ns/pid"))
    return hashlib.sha256("|".join(parts).encode()).hexdigest()[:8]


def _temp_prefix(name: str) -> str:
    return f".{name}.{os.getpid()}@{machine_tag()}."


def aside_path(target: Path | str) -> Path:
    """Where :func:`atomic_directory` keeps the previous ``target`` during its swap."""
    target = Path(target)
    return target.with_name(f".{target.name}.old")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OverflowError, ValueError):
        return False  # not a pid this system can have
    except OSError:
        return True  # EPERM: alive, owned by someone else
    return True


def is_temporary(name: str) -> bool:
    """Whether a folder entry of this name is a temporary entry of this module (a write in progress or
    killed, or the aside copy of a directory swap), not content of the folder."""
    return bool(_TEMP_RE.match(name)) or (name.startswith(".") and name.endswith(".old"))


def is_stale(entry: Path, now_s: float | None = None) -> bool:
    """Whether ``entry`` is a temporary entry of this module whose writer is gone (see the module docstring)."""
    match = _TEMP_RE.match(entry.name)
    if match is None:
        return False
    if match["pid"] is not None and match["machine"] == machine_tag():
        return not _alive(int(match["pid"]))
    try:
        age_s = (time.time() if now_s is None else now_s) - entry.lstat().st_mtime
    except OSError:
        return False
    return age_s > STALE_AFTER_S


def sweep_stale(folder: Path | str, force: bool = False) -> list[Path]:
    """Remove the stale temporary entries of killed writes from ``folder``; the entries removed.

    Without ``force``, a folder swept by this process less than :data:`SWEEP_INTERVAL_S` ago is
    left alone.
    """
    folder = Path(folder)
    key = str(folder.absolute())
    now = time.monotonic()
    if not force and now - _last_sweep.get(key, -SWEEP_INTERVAL_S) < SWEEP_INTERVAL_S:
        return []
    if len(_last_sweep) > 10_000:  # a long-running process writing into many folders
        _last_sweep.clear()
    _last_sweep[key] = now
    removed = []
    try:
        entries = [Path(e.path) for e in os.scandir(folder) if e.name.startswith(".") and ".tmp" in e.name]
    except OSError:
        return []
    wall = time.time()
    for entry in entries:
        if not is_stale(entry, wall):
            continue
        # Another process may sweep the same entry at the same moment: losing that race is fine.
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
        if not entry.exists():
            removed.append(entry)
    return removed


@contextmanager
def atomic_path(target: Path | str) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; on success rename it onto ``target``.

    The temporary file keeps the target's suffix, so libraries that pick a format by suffix work.
    """
    target = Path(target)
    check_output_file(target)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        sweep_stale(target.parent)
        fd, tmp_name = tempfile.mkstemp(prefix=_temp_prefix(target.name), suffix=f".tmp{target.suffix}",
                                        dir=target.parent)
    except OSError as exc:
        raise OutputPathError(target, f"cannot be written in {target.parent} ({exc.strerror or exc})") from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if tmp.exists():
            os.chmod(tmp, _FILE_MODE & ~_umask())
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def scratch_path(beside: Path | str) -> Iterator[Path]:
    """Yield a temporary file path beside ``beside`` (named as this module's temporary entries, so a
    killed writer's file is swept as theirs are), removed when the block ends: room on the output's
    own file system for what a writer spools before it writes the output."""
    beside = Path(beside)
    beside.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(beside.parent)
    fd, name = tempfile.mkstemp(prefix=_temp_prefix(beside.name), suffix=f".tmp{beside.suffix}", dir=beside.parent)
    os.close(fd)
    try:
        yield Path(name)
    finally:
        Path(name).unlink(missing_ok=True)


def atomic_write_bytes(target: Path | str, data: bytes) -> None:
    """Write ``data`` to ``target`` atomically."""
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(target: Path | str, text: str) -> None:
    """Write ``text`` (UTF-8) to ``target`` atomically."""
    atomic_write_bytes(target, text.encode("utf-8"))


def atomic_write_with(target: Path | str, writer: Callable[[Path], None]) -> None:
    """Call ``writer(tmp_path)`` and rename the result onto ``target``."""
    with atomic_path(target) as tmp:
        writer(tmp)


@contextmanager
def _folder_lock(folder: Path, shared: bool = False) -> Iterator[bool]:
    """Hold an exclusive (or ``shared``) ``flock`` on ``folder``; yields False where the file system offers none."""
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        yield False
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH if shared else fcntl.LOCK_EX)
        except OSError:
            yield False
            return
        yield True
    finally:
        os.close(fd)  # releases the lock


def _restore_aside(target: Path) -> bool:
    """With the folder lock held: move the aside copy of a swap killed between its renames back to ``target``.

    Returns False when it is there but cannot be moved (a read-only folder).
    """
    aside = aside_path(target)
    if target.exists() or not aside.is_dir():
        return True
    try:
        os.replace(aside, target)
    except OSError:
        return False
    return True


def recover_directory(target: Path | str) -> Path:
    """The directory to read at ``target``, after finishing a swap that a kill interrupted.

    When a swap was killed between its two renames, the complete previous directory is moved back
    to ``target``; where the folder is read-only (or offers no locks), that aside copy is returned
    to be read in place. Otherwise ``target`` itself is returned, existing or not.
    """
    target = Path(target)
    aside = aside_path(target)
    if target.exists() or not aside.is_dir():
        return target
    with _folder_lock(target.parent) as locked:
        # Without the lock a swap may be in progress: read the aside copy, move nothing.
        if locked and _restore_aside(target):
            return target if target.exists() else aside
    return target if target.exists() else aside


@contextmanager
def reading_directory(target: Path | str) -> Iterator[Path]:
    """Yield the directory to read at ``target`` (as :func:`recover_directory`), kept in place while the block reads it.

    A shared lock on the parent folder makes a concurrent :func:`atomic_directory` swap of
    ``target`` wait until the block is done: without it, a reader could take the manifest of one
    version and the files of the next, or find ``target`` gone between the swap's two renames.
    Files opened (or memory-mapped) inside the block stay readable after it, whatever a later swap
    does. Do not write ``target`` inside the block: the swap would wait for its own reader.
    """
    target = Path(target)
    recover_directory(target)  # takes the exclusive lock itself: before ours, never under it
    with _folder_lock(target.parent, shared=True):
        # Under the lock no swap is half done unless its writer was killed: then read the aside copy.
        aside = aside_path(target)
        yield target if target.exists() or not aside.is_dir() else aside


def _trash_name(target: Path) -> Path:
    return target.with_name(f"{_temp_prefix(target.name)}{secrets.token_hex(4)}.tmp-old")


@contextmanager
def atomic_directory(target: Path | str, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary directory beside ``target``; on success move it to ``target``.

    With ``overwrite`` an existing ``target`` is replaced only after the new one is complete. A
    swap that an earlier writer left half done is finished first (see the module docstring).
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(target.parent)
    recover_directory(target)
    if target.exists() and not overwrite:
        raise FileExistsError(f"{target} already exists")
    tmp = Path(tempfile.mkdtemp(prefix=_temp_prefix(target.name), suffix=".tmp", dir=target.parent))
    trash: list[Path] = []
    try:
        yield tmp
        os.chmod(tmp, _DIR_MODE & ~_umask())
        with _folder_lock(target.parent):
            _restore_aside(target)
            aside = aside_path(target)
            if target.exists():
                if not overwrite:
                    raise FileExistsError(f"{target} already exists")
                if aside.exists():  # left by a kill after a swap's second rename: garbage
                    trash.append(_trash_name(target))
                    os.replace(aside, trash[-1])
                os.replace(target, aside)
                os.replace(tmp, target)
                # Renamed to a temporary name before removal, so a kill while removing leaves an
                # entry that the next sweep recognises, never a stale aside copy.
                trash.append(_trash_name(target))
                os.replace(aside, trash[-1])
            else:
                os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    for old in trash:
        shutil.rmtree(old, ignore_errors=True)
