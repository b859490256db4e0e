"""How much captions change when tracks come from a tracker instead of ground truth.

Both logs are captioned with the same rules. Ground-truth tracks are matched to predicted tracks
frame by frame (Hungarian assignment on the planar distance of city-frame centres, up to a
threshold). Then, for every ground-truth neighbour caption:

- its predicted counterpart is the track matched to it in most frames of the caption's window;
- that track's caption is the one whose window overlaps the ground truth's most in time
  (temporal IoU ≥ 0.5, otherwise the caption has no counterpart);
- the two agree when their unified tag sequences are identical.

Frame-level agreement compares the lane and motion tags of matched (track, frame) pairs where
both carry tags.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from captioning.config import CaptioningConfig
from captioning.pipeline import Caption, LogCaptions, caption_log
from scenes.log import Log

EGO = "ego"


@dataclass(frozen=True)
class CaptionAgreement:
    """Agreement of captions from predicted tracks with those from ground truth.

    Attributes:
        gt_captions: ground-truth neighbour captions compared.
        matched: of those, how many have a predicted counterpart.
        sequence_agreement: share of ground-truth captions whose counterpart has the same unified
            tag sequence (captions without a counterpart count as disagreeing).
        sequence_agreement_matched: the same share among matched captions only.
        frame_pairs: matched (track, frame) pairs where both carry lane and motion tags.
        frame_lane_agreement: share of those pairs with the same lane tag.
        frame_motion_agreement: share with the same motion tag.
    """

    gt_captions: int
    matched: int
    sequence_agreement: float
    sequence_agreement_matched: float
    frame_pairs: int
    frame_lane_agreement: float
    frame_motion_agreement: float

    def to_dict(self) -> dict[str, Any]:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


def _city_xy(log: Log, result: LogCaptions) -> np.ndarray:
    """(K, T, 2) city-frame centres on the captions' grid, NaN where unobserved."""
    dense = log.dense_tracks()
    assert np.array_equal(dense.track_ids, result.track_ids), "captions and tracks disagree on track order"
    return dense.center_city_xyz_m[..., :2]


def match_tracks(
    gt_ts: np.ndarray, gt_xy: np.ndarray, pred_ts: np.ndarray, pred_xy: np.ndarray, max_distance_m: float
) -> np.ndarray:
    """Per ground-truth (track, frame), the matched predicted track index (−1 when none).

    Args:
        gt_ts: (T,) ground-truth frame timestamps.
        gt_xy: (K, T, 2) ground-truth centres, NaN where unobserved.
        pred_ts: (T',) predicted frame timestamps.
        pred_xy: (K', T', 2) predicted centres, NaN where unobserved.
        max_distance_m: the largest centre distance of a match.

    Returns:
        (K, T) indices into the predicted tracks.
    """
    out = np.full(gt_xy.shape[:2], -1, dtype=np.int64)
    pred_frame = {int(t): i for i, t in enumerate(pred_ts)}
    for t, ts in enumerate(gt_ts):
        j = pred_frame.get(int(ts))
        if j is None:
            continue
        g = np.flatnonzero(~np.isnan(gt_xy[:, t, 0]))
        p = np.flatnonzero(~np.isnan(pred_xy[:, j, 0]))
        if g.size == 0 or p.size == 0:
            continue
        dist = np.linalg.norm(gt_xy[g, t][:, None] - pred_xy[p, j][None], axis=2)
        rows, cols = linear_sum_assignment(np.where(dist <= max_distance_m, dist, 1e6))
        ok = dist[rows, cols] <= max_distance_m
        out[g[rows[ok]], t] = p[cols[ok]]
    return out


def _temporal_iou(a: Caption, b: Caption) -> float:
    inter = min(a.end_ns, b.end_ns) - max(a.start_ns, b.start_ns)
    union = max(a.end_ns, b.end_ns) - min(a.start_ns, b.start_ns)
    return max(inter, 0) / union if union > 0 else float(a.start_ns == b.start_ns)


def caption_agreement(
    pred_log: Log, gt_log: Log, config: CaptioningConfig | None = None, max_distance_m: float = 2.0
) -> CaptionAgreement:
    """Compare the captions of a tracked log with those of its ground truth (see the module docstring)."""
    config = config or CaptioningConfig()
    gt, pred = caption_log(gt_log, config), caption_log(pred_log, config)
    matches = match_tracks(gt.timestamps_ns, _city_xy(gt_log, gt), pred.timestamps_ns,
                           _city_xy(pred_log, pred), max_distance_m)
    gt_index = {str(t): i for i, t in enumerate(gt.track_ids)}
    pred_caps: dict[str, list[Caption]] = {}
    for cap in pred.captions:
        if cap.track_id != EGO:
            pred_caps.setdefault(cap.track_id, []).append(cap)
    compared = matched = agree = 0
    for cap in gt.captions:
        if cap.track_id == EGO:
            continue
        compared += 1
        k = gt_index[cap.track_id]
        in_window = (gt.timestamps_ns >= cap.start_ns) & (gt.timestamps_ns <= cap.end_ns)
        candidates = matches[k, in_window]
        candidates = candidates[candidates >= 0]
        if candidates.size == 0:
            continue
        pred_track = str(pred.track_ids[np.bincount(candidates).argmax()])
        best = max(pred_caps.get(pred_track, []), key=lambda c: _temporal_iou(c, cap), default=None)
        if best is None or _temporal_iou(best, cap) < 0.5:
            continue
        matched += 1
        agree += int(best.tags == cap.tags)
    # Frame level: matched pairs where both sides carry tags.
    pred_frame = {int(t): i for i, t in enumerate(pred.timestamps_ns)}
    g_k, g_t = np.nonzero((matches >= 0) & gt.neighbors.tagged)
    p_t = np.array([pred_frame[int(gt.timestamps_ns[t])] for t in g_t], dtype=np.int64)
    p_k = matches[g_k, g_t]
    both = pred.neighbors.tagged[p_k, p_t] if p_k.size else np.zeros(0, bool)
    g_k, g_t, p_k, p_t = g_k[both], g_t[both], p_k[both], p_t[both]
    pairs = int(g_k.size)
    lane_agree = float(np.mean(gt.neighbors.lane[g_k, g_t] == pred.neighbors.lane[p_k, p_t])) if pairs else 0.0
    motion_agree = float(np.mean(gt.neighbors.motion[g_k, g_t] == pred.neighbors.motion[p_k, p_t])) if pairs else 0.0
    return CaptionAgreement(
        gt_captions=compared,
        matched=matched,
        sequence_agreement=agree / compared if compared else 0.0,
        sequence_agreement_matched=agree / matched if matched else 0.0,
        frame_pairs=pairs,
        frame_lane_agreement=lane_agree,
        frame_motion_agreement=motion_agree,
    )
