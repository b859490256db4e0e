"""Inputs and outputs that are local paths or ``pyarrow.fs`` URIs (``s3://``, ``gs://``, ``file://``).

The stages read and write local files (memory maps, atomic renames). A task given a URI stages
it: :func:`staged_input` copies a log folder (or a file) to a local temporary folder for the
task's duration; :func:`staged_output` gives the task a local folder and uploads what it wrote
there once the task succeeded. Local paths pass through untouched, so the serial path on local
files does exactly what it did before. Credentials and regions come from the environment, as
``pyarrow.fs`` reads them (``AWS_*``, ``GOOGLE_APPLICATION_CREDENTIALS``, ...).

An object store has no atomic rename: an upload is complete file by file, and the files the
driver writes last (a clip table, a manifest) name only what was uploaded whole before them.
"""

from __future__ import annotations

import contextlib
import re
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from scenesearch_base.atomic import atomic_write_with

_URI = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://")

#: A location: a local path, or a URI string.
Location = str | Path


def is_uri(location: Location) -> bool:
    """Whether ``location`` is a URI (``scheme://...``) rather than a local path."""
    return isinstance(location, str) and bool(_URI.match(location))


def as_location(text: str) -> Location:
    """A command-line argument as a location: URIs stay strings, everything else becomes a Path."""
    return text if is_uri(text) else Path(text)


def _filesystem(uri: str) -> tuple[Any, str]:
    import pyarrow.fs as pafs

    try:
        return pafs.FileSystem.from_uri(uri)
    except (ValueError, OSError) as exc:  # unknown scheme, a bucket's region not found, ...
        raise FileNotFoundError(f"{uri}: cannot open this location ({exc})") from None


def name_of(location: Location) -> str:
    """The last part of a location: a log folder's name is its log id."""
    return Path(str(location).rstrip("/")).name if is_uri(location) else Path(location).name


def parent(location: Location) -> Location:
    """The folder holding ``location``, for paths and URIs alike."""
    if is_uri(location):
        return str(location).rstrip("/").rsplit("/", 1)[0]
    return Path(location).parent


def join(location: Location, *parts: str) -> Location:
    """``location / part / ...`` for paths and URIs alike."""
    if is_uri(location):
        return "/".join([str(location).rstrip("/"), *parts])
    return Path(location).joinpath(*parts)


def distinct_by_name(locations: Sequence[Location]) -> tuple[dict[str, Location], dict[str, str]]:
    """The locations by their last part (a log folder's name is its log id), each name once.

    Returns:
        (name → the first location of that name, label of each later one → why it is left out):
        a batch that names a log twice, as the same folder or as two folders of one log id,
        processes it once and reports the rest.
    """
    kept: dict[str, Location] = {}
    repeated: dict[str, str] = {}
    for location in locations:
        name = name_of(location)
        if name in kept:
            same = not is_uri(location) and not is_uri(kept[name]) and Path(location).resolve() == \
                Path(kept[name]).resolve()
            repeated[str(location)] = (f"log given twice (the same folder as {kept[name]})" if same
                                       else f"log id {name} given twice (kept {kept[name]})")
        else:
            kept[name] = location
    return kept, repeated


def exists(location: Location) -> bool:
    if not is_uri(location):
        return Path(location).exists()
    import pyarrow.fs as pafs

    fs, path = _filesystem(str(location))
    return bool(fs.get_file_info(path).type != pafs.FileType.NotFound)


def expand(locations: Sequence[str]) -> list[Location]:
    """Command-line locations, a URI ending in ``/*`` replaced by the folders under it (sorted)."""
    import pyarrow.fs as pafs

    out: list[Location] = []
    for text in locations:
        if not (is_uri(text) and text.endswith("/*")):
            out.append(as_location(text))
            continue
        base = text[:-2]
        fs, path = _filesystem(base)
        try:
            infos = fs.get_file_info(pafs.FileSelector(path, recursive=False))
        except FileNotFoundError:
            raise FileNotFoundError(f"{base}: no such folder") from None
        out += sorted(join(base, Path(i.path).name) for i in infos
                      if i.type == pafs.FileType.Directory and not Path(i.path).name.startswith("."))
    return out


