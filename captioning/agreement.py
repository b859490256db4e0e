"""Agreement of the rule-based tags with a simulator's behaviour labels.

Two checks, per labelled *event* (a contiguous run of frames where a label holds for one track):

- **Neighbour lane changes** (``left_lane_change`` / ``right_lane_change`` of a non-ego track):
  within the event widened by ``margin_frames`` on both sides, the track's per-frame lane tags,
  restricted to the same-direction lanes ``right < host < left``, should change at least once
  (*transition*), and at least once in the labelled direction (*directed*: a left change of a
  same-direction neighbour moves it toward ``left`` in the ego frame). Events where the track carries
  fewer than two same-direction lane tags (oncoming, crossing, stationary or unseen) are not evaluable.
  Three lane classes cannot show a change between two lanes on the same side of the host (e.g. two
  and one lanes to the left), so the events whose lateral offset crosses a host-band edge
  (``±host_lane_half_width_m``) are also counted apart (*band crossing*).
- **Ego turns** (``left_turn`` / ``right_turn`` of the ego): the host direction tags inside the
  event should include ``steering_left`` / ``steering_right``.

And per frame, the **own-behaviour tags** (:mod:`captioning.behavior`) against the labels of the same
name: F1, precision and recall per label over the object frames that carry both a label row and a
computed tag (:func:`behavior_counts`, :func:`behavior_counts_for_logs`). Objects under a new id after
a tracker's id switch have no label rows and are left out.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from captioning.behavior import LABELS
from captioning.config import CaptioningConfig, RuleSet
from captioning.pipeline import EGO_TRACK_ID, LogCaptions, caption_log
from captioning.tags import HOST_DIRECTIONS, LANES, NO_TAG, HostDirection, Lane

#: Same-direction lanes ordered from right to left in the ego frame.
_ORDER = {LANES.index(Lane.RIGHT): 0, LANES.index(Lane.HOST): 1, LANES.index(Lane.LEFT): 2}


def _rate(agreeing: int, events: int) -> float:
    """Share of ``events`` that the tags agree with; NaN without events."""
    return agreeing / events if events else float("nan")


@dataclass(frozen=True)
class AgreementReport:
    """Counts of labelled events and how many the tags agree with."""

    lane_change_events: int = 0
    lane_change_evaluable: int = 0
    lane_change_transition: int = 0
    lane_change_directed: int = 0
    band_crossing_events: int = 0
    band_crossing_transition: int = 0
    ego_turn_events: int = 0
    ego_turn_steering: int = 0

    @property
    def lane_change_rate(self) -> float:
        """Share of evaluable lane-change events whose lane tags change (NaN if none)."""
        return _rate(self.lane_change_transition, self.lane_change_evaluable)

    @property
    def lane_change_directed_rate(self) -> float:
        """Share of evaluable lane-change events whose lane tags move the labelled way (NaN if none)."""
        return _rate(self.lane_change_directed, self.lane_change_evaluable)

    @property
    def band_crossing_rate(self) -> float:
        """Share of band-crossing lane changes whose lane tags change (NaN if none)."""
        return _rate(self.band_crossing_transition, self.band_crossing_events)

    @property
    def ego_turn_rate(self) -> float:
        """Share of ego turns whose host tags steer the labelled way (NaN if none)."""
        return _rate(self.ego_turn_steering, self.ego_turn_events)

    def __add__(self, other: AgreementReport) -> AgreementReport:
        a, b = asdict(self), asdict(other)
        return AgreementReport(**{key: a[key] + b[key] for key in a})

    def to_dict(self) -> dict[str, float]:
        out: dict[str, float] = dict(asdict(self))
        out.update(
            lane_change_rate=self.lane_change_rate,
            lane_change_directed_rate=self.lane_change_directed_rate,
            band_crossing_rate=self.band_crossing_rate,
            ego_turn_rate=self.ego_turn_rate,
        )
        return out


def _events(flags: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(T,) booleans → inclusive (start, end) runs of True."""
    padded = np.r_[False, flags, False].astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(s), int(e) - 1) for s, e in zip(edges[::2], edges[1::2])]


