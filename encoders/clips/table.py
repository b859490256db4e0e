"""The clip table: one row per neighbour caption, an index into its log's rendered arrays.

``CLIPS_DIR/clips.parquet`` columns (see :data:`CLIP_SCHEMA`): ``clip_id`` (``log_id:track_id:start_ns``),
``log_id, track_id, category, start_ns, end_ns, caption, canonical_caption, paraphrases, tags,
host_tags, split, has_camera, bev_source, time_of_day, weather, frame_indices`` (T int32 indices
into the per-log arrays, uniform over the window, repeated when the window has fewer frames) and
``preview_path`` (relative to CLIPS_DIR, null without a preview), the rules' tags at each clip frame
(``frame_lane, frame_motion, frame_host_motion, frame_host_direction``: :mod:`encoders.clips.frame_tags`,
null where untagged); when the captions carry the
objects' own behaviour (``rules: behavior``), also its columns (``parked`` … ``braking_for``,
``at_intersection``, ``on_crosswalk``, ``junction_kind``), so that searches can filter on them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from captioning.tables import BEHAVIOR_CAPTION_FIELDS
from encoders.clips.frame_tags import FRAME_TAG_COLUMNS
from encoders.clips.layout import CLIPS_FILE, clip_id
from scenes.categories import CATEGORY_NAMES, Category
from scenesearch_base.atomic import atomic_write_with

HOST_TRACK_ID = "ego"
REQUIRED_CAPTION_COLUMNS = ("log_id", "track_id", "start_ns", "end_ns", "caption")

CLIP_SCHEMA = pa.schema(
    [
        ("clip_id", pa.string()),
        ("log_id", pa.string()),
        ("track_id", pa.string()),
        ("category", pa.string()),
        ("start_ns", pa.int64()),
        ("end_ns", pa.int64()),
        ("caption", pa.string()),
        ("canonical_caption", pa.string()),
        ("paraphrases", pa.list_(pa.string())),
        ("tags", pa.list_(pa.string())),
        ("host_tags", pa.list_(pa.string())),
        ("split", pa.string()),
        ("has_camera", pa.bool_()),
        ("bev_source", pa.string()),
        ("time_of_day", pa.string()),
        ("weather", pa.string()),
        ("frame_indices", pa.list_(pa.int32())),
        ("preview_path", pa.string()),
        *((name, pa.list_(pa.string())) for name in FRAME_TAG_COLUMNS),
    ]
)


class ClipsInputError(ValueError):
    """Captions that cannot become clips; the message names the file, row, field and value."""


@dataclass(frozen=True)
class CaptionRow:
    """One neighbour caption, as read from ``captions.parquet``: the parts of its clip id first."""

    row: int
    log_id: str
    track_id: str
    start_ns: int
    end_ns: int
    category: str
    caption: str
    canonical_caption: str
    paraphrases: list[str]
    tags: list[str]
    host_tags: list[str]
    #: The caption's own-behaviour columns, when it has them (see the module docstring).
    behavior: dict[str, Any] = field(default_factory=dict)

    @property
    def clip_id(self) -> str:
        return clip_id(self.log_id, self.track_id, self.start_ns)


@dataclass
class Skipped:
    """Things left out, each with a reason, for the manifest and the command's report."""

    items: list[dict[str, Any]] = field(default_factory=list)

    def add(self, reason: str, **where: Any) -> None:
        self.items.append({**where, "reason": reason})


