"""The captions folder: ``frame_tags.parquet``, ``captions.parquet`` and ``logs.json``, published together.

``logs.json`` maps each captioned log's id to its folder, so that later stages can read the logs
again (the scenario queries' features). The three files are written as one generation
(:mod:`scenesearch_base.publish`): readers never see a new one beside an old one.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Sequence
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from captioning.pipeline import CAPTIONS_FILENAME, FRAME_TAGS_FILENAME, LOGS_FILENAME, LogCaptions
from captioning.tables import FRAME_TAGS_BEHAVIOR_SCHEMA, FRAME_TAGS_SCHEMA, captions_to_table
from scenesearch_base.folders import FolderKind, claim_folder, mark_folder
from scenesearch_base.publish import GENERATIONS_DIR, publish
from scenesearch_base.storage import is_uri

#: The folder ``scenesearch caption`` writes (:mod:`scenesearch_base.folders`).
CAPTIONS_FOLDER = FolderKind("captions", CAPTIONS_FILENAME, (CAPTIONS_FILENAME, FRAME_TAGS_FILENAME, LOGS_FILENAME,
                                                             GENERATIONS_DIR))


def output_tables(results: Sequence[LogCaptions]) -> dict[str, pa.Table]:
    """``frame_tags.parquet`` and ``captions.parquet`` of the logs, in their order."""
    behavior = any(r.behavior is not None for r in results)
    schema = FRAME_TAGS_BEHAVIOR_SCHEMA if behavior else FRAME_TAGS_SCHEMA
    frames = pa.concat_tables([r.frame_tags_table() for r in results]) if results else schema.empty_table()
    captions = captions_to_table([c for r in results for c in r.captions], behavior)
    return {FRAME_TAGS_FILENAME: frames, CAPTIONS_FILENAME: captions}


def write_outputs(out_dir: Path | str, results: Sequence[LogCaptions],
                  inputs: Sequence[Path | str] = ()) -> tuple[Path, Path]:
    """Write ``frame_tags.parquet``, ``captions.parquet`` and ``logs.json`` and publish them together
    (:mod:`scenesearch_base.publish`: readers never see a new one beside an old one; what an earlier
    killed write left behind is removed). ``out_dir`` must be new, empty or a captions folder, and not
    one of ``inputs`` (the log folders) nor inside one, else :class:`FolderClaimError`."""
    claim_folder(out_dir, CAPTIONS_FOLDER, inputs)
    mark_folder(out_dir, CAPTIONS_FOLDER, CAPTIONS_FOLDER.entries)  # first: a killed write leaves its kind
    logs = logs_index(results, inputs)
    writers = {name: functools.partial(_write_parquet, table) for name, table in output_tables(results).items()}
    paths = publish(out_dir, {**writers, LOGS_FILENAME: functools.partial(_write_text, logs)})
    return paths[FRAME_TAGS_FILENAME], paths[CAPTIONS_FILENAME]


def logs_index(results: Sequence[LogCaptions], inputs: Sequence[Path | str]) -> str:
    """``logs.json``'s text: each captioned log's id → its folder (a local folder resolved, ``file://``
    read as the local folder it names, any other URI as given)."""
    folders: dict[str, str] = {}
    for d in inputs:
        text = str(d).rstrip("/")
        local = text.removeprefix("file://") if text.startswith("file://") or not is_uri(text) else None
        folders[Path(text).name] = str(Path(local).resolve()) if local is not None else text
    return json.dumps({r.log_id: folders[r.log_id] for r in results if r.log_id in folders}, indent=1)


def _write_parquet(table: pa.Table, path: Path) -> None:
    pq.write_table(table, path)


def _write_text(text: str, path: Path) -> None:
    path.write_text(text, encoding="utf-8")
