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

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from captioning.outputs import log_row_groups
from captioning.tables import BEHAVIOR_CAPTION_FIELDS
from encoders.clips.frame_tags import FRAME_TAG_COLUMNS
from encoders.clips.layout import CLIPS_FILE, clip_id
from scenes.categories import CATEGORY_NAMES, Category
from scenesearch_base.atomic import atomic_write_with, scratch_path

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

#: Spooled rows hold every behaviour column (null where a caption has none); the table keeps those every row has.
_SPOOL_SCHEMA = pa.schema([*CLIP_SCHEMA, *BEHAVIOR_CAPTION_FIELDS])


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


@dataclass(frozen=True)
class LogCaptionRows:
    """One log's neighbour caption rows, in file order: held in ``rows``, or where its task reads them
    (``row_groups`` of the local ``captions.parquet`` at ``path``, which holds a log per row group, as
    ``caption`` writes it), so that no process holds every log's captions.

    Attributes:
        log_id: the log.
        first_row: the file's row number of the log's first neighbour caption.
    """

    log_id: str
    first_row: int
    rows: tuple[CaptionRow, ...] = ()
    path: str | None = None
    row_groups: tuple[int, ...] = ()

    def load(self) -> tuple[CaptionRow, ...]:
        """The rows (read again, and checked again, from the file for a reference)."""
        if self.path is None:
            return self.rows
        path = Path(self.path)
        source = _parquet_file(path)
        firsts = np.cumsum([0, *(source.metadata.row_group(g).num_rows for g in range(source.num_row_groups))])
        return tuple(row for g in self.row_groups
                     for row in _caption_rows(source.read_row_group(g), path, int(firsts[g]))
                     if row.log_id == self.log_id)


def captions_by_log(captions_path: Path, refer: bool = True) -> dict[str, LogCaptionRows]:
    """Every log's neighbour caption rows, the logs in the order of their first row. Every row is
    checked here, a row group at a time; with ``refer``, where every row group holds one log
    (:func:`captioning.outputs.log_row_groups`), each log's rows are a reference to its row groups,
    else they are held.

    Raises:
        FileNotFoundError: the file is missing.
        ClipsInputError: a required column is missing or a value is null / bad (names row and field).
    """
    if not captions_path.is_file():
        raise FileNotFoundError(f"{captions_path}: captions file not found")
    source = _parquet_file(captions_path)
    names = source.schema_arrow.names
    missing = [c for c in REQUIRED_CAPTION_COLUMNS if c not in names]
    if missing:
        raise ClipsInputError(f"{captions_path}: missing column(s) {missing}")
    for name in ("start_ns", "end_ns"):  # seconds as floats would read as a window of a few nanoseconds
        if not pa.types.is_integer(source.schema_arrow.field(name).type):
            raise ClipsInputError(f"{captions_path}, field '{name}': {source.schema_arrow.field(name).type}; "
                                  "expected int64 nanoseconds (as `scenesearch caption` writes them)")
    groups = log_row_groups(source) if refer else None
    first_row: dict[str, int] = {}
    held: dict[str, list[CaptionRow]] = {}
    row = 0
    for g in range(source.num_row_groups):
        try:
            table = source.read_row_group(g)
        except (OSError, pa.ArrowInvalid) as exc:
            raise ClipsInputError(f"{captions_path}: unreadable Parquet file ({exc})") from exc
        for caption in _caption_rows(table, captions_path, row):
            first_row.setdefault(caption.log_id, caption.row)
            if groups is None:
                held.setdefault(caption.log_id, []).append(caption)
        row += table.num_rows
    if groups is None:
        return {lid: LogCaptionRows(lid, first, tuple(held[lid])) for lid, first in first_row.items()}
    # The file itself, not a link to it: a later `caption` may publish another generation while logs run.
    real = str(captions_path.resolve())
    return {lid: LogCaptionRows(lid, first, path=real, row_groups=tuple(groups[lid]))
            for lid, first in first_row.items()}


def _parquet_file(path: Path) -> pq.ParquetFile:
    try:
        return pq.ParquetFile(path)
    except (OSError, pa.ArrowInvalid) as exc:
        raise ClipsInputError(f"{path}: unreadable Parquet file ({exc})") from exc