def _label_grid(result: LogCaptions, labels: pa.Table, track_id: str, column: str) -> NDArray[np.bool_]:
    """(T,) the label on the result's frame grid (False where the track has no label row)."""
    mask = np.asarray(labels.column("track_id").to_numpy(zero_copy_only=False) == track_id)
    ts = np.asarray(labels.column("timestamp_ns").to_numpy())[mask]
    flag = np.asarray(labels.column(column).to_numpy(zero_copy_only=False), dtype=bool)[mask]
    grid = np.zeros(result.timestamps_ns.shape[0], dtype=bool)
    idx = np.searchsorted(result.timestamps_ns, ts)
    ok = (idx < grid.shape[0]) & (result.timestamps_ns[np.minimum(idx, grid.shape[0] - 1)] == ts)
    grid[idx[ok]] = flag[ok]
    return grid


def agreement(
    result: LogCaptions, labels: pa.Table, margin_frames: int = 10, host_lane_half_width_m: float = 1.85
) -> AgreementReport:
    """Compare one captioned log with its behaviour labels (``scenes.behavior`` table).

    ``host_lane_half_width_m`` should be the value the log was captioned with.
    """
    t = result.timestamps_ns.shape[0]
    counts = dict.fromkeys(asdict(AgreementReport()), 0)
    labelled = set(labels.column("track_id").to_pylist())
    for k, track_id in enumerate(result.track_ids.tolist()):
        if track_id not in labelled:
            continue
        for column, step in (("left_lane_change", +1), ("right_lane_change", -1)):
            for start, end in _events(_label_grid(result, labels, track_id, column)):
                counts["lane_change_events"] += 1
                lo, hi = max(start - margin_frames, 0), min(end + margin_frames, t - 1)
                window = result.neighbors.lane[k, lo : hi + 1].tolist()
                same_direction = [i for i, c in enumerate(window) if c in _ORDER]
                if len(same_direction) < 2:
                    continue
                lanes = [_ORDER[window[i]] for i in same_direction]
                counts["lane_change_evaluable"] += 1
                steps = np.diff(lanes)
                changed = int(bool((steps != 0).any()))
                counts["lane_change_transition"] += changed
                y_m = result.center_ego_xy_m[k, lo + np.array(same_direction), 1]
                edges = (-host_lane_half_width_m, host_lane_half_width_m)
                if any(y_m.min() < edge < y_m.max() for edge in edges):
                    counts["band_crossing_events"] += 1
                    counts["band_crossing_transition"] += changed
                counts["lane_change_directed"] += int(bool((np.sign(steps) == step).any()))
    if EGO_TRACK_ID in labelled:
        turns = (("left_turn", HostDirection.STEERING_LEFT), ("right_turn", HostDirection.STEERING_RIGHT))
        for column, direction in turns:
            code = HOST_DIRECTIONS.index(direction)
            for start, end in _events(_label_grid(result, labels, EGO_TRACK_ID, column)):
                counts["ego_turn_events"] += 1
                window = result.host_direction[start : end + 1]
                counts["ego_turn_steering"] += int(bool((window[window != NO_TAG] == code).any()))
    return AgreementReport(**counts)


def agreement_for_logs(log_dirs: Iterable[Path | str], config: CaptioningConfig | None = None) -> AgreementReport:
    """Caption simulated logs and sum their agreement with ``behavior_labels.feather``.

    Logs without labels (real logs) add nothing.
    """
    from scenes.behavior import read_behavior_labels
    from scenes.log import Log

    config = config or CaptioningConfig()
    total = AgreementReport()
    for log_dir in log_dirs:
        labels = read_behavior_labels(log_dir)
        if labels is None:
            continue
        result = caption_log(Log.open(log_dir), config)
        total = total + agreement(result, labels, host_lane_half_width_m=config.neighbor.host_lane_half_width_m)
    return total


