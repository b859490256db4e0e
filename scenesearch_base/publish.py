"""Publishing a set of files together: readers see all of the new ones or all of the old ones.

Files that belong together (``frame_tags.parquet`` and ``captions.parquet``) cannot be replaced
together by renaming each onto its name: a crash between the two renames would leave a new file
beside an old one. Instead each run writes a complete *generation* and switches to it with one
rename::

    OUT/frame_tags.parquet -> .generations/current/frame_tags.parquet     (relative links, made once)
    OUT/captions.parquet   -> .generations/current/captions.parquet
    OUT/.generations/current -> gen-<id>                                    (replaced by one rename)
    OUT/.generations/gen-<id>/frame_tags.parquet, captions.parquet

A generation is written into ``.generations/.tmp-<id>`` and renamed to ``gen-<id>`` only when all
its files are complete and synced; the link ``current`` is then replaced atomically. A process
killed at any point leaves ``current`` on the previous generation; what it left behind (temporary
folders, generations no longer current, temporary links, temporary files of the earlier one-file
writer) is removed by the next run. Plain files from before (an older output folder) are first
moved into a generation of their own, so that readers never see a mix of old and new either.
One writer at a time per folder.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import uuid
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

from scenesearch_base.atomic import sweep_stale

#: Folder of the generations, inside the output folder.
GENERATIONS_DIR = ".generations"
CURRENT = "current"
_GEN_PREFIX = "gen-"


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_file(path: Path) -> None:
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def _link(target: str, path: Path) -> None:
    """Make ``path`` a symbolic link to ``target``, replacing whatever is there in one rename."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp-link")
    os.symlink(target, tmp)
    os.replace(tmp, path)


def current_generation(out_dir: Path | str) -> Path | None:
    """The folder of the published generation, or None when nothing was published this way."""
    link = Path(out_dir) / GENERATIONS_DIR / CURRENT
    if not link.is_symlink():
        return None
    return link.parent / os.readlink(link)


def remove_stale(out_dir: Path | str) -> list[Path]:
    """Remove what killed writes left behind; returns what was removed.

    Everything in ``.generations`` but the current generation and its link, and the temporary files
    of killed single-file writes beside the outputs (:func:`scenesearch_base.atomic.sweep_stale`).
    """
    out = Path(out_dir)
    removed: list[Path] = []
    gens = out / GENERATIONS_DIR
    current = current_generation(out)
    if gens.is_dir():
        for entry in gens.iterdir():
            if entry.name == CURRENT or (current is not None and entry.name == current.name):
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
            else:
                entry.unlink(missing_ok=True)
            removed.append(entry)
    if out.is_dir():
        removed += sweep_stale(out, force=True)
    return removed


def _adopt_plain_files(out: Path, names: tuple[str, ...]) -> None:
    """Move plain output files of an older writer into a generation of their own, so that the switch
    to links never shows a new file beside an old one."""
    plain = [name for name in names if (out / name).is_file() and not (out / name).is_symlink()]
    if not plain:
        return
    gens = out / GENERATIONS_DIR
    tmp = gens / f".tmp-{uuid.uuid4().hex}"
    tmp.mkdir(parents=True)
    for name in plain:
        os.link(out / name, tmp / name)  # same content, no copy
    gen = gens / f"{_GEN_PREFIX}{uuid.uuid4().hex}"
    os.replace(tmp, gen)
    _link(gen.name, gens / CURRENT)
    for name in plain:
        _link(f"{GENERATIONS_DIR}/{CURRENT}/{name}", out / name)


def publish(out_dir: Path | str, writers: Mapping[str, Callable[[Path], None]]) -> dict[str, Path]:
    """Write and publish the files ``writers`` name together (see the module docstring).

    Args:
        out_dir: the output folder (created when missing).
        writers: file name → function writing that file at the path it is given.

    Returns:
        file name → its path in ``out_dir`` (a link into the current generation).
    """
    with generation(out_dir, tuple(writers)) as folder:
        for name, write in writers.items():
            write(folder / name)
    return {name: Path(out_dir) / name for name in writers}


@contextlib.contextmanager
def generation(out_dir: Path | str, names: tuple[str, ...]) -> Iterator[Path]:
    """A new generation's folder, to write the files ``names`` in (a writer that streams keeps them
    open while it works); published when the block ends, and removed, with nothing published, when
    it raises (see the module docstring)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    remove_stale(out)
    _adopt_plain_files(out, names)
    gens = out / GENERATIONS_DIR
    gens.mkdir(exist_ok=True)
    previous = current_generation(out)
    tmp = gens / f".tmp-{uuid.uuid4().hex}"
    tmp.mkdir()
    try:
        yield tmp
        for name in names:
            _fsync_file(tmp / name)
        _fsync_dir(tmp)
        gen = gens / f"{_GEN_PREFIX}{uuid.uuid4().hex}"
        os.replace(tmp, gen)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _link(gen.name, gens / CURRENT)  # the commit
    _fsync_dir(gens)
    for name in names:
        path = out / name
        target = f"{GENERATIONS_DIR}/{CURRENT}/{name}"
        if not (path.is_symlink() and os.readlink(path) == target):
            _link(target, path)
    _fsync_dir(out)
    if previous is not None and previous.name != gen.name:
        shutil.rmtree(previous, ignore_errors=True)
