"""Scenario queries in search: the query compiled to a program, answered on the index's logs, the search
kept to the moments the program selects.

An index keeps each of its logs' scenario features in ``INDEX/scenarios/<log_id>.features``
(:mod:`scenarios.cache`), built from the logs' folders when the index is built (:func:`build_store`)
and covered by the index's checksums. At query time :meth:`ScenarioStore.match` compiles the query
(:mod:`scenarios.compiler`), answers it on every log that has indexed moments, and keeps the moments
(clip windows) in which an object the program refers to is referred at some frame: the clip's own
track, or any clip of the log where the program refers to the ego (whose own moments have no clip).
For a sequence ("drives off", "slows down and stops") the frame must be where it happens, its last
step beginning after the ones before (:attr:`scenarios.evaluate.Evaluation.events`): a window that
holds only the stop, or only the driving after it, does not show the sequence.
The search then ranks those moments with its usual scores (model, hybrid or rule captions), so the
program decides *which* moments and the learned model *in which order*.

Where the query does not compile, or its program selects no indexed moment, the search ranks every
moment as before and :attr:`ScenarioMatch.fallback` says why.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from indexes.filters import Condition, FilterSpec, Op
from indexes.metadata import MetadataStore
from retrieval.querying import build_query, check_query
from retrieval.records import SearchResult
from scenarios.cache import FEATURES_SUFFIX, cached_features, decode
from scenarios.compiler import Compiled, DescriptionError, compile_description
from scenarios.evaluate import evaluate, grouped_notes
from scenarios.features import EGO_TRACK_ID, LogFeatures
from scenes.errors import ScenesError
from scenesearch_base.arrow_numpy import from_numpy, to_numpy
from scenesearch_base.lru import Lru

#: The folder of the logs' scenario features inside an index.
SCENARIOS_DIR = "scenarios"


@dataclass(frozen=True)
class ScenarioMatch:
    """What the query's program selected among the indexed moments.

    Attributes:
        query: the query.
        compiled: the program it compiled to, or None.
        clip_ids: the moments the program selects (empty with a fallback).
        referred: clip id → the tracks the program refers to in that moment's window.
        related: clip id → the tracks those relate to (the bicycle of "vehicle with a bicycle to its right").
        notes: what some logs could not answer (no map, no recorded weather, no features).
        fallback: why the search ranks every moment instead (None when the program decides).
        filled: the results after the program's own: where it selects fewer moments than asked for, the
            search's next best, which it does not select (in rank order).
    """

    query: str
    compiled: Compiled | None
    clip_ids: tuple[str, ...] = ()
    referred: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    related: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    fallback: str | None = None
    filled: tuple[str, ...] = ()

    def selects(self, clip_id: str) -> bool:
        """Whether the program decided and selects this result (not one of the next best that fill the list)."""
        return self.fallback is None and clip_id not in self.filled

    def result_fields(self, clip_id: str) -> dict[str, Any]:
        """What a result's record says of the program where it decided (none where it did not): whether
        it selects the moment, the tracks it refers to there and those they relate to."""
        if self.fallback is not None:
            return {}
        return {"program_selects": self.selects(clip_id), "referred_tracks": list(self.referred.get(clip_id, ())),
                "related_tracks": list(self.related.get(clip_id, ()))}

    def preview_marks(self, clip_id: str, track_id: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """The tracks a preview of the moment marks: those the program refers to besides the moment's own
        track, and those they relate to (the ego, always drawn, in neither)."""
        referred = tuple(t for t in self.referred.get(clip_id, ()) if t not in (track_id, EGO_TRACK_ID))
        related = tuple(t for t in self.related.get(clip_id, ()) if t != EGO_TRACK_ID)
        return referred, related

    def to_dict(self) -> dict[str, Any]:
        """The match as the service and ``search --json`` report it."""
        c = self.compiled
        return {"program": c.text if c else None, "reads": c.rendering if c else None,
                "unused_words": list(c.unused) if c else [], "matched_moments": len(self.clip_ids),
                "fallback": self.fallback, "notes": list(self.notes), "filled": len(self.filled)}


def build_store(folder: Path, log_dirs: Mapping[str, str], log_ids: Iterable[str] = ()) -> dict[str, Any]:
    """Write the scenario features of each log (id → folder) into ``folder``; what was left out, and why.

    ``log_ids``: the logs of the indexed moments; one that ``log_dirs`` does not name is reported missing
    too (its moments would otherwise quietly never match a scenario query).

    Returns:
        ``{"logs": built, "missing": {log_id: reason}}``.
    """
    folder.mkdir(parents=True, exist_ok=True)
    missing: dict[str, str] = {str(log_id): "its folder is not recorded (no entry in the log list of its captions "
                                            "or clips), so scenario queries cannot select its moments"
                               for log_id in sorted(set(map(str, log_ids)) - set(log_dirs))}
    for log_id, log_dir in sorted(log_dirs.items()):
        try:
            cached_features(Path(log_dir), folder)
        except (ScenesError, OSError, ValueError) as exc:
            missing[log_id] = f"its folder {log_dir} cannot be read ({exc})"
    built = sum(1 for log_id in log_dirs if log_id not in missing)
    return {"logs": built, "missing": missing}


def log_folders_of(captions_dir: Path) -> dict[str, str]:
    """The ``logs.json`` of a captions folder (log id → folder); empty when it has none.

    Raises:
        ValueError: the file is there but unreadable, or not an object of folder names (naming it).
    """
    path = captions_dir / "logs.json"
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: unreadable ({exc}); write the captions again with `scenesearch caption`") from None
    if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
        raise ValueError(f"{path}: expected an object of log id → folder, got {type(data).__name__}")
    return {str(k): v for k, v in data.items()}


def clip_log_folders(clips_dir: Path) -> dict[str, str]:
    """Log id → folder of the logs a clips folder was made from (as its manifest records them)."""
    from encoders.clips.layout import read_manifest

    try:
        logs = read_manifest(clips_dir).get("logs", {})
    except (FileNotFoundError, ValueError):
        return {}
    return {str(log_id): str(entry["log_dir"]) for log_id, entry in logs.items()
            if isinstance(entry, dict) and entry.get("log_dir") and "://" not in str(entry["log_dir"])}


#: Bytes of decoded scenario features a store keeps: a query over a fleet's index reads every log's,
#: which would otherwise all stay (sizes: docs/research/scenario-queries.md).
FEATURES_KEPT_BYTES = 1 << 30


class ScenarioStore:
    """The scenario features of an index's logs, read when a query first needs them and kept, the least
    recently used going first, up to :data:`FEATURES_KEPT_BYTES`."""

    def __init__(self, folder: Path | None) -> None:
        self.folder = folder
        # log id → (its features, or None without any): a one-element tuple, so that a log known to have
        # none is told apart from one not read yet.
        self._features: Lru[str, tuple[LogFeatures | None]] = Lru(
            FEATURES_KEPT_BYTES, lambda kept: kept[0].nbytes if kept[0] is not None else 0)
        self._problems: dict[str, str] = {}  # log id → why its features could not be read

    @property
    def available(self) -> bool:
        return self.folder is not None and self.folder.is_dir() and any(self.folder.glob(f"*{FEATURES_SUFFIX}"))

    def features(self, log_id: str) -> LogFeatures | None:
        if self.folder is None:
            return None
        kept = self._features.get(log_id)
        if kept is None:
            path = self.folder / f"{log_id}{FEATURES_SUFFIX}"
            try:
                kept = (decode(path.read_bytes())[0] if path.is_file() else None,)
            except ValueError as exc:  # another format (an index built by another release) or damaged
                kept = (None,)
                self._problems[log_id] = f"{path.name}: {exc}; build the index again to answer scenario programs"
            self._features.put(log_id, kept)
        return kept[0]

    def match(self, query: str, moments: pa.Table) -> ScenarioMatch:
        """The moments of ``moments`` (``clip_id``, ``log_id``, ``track_id``, ``start_ns``, ``end_ns``) the
        query's program selects (see the module docstring)."""
        try:
            compiled = compile_description(query)
        except DescriptionError as exc:
            return ScenarioMatch(query, None, fallback=f"the query does not compile to a scenario program: {exc}")
        if not self.available:
            return ScenarioMatch(query, compiled, fallback="this index holds no scenario features (build it again "
                                                          "to answer scenario programs)")
        logs = to_numpy(moments.column("log_id")).astype(str)
        selected: list[str] = []
        referred: dict[str, tuple[str, ...]] = {}
        related: dict[str, tuple[str, ...]] = {}
        said: list[tuple[str, str]] = []  # (log id, what it could not answer)
        for log_id in dict.fromkeys(logs.tolist()):
            x = self.features(log_id)
            if x is None:
                why = self._problems.get(log_id, "no scenario features")
                said.append((log_id, f"{why}: its moments are left out of the program's answer"))
                continue
            result = evaluate(compiled.program, x, events=True)
            said += [(log_id, note) for note in result.notes]
            rows = moments.filter(from_numpy(logs == log_id))
            found = _moments_selected(x, result.selection.mask, result.selection.related, rows, result.events)
            for clip_id, refs, rels in found:
                selected.append(clip_id)
                referred[clip_id], related[clip_id] = refs, rels
        notes = grouped_notes(said)
        if not selected:
            return ScenarioMatch(query, compiled, notes=notes,
                                 fallback="the program selects none of the indexed moments")
        return ScenarioMatch(query, compiled, tuple(selected), referred, related, notes)


