"""The captions folder: ``frame_tags.parquet``, ``captions.parquet`` and ``logs.json``, published together.

``logs.json`` maps each captioned log's id to its folder, so that later stages can read the logs
again (the scenario queries' features). The three files are written as one generation
(:mod:`scenesearch_base.publish`): readers never see a new one beside an old one.

:class:`CaptionsWriter` writes the files log by log, a row group per log, so that captioning a fleet's
logs holds one log's captions at a time, not all of them until the end.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import TracebackType

import pyarrow.parquet as pq

from captioning.pipeline import CAPTIONS_FILENAME, FRAME_TAGS_FILENAME, LOGS_FILENAME, LogCaptions
from captioning.tables import CAPTIONS_BEHAVIOR_SCHEMA, CAPTIONS_SCHEMA, FRAME_TAGS_BEHAVIOR_SCHEMA, FRAME_TAGS_SCHEMA
from scenesearch_base.folders import FolderKind, claim_folder, mark_folder
from scenesearch_base.publish import GENERATIONS_DIR, generation
from scenesearch_base.storage import is_uri

#: The folder ``scenesearch caption`` writes (:mod:`scenesearch_base.folders`).
CAPTIONS_FOLDER = FolderKind("captions", CAPTIONS_FILENAME, (CAPTIONS_FILENAME, FRAME_TAGS_FILENAME, LOGS_FILENAME,
                                                             GENERATIONS_DIR))
#: The files of a captions folder, published together.
CAPTIONS_FILES = (FRAME_TAGS_FILENAME, CAPTIONS_FILENAME, LOGS_FILENAME)


class CaptionsWriter:
    """Writes a captions folder's three files into ``folder``, log by log, in the order given.

    Args:
        folder: where the files go (a generation being written, or a folder to upload).
        behavior: whether the logs were captioned with ``rules: behavior`` (the tables' behaviour columns).
        inputs: the log folders, for ``logs.json`` (a log not among them is left out of it).
    """

    def __init__(self, folder: Path, behavior: bool, inputs: Sequence[Path | str] = ()) -> None:
        self.behavior = behavior
        self._frames = pq.ParquetWriter(folder / FRAME_TAGS_FILENAME,
                                        FRAME_TAGS_BEHAVIOR_SCHEMA if behavior else FRAME_TAGS_SCHEMA)
        self._captions = pq.ParquetWriter(folder / CAPTIONS_FILENAME,
                                          CAPTIONS_BEHAVIOR_SCHEMA if behavior else CAPTIONS_SCHEMA)
        self._logs = folder / LOGS_FILENAME
        self._inputs = inputs
        self.log_ids: list[str] = []

    def add(self, result: LogCaptions) -> None:
        """Append one log's frame tags and captions."""
        if (result.behavior is not None) != self.behavior:
            raise ValueError(f"log {result.log_id} was captioned with other rules than the logs before it")
        self._frames.write_table(result.frame_tags_table())
        self._captions.write_table(result.captions_table())
        self.log_ids.append(result.log_id)

    def close(self) -> None:
        """Finish the Parquet files and write ``logs.json``."""
        self._frames.close()
        self._captions.close()
        self._logs.write_text(logs_index(self.log_ids, self._inputs), encoding="utf-8")

    def __enter__(self) -> CaptionsWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        if kind is None:
            self.close()
        else:  # the folder is thrown away: just release the files
            self._frames.close()
            self._captions.close()


def log_row_groups(source: pq.ParquetFile) -> dict[str, list[int]] | None:
    """Each log's row groups in a file :class:`CaptionsWriter` wrote (a log per row group), read from
    the row groups' ``log_id`` statistics; None where a row group may hold several logs (a file written
    at once, or without statistics)."""
    meta = source.metadata
    at = [meta.schema.column(i).path for i in range(meta.num_columns)].index("log_id")
    groups: dict[str, list[int]] = {}
    for g in range(meta.num_row_groups):
        stats = meta.row_group(g).column(at).statistics
        if stats is None or not stats.has_min_max or stats.min != stats.max:
            return None
        groups.setdefault(str(stats.min), []).append(g)
    return groups


@contextlib.contextmanager
def captions_folder(out_dir: Path | str, behavior: bool, inputs: Sequence[Path | str] = ()) -> Iterator[CaptionsWriter]:
    """A :class:`CaptionsWriter` into a new generation of ``out_dir``, published when the block ends
    (:mod:`scenesearch_base.publish`: readers never see a new file beside an old one; what an earlier
    killed write left behind is removed), and nothing published when it raises. ``out_dir`` must be
    new, empty or a captions folder, and not one of ``inputs`` (the log folders) nor inside one, else
    :class:`FolderClaimError`."""
    claim_folder(out_dir, CAPTIONS_FOLDER, inputs)
    mark_folder(out_dir, CAPTIONS_FOLDER, CAPTIONS_FOLDER.entries)  # first: a killed write leaves its kind
    with generation(out_dir, CAPTIONS_FILES) as folder, CaptionsWriter(folder, behavior, inputs) as writer:
        yield writer


def write_outputs(out_dir: Path | str, results: Sequence[LogCaptions],
                  inputs: Sequence[Path | str] = ()) -> tuple[Path, Path]:
    """Write the captions folder of ``results`` (:func:`captions_folder`) → the frame tags' and the
    captions' paths."""
    with captions_folder(out_dir, any(r.behavior is not None for r in results), inputs) as writer:
        for result in results:
            writer.add(result)
    return Path(out_dir) / FRAME_TAGS_FILENAME, Path(out_dir) / CAPTIONS_FILENAME


def logs_index(log_ids: Sequence[str], inputs: Sequence[Path | str]) -> str:
    """``logs.json``'s text: each captioned log's id → its folder (a local folder resolved, ``file://``
    read as the local folder it names, any other URI as given)."""
    folders: dict[str, str] = {}
    for d in inputs:
        text = str(d).rstrip("/")
        local = text.removeprefix("file://") if text.startswith("file://") or not is_uri(text) else None
        folders[Path(text).name] = str(Path(local).resolve()) if local is not None else text
    return json.dumps({log_id: folders[log_id] for log_id in log_ids if log_id in folders}, indent=1)
