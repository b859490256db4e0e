"""Short ids of indexed moments, which the command line prints and ``scenesearch similar`` accepts.

A clip id (``LOG_ID:TRACK_ID:START_NS``, :func:`encoders.clips.layout.clip_id`) is exact but long. Two
shorter forms name a moment of one index:

- ``#N``: the moment at rank N of the last ``search`` (or ``similar``) of that index directory. Each
  such command remembers its ranked clip ids in a small state file of the user's cache directory
  (:func:`state_path`: ``$XDG_CACHE_HOME/scenesearch/last_search.json``, else
  ``~/.cache/scenesearch/last_search.json``), keyed by the index directory's resolved path and
  written atomically (:mod:`scenesearch_base.atomic`); it holds the last search of at most
  :data:`MAX_REMEMBERED` index directories.
- ``LOG/TRACK@SECONDSs``, the *readable* form, e.g. ``5620d013/8e7d6a5c@12.4s``: a prefix of the log
  id, ``/``, a prefix of the track id, ``@``, and the moment's start in seconds within its log, to
  0.1 s: the start of :func:`retrieval.records.time_in_log`, from the log's first frame where its
  rendered frames are at hand (:func:`retrieval.records.read_log_spans`), else from the log's earliest
  indexed moment.
  :class:`ShortIds` prints each prefix at :data:`PREFIX_CHARS` characters, longer where that many
  would name more than one log of the index (or more than one track of the log), so every printed
  form names one moment. Read back, an id given in full wins over a longer id it begins; a prefix
  that still names several logs or tracks, or a time that matches no moment of the track, is
  refused with the candidates named (:class:`ShortIdError`).

A full clip id is taken as it is.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from retrieval.errors import RetrievalError
from retrieval.records import LogSpan, SearchResult
from scenesearch_base.arrow_numpy import scalar, to_numpy

#: Characters of the log and track prefixes in a readable id (more where that many are ambiguous).
PREFIX_CHARS = 8
#: Index directories whose last search the state file keeps (the oldest is dropped first).
MAX_REMEMBERED = 32
STATE_FILE = "last_search.json"
_STATE_FORMAT = 1
_RANK = re.compile(r"#(\d+)")
_READABLE = re.compile(r"(?P<log>[^/@\s]+)/(?P<track>[^@\s]+)@(?P<seconds>-?\d+(?:\.\d+)?)s?")


class ShortIdError(RetrievalError):
    """A short id that names no moment of the index, or several (the message names the candidates)."""


def state_path() -> Path:
    """The state file of the last searches: under ``$XDG_CACHE_HOME`` (default ``~/.cache``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "scenesearch" / STATE_FILE


def _index_key(index_dir: Path | str) -> str:
    return str(Path(index_dir).resolve())


def _read_state(path: Path) -> dict[str, Any]:
    """The state file's searches (index dir → record); empty when it is absent or unreadable."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return {}
    if not isinstance(data, dict) or data.get("format") != _STATE_FORMAT or not isinstance(data.get("searches"), dict):
        return {}
    return dict(data["searches"])


def remember(index_dir: Path | str, query: str, clip_ids: Sequence[str], path: Path | None = None) -> None:
    """Record ``clip_ids`` (rank 1 first) as the last search of ``index_dir``, for ``#N`` ids.

    A state file that cannot be written (a read-only home, say) costs the ``#N`` ids only: the search
    itself has succeeded, so the failure is ignored.
    """
    from scenesearch_base.atomic import atomic_write_text

    path = path or state_path()
    searches = _read_state(path)
    key = _index_key(index_dir)
    searches.pop(key, None)
    searches[key] = {"query": query, "clip_ids": list(clip_ids)}
    while len(searches) > MAX_REMEMBERED:
        searches.pop(next(iter(searches)))
    with contextlib.suppress(OSError):
        atomic_write_text(path, json.dumps({"format": _STATE_FORMAT, "searches": searches}, indent=1))


def last_search(index_dir: Path | str, path: Path | None = None) -> tuple[str, list[str]] | None:
    """The query and ranked clip ids of the last search of ``index_dir``, or None."""
    record = _read_state(path or state_path()).get(_index_key(index_dir))
    if not isinstance(record, dict) or not isinstance(record.get("clip_ids"), list):
        return None
    return str(record.get("query", "")), [str(c) for c in record["clip_ids"]]


def _unique_prefixes(names: Iterable[str], shortest: int) -> dict[str, str]:
    """Each name → its shortest prefix of at least ``shortest`` characters that no other name starts with
    (the whole name where none is)."""
    ordered = sorted(set(names))
    out: dict[str, str] = {}
    for i, name in enumerate(ordered):
        need = shortest
        for other in (ordered[i - 1] if i else None, ordered[i + 1] if i + 1 < len(ordered) else None):
            if other is None:
                continue
            common = next((i for i, (a, b) in enumerate(zip(name, other)) if a != b), min(len(name), len(other)))
            need = max(need, common + 1)
        out[name] = name[:need]
    return out


_COLUMNS = ("clip_id", "log_id", "track_id", "start_ns", "end_ns")


class ShortIds:
    """The readable ids of an index's moments, and the reading of any short id back to a clip id.

    Built from the index's metadata table (columns ``clip_id``, ``log_id``, ``track_id``, ``start_ns``,
    ``end_ns``); the work per query is per log, in Arrow, so it stays small on large indexes. A log's span
    comes from ``read_spans`` (log ids → their spans, e.g. from the rendered frames by
    :func:`retrieval.records.read_log_spans`), asked once per log when first needed; a log it does not
    give spans from its earliest indexed moment to its latest.
    """

    def __init__(self, table: pa.Table, read_spans: Callable[[list[str]], Mapping[str, LogSpan]] | None = None
                 ) -> None:
        self._table = table.select(list(_COLUMNS))
        # Each log's first and last indexed moment, in numpy: Arrow's group_by imports its query engine and
        # pyarrow.dataset, which a search's start-up would pay for (docs/research/cli-startup.md).
        logs, inverse = np.unique(to_numpy(self._table.column("log_id")).astype(str), return_inverse=True)
        first = np.full(logs.shape[0], np.iinfo(np.int64).max, dtype=np.int64)
        last = np.full(logs.shape[0], np.iinfo(np.int64).min, dtype=np.int64)
        np.minimum.at(first, inverse, to_numpy(self._table.column("start_ns")).astype(np.int64))
        np.maximum.at(last, inverse, to_numpy(self._table.column("end_ns")).astype(np.int64))
        self._covered = {str(lg): LogSpan(int(a), int(b)) for lg, a, b in zip(logs, first, last)}
        self._read_spans = read_spans
        self._spans: dict[str, LogSpan] = {}
        self._log_prefix = _unique_prefixes(self._covered, PREFIX_CHARS)
        self._track_prefix: dict[str, dict[str, str]] = {}

    @classmethod
    def of_table(cls, table: pa.Table, clips_dir: Path | str | None = None) -> ShortIds:
        """From an index's metadata table; the logs' spans from the rendered frames of ``clips_dir`` where
        it holds them."""
        if clips_dir is None:
            return cls(table)
        from retrieval.records import read_log_spans

        folder = Path(clips_dir)
        return cls(table, lambda logs: read_log_spans(folder, logs))

    @classmethod
    def of_results(cls, results: Sequence[SearchResult], spans: Mapping[str, LogSpan] | None = None) -> ShortIds:
        """From the moments of ``results`` alone (logs' spans from ``spans``, else from these moments)."""
        given = dict(spans or {})
        table = pa.table({"clip_id": [r.clip_id for r in results], "log_id": [r.log_id for r in results],
                          "track_id": [r.track_id for r in results],
                          "start_ns": pa.array([r.start_ns for r in results], pa.int64()),
                          "end_ns": pa.array([r.end_ns for r in results], pa.int64())})
        return cls(table, lambda logs: {lg: given[lg] for lg in logs if lg in given})

    def spans(self, log_ids: Iterable[str]) -> dict[str, LogSpan]:
        """The span of each indexed log among ``log_ids`` (those not known yet are read in one call)."""
        wanted = [lg for lg in dict.fromkeys(log_ids) if lg in self._covered]
        missing = [lg for lg in wanted if lg not in self._spans]
        if missing:
            read = dict(self._read_spans(missing)) if self._read_spans is not None else {}
            for log_id in missing:
                self._spans[log_id] = read.get(log_id) or self._covered[log_id]
        return {lg: self._spans[lg] for lg in wanted}

    def _moments_of(self, log_id: str) -> pa.Table:
        return self._table.filter(pc.equal(self._table.column("log_id"), scalar(log_id, pa.string())))

    def _tracks(self, log_id: str) -> dict[str, str]:
        """Each track of the log → its printed prefix."""
        if log_id not in self._track_prefix:
            tracks = pc.unique(self._moments_of(log_id).column("track_id")).to_pylist()
            self._track_prefix[log_id] = _unique_prefixes(map(str, tracks), PREFIX_CHARS)
        return self._track_prefix[log_id]

    def start_s(self, log_id: str, start_ns: int) -> float:
        """A moment's start in seconds within its log (see the module docstring)."""
        return (int(start_ns) - self.spans([log_id])[log_id].first_ns) / 1e9

    def readable(self, log_id: str, track_id: str, start_ns: int) -> str:
        """The readable id (``LOG/TRACK@SECONDSs``) of an indexed moment."""
        return f"{self._log_prefix[log_id]}/{self._tracks(log_id)[track_id]}@{self.start_s(log_id, start_ns):.1f}s"

    def readable_ids(self, results: Iterable[SearchResult]) -> dict[str, str]:
        """Clip id → readable id of each of ``results`` (moments of the index)."""
        return {r.clip_id: self.readable(r.log_id, r.track_id, r.start_ns) for r in results}

    def resolve(self, text: str, index_dir: Path | str, state: Path | None = None) -> str:
        """The clip id that ``text`` names: a clip id, ``#N`` or a readable id (see the module docstring).

        Raises:
            ShortIdError: ``text`` names no indexed moment or several; the message names the candidates
                (or the ranks of the last search).
        """
        text = text.strip()
        if self._holds(text):
            return text
        rank = _RANK.fullmatch(text)
        if rank:
            return self._resolve_rank(int(rank.group(1)), index_dir, state)
        readable = _READABLE.fullmatch(text)
        if readable:
            return self._resolve_readable(readable.group("log"), readable.group("track"),
                                          float(readable.group("seconds")))
        first = self._table.slice(0, 3).to_pylist()
        examples = ", ".join(self.readable(r["log_id"], r["track_id"], r["start_ns"]) for r in first)
        raise ShortIdError(f"unknown clip id {text!r}: give a clip id LOG_ID:TRACK_ID:START_NS, #N (rank N of the "
                           f"last search of this index) or LOG/TRACK@SECONDSs (e.g. {examples})")

    def _holds(self, clip_id: str) -> bool:
        return bool(pc.any(pc.equal(self._table.column("clip_id"), scalar(clip_id, pa.string()))).as_py())

    def _resolve_rank(self, rank: int, index_dir: Path | str, state: Path | None) -> str:
        last = last_search(index_dir, state)
        if last is None:
            raise ShortIdError(f"#{rank}: no search of {index_dir} is remembered; run `scenesearch search "
                               f"{index_dir} QUERY` first (or give a clip id)")
        query, ranked = last
        if not 1 <= rank <= len(ranked):
            span = f"#1 … #{len(ranked)}" if ranked else "none"
            raise ShortIdError(f"#{rank}: the last search of {index_dir} ({query!r}) has {len(ranked)} result(s): "
                               f"{span}")
        clip = ranked[rank - 1]
        if not self._holds(clip):
            raise ShortIdError(f"#{rank}: {clip!r} of the last search ({query!r}) is no longer in {index_dir}; "
                               "search again")
        return clip

    def _resolve_readable(self, log: str, track: str, seconds: float) -> str:
        logs = _matching(log, self._covered)
        if not logs:
            raise ShortIdError(f"no log of this index starts with {log!r} (logs: "
                               f"{_listed(self._log_prefix[lg] for lg in sorted(self._covered))})")
        if len(logs) > 1:
            raise ShortIdError(f"{log!r} names {len(logs)} logs: {_listed(logs)}; give more of the log id")
        log_id = logs[0]
        tracks = _matching(track, self._tracks(log_id))
        if not tracks:
            raise ShortIdError(f"log {log_id} has no indexed track starting with {track!r}")
        if len(tracks) > 1:
            raise ShortIdError(f"{track!r} names {len(tracks)} tracks of log {log_id}: {_listed(tracks)}; give more "
                               "of the track id")
        rows = self._moments_of(log_id)
        rows = rows.filter(pc.equal(rows.column("track_id"), scalar(tracks[0], pa.string())))
        rows = rows.sort_by("start_ns").to_pylist()
        hits = [r for r in rows if round(self.start_s(log_id, r["start_ns"]), 1) == round(seconds, 1)]
        if len(hits) == 1:
            return str(hits[0]["clip_id"])
        if not hits:
            listed = _listed(self.readable(log_id, tracks[0], r["start_ns"]) for r in rows)
            raise ShortIdError(f"track {tracks[0]} of log {log_id} has no moment starting at {seconds:.1f} s; its "
                               f"moments: {listed}")
        raise ShortIdError(f"{len(hits)} moments of track {tracks[0]} start at {seconds:.1f} s: "
                           f"{_listed(str(r['clip_id']) for r in hits)}; give the clip id")


def _matching(prefix: str, names: Mapping[str, object]) -> list[str]:
    """The names equal to ``prefix`` (an id given in full wins), else those that start with it."""
    if prefix in names:
        return [prefix]
    return sorted(n for n in names if n.startswith(prefix))


def _listed(items: Iterable[str], limit: int = 8) -> str:
    shown = list(items)
    more = f" and {len(shown) - limit} more" if len(shown) > limit else ""
    return ", ".join(shown[:limit]) + more
