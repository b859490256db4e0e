"""The rows of the captioning stage's files: their schemas, a caption row, and the caption table.

Column meanings are in :mod:`captioning.pipeline`'s docstring; this module holds what both the
pipeline and the readers of its files (clips, rule-caption search) name.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from captioning.behavior import LABELS, BehaviorTags
from captioning.map_context import JUNCTION_KINDS
from captioning.smoothing import BoolArray, IntArray
from captioning.tags import ACTIONS, CONTEXTS, HOST_DIRECTIONS, HOST_MOTIONS, NO_TAG, NOTHING_NAMED
from captioning.unify import Segment

#: Track id of the ego's rows in both files.
EGO_TRACK_ID = "ego"
#: Category value of the ego's rows in both files (the ego is not an object category).
EGO_CATEGORY = "ego"
#: Unified host tags by code (motion · len(directions) + direction).
HOST_STRINGS = [f"{m.value}:{d.value}" for m in HOST_MOTIONS for d in HOST_DIRECTIONS]

FRAME_TAGS_SCHEMA = pa.schema(
    [
        pa.field("log_id", pa.string(), nullable=False),
        pa.field("timestamp_ns", pa.int64(), nullable=False),
        pa.field("track_id", pa.string(), nullable=False),
        pa.field("category", pa.string(), nullable=False),
        pa.field("x_m", pa.float64()),
        pa.field("y_m", pa.float64()),
        pa.field("host_motion", pa.string()),
        pa.field("host_direction", pa.string()),
        pa.field("stationary", pa.bool_()),
        pa.field("baseline_lane", pa.string()),
        pa.field("lane", pa.string()),
        pa.field("motion", pa.string()),
    ]
)
#: Columns of object rows under ``rules: behavior`` (after :data:`FRAME_TAGS_SCHEMA`'s); ``action`` and
#: ``context`` are what the frame's unified tag carries (:func:`unified_action_columns`).
BEHAVIOR_FRAME_FIELDS = (
    [pa.field(label.value, pa.bool_()) for label in LABELS]
    + [pa.field("speed_mps", pa.float64()), pa.field("at_intersection", pa.bool_()),
       pa.field("on_crosswalk", pa.bool_()), pa.field("junction_kind", pa.string()),
       pa.field("action", pa.string()), pa.field("context", pa.string())]
)
FRAME_TAGS_BEHAVIOR_SCHEMA = pa.schema(list(FRAME_TAGS_SCHEMA) + BEHAVIOR_FRAME_FIELDS)
CAPTIONS_SCHEMA = pa.schema(
    [
        pa.field("log_id", pa.string(), nullable=False),
        pa.field("track_id", pa.string(), nullable=False),
        pa.field("category", pa.string(), nullable=False),
        pa.field("start_ns", pa.int64(), nullable=False),
        pa.field("end_ns", pa.int64(), nullable=False),
        pa.field("num_frames", pa.int64(), nullable=False),
        pa.field("tags", pa.list_(pa.string()), nullable=False),
        pa.field("host_tags", pa.list_(pa.string()), nullable=False),
        pa.field("caption", pa.string(), nullable=False),
        pa.field("canonical_caption", pa.string(), nullable=False),
        pa.field("paraphrases", pa.list_(pa.string()), nullable=False),
        pa.field("window", pa.string(), nullable=False),
    ]
)
#: Columns of caption rows under ``rules: behavior`` (after :data:`CAPTIONS_SCHEMA`'s).
BEHAVIOR_CAPTION_FIELDS = (
    [pa.field(label.value, pa.bool_()) for label in LABELS]
    + [pa.field("at_intersection", pa.bool_()), pa.field("on_crosswalk", pa.bool_()),
       pa.field("junction_kind", pa.string())]
)
CAPTIONS_BEHAVIOR_SCHEMA = pa.schema(list(CAPTIONS_SCHEMA) + BEHAVIOR_CAPTION_FIELDS)


@dataclass(frozen=True)
class Caption:
    """One caption row (see the module docstring)."""

    log_id: str
    track_id: str
    category: str
    start_ns: int
    end_ns: int
    num_frames: int
    tags: tuple[str, ...]
    host_tags: tuple[str, ...]
    canonical_caption: str
    paraphrases: tuple[str, ...]
    window: str
    #: Under ``rules: behavior``: label / context → value over the window (see the module docstring).
    attributes: dict[str, bool | str | None] | None = None

    @property
    def caption(self) -> str:
        return self.canonical_caption


def captions_to_table(captions: Sequence[Caption], behavior: bool | None = None) -> pa.Table:
    """The rows of ``captions.parquet``; with ``behavior`` (default: when a caption has attributes) the
    behaviour columns too."""
    if behavior is None:
        behavior = any(c.attributes is not None for c in captions)
    columns = {
            "log_id": pa.array([c.log_id for c in captions], pa.string()),
            "track_id": pa.array([c.track_id for c in captions], pa.string()),
            "category": pa.array([c.category for c in captions], pa.string()),
            "start_ns": pa.array([c.start_ns for c in captions], pa.int64()),
            "end_ns": pa.array([c.end_ns for c in captions], pa.int64()),
            "num_frames": pa.array([c.num_frames for c in captions], pa.int64()),
            "tags": pa.array([list(c.tags) for c in captions], pa.list_(pa.string())),
            "host_tags": pa.array([list(c.host_tags) for c in captions], pa.list_(pa.string())),
            "caption": pa.array([c.canonical_caption for c in captions], pa.string()),
            "canonical_caption": pa.array([c.canonical_caption for c in captions], pa.string()),
            "paraphrases": pa.array([list(c.paraphrases) for c in captions], pa.list_(pa.string())),
            "window": pa.array([c.window for c in captions], pa.string()),
        }
    if not behavior:
        return pa.table(columns, schema=CAPTIONS_SCHEMA)
    for f in BEHAVIOR_CAPTION_FIELDS:
        columns[f.name] = pa.array([None if c.attributes is None else c.attributes.get(f.name) for c in captions],
                                   f.type)
    return pa.table(columns, schema=CAPTIONS_BEHAVIOR_SCHEMA)


def strings_column(codes: IntArray, vocabulary: list[str]) -> pa.Array:
    lookup = np.array([*vocabulary, None], dtype=object)
    return pa.array(lookup[np.where(codes == NO_TAG, len(vocabulary), codes)], pa.string())


def unified_action_columns(action_code: IntArray, context_code: IntArray, tagged: BoolArray, t: int,
                           order: IntArray) -> dict[str, pa.Array]:
    """``frame_tags.parquet``'s ``action`` and ``context``: the own action and the map context of each
    object row's unified tag (flicker suppressed, as in its caption), :data:`~captioning.tags.NOTHING_NAMED`
    where the tag names none, null on the ego's rows and on untagged frames.

    Args:
        action_code: (N,) :data:`~captioning.tags.ACTIONS` code of each object row, −1 none.
        context_code: (N,) :data:`~captioning.tags.CONTEXTS` code of each object row, −1 none.
        tagged: (N,) whether the row's frame is tagged.
        t: number of frames (the ego's rows come first, one per frame).
        order: (T + N,) the rows' order in the file.
    """
    columns: dict[str, pa.Array] = {}
    for name, codes, vocabulary in (("action", action_code, [a.value for a in ACTIONS]),
                                    ("context", context_code, [c.value for c in CONTEXTS])):
        named = np.where(tagged, np.where(codes >= 0, codes, len(vocabulary)), NO_TAG)  # the last: none
        columns[name] = strings_column(np.r_[np.full(t, NO_TAG), named][order], [*vocabulary, NOTHING_NAMED])
    return columns


def window_attributes(
    beh: BehaviorTags, tracks: IntArray, window: Segment, tagged: BoolArray
) -> list[dict[str, bool | str | None]]:
    """Each chosen track's behaviour over its tagged frames of a window: a label holds when it holds in
    some frame (null when never known); the junction kind is the most frequent one.

    Args:
        tracks: (N,) track indices.
        tagged: (N, W) their tagged frames in the window.
    """
    span = slice(window.start, window.end + 1)
    known = beh.known_cell[tracks, span][..., None] & beh.label_known & tagged[..., None]  # (N, W, L)
    holds = np.asarray((beh.flags[tracks, span] & known).any(axis=1), dtype=bool)  # (N, L)
    is_known = np.asarray(known.any(axis=1), dtype=bool)
    context = {name: np.asarray((grid[tracks, span] & tagged).any(axis=1), dtype=bool)
               for name, grid in (("at_intersection", beh.at_intersection), ("on_crosswalk", beh.on_crosswalk))}
    kinds = np.where(tagged, beh.junction_kind[tracks, span].astype(np.int64), NO_TAG)
    counts = np.stack([(kinds == code).sum(axis=1) for code in range(len(JUNCTION_KINDS))], axis=1)  # (N, J)
    kind = np.where(counts.max(axis=1) > 0, counts.argmax(axis=1), NO_TAG).tolist()
    out: list[dict[str, bool | str | None]] = []
    for n in range(len(tracks)):
        row: dict[str, bool | str | None] = {
            label.value: (bool(holds[n, i]) if is_known[n, i] else None) for i, label in enumerate(LABELS)
        }
        for name, values in context.items():
            row[name] = bool(values[n]) if beh.has_map else None
        row["junction_kind"] = JUNCTION_KINDS[kind[n]].value if kind[n] >= 0 else None
        out.append(row)
    return out


def behavior_frame_columns(
    beh: BehaviorTags, t: int, track_idx: IntArray, frame_idx: IntArray, order: IntArray
) -> dict[str, pa.Array]:
    """The own-behaviour columns of ``frame_tags.parquet`` (null on the ego's rows and where unknown).

    Args:
        beh: the log's own-behaviour tags.
        t: number of frames (the ego's rows come first, one per frame).
        track_idx: (N,) track of each object row.
        frame_idx: (N,) frame of each object row.
        order: (T + N,) the rows' order in the file.
    """
    n_obj = track_idx.shape[0]
    ego_null = np.ones(t, bool)
    known = beh.known_cell[track_idx, frame_idx]
    flags = beh.flags[track_idx, frame_idx]  # (N, L)
    columns: dict[str, pa.Array] = {}
    for i, label in enumerate(LABELS):
        value = np.r_[np.zeros(t, bool), flags[:, i]][order]
        null = np.r_[ego_null, ~(known & beh.label_known[i])][order]
        columns[label.value] = pa.array(value, pa.bool_(), mask=null)
    speed = beh.speed_mps[track_idx, frame_idx]
    columns["speed_mps"] = pa.array(np.r_[np.zeros(t), speed][order], pa.float64(),
                                    mask=np.r_[ego_null, ~np.isfinite(speed)][order])
    context_null = np.r_[ego_null, np.full(n_obj, not beh.has_map)][order]
    for name, grid in (("at_intersection", beh.at_intersection), ("on_crosswalk", beh.on_crosswalk)):
        columns[name] = pa.array(np.r_[np.zeros(t, bool), grid[track_idx, frame_idx]][order], pa.bool_(),
                                 mask=context_null)
    kind = np.r_[np.full(t, NO_TAG), beh.junction_kind[track_idx, frame_idx]][order]
    columns["junction_kind"] = strings_column(kind, [k.value for k in JUNCTION_KINDS])
    return columns