def _moments_selected(x: LogFeatures, referred: np.ndarray, related: np.ndarray, rows: pa.Table,
                      events: np.ndarray | None = None) -> list[tuple[str, tuple[str, ...], tuple[str, ...]]]:
    """The moments of one log (``rows``) whose window holds a referred frame of their track (or of the ego),
    or with ``events`` one of its events, each with the referred and related tracks in its window."""
    ts = x.timestamps_ns
    lo = np.searchsorted(ts, to_numpy(rows.column("start_ns")).astype(np.int64), side="left")
    hi = np.searchsorted(ts, to_numpy(rows.column("end_ns")).astype(np.int64), side="right")

    def in_window(mask: np.ndarray) -> np.ndarray:  # (K, M): the mask holds somewhere in each window
        counts = np.concatenate([np.zeros((x.num_objects, 1), np.int64), np.cumsum(mask, axis=1)], axis=1)
        return (counts[:, hi] - counts[:, lo]) > 0

    in_window_ref, in_window_rel = in_window(referred), in_window(related)
    deciding = in_window_ref if events is None else in_window(events)
    track_row = {str(t): i for i, t in enumerate(x.track_ids)}
    ego = x.ego_index
    out = []
    for m, (clip_id, track) in enumerate(zip(rows.column("clip_id").to_pylist(), rows.column("track_id").to_pylist())):
        k = track_row.get(str(track))
        own = k is not None and bool(deciding[k, m])
        by_ego = bool(deciding[ego, m]) and str(track) != EGO_TRACK_ID
        if not (own or by_ego):
            continue
        refs = tuple(str(x.track_ids[i]) for i in np.flatnonzero(in_window_ref[:, m]))
        rels = tuple(str(x.track_ids[i]) for i in np.flatnonzero(in_window_rel[:, m]))
        out.append((str(clip_id), refs, rels))
    return out


