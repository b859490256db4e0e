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
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from captioning.config import CaptioningConfig
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
