"""The multi-object tracker and the log-level entry point.

Per frame: predict every track, associate predictions with detections by the Hungarian algorithm
(one assignment over all categories, with cross-category pairs forbidden), update matched tracks,
age unmatched ones, and start tracks from unmatched detections.

Logs are processed offline, so once a track is confirmed (``min_hits`` matches) its whole history
is reported, including the frames before confirmation; a track never confirmed is dropped as a
false positive.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

import scenes.tracking.kalman as kalman
from scenes.categories import CATEGORY_TO_AV2, Category
from scenes.errors import ImportFormatError
from scenes.geometry import FloatArray, wrap_angle_rad
from scenes.tracking.config import Association, TrackerConfig
from scenes.tracking.detections import Detections
from scenes.tracks import Annotations, EgoTrajectory

#: Cost of a forbidden pair (other category, or outside the gate); any real cost is ≤ 1.
_FORBIDDEN = 1e6


@dataclass
class _TrackSet:
    """The live tracks, as parallel arrays."""

    states: FloatArray = field(default_factory=lambda: np.zeros((0, kalman.STATE_DIM)))
    covariances: FloatArray = field(default_factory=lambda: np.zeros((0, kalman.STATE_DIM, kalman.STATE_DIM)))
    ids: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    categories: NDArray[np.str_] = field(default_factory=lambda: np.zeros(0, np.str_))
    hits: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    misses: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))

    def keep(self, mask: NDArray[np.bool_]) -> None:
        self.states, self.covariances = self.states[mask], self.covariances[mask]
        self.ids, self.categories = self.ids[mask], self.categories[mask]
        self.hits, self.misses = self.hits[mask], self.misses[mask]


@dataclass(frozen=True)
class TrackedBox:
    """One reported box: a track's filtered state at a frame (city frame)."""

    track_id: int
    frame_index: int
    category: str
    box_city: FloatArray  # (7,) x y z yaw l w h


def bev_iou(boxes_a: FloatArray, boxes_b: FloatArray) -> FloatArray:
    """Bird's-eye-view IoU of rotated boxes, all pairs.

    Args:
        boxes_a: (N, 7) boxes ``x y z yaw l w h``.
        boxes_b: (M, 7) boxes.

    Returns:
        (N, M) IoU in [0, 1]; pairs whose circumscribed circles do not meet are 0 without a
        polygon intersection.
    """
    import cv2

    n, m = boxes_a.shape[0], boxes_b.shape[0]
    iou = np.zeros((n, m))
    if n == 0 or m == 0:
        return iou
    radius_a = 0.5 * np.hypot(boxes_a[:, 4], boxes_a[:, 5])
    radius_b = 0.5 * np.hypot(boxes_b[:, 4], boxes_b[:, 5])
    dist = np.linalg.norm(boxes_a[:, None, :2] - boxes_b[None, :, :2], axis=2)
    near = dist < radius_a[:, None] + radius_b[None, :]
    area_a = boxes_a[:, 4] * boxes_a[:, 5]
    area_b = boxes_b[:, 4] * boxes_b[:, 5]
    for i, j in zip(*np.nonzero(near)):
        ra = ((boxes_a[i, 0], boxes_a[i, 1]), (boxes_a[i, 4], boxes_a[i, 5]), np.degrees(boxes_a[i, 3]))
        rb = ((boxes_b[j, 0], boxes_b[j, 1]), (boxes_b[j, 4], boxes_b[j, 5]), np.degrees(boxes_b[j, 3]))
        kind, pts = cv2.rotatedRectangleIntersection(ra, rb)
        if kind == cv2.INTERSECT_NONE or pts is None:
            continue
        inter = float(cv2.contourArea(cv2.convexHull(pts)))
        iou[i, j] = inter / max(area_a[i] + area_b[j] - inter, 1e-9)
    return iou


