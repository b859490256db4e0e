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

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

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
    columns = ["log_id", "timestamp_ns", "track_id", *_OBJECT_FIELDS, *_HOST_FIELDS]
    try:
        names = pq.read_schema(path).names
        missing = [c for c in columns if c not in names and c not in _OPTIONAL_FIELDS]
        if missing:
            raise ValueError(f"{path}: missing column(s) {missing}")
        columns = [c for c in columns if c in names]
        if log_ids is not None and not log_ids:
            return {}
        filters = [("log_id", "in", list(log_ids))] if log_ids is not None else None
        table = pq.read_table(path, columns=columns, filters=filters)
    except (OSError, pa.ArrowInvalid) as exc:
        raise ValueError(f"{path}: unreadable Parquet file ({exc})") from exc
    cols = {name: table.column(name).to_pylist() for name in columns}
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