def label_grid(labels: pa.Table, timestamps_ns: NDArray[np.int64], track_ids: NDArray[np.str_]
               ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Behaviour labels on a log's (K, T) grid.

    Args:
        labels: the ``scenes.behavior`` table.
        timestamps_ns: (T,) the frame grid.
        track_ids: (K,) the tracks.

    Returns:
        (K, T, len(LABELS)) label values and (K, T) whether the cell has a label row.
    """
    k, t = len(track_ids), len(timestamps_ns)
    flags = np.zeros((k, t, len(LABELS)), dtype=bool)
    labelled = np.zeros((k, t), dtype=bool)
    if k == 0 or t == 0 or labels.num_rows == 0:
        return flags, labelled
    ts = np.asarray(labels.column("timestamp_ns").to_numpy())
    ids = np.asarray(labels.column("track_id").to_numpy(zero_copy_only=False)).astype(str)
    order = np.argsort(np.asarray(track_ids).astype(str))
    sorted_ids = np.asarray(track_ids).astype(str)[order]
    pos = np.clip(np.searchsorted(sorted_ids, ids), 0, k - 1)
    row = order[pos]
    col = np.clip(np.searchsorted(timestamps_ns, ts), 0, t - 1)
    ok = (sorted_ids[pos] == ids) & (timestamps_ns[col] == ts)
    values = np.stack([np.asarray(labels.column(label.value).to_numpy(zero_copy_only=False), dtype=bool)
                       for label in LABELS], axis=1)
    flags[row[ok], col[ok]] = values[ok]
    labelled[row[ok], col[ok]] = True
    return flags, labelled


@dataclass(frozen=True)
class BehaviorCounts:
    """True positives, false positives and false negatives per label (in :data:`~captioning.behavior.LABELS` order)."""

    tp: tuple[int, ...] = (0,) * len(LABELS)
    fp: tuple[int, ...] = (0,) * len(LABELS)
    fn: tuple[int, ...] = (0,) * len(LABELS)

    def __add__(self, other: BehaviorCounts) -> BehaviorCounts:
        return BehaviorCounts(*(tuple(a + b for a, b in zip(x, y)) for x, y in
                                ((self.tp, other.tp), (self.fp, other.fp), (self.fn, other.fn))))

    def f1(self) -> dict[str, float]:
        """Label → F1 (NaN for a label that is never true and never tagged)."""
        return {label.value: (2 * tp / (2 * tp + fp + fn) if tp + fp + fn else float("nan"))
                for label, tp, fp, fn in zip(LABELS, self.tp, self.fp, self.fn)}

    def to_dict(self) -> dict[str, dict[str, float]]:
        """Label → ``{"f1", "precision", "recall", "positives"}``."""
        out: dict[str, dict[str, float]] = {}
        for (name, f1), tp, fp, fn in zip(self.f1().items(), self.tp, self.fp, self.fn):
            out[name] = {"f1": round(f1, 3), "precision": round(tp / (tp + fp), 3) if tp + fp else float("nan"),
                         "recall": round(tp / (tp + fn), 3) if tp + fn else float("nan"), "positives": tp + fn}
        return out


def behavior_counts(result: LogCaptions, labels: pa.Table) -> BehaviorCounts:
    """Own-behaviour tags of a log (captioned under ``rules: behavior``) against its behaviour labels."""
    beh = result.behavior
    if beh is None:
        raise ValueError(f"log {result.log_id} was captioned under rules: paper; own behaviour needs rules: behavior")
    truth, labelled = label_grid(labels, result.timestamps_ns, result.track_ids)
    scored = labelled[..., None] & beh.known
    tagged = beh.flags & scored
    true = truth & scored
    return BehaviorCounts(tuple(int(x) for x in (tagged & true).sum(axis=(0, 1))),
                          tuple(int(x) for x in (tagged & ~true).sum(axis=(0, 1))),
                          tuple(int(x) for x in (~tagged & true).sum(axis=(0, 1))))


def behavior_counts_for_logs(
    log_dirs: Iterable[Path | str], config: CaptioningConfig | None = None
) -> BehaviorCounts:
    """Caption simulated logs under ``rules: behavior`` and sum :func:`behavior_counts` (logs without
    labels add nothing)."""
    from dataclasses import replace

    from scenes.behavior import read_behavior_labels
    from scenes.log import Log

    config = replace(config or CaptioningConfig(), rules=RuleSet.BEHAVIOR)
    total = BehaviorCounts()
    for log_dir in log_dirs:
        labels = read_behavior_labels(log_dir)
        if labels is None:
            continue
        total = total + behavior_counts(caption_log(Log.open(log_dir), config), labels)
    return total
