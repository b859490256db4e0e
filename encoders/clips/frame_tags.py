"""The rules' tags at each frame of a clip: dense targets for the video towers.

Captioning writes ``frame_tags.parquet`` beside ``captions.parquet``: one row per (log, timestamp,
track) with the object's ``lane`` and ``motion`` relative to the ego, the own ``action`` and map
``context`` its unified tag carries (``none`` where it names none), and the ego's ``host_motion`` and
``host_direction`` (:mod:`captioning.pipeline`). A caption's tag sequence is those per-frame tags
collapsed (eq. 8), so they say *when* each step of the caption holds. A clip samples T frames of its
window (``frame_indices``); the clip table keeps the tags at those frames in six list columns,
:data:`FRAME_TAG_COLUMNS`, null where the rules did not tag a frame (and all null when the captions
came without ``frame_tags.parquet``). Files written under ``rules: paper`` have no action and context
columns: they give null actions and contexts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from captioning.outputs import log_row_groups
from scenesearch_base.storage import Location, exists, is_uri, staged_input

#: Clip-table columns (list<string>, one entry per clip frame) and the frame_tags.parquet column of each.
FRAME_TAG_COLUMNS: dict[str, str] = {
    "frame_lane": "lane",
    "frame_motion": "motion",
    "frame_host_motion": "host_motion",
    "frame_host_direction": "host_direction",
    "frame_action": "action",
    "frame_context": "context",
}
_OBJECT_FIELDS = ("lane", "motion", "action", "context")
#: Object fields that a frame_tags.parquet may lack (``rules: paper``): null there.
_OPTIONAL_FIELDS = ("action", "context")
_HOST_FIELDS = ("host_motion", "host_direction")
_HOST_TRACK_ID = "ego"

FrameTag = tuple[str | None, ...]


@dataclass(frozen=True)
class LogFrameTags:
    """One log's per-frame tags.

    Attributes:
        objects: (timestamp_ns, track_id) → (lane, motion, action, context).
        host: timestamp_ns → (host_motion, host_direction).
    """

    objects: dict[tuple[int, str], FrameTag]
    host: dict[int, FrameTag]

    def clip_columns(self, track_id: str, timestamps_ns: NDArray[np.int64]) -> dict[str, list[str | None]]:
        """timestamps_ns: (T,) the clip's frames → the :data:`FRAME_TAG_COLUMNS` values of the clip."""
        obj = [self.objects.get((int(t), track_id), (None,) * len(_OBJECT_FIELDS)) for t in timestamps_ns]
        host = [self.host.get(int(t), (None,) * len(_HOST_FIELDS)) for t in timestamps_ns]
        values = {**dict(zip(_OBJECT_FIELDS, zip(*obj))), **dict(zip(_HOST_FIELDS, zip(*host)))}
        return {column: list(values.get(field, ())) for column, field in FRAME_TAG_COLUMNS.items()}


def empty_clip_columns(num_frames: int) -> dict[str, list[str | None]]:
    """The :data:`FRAME_TAG_COLUMNS` of a clip whose frames have no tags."""
    return {name: [None] * num_frames for name in FRAME_TAG_COLUMNS}


def read_frame_tags(path: Path, log_ids: Sequence[str] | None = None) -> dict[str, LogFrameTags]:
    """``frame_tags.parquet`` (only the rows of ``log_ids`` when given) → log id → its tags.

    Raises:
        ValueError: the file is unreadable or lacks a column (names the file and the columns).
    """
    columns = _columns(path)
    if log_ids is not None and not log_ids:
        return {}
    filters = [("log_id", "in", list(log_ids))] if log_ids is not None else None
    try:
        table = pq.read_table(path, columns=columns, filters=filters)
    except (OSError, pa.ArrowInvalid) as exc:
        raise ValueError(f"{path}: unreadable Parquet file ({exc})") from exc
    return _by_log(table, path)