def search_within(store: ScenarioStore, metadata: MetadataStore, query: str, k: int, filters: FilterSpec,
                  max_k: int, rank: Callable[[FilterSpec], list[SearchResult]], fill: bool = True
                  ) -> tuple[list[SearchResult], ScenarioMatch]:
    """Rank with ``rank`` (a search of k given a filter) among the moments of ``metadata`` that the query's
    program selects, the caller's ``filters`` included; every moment when the program cannot decide.

    Where the program selects fewer than k moments, the list goes on (``fill``) with ``rank``'s next best
    among the others, named in :attr:`ScenarioMatch.filled`: a short answer is all the program selects,
    and what follows is said to be outside it, as a search engine shows its closest other results after
    the exact ones (docs/research/scenario-queries.md, "Filling a short answer").
    """
    query = check_query(query)
    user = build_query(k, filters, metadata, len(metadata), max_k).filters  # the caller's filter, checked first
    match = store.match(query, metadata.table)
    if match.fallback is not None:
        return rank(filters), match
    within = Condition("clip_id", Op.IN, tuple(match.clip_ids))
    results = rank([*(user or ()), within])
    if not fill:
        return results, match
    results, filled = filled_up(results, k, lambda: rank(filters))
    return results, dataclasses.replace(match, filled=filled)


def filled_up(selected: list[SearchResult], k: int, best: Callable[[], list[SearchResult]]
              ) -> tuple[list[SearchResult], tuple[str, ...]]:
    """``selected`` (every moment a program selects, ranked) followed by the best others of ``best()`` (the
    search's best k, program aside) up to k in all; with the ids of those others."""
    if len(selected) >= k:
        return selected, ()
    have = {r.clip_id for r in selected}  # every selected moment is here: the best k of all hold k others
    more = [r for r in best() if r.clip_id not in have][:k - len(selected)]
    ranked = [*selected, *(dataclasses.replace(r, rank=len(selected) + i) for i, r in enumerate(more, start=1))]
    return ranked, tuple(r.clip_id for r in more)
