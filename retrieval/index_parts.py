"""The parts of an index directory as :class:`retrieval.SceneSearch` opens them: the checks of the top
manifest over its parts, their counts, and the caption index, opened at once or when first used.

A process that ranks by the model or by clip alone never reads the caption index (``SceneSearch.open``
with ``lazy_captions``): :func:`open_captions` opens it later, under a read lock of its own
(:func:`scenesearch_base.atomic.reading_directory`), with the same checks as an eager open.
"""

from __future__ import annotations

import warnings
from contextlib import nullcontext
from pathlib import Path
from typing import TYPE_CHECKING

from indexes.errors import IndexesError, ManifestError
from indexes.integrity import IntegrityWarning, Verify, parse_file_entries, verify_files
from retrieval.embedding import CONFIG_FILE
from retrieval.errors import IndexDirError
from retrieval.index_manifest import MANIFEST, IndexManifest
from scenesearch_base.atomic import reading_directory

if TYPE_CHECKING:
    from retrieval.captions_search import CaptionSearch, TextEncoder

CAPTIONS_DIR = "captions"
RUN_CONFIG = f"run/{CONFIG_FILE}"


def open_captions(index_dir: Path, manifest: IndexManifest, text_encoder: TextEncoder | None, mode: Verify,
                   later: bool = False) -> CaptionSearch:
    """The caption index of an index directory, checked against the top manifest. ``later``: after
    :meth:`SceneSearch.open` has returned, so under a read lock of its own, with its sub-manifest checked
    here (``open`` checks it otherwise) and without a second warning of unchecked files."""
    from retrieval.captions_search import CaptionSearch

    with reading_directory(index_dir) if later else nullcontext(index_dir) as index_dir, \
            warnings.catch_warnings():
        if later:
            warnings.filterwarnings("ignore", message=".*checksums not verified", category=IntegrityWarning)
            try:
                verify_top_files(index_dir, manifest, (CAPTIONS_DIR,), mode)
            except IndexesError as exc:
                raise IndexDirError(str(exc)) from exc
        captions = CaptionSearch.open(index_dir / CAPTIONS_DIR, encoder=text_encoder, verify=mode)
    check_count(index_dir, manifest, "captions", len(captions))
    captions.base_dir = Path(manifest.clips_dir)
    return captions


def check_count(index_dir: Path, manifest: IndexManifest, name: str, size: int) -> None:
    """Raise :class:`IndexDirError` when the part ``name`` holds another number of entries than the manifest says."""
    if manifest.counts.get(name) not in (None, size):
        raise IndexDirError(f"{index_dir / name}: holds {size} entries, {index_dir / MANIFEST} says "
                            f"{manifest.counts[name]}")


def verify_top_files(index_dir: Path, manifest: IndexManifest, parts: tuple[str, ...], mode: Verify) -> None:
    """Check the files the top manifest covers: the sub-manifests of ``parts`` (views and ``captions``), and
    the run config."""
    path = index_dir / MANIFEST
    files = parse_file_entries(manifest.files, path)
    wanted = [f"{d}/{MANIFEST}" for d in parts]
    missing = [n for n in wanted if n not in files]
    if missing:
        raise ManifestError(path, f"does not list {', '.join(missing)}", field="files")
    wanted += [n for n in files if n == RUN_CONFIG]
    verify_files(index_dir, {n: files[n] for n in wanted}, mode)