class Tracker:
    """Frame-by-frame tracker. Feed frames in time order with :meth:`step`; read :meth:`finish`."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config or TrackerConfig()
        self._tracks = _TrackSet()
        self._next_id = 0
        self._last_time_ns: int | None = None
        self._frame_index = -1
        # Per frame, the boxes reported then: (track ids (n,), categories (n,), boxes (n, 7)).
        self._history: list[tuple[int, NDArray[np.int64], NDArray[np.str_], FloatArray]] = []
        self._confirmed: set[int] = set()

    def _cost(self, predicted: FloatArray, categories: NDArray[np.str_], boxes: FloatArray,
              det_categories: NDArray[np.str_]) -> FloatArray:
        """(N_tracks, N_dets) costs in [0, 1] for admissible pairs, :data:`_FORBIDDEN` otherwise."""
        cfg = self.config
        if cfg.association is Association.DISTANCE:
            dist = np.linalg.norm(predicted[:, None, :2] - boxes[None, :, :2], axis=2)
            names, inverse = np.unique(det_categories, return_inverse=True)
            gates = np.array([cfg.gate_m(str(c)) for c in names])[inverse]
            cost = dist / gates[None, :]
            cost[cost > 1.0] = _FORBIDDEN
        else:
            iou = bev_iou(predicted[:, :7], boxes)
            cost = 1.0 - iou
            cost[iou < cfg.min_bev_iou] = _FORBIDDEN
        if cfg.per_category:
            cost[categories[:, None] != det_categories[None, :]] = _FORBIDDEN
        return cost

    def step(self, timestamp_ns: int, boxes_city: FloatArray, categories: NDArray[np.str_]) -> None:
        """Advance to a frame and fuse its detections.

        Args:
            timestamp_ns: the frame's time; must increase from call to call.
            boxes_city: (M, 7) detections ``x y z yaw l w h`` in the city frame (may be empty).
            categories: (M,) public categories of the detections.
        """
        cfg = self.config
        if self._last_time_ns is not None and timestamp_ns <= self._last_time_ns:
            raise ValueError(f"frames must be in increasing time order: {timestamp_ns} after {self._last_time_ns}")
        dt_s = 0.1 if self._last_time_ns is None else (timestamp_ns - self._last_time_ns) * 1e-9
        self._last_time_ns = timestamp_ns
        self._frame_index += 1
        tr = self._tracks
        if len(tr.ids):
            tr.states, tr.covariances = kalman.predict(tr.states, tr.covariances, dt_s, cfg)
        matched_trk = np.zeros(0, np.int64)
        matched_det = np.zeros(0, np.int64)
        if len(tr.ids) and boxes_city.shape[0]:
            cost = self._cost(tr.states, tr.categories, boxes_city, categories)
            rows, cols = linear_sum_assignment(cost)
            ok = cost[rows, cols] < _FORBIDDEN
            matched_trk, matched_det = rows[ok], cols[ok]
        if matched_trk.size:
            meas = boxes_city[matched_det].copy()
            meas[:, kalman.YAW] = kalman.align_yaw(meas[:, kalman.YAW], tr.states[matched_trk, kalman.YAW])
            tr.states[matched_trk], tr.covariances[matched_trk] = kalman.update(
                tr.states[matched_trk], tr.covariances[matched_trk], meas, cfg
            )
        updated = np.zeros(len(tr.ids), dtype=bool)
        updated[matched_trk] = True
        tr.hits[updated] += 1
        confirmed = updated & (tr.hits >= cfg.min_hits)
        if confirmed.any():
            tr.states[confirmed] = kalman.heading_from_motion(tr.states[confirmed], cfg.heading_min_speed_mps)
        tr.misses[updated] = 0
        tr.misses[~updated] += 1
        self._record(tr.ids[updated], tr.categories[updated], tr.states[updated, :7], tr.hits[updated])
        tr.keep(tr.misses <= cfg.max_age)
        # Births from detections no track claimed.
        unmatched = np.ones(boxes_city.shape[0], dtype=bool)
        unmatched[matched_det] = False
        if unmatched.any():
            new_boxes = boxes_city[unmatched]
            states, covs = kalman.initial_states(new_boxes, cfg)
            new_ids = np.arange(self._next_id, self._next_id + new_boxes.shape[0], dtype=np.int64)
            self._next_id += new_boxes.shape[0]
            tr.states = np.concatenate([tr.states, states])
            tr.covariances = np.concatenate([tr.covariances, covs])
            tr.ids = np.concatenate([tr.ids, new_ids])
            tr.categories = np.concatenate([tr.categories, categories[unmatched].astype(np.str_)])
            tr.hits = np.concatenate([tr.hits, np.ones(new_boxes.shape[0], np.int64)])
            tr.misses = np.concatenate([tr.misses, np.zeros(new_boxes.shape[0], np.int64)])
            self._record(new_ids, categories[unmatched].astype(np.str_), new_boxes,
                         np.ones(new_boxes.shape[0], np.int64))

    def _record(self, ids: NDArray[np.int64], categories: NDArray[np.str_], boxes: FloatArray,
                hits: NDArray[np.int64]) -> None:
        """Remember the boxes reported at this frame. ``boxes``: (n, 7); the others (n,)."""
        if ids.size:
            self._history.append((self._frame_index, ids.copy(), categories.copy(), boxes.copy()))
            self._confirmed.update(ids[hits >= self.config.min_hits].tolist())

    def finish(self) -> list[TrackedBox]:
        """Every reported box of every confirmed track, ordered by frame then track.

        With ``fill_gaps``, frames a track missed between two matches are filled by interpolation.
        """
        confirmed = np.array(sorted(self._confirmed), dtype=np.int64)
        out: list[TrackedBox] = []
        for frame_index, ids, categories, boxes in self._history:
            keep = np.isin(ids, confirmed)
            order = np.argsort(ids[keep], kind="stable")
            out.extend(TrackedBox(int(t), frame_index, str(c), b)
                       for t, c, b in zip(ids[keep][order], categories[keep][order], boxes[keep][order]))
        if self.config.fill_gaps:
            out.extend(_interpolate_gaps(out, self.config.max_age))
        return sorted(out, key=lambda b: (b.frame_index, b.track_id))


def _interpolate_gaps(boxes: list[TrackedBox], max_gap: int) -> list[TrackedBox]:
    """Boxes for the frames inside each track's gaps of at most ``max_gap`` frames."""
    by_track: dict[int, list[TrackedBox]] = {}
    for box in boxes:
        by_track.setdefault(box.track_id, []).append(box)
    filled = []
    for track in by_track.values():
        track.sort(key=lambda b: b.frame_index)
        for before, after in zip(track, track[1:]):
            gap = after.frame_index - before.frame_index - 1
            if not 0 < gap <= max_gap:
                continue
            for k in range(1, gap + 1):
                w = k / (gap + 1)
                box_city = (1 - w) * before.box_city + w * after.box_city
                box_city[3] = before.box_city[3] + w * wrap_angle_rad(after.box_city[3] - before.box_city[3])
                filled.append(TrackedBox(before.track_id, before.frame_index + k, before.category, box_city))
    return filled


