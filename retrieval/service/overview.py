"""What the landing page and the filters show about an index, computed once from its metadata: a summary,
filter values with counts and readable names, example queries, and the embedding map.

The embedding map is each clip's embedding projected on the first two principal components of the
view's embeddings (PCA: one SVD of the D × D covariance, milliseconds for thousands of clips), coloured by
the clip's action (:func:`action_of`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa

from captioning.tags import split_neighbor_tag
from retrieval.records import LogSpan
from retrieval.service.explain import object_sentence, tag_label

#: Fields offered as menus of their values, each value with its count.
MENU_FIELDS = ("category", "weather", "time_of_day", "split", "junction_kind", "log_id")
#: Own actions and places, in the order a clip's action is named by (:func:`action_of`).
ACTION_FIELDS = ("left_turn", "right_turn", "left_lane_change", "right_lane_change", "braking", "braking_for",
                 "blocked_by", "stopped", "parked", "keeping_lane")
#: Boolean fields offered as switches, beyond the actions.
PLACE_FIELDS = ("at_intersection", "on_crosswalk", "has_camera")
FIELD_NAMES = {"category": "Category", "weather": "Weather", "time_of_day": "Time of day", "split": "Split",
               "junction_kind": "Junction", "log_id": "Log", "tags": "Step", "has_camera": "seen by the camera",
               "at_intersection": "at an intersection", "on_crosswalk": "on a crosswalk", "blocked_by": "blocked",
               "braking_for": "braking for a leader", "keeping_lane": "keeping its lane",
               "left_lane_change": "lane change left", "right_lane_change": "lane change right"}
#: Example queries offered on the landing page when the index holds moments their programs select.
EXAMPLE_QUERIES = (
    "a car in the left lane approaches, then moves into the ego lane",
    "a pedestrian crossing in front of the ego vehicle",
    "a vehicle turning left at an intersection",
    "a car braking ahead of the ego vehicle",
    "a parked car on the right",
    "a cyclist",
    "a bus",
    "the ego vehicle stopped",
)


def field_name(field: str) -> str:
    return FIELD_NAMES.get(field, field.replace("_", " "))


def action_of(row: Mapping[str, Any]) -> str:
    """A clip's action, to colour the map by: its first own action that holds (:data:`ACTION_FIELDS`), else
    the lane and motion of the first step of its tag sequence, else ``other``."""
    for name in ACTION_FIELDS:
        if row.get(name) is True:
            return field_name(name)
    tags = row.get("tags") or ()
    if tags:
        lane, motion, _action, _context = split_neighbor_tag(str(tags[0]))
        return tag_label(f"{lane}:{motion}")
    return "other"


def short_log_names(log_ids: Sequence[str]) -> dict[str, str]:
    """``log 3 · 5620d013`` for each log id, numbered in sorted order."""
    return {log_id: f"log {i} · {log_id[:8]}" for i, log_id in enumerate(sorted(log_ids), start=1)}


def field_summary(table: pa.Table) -> dict[str, Any]:
    """Menus (value → count, with a readable name), switches (boolean fields → clips where true) and the
    index summary, from a metadata table."""
    names = set(table.column_names)
    menus: dict[str, Any] = {}
    for f in MENU_FIELDS:
        if f not in names:
            continue
        counts = Counter(str(v) for v in table.column(f).to_pylist() if v is not None)
        labels = short_log_names(list(counts)) if f == "log_id" else {v: v.replace("_", " ") for v in counts}
        menus[f] = {"name": field_name(f), "values": [{"value": v, "label": labels[v], "count": c}
                                                     for v, c in sorted(counts.items())]}
    if "tags" in names:
        counts = Counter(t for row in table.column("tags").to_pylist() for t in dict.fromkeys(row or ()))
        menus["tags"] = {"name": field_name("tags"), "values": [
            {"value": t, "label": tag_label(t), "count": c} for t, c in sorted(counts.items(), key=lambda kv: -kv[1])]}
    switches = []
    for f in (*ACTION_FIELDS, *PLACE_FIELDS):
        if f in names and pa.types.is_boolean(table.schema.field(f).type):
            true = int(np.count_nonzero(np.asarray(table.column(f).fill_null(False).to_numpy(zero_copy_only=False))))
            switches.append({"field": f, "label": field_name(f), "count": true,
                             "kind": "action" if f in ACTION_FIELDS else "place"})
    categories = menus.get("category", {}).get("values", [])
    summary = {"clips": table.num_rows, "logs": len(menus.get("log_id", {}).get("values", [])),
               "categories": {c["value"]: c["count"] for c in categories},
               "splits": {c["value"]: c["count"] for c in menus.get("split", {}).get("values", [])}}
    return {"menus": menus, "switches": switches, "summary": summary}


def log_spans_from_clips(table: pa.Table) -> dict[str, LogSpan]:
    """Each log's span as its indexed moments cover it (earliest start to latest end): the stand-in for logs
    whose rendered frames are not at hand."""
    out: dict[str, LogSpan] = {}
    logs = table.column("log_id").to_pylist()
    for log_id, start, end in zip(logs, table.column("start_ns").to_pylist(), table.column("end_ns").to_pylist()):
        span = out.get(log_id)
        out[log_id] = LogSpan(min(start, span.first_ns) if span else start, max(end, span.last_ns) if span else end)
    return out


def examples(table: pa.Table, selects: Callable[[str], bool], limit: int = 6) -> list[str]:
    """Example queries for the landing page: those of :data:`EXAMPLE_QUERIES` that ``selects`` (whether the
    query's program selects indexed moments), then the index's most common object sentences."""
    out = [q for q in EXAMPLE_QUERIES if selects(q)][: limit - 2]
    if "caption" in table.column_names:
        common = Counter(object_sentence(str(c or "")).rstrip(".") for c in table.column("caption").to_pylist())
        for sentence, _count in common.most_common(limit):
            if len(out) >= limit:
                break
            if sentence and sentence.lower() not in {q.lower() for q in out}:
                out.append(sentence[0].lower() + sentence[1:])
    return out


def pca_2d(x: np.ndarray) -> np.ndarray:
    """(N, 2) projection of (N, D) rows on their first two principal components, scaled into [0, 1]."""
    x = np.asarray(x, dtype=np.float64)
    centred = x - x.mean(axis=0, keepdims=True)
    _, vectors = np.linalg.eigh(centred.T @ centred)  # (D, D): ascending eigenvalues
    xy = centred @ vectors[:, ::-1][:, :2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    return np.asarray((xy - lo) / np.where(hi > lo, hi - lo, 1.0))


def embedding_map(table: pa.Table, x: np.ndarray, max_actions: int = 9) -> dict[str, Any]:
    """The map's points: (x, y) in [0, 1], an action index (the ``max_actions`` most common actions, then
    ``other``) and a category index per clip, with the clip ids in the same order."""
    rows = table.select([c for c in table.column_names if c in {"tags", "category", *ACTION_FIELDS}]).to_pylist()
    actions = [action_of(r) for r in rows]
    common = [a for a, _ in Counter(actions).most_common(max_actions) if a != "other"][:max_actions]
    names = [*common, "other"]
    index = {a: i for i, a in enumerate(names)}
    categories = sorted({str(r.get("category")) for r in rows})
    cat_index = {c: i for i, c in enumerate(categories)}
    xy = pca_2d(x) if len(x) > 2 else np.full((len(x), 2), 0.5)
    action_ids = [index.get(a, len(names) - 1) for a in actions]
    points = [[round(float(px), 4), round(float(py), 4), a, cat_index[str(r.get("category"))]]
              for (px, py), a, r in zip(xy, action_ids, rows)]
    return {"actions": names, "action_counts": [action_ids.count(i) for i in range(len(names))],
            "categories": categories, "clip_ids": table.column("clip_id").to_pylist(), "points": points}