def read_captions(captions_path: Path) -> list[CaptionRow]:
    """Neighbour caption rows (host rows, ``track_id == 'ego'``, have no clip).

    Raises:
        FileNotFoundError: the file is missing.
        ClipsInputError: a required column is missing or a value is null / bad (names row and field).
    """
    if not captions_path.is_file():
        raise FileNotFoundError(f"{captions_path}: captions file not found")
    try:
        table = pq.read_table(captions_path)
    except (OSError, pa.ArrowInvalid) as exc:
        raise ClipsInputError(f"{captions_path}: unreadable Parquet file ({exc})") from exc
    missing = [c for c in REQUIRED_CAPTION_COLUMNS if c not in table.column_names]
    if missing:
        raise ClipsInputError(f"{captions_path}: missing column(s) {missing}")
    for name in ("start_ns", "end_ns"):  # seconds as floats would read as a window of a few nanoseconds
        if not pa.types.is_integer(table.schema.field(name).type):
            raise ClipsInputError(f"{captions_path}, field '{name}': {table.schema.field(name).type}; expected int64 "
                                  "nanoseconds (as `scenesearch caption` writes them)")
    cols = {name: table.column(name).to_pylist() for name in table.column_names}
    n = table.num_rows

    def get(name: str, default: Any) -> list[Any]:
        return cols.get(name, [default] * n)

    rows: list[CaptionRow] = []
    categories, canon, para = get("category", "other"), get("canonical_caption", None), get("paraphrases", None)
    tags, host_tags = get("tags", None), get("host_tags", None)
    behavior = [f.name for f in BEHAVIOR_CAPTION_FIELDS if f.name in cols]
    for i in range(n):
        for name in REQUIRED_CAPTION_COLUMNS:
            if cols[name][i] is None:
                raise ClipsInputError(f"{captions_path}, row {i}, field '{name}': null value")
        if str(cols["track_id"][i]) == HOST_TRACK_ID:
            continue
        start, end = int(cols["start_ns"][i]), int(cols["end_ns"][i])
        if end < start:
            raise ClipsInputError(f"{captions_path}, row {i}, field 'end_ns': {end} is before start_ns {start}")
        category = str(categories[i] or Category.OTHER.value)
        if category not in CATEGORY_NAMES:
            raise ClipsInputError(f"{captions_path}, row {i}, field 'category': {category!r} is not one of "
                                  f"{list(CATEGORY_NAMES)}")
        caption = str(cols["caption"][i])
        if not caption.strip():
            raise ClipsInputError(f"{captions_path}, row {i}, field 'caption': empty (a clip is its caption's moment)")
        rows.append(
            CaptionRow(
                row=i,
                log_id=str(cols["log_id"][i]),
                track_id=str(cols["track_id"][i]),
                category=category,
                start_ns=start,
                end_ns=end,
                caption=caption,
                canonical_caption=str(canon[i]) if canon[i] is not None else caption,
                paraphrases=[str(p) for p in (para[i] or [])],
                tags=[str(t) for t in (tags[i] or [])],
                host_tags=[str(t) for t in (host_tags[i] or [])],
                behavior={name: cols[name][i] for name in behavior},
            )
        )
    return rows


def sample_frame_indices(first: int, last: int, num_frames: int) -> NDArray[np.int32]:
    """T indices uniform over ``[first, last]`` (inclusive), repeating frames for short windows."""
    return np.round(np.linspace(first, last, num_frames)).astype(np.int32)


def window_frames(
    frame_ts: NDArray[np.int64], start_ns: int, end_ns: int, tolerance_ns: int
) -> tuple[int, int] | None:
    """First and last frame index of a window, or None when it is not inside the log's frames."""
    if frame_ts.shape[0] == 0:
        return None
    if start_ns < frame_ts[0] - tolerance_ns or end_ns > frame_ts[-1] + tolerance_ns:
        return None
    first = int(np.searchsorted(frame_ts, start_ns - tolerance_ns, side="left"))
    last = int(np.searchsorted(frame_ts, end_ns + tolerance_ns, side="right")) - 1
    if last < first:
        return None
    return first, last


def write_clip_table(clips_dir: Path, rows: list[dict[str, Any]]) -> None:
    """Write ``CLIPS_DIR/clips.parquet`` atomically."""
    extra = [f for f in BEHAVIOR_CAPTION_FIELDS if rows and all(f.name in r for r in rows)]
    table = pa.Table.from_pylist(rows, schema=pa.schema([*CLIP_SCHEMA, *extra]))
    path = Path(clips_dir) / CLIPS_FILE
    atomic_write_with(path, lambda tmp: pq.write_table(table, tmp))
