"""Search over rule captions alone: works on any log with tracks, including real logs without sensors.

The rule captions of every (object, window) are embedded with the frozen sentence encoder
(:class:`retrieval.embedding.SentenceEncoder`), not with a trained model, so no clips and no training
are needed. A query is embedded the same way and compared by cosine similarity.

>>> search = CaptionSearch.build("captions/captions.parquet", "captions_index")
>>> search.search("stopped car", k=5, filters={"category": "car"})

:func:`caption_logs` captions log folders end to end (``captioning.caption_log``) and returns the
caption table, so real AV2 logs can be searched in two lines (see :func:`search_logs`).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from indexes.clip_index import ClipIndex
from indexes.errors import FilterError
from indexes.errors import InvalidKError as IndexInvalidKError
from indexes.filters import FilterSpec
from retrieval.embedding import SentenceEncoder
from retrieval.errors import EmptyQueryError, FilterSyntaxError, IndexDirError, InvalidKError
from retrieval.records import SearchResult
from scenes.atomic import atomic_directory

TextEncoder = Callable[[Sequence[str]], np.ndarray]
INFO_FILE = "caption_search.json"
INDEX_SUBDIR = "index"
FORMAT_VERSION = 1
#: Columns kept as metadata (and filterable) when present in the caption table.
METADATA_COLUMNS = ("clip_id", "log_id", "track_id", "category", "start_ns", "end_ns", "caption", "tags",
                    "host_tags", "window", "split", "time_of_day", "weather", "has_camera", "preview_path")


@dataclass(frozen=True)
class Skipped:
    """An input left out of an index, and why."""

    item: str
    reason: str


def clip_id_of(log_id: str, track_id: str, start_ns: int) -> str:
    """The stable id of a moment: ``f"{log_id}:{track_id}:{start_ns}"``."""
    return f"{log_id}:{track_id}:{int(start_ns)}"


def caption_rows(table: pa.Table) -> tuple[pa.Table, list[Skipped]]:
    """The metadata table of a caption (or clip) table: one row per unique moment with a caption.

    Adds ``clip_id`` when absent; drops rows without a caption and repeated ids (reported).
    """
    missing = [c for c in ("log_id", "track_id", "start_ns", "caption") if c not in table.column_names]
    if "caption" in missing and "canonical_caption" in table.column_names:
        table = table.append_column("caption", table.column("canonical_caption"))
        missing.remove("caption")
    if missing:
        raise ValueError(f"the caption table lacks the columns {missing}; it has {table.column_names}")
    if "clip_id" not in table.column_names:
        ids = [clip_id_of(lg, tr, st) for lg, tr, st in zip(table.column("log_id").to_pylist(),
                                                            table.column("track_id").to_pylist(),
                                                            table.column("start_ns").to_pylist())]
        table = table.append_column("clip_id", pa.array(ids, pa.string()))
    keep = [c for c in METADATA_COLUMNS if c in table.column_names]
    table = table.select(keep)
    skipped: list[Skipped] = []
    captions = table.column("caption").to_pylist()
    ids = table.column("clip_id").to_pylist()
    seen: set[str] = set()
    mask = np.zeros(table.num_rows, dtype=bool)
    for i, (cid, cap) in enumerate(zip(ids, captions)):
        if not cap or not str(cap).strip():
            skipped.append(Skipped(str(cid), "no caption"))
        elif cid in seen:
            skipped.append(Skipped(str(cid), "repeated clip id (kept the first row)"))
        else:
            seen.add(cid)
            mask[i] = True
    return table.filter(pa.array(mask)), skipped


class CaptionSearch:
    """Rule captions embedded by a frozen sentence encoder, searchable by text."""

    def __init__(self, index: ClipIndex, encoder: TextEncoder | None = None, encoder_name: str | None = None,
                 base_dir: Path | None = None, skipped: Sequence[Skipped] = ()) -> None:
        self.index = index
        self.encoder: TextEncoder = encoder if encoder is not None else SentenceEncoder()
        self.encoder_name = str(encoder_name or getattr(self.encoder, "name", type(self.encoder).__name__))
        self.base_dir = base_dir
        self.skipped = list(skipped)

    def __len__(self) -> int:
        return len(self.index)

    @property
    def fields(self) -> list[str]:
        return [f for f in self.index.fields if f != "id"]

    @classmethod
    def build(cls, captions: Path | str | pa.Table, out_dir: Path | str | None = None,
              encoder: TextEncoder | None = None, base_dir: Path | None = None) -> CaptionSearch:
        """Embed the captions of ``captions`` (a ``captions.parquet``, a captions directory, or a table).

        Identical caption texts are embedded once. Written to ``out_dir`` atomically when given.
        """
        if isinstance(captions, pa.Table):
            table = captions
        else:
            path = Path(captions)
            if path.is_dir():
                path = path / "captions.parquet"
            if not path.is_file():
                raise FileNotFoundError(f"{path}: no caption table here (run `scenesearch caption` first)")
            table = pq.read_table(path)
            base_dir = base_dir or path.parent
        rows, skipped = caption_rows(table)
        if rows.num_rows == 0:
            raise ValueError("no captions to index" + (f"; skipped: {skipped[:5]}" if skipped else ""))
        encoder = encoder if encoder is not None else SentenceEncoder()
        texts = rows.column("caption").to_pylist()
        unique, inverse = np.unique(np.asarray(texts, dtype=object), return_inverse=True)
        emb = np.asarray(encoder([str(u) for u in unique]), dtype=np.float32)[inverse.reshape(-1)]
        index = ClipIndex.build(emb, rows, metric="cosine", factory="auto")
        out = cls(index, encoder, None, base_dir, skipped)
        if out_dir is not None:
            out.save(out_dir)
        return out

    def save(self, out_dir: Path | str) -> None:
        """Write ``out_dir/index/`` (the caption index) and ``out_dir/caption_search.json``, atomically."""
        with atomic_directory(out_dir, overwrite=True) as tmp:
            self.index.save(tmp / INDEX_SUBDIR)
            info = {"format_version": FORMAT_VERSION, "kind": "caption_search", "text_encoder": self.encoder_name,
                    "count": len(self.index), "dim": self.index.dim,
                    "base_dir": None if self.base_dir is None else str(Path(self.base_dir).resolve()),
                    "skipped": [{"item": s.item, "reason": s.reason} for s in self.skipped]}
            (tmp / INFO_FILE).write_text(json.dumps(info, indent=2))

    @classmethod
    def open(cls, directory: Path | str, encoder: TextEncoder | None = None) -> CaptionSearch:
        directory = Path(directory)
        info_path = directory / INFO_FILE
        if not info_path.is_file():
            raise IndexDirError(f"{directory}: not a caption index ({INFO_FILE} is missing; build one with "
                                "CaptionSearch.build or `scenesearch index`)")
        info = json.loads(info_path.read_text())
        if int(info.get("format_version", 0)) > FORMAT_VERSION:
            raise IndexDirError(f"{info_path}: format version {info['format_version']} is newer than "
                                f"{FORMAT_VERSION}; upgrade scenesearch")
        index = ClipIndex.load(directory / INDEX_SUBDIR)
        base = info.get("base_dir")
        return cls(index, encoder, info.get("text_encoder"), Path(base) if base else None,
                   [Skipped(s["item"], s["reason"]) for s in info.get("skipped", [])])

    def search(self, query: str, k: int = 10, filters: FilterSpec = None) -> list[SearchResult]:
        """The k moments whose rule captions are closest to ``query``.

        Raises:
            EmptyQueryError, InvalidKError, FilterSyntaxError: bad arguments.
        """
        query = check_query(query)
        check_k(k, len(self.index))
        xq = np.asarray(self.encoder([query]), dtype=np.float32)
        return hits_to_results(self.index, xq, k, filters, "captions", self.base_dir)


def check_query(query: object) -> str:
    if not isinstance(query, str) or not query.strip():
        raise EmptyQueryError()
    return query.strip()


def check_k(k: object, size: int) -> int:
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 1 <= int(k) <= size:
        raise InvalidKError(k, size)
    return int(k)


def check_filters(index: ClipIndex, filters: FilterSpec) -> FilterSpec:
    """Reject unknown fields with the list of valid ones; other errors come from the filter language."""
    if filters is None or isinstance(filters, str):
        return filters
    if isinstance(filters, dict):
        valid = [f for f in index.fields if f != "id"]
        unknown = [f for f in filters if f not in valid]
        if unknown:
            raise FilterSyntaxError(f"unknown filter field {unknown[0]!r}; valid fields: {', '.join(valid)}")
    return filters


def hits_to_results(index: ClipIndex, xq: np.ndarray, k: int, filters: FilterSpec, view: str,
                    base_dir: Path | None, exclude_clip: str | None = None) -> list[SearchResult]:
    """Search ``index`` with one query vector (1, D) and turn the hits into records."""
    filters = check_filters(index, filters)
    try:
        if exclude_clip is not None:
            found = index.search_clip(exclude_clip, k, filters)
        else:
            found = index.search(xq, k, filters)
    except FilterError as exc:
        valid = ", ".join(f for f in index.fields if f != "id")
        message = str(exc)
        raise FilterSyntaxError(message if "valid fields" in message else f"{message}; valid fields: {valid}") \
            from None
    except IndexInvalidKError as exc:
        raise InvalidKError(k, exc.size) from None
    results = []
    for rank, hit in enumerate(found.hits[0], start=1):
        results.append(SearchResult.from_row(rank, hit.metadata, hit.score, view,
                                             preview_of(hit.metadata, base_dir)))
    return results


def preview_of(row: dict[str, Any], base_dir: Path | None) -> str | None:
    rel = row.get("preview_path")
    if not rel:
        return None
    path = Path(rel)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    return str(path)


# ---------------------------------------------------------------------- logs end to end


def caption_logs(log_dirs: Sequence[Path | str], config: Any = None,
                 progress: Callable[[str], None] | None = None) -> tuple[pa.Table, list[Skipped]]:
    """Caption log folders with ``captioning.caption_log``; returns the caption table and skipped logs.

    A log that cannot be opened or captioned is skipped with its reason; the others go on.
    """
    import captioning
    from scenes.errors import ScenesError
    from scenes.log import Log

    tables: list[pa.Table] = []
    skipped: list[Skipped] = []
    for log_dir in log_dirs:
        name = Path(log_dir).name
        try:
            log = Log.open(log_dir)
            caption_log = getattr(captioning, "caption_log")  # noqa: B009 - written beside this package
            out = caption_log(log, config) if config is not None else caption_log(log)
            table = _as_table(out)
        except (ScenesError, ValueError, OSError) as exc:
            skipped.append(Skipped(name, f"{type(exc).__name__}: {exc}"))
            continue
        if table.num_rows == 0:
            skipped.append(Skipped(name, "no captions (no neighbour tracks long enough for a window)"))
            continue
        tables.append(table)
        if progress is not None:
            progress(f"captioned {name}: {table.num_rows} captions")
    if not tables:
        raise ValueError("no log gave captions; skipped: " + "; ".join(f"{s.item}: {s.reason}" for s in skipped))
    return pa.concat_tables(tables, promote_options="permissive"), skipped


def _as_table(out: Any) -> pa.Table:
    """``caption_log``'s result as a table: a table, an object with ``.captions``/``.table``, or records."""
    if isinstance(out, pa.Table):
        return out
    for attr in ("captions", "table"):
        value = getattr(out, attr, None)
        if isinstance(value, pa.Table):
            return value
        if value is not None and not callable(value):
            return _as_table(value)
    if isinstance(out, tuple) and out and isinstance(out[0], pa.Table):
        return out[0]
    if hasattr(out, "to_table"):
        return _as_table(out.to_table())
    rows = []
    for item in out:
        if isinstance(item, dict):
            rows.append(item)
        elif hasattr(item, "to_dict"):
            rows.append(item.to_dict())
        else:
            from dataclasses import asdict

            rows.append(asdict(item))
    table = pa.Table.from_pylist(rows)
    for name in table.column_names:
        if pa.types.is_dictionary(table.column(name).type):
            table = table.set_column(table.column_names.index(name), name, pc.cast(table.column(name), pa.string()))
    return table


def search_logs(log_dirs: Sequence[Path | str], query: str, k: int = 10, filters: FilterSpec = None,
                encoder: TextEncoder | None = None) -> list[SearchResult]:
    """Caption ``log_dirs`` and search their captions for ``query`` in one call (tracks only)."""
    table, _ = caption_logs(log_dirs)
    search = CaptionSearch.build(table, encoder=encoder)
    return search.search(query, k=min(k, len(search)), filters=filters)