def copy_to_local(uri: str, local: Path) -> Path:
    """Copy a URI (a folder, recursively, or a file) to the local path ``local``."""
    import pyarrow.fs as pafs

    fs, path = _filesystem(uri)
    info = fs.get_file_info(path)
    if info.type == pafs.FileType.NotFound:
        raise FileNotFoundError(f"{uri}: not found")
    local.parent.mkdir(parents=True, exist_ok=True)
    if info.type == pafs.FileType.Directory:
        local.mkdir(exist_ok=True)
    pafs.copy_files(path, str(local), source_filesystem=fs, destination_filesystem=pafs.LocalFileSystem())
    return local


def upload(local: Path, uri: str) -> None:
    """Copy a local folder (recursively) or file to ``uri``, replacing the files of the same names."""
    import pyarrow.fs as pafs

    fs, path = _filesystem(uri)
    if local.is_dir():
        fs.create_dir(path, recursive=True)
    pafs.copy_files(str(local), path, source_filesystem=pafs.LocalFileSystem(), destination_filesystem=fs)


def list_files(location: Location, pattern: str) -> list[Location]:
    """The files directly in the folder ``location`` whose names match the glob ``pattern``, sorted
    (none when the folder does not exist)."""
    if not is_uri(location):
        folder = Path(location)
        return sorted(p for p in folder.glob(pattern) if p.is_file()) if folder.is_dir() else []
    fs, path = _filesystem(str(location))
    return sorted(join(location, Path(i.path).name) for i in _matching_files(fs, path, pattern))


def remove_files(location: Location, pattern: str) -> None:
    """Create the folder ``location`` if missing, and remove the files directly in it whose names
    match the glob ``pattern`` (nothing else: it may hold a user's other files)."""
    if not is_uri(location):
        Path(location).mkdir(parents=True, exist_ok=True)
        for path in list_files(location, pattern):
            Path(path).unlink(missing_ok=True)
        return
    fs, path = _filesystem(str(location))
    fs.create_dir(path, recursive=True)
    for info in _matching_files(fs, path, pattern):
        fs.delete_file(info.path)


def _matching_files(fs: Any, path: str, pattern: str) -> list[Any]:
    """``pyarrow.fs.FileInfo`` of the files directly in ``path`` on ``fs`` whose names match ``pattern``."""
    import fnmatch

    import pyarrow.fs as pafs

    infos = fs.get_file_info(pafs.FileSelector(path, recursive=False, allow_not_found=True))
    return [i for i in infos if i.type == pafs.FileType.File and fnmatch.fnmatchcase(Path(i.path).name, pattern)]


def write_file(location: Location, writer: Callable[[Path], None]) -> None:
    """Have ``writer`` write a local file, then make it ``location`` whole: by an atomic rename on a
    local path (readers never see part of it), by one upload to a URI (an object appears whole)."""
    if not is_uri(location):
        atomic_write_with(location, writer)
        return
    with staged_output(parent(location)) as folder:
        writer(folder / name_of(location))


def read_bytes(location: Location) -> bytes:
    """The bytes of a local file or of a URI."""
    if not is_uri(location):
        return Path(location).read_bytes()
    fs, path = _filesystem(str(location))
    try:
        with fs.open_input_stream(path) as stream:
            return bytes(stream.read())
    except FileNotFoundError:
        raise FileNotFoundError(f"{location}: not found") from None


@contextlib.contextmanager
def staged_input(location: Location) -> Iterator[Path]:
    """A local path holding ``location``'s content: the path itself, or a temporary copy of a URI
    (removed afterwards) under the same name."""
    if not is_uri(location):
        yield Path(location)
        return
    scratch = Path(tempfile.mkdtemp(prefix="scenesearch-in-"))
    try:
        yield copy_to_local(str(location), scratch / name_of(location))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


@contextlib.contextmanager
def staged_output(location: Location) -> Iterator[Path]:
    """A local folder to write ``location``'s files into: the path itself, or a temporary folder
    uploaded to the URI when the block succeeds (and removed either way)."""
    if not is_uri(location):
        yield Path(location)
        return
    scratch = Path(tempfile.mkdtemp(prefix="scenesearch-out-"))
    try:
        yield scratch
        upload(scratch, str(location))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