def track_detections(
    detections: Detections,
    ego: EgoTrajectory,
    config: TrackerConfig | None = None,
    frame_timestamps_ns: NDArray[np.integer] | None = None,
    source: Path | str = "detections",
    pose_tolerance_ns: int = 200_000_000,
) -> Annotations:
    """Track a log's detections and return annotations in the log contract (ego frame).

    Args:
        detections: boxes in the ego frame of their timestamps.
        ego: ``city_SE3_ego`` covering the detection timestamps.
        config: tracker parameters.
        frame_timestamps_ns: (F,) all frames of the log, including frames with no detection
            (tracks age through them); defaults to the detections' own timestamps.
        source: file name for error messages.
        pose_tolerance_ns: how far outside the pose stream a detection may lie.

    Raises:
        ImportFormatError: a detection's timestamp has no ego pose (names the line).
    """
    cfg = config or TrackerConfig()
    dets = detections.select(detections.score >= cfg.score_threshold)
    lo, hi = int(ego.timestamps_ns[0]) - pose_tolerance_ns, int(ego.timestamps_ns[-1]) + pose_tolerance_ns
    outside = (detections.timestamp_ns < lo) | (detections.timestamp_ns > hi)
    if outside.any():
        i = int(np.argmax(outside))
        raise ImportFormatError(source, f"timestamp {int(detections.timestamp_ns[i])} has no ego pose",
                                line=int(detections.source_line[i]), field="timestamp_ns")
    frames = np.unique(np.concatenate([
        dets.timestamp_ns, np.zeros(0, np.int64) if frame_timestamps_ns is None else np.asarray(frame_timestamps_ns)
    ])).astype(np.int64)
    if frames.size == 0:
        return Annotations.empty()
    ego_at = ego.interpolate(frames)
    rot, trans, ego_yaw = ego_at.rotation, ego_at.translation_m, ego_at.yaw_rad
    frame_of_det = np.searchsorted(frames, dets.timestamp_ns)
    # Detections into the city frame, where objects move at constant velocity (ego motion removed).
    center_city = np.einsum("nij,nj->ni", rot[frame_of_det], dets.center_xyz_m) + trans[frame_of_det]
    yaw_city = wrap_angle_rad(dets.yaw_rad + ego_yaw[frame_of_det])
    boxes_city = np.concatenate([center_city, yaw_city[:, None], dets.size_lwh_m], axis=1)
    tracker = Tracker(cfg)
    bounds = np.searchsorted(frame_of_det, np.arange(frames.size + 1))
    for f in range(frames.size):
        sel = slice(bounds[f], bounds[f + 1])
        tracker.step(int(frames[f]), boxes_city[sel], dets.category[sel])
    boxes = tracker.finish()
    if not boxes:
        return Annotations.empty()
    frame_idx = np.array([b.frame_index for b in boxes])
    box_city = np.stack([b.box_city for b in boxes])
    # Back into the ego frame of each box's frame: p_ego = Rᵀ (p_city − t).
    rel = box_city[:, :3] - trans[frame_idx]
    center_ego = np.einsum("nji,nj->ni", rot[frame_idx], rel)
    yaw_ego = wrap_angle_rad(box_city[:, 3] - ego_yaw[frame_idx])
    raw = [CATEGORY_TO_AV2[Category(b.category)] for b in boxes]
    return Annotations.from_yaw(
        timestamp_ns=frames[frame_idx],
        track_id=[f"track-{b.track_id:06d}" for b in boxes],
        category=raw,
        center_xyz_m=center_ego,
        size_lwh_m=box_city[:, 4:7],
        yaw_rad=yaw_ego,
    ).sorted()