def _caption_rows(table: pa.Table, captions_path: Path, first_row: int) -> list[CaptionRow]:
    """The neighbour caption rows of ``table``, whose first row is row ``first_row`` of the file, checked."""
    cols = {name: table.column(name).to_pylist() for name in table.column_names}
    n = table.num_rows

    def get(name: str, default: Any) -> list[Any]:
        return cols.get(name, [default] * n)

    rows: list[CaptionRow] = []
    categories, canon, para = get("category", "other"), get("canonical_caption", None), get("paraphrases", None)
    tags, host_tags = get("tags", None), get("host_tags", None)
    behavior = [f.name for f in BEHAVIOR_CAPTION_FIELDS if f.name in cols]
    for j in range(n):
        i = first_row + j
        for name in REQUIRED_CAPTION_COLUMNS:
            if cols[name][j] is None:
                raise ClipsInputError(f"{captions_path}, row {i}, field '{name}': null value")
        if str(cols["track_id"][j]) == HOST_TRACK_ID:
            continue
        start, end = int(cols["start_ns"][j]), int(cols["end_ns"][j])
        if end < start:
            raise ClipsInputError(f"{captions_path}, row {i}, field 'end_ns': {end} is before start_ns {start}")
        category = str(categories[j] or Category.OTHER.value)
        if category not in CATEGORY_NAMES:
            raise ClipsInputError(f"{captions_path}, row {i}, field 'category': {category!r} is not one of "
                                  f"{list(CATEGORY_NAMES)}")
        caption = str(cols["caption"][j])
        if not caption.strip():
            raise ClipsInputError(f"{captions_path}, row {i}, field 'caption': empty (a clip is its caption's moment)")
        rows.append(
            CaptionRow(
                row=i,
                log_id=str(cols["log_id"][j]),
                track_id=str(cols["track_id"][j]),
                category=category,
                start_ns=start,
                end_ns=end,
                caption=caption,
                canonical_caption=str(canon[j]) if canon[j] is not None else caption,
                paraphrases=[str(p) for p in (para[j] or [])],
                tags=[str(t) for t in (tags[j] or [])],
                host_tags=[str(t) for t in (host_tags[j] or [])],
                behavior={name: cols[name][j] for name in behavior},
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


class ClipTableSpool:
    """Writes ``CLIPS_DIR/clips.parquet`` log by log: each log's rows go, as its clips are cut, to a
    temporary file beside the table (a row group per log); :meth:`publish` then writes the table in
    the logs' final order with their splits, which depend on every log. No process holds every
    log's rows. Use it as a context manager: the temporary file goes when the block ends.

    The table has :data:`CLIP_SCHEMA`'s columns, and the behaviour columns that every row has.
    """

    def __init__(self, clips_dir: Path) -> None:
        self._clips_dir = Path(clips_dir)
        self._scratch = scratch_path(self._clips_dir / CLIPS_FILE)
        self._writer: pq.ParquetWriter | None = None
        self._groups: dict[str, int] = {}
        self._behavior = {f.name for f in BEHAVIOR_CAPTION_FIELDS}  # the columns every row so far has
        self.num_rows = 0

    def __enter__(self) -> ClipTableSpool:
        self._path = self._scratch.__enter__()
        self._writer = pq.ParquetWriter(self._path, _SPOOL_SCHEMA)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._writer is not None:
            self._writer.close()
        self._scratch.__exit__(None, None, None)

    def add(self, log_id: str, rows: list[dict[str, Any]]) -> None:
        """Spool one log's clip rows (their ``split`` is set by :meth:`publish`)."""
        if not rows:
            return
        if self._writer is None or log_id in self._groups:
            raise ValueError(f"log {log_id}: spooled twice, or the spool is not open")
        self._behavior &= {name for name in self._behavior if all(name in r for r in rows)}
        self._writer.write_table(pa.Table.from_pylist(rows, schema=_SPOOL_SCHEMA), row_group_size=len(rows))
        self._groups[log_id] = len(self._groups)
        self.num_rows += len(rows)

    def publish(self, order: Sequence[str], splits: Mapping[str, str]) -> None:
        """Write ``clips.parquet`` atomically: the logs' rows in ``order`` (logs not spooled are passed
        over), each with its split."""
        assert self._writer is not None
        self._writer.close()
        self._writer = None
        source = pq.ParquetFile(self._path)
        schema = pa.schema([*CLIP_SCHEMA, *(f for f in BEHAVIOR_CAPTION_FIELDS if f.name in self._behavior)])
        at = schema.get_field_index("split")

        def write(tmp: Path) -> None:
            with pq.ParquetWriter(tmp, schema) as out:
                for log_id in order:
                    if log_id in self._groups:
                        table = source.read_row_group(self._groups[log_id], columns=schema.names)
                        split = pa.array([splits[log_id]] * table.num_rows, pa.string())
                        out.write_table(table.set_column(at, "split", split))

        atomic_write_with(self._clips_dir / CLIPS_FILE, write)