@dataclass(frozen=True)
class LogFrameTagsRef:
    """One log's row groups in a ``frame_tags.parquet`` that holds a log per row group (as ``caption``
    writes it): its task reads them (:meth:`load`), so that no process holds every log's tags."""

    path: str
    log_id: str
    row_groups: tuple[int, ...]

    def load(self) -> LogFrameTags:
        path = Path(self.path)
        try:
            table = pq.ParquetFile(path).read_row_groups(list(self.row_groups), columns=_columns(path))
        except (OSError, pa.ArrowInvalid) as exc:
            raise ValueError(f"{path}: unreadable Parquet file ({exc})") from exc
        return _by_log(table, path).get(self.log_id, LogFrameTags({}, {}))


def frame_tags_by_log(path: Path, log_ids: Sequence[str]) -> dict[str, LogFrameTags | LogFrameTagsRef]:
    """The tags of ``log_ids`` in a local ``frame_tags.parquet``: where each row group holds one log (its
    ``log_id`` statistics say so), a reference to each log's row groups; else the tags, read at once.

    Raises:
        ValueError: the file is unreadable or lacks a column (names the file and the columns).
    """
    _columns(path)
    try:
        groups = log_row_groups(pq.ParquetFile(path))
    except (OSError, pa.ArrowInvalid) as exc:
        raise ValueError(f"{path}: unreadable Parquet file ({exc})") from exc
    if groups is None:
        return dict(read_frame_tags(path, log_ids))
    real = str(path.resolve())  # the file itself, not a link that a later `caption` may point elsewhere
    return {lid: LogFrameTagsRef(real, lid, tuple(groups[lid])) for lid in log_ids if lid in groups}


def frame_tags_of(path: Location, log_ids: list[str]) -> dict[str, LogFrameTags | LogFrameTagsRef]:
    """The per-frame tags of ``log_ids`` in ``path`` (the ``frame_tags.parquet`` written beside the
    captions, local or a URI), by log: a local file's as references that each log's task reads
    (:func:`frame_tags_by_log`); none when the file is absent.

    Raises:
        ValueError: the file is unreadable or lacks a column.
    """
    if not exists(path):
        return {}
    if is_uri(path):
        with staged_input(path) as local:
            return dict(read_frame_tags(local, log_ids))
    return frame_tags_by_log(Path(path), log_ids)


def _columns(path: Path) -> list[str]:
    """The columns to read of ``path``; ValueError when it is unreadable or lacks one."""
    columns = ["log_id", "timestamp_ns", "track_id", *_OBJECT_FIELDS, *_HOST_FIELDS]
    try:
        names = pq.read_schema(path).names
    except (OSError, pa.ArrowInvalid) as exc:
        raise ValueError(f"{path}: unreadable Parquet file ({exc})") from exc
    missing = [c for c in columns if c not in names and c not in _OPTIONAL_FIELDS]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}")
    return [c for c in columns if c in names]


def _by_log(table: pa.Table, path: Path) -> dict[str, LogFrameTags]:
    """Rows of ``frame_tags.parquet`` → log id → its tags."""
    cols = {name: _shared_values(table.column(name)) for name in table.column_names}
    null: list[str | None] = [None] * table.num_rows
    objects = list(zip(*(cols.get(name, null) for name in _OBJECT_FIELDS)))  # (lane, motion, action, context)
    out: dict[str, LogFrameTags] = {}
    for i in range(table.num_rows):
        log_id, t, track = cols["log_id"][i], cols["timestamp_ns"][i], cols["track_id"][i]
        if log_id is None or t is None or track is None:
            raise ValueError(f"{path}, row {i}: null log_id, timestamp_ns or track_id")
        tags = out.get(log_id)
        if tags is None:
            tags = out[log_id] = LogFrameTags({}, {})
        if track == _HOST_TRACK_ID:
            tags.host[int(t)] = (cols["host_motion"][i], cols["host_direction"][i])
        else:
            tags.objects[(int(t), str(track))] = objects[i]
    return out


def _shared_values(column: pa.ChunkedArray) -> list[Any]:
    """The column's values as Python objects, each distinct string one object: the clip table keeps
    every clip's tags until it is written, and a few dozen tag names repeat over every frame."""
    if not pa.types.is_string(column.type) and not pa.types.is_large_string(column.type):
        return column.to_pylist()
    encoded = column.dictionary_encode().combine_chunks()
    values = [*encoded.dictionary.to_pylist(), None]
    return [values[i] for i in encoded.indices.fill_null(len(values) - 1).to_numpy()]
