"""Output folders that belong to scenesearch: each says what it is, and a writer replaces only its own kind.

Every folder a command writes (captions, clips, an index, a training run, a demo, a log) holds a
marker, ``.scenesearch.json``: the folder's kind and the top-level entries its writers made. Before a
writer touches a folder, :func:`claim_folder` checks it:

- an output that is one of the writer's inputs, lies inside one, or holds one is refused: writing
  it would replace or mix up what the command reads;
- a missing or empty folder is taken;
- a folder marked with another kind is refused (an index is never written over clips);
- a folder marked with this kind is taken. A writer that replaces the whole folder
  (:func:`scenesearch_base.atomic.atomic_directory` with a ``kind``) also refuses one that holds entries no
  writer of this kind made, such as a user's notes left inside, so that they are never deleted;
- an unmarked folder is taken only when a writer of this kind made it before markers existed: its
  signature file is there and every entry has one of the kind's names. Anything else is refused,
  naming a few of the entries it holds.

Temporary entries of killed writes (:mod:`scenesearch_base.atomic`) are never counted as the folder's content.
Folders given as URIs are not checked: an object store has no folders to own.
"""

from __future__ import annotations

import fnmatch
import json
import os
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from scenesearch_base.atomic import atomic_directory, atomic_write_text, is_temporary

#: The marker file in every folder scenesearch writes.
MARKER_FILE = ".scenesearch.json"
#: Version of the marker's layout.
MARKER_VERSION = 1


class FolderClaimError(FileExistsError):
    """An output folder that a writer must not write into (it names the folder and why)."""


@dataclass(frozen=True)
class FolderKind:
    """A kind of folder scenesearch writes.

    Attributes:
        name: the kind as the marker and messages say it (``index``, ``clips``, ...).
        signature: a file every folder of this kind holds; with ``entries`` it recognises a folder
            written before markers existed.
        entries: glob patterns of the top-level entries this kind's writers make.
    """

    name: str
    signature: str
    entries: tuple[str, ...]

    def owns(self, entry_name: str) -> bool:
        """Whether a top-level entry of this name is one this kind's writers make."""
        return any(fnmatch.fnmatchcase(entry_name, pattern) for pattern in self.entries)


@dataclass(frozen=True)
class Marker:
    """What a folder's marker says: its kind and the top-level entries its writers made."""

    kind: str
    entries: tuple[str, ...]


def read_marker(folder: Path) -> Marker | None:
    """The marker of ``folder``, or None when it has none.

    Raises:
        FolderClaimError: the marker is there but unreadable.
    """
    path = folder / MARKER_FILE
    if not path.is_file():
        return None
    try:
        marker = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FolderClaimError(f"{path}: unreadable folder marker ({exc}); remove it only if {folder} is "
                               "scenesearch's output") from None
    if not isinstance(marker, dict) or not isinstance(marker.get("kind"), str) \
            or not isinstance(marker.get("entries", []), list):
        raise FolderClaimError(f"{path}: field 'kind' or 'entries' is not what a folder marker holds")
    return Marker(marker["kind"], tuple(str(name) for name in marker.get("entries", [])))


def _content(folder: Path) -> list[str]:
    """The top-level entries of ``folder`` that are its content (no marker, no temporary entries)."""
    return sorted(e.name for e in os.scandir(folder) if e.name != MARKER_FILE and not is_temporary(e.name))


def _named(names: Sequence[str], limit: int = 5) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def check_inputs(out: Path | str, inputs: Iterable[Path | str | None]) -> None:
    """Refuse an output folder that is one of ``inputs``, lies inside one, or holds one.

    URIs among the inputs (and a URI output) are not checked.

    Raises:
        FolderClaimError: naming the output and the input.
    """
    if "://" in str(out):
        return
    out_path = Path(out).resolve()
    for given in inputs:
        if given is None or "://" in str(given):
            continue
        path = Path(given).resolve()
        if out_path == path:
            raise FolderClaimError(f"--out {out}: is the input {given}; write the output to another folder")
        if path in out_path.parents:
            raise FolderClaimError(f"--out {out}: lies inside the input {given}; write the output elsewhere")
        if out_path in path.parents:
            raise FolderClaimError(f"--out {out}: holds the input {given}; write the output to another folder")


def claim_folder(out: Path | str, kind: FolderKind, inputs: Iterable[Path | str | None] = (),
                 whole: bool = False) -> None:
    """Check that a writer of ``kind`` may write ``out`` (see the module docstring).

    Args:
        out: the output folder (a URI is not checked).
        kind: what the writer makes.
        inputs: the folders and files the writer reads.
        whole: the writer replaces the whole folder, so entries it did not make would be lost.

    Raises:
        FolderClaimError: naming the folder and what makes it another's.
    """
    check_inputs(out, inputs)
    if "://" in str(out):
        return
    folder = Path(out)
    if not folder.exists():
        return
    if not folder.is_dir():
        raise FolderClaimError(f"--out {out}: is a file, not a folder; give a folder for the {kind.name}")
    content = _content(folder)
    if not content:
        return
    marker = read_marker(folder)
    if marker is not None:
        if marker.kind != kind.name:
            raise FolderClaimError(f"--out {out}: is a scenesearch {marker.kind} folder ({MARKER_FILE}), "
                                   f"not a {kind.name} folder; give another folder")
        foreign = [name for name in content if name not in marker.entries and not kind.owns(name)]
        if whole and foreign:
            raise FolderClaimError(f"--out {out}: holds {_named(foreign)}, which scenesearch did not write; "
                                   f"writing the {kind.name} would delete them: move them away or give another "
                                   "folder")
        return
    foreign = [name for name in content if not kind.owns(name)]
    if foreign or kind.signature not in content:
        raise FolderClaimError(f"--out {out}: is not empty and not a scenesearch {kind.name} folder (it holds "
                               f"{_named(foreign or content)}); give a new or empty folder")


def mark_folder(folder: Path | str, kind: FolderKind, entries: Iterable[str] | None = None) -> None:
    """Write (or update) the marker of ``folder`` (created when missing): its kind and the entries its
    writers made.

    ``entries`` None lists the folder's content now (a folder about to be published whole); given
    names are added to those an earlier writer recorded.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if entries is None:
        names = set(_content(folder))
    else:
        previous = read_marker(folder)
        names = set(previous.entries if previous is not None else ()) | set(entries)
    payload = {"format_version": MARKER_VERSION, "kind": kind.name, "entries": sorted(names)}
    atomic_write_text(folder / MARKER_FILE, json.dumps(payload, indent=2) + "\n")


@contextmanager
def claimed_directory(target: Path | str, kind: FolderKind, inputs: Iterable[Path | str | None] = (),
                      overwrite: bool = True) -> Iterator[Path]:
    """:func:`scenesearch_base.atomic.atomic_directory` for a folder of ``kind``: claimed first, marked when complete.

    The new folder replaces ``target`` (with ``overwrite``) only when :func:`claim_folder` takes it
    as a whole; its marker lists what the caller wrote into the temporary folder.

    Raises:
        FolderClaimError: ``target`` is an input, another kind's folder, or holds entries that
            scenesearch did not write.
    """
    if overwrite:
        claim_folder(target, kind, inputs, whole=True)
    else:  # an existing target is refused by the swap itself
        check_inputs(target, inputs)
    with atomic_directory(target, overwrite=overwrite) as tmp:
        yield tmp
        mark_folder(tmp, kind)
