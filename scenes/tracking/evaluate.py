"""Tracking metrics of a predicted log against a ground-truth log, by category.

CLEAR-MOT (MOTA, MOTP) and IDF1 come from the ``motmetrics`` library. Boxes are matched by the
planar distance of their centres in the city frame, up to a threshold (default 2 m); MOTP is
the mean distance of matched pairs in metres (lower is better). Frames are matched by timestamp.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from scenes.categories import Category
from scenes.tracks import Annotations, EgoTrajectory, tracks_from_annotations

#: Categories reported by default: the classes of KITTI's tracking benchmark.
DEFAULT_CATEGORIES = (Category.CAR, Category.PEDESTRIAN, Category.CYCLIST)

METRICS = ("mota", "motp", "idf1", "num_switches", "num_false_positives", "num_misses", "num_objects", "precision",
           "recall", "mostly_tracked", "num_unique_objects")
_PUBLIC_NAMES = {"mota": "MOTA", "motp": "MOTP", "idf1": "IDF1", "num_switches": "IDSW",
                 "num_false_positives": "FP", "num_misses": "FN", "num_objects": "GT", "precision": "precision",
                 "recall": "recall", "mostly_tracked": "MT", "num_unique_objects": "GT_tracks"}


def _per_frame(
    annotations: Annotations, ego: EgoTrajectory, category: Category
) -> dict[int, tuple[list[int], np.ndarray]]:
    """Per timestamp: integer track numbers (motmetrics wants numbers) and (N, 2) city-frame centres."""
    frames: dict[int, tuple[list[int], list[np.ndarray]]] = {}
    tracks = [t for t in tracks_from_annotations(annotations, ego).values() if t.category is category]
    for number, track in enumerate(tracks):
        for ts, xy in zip(track.timestamps_ns, track.center_city_xyz_m[:, :2]):
            ids, pts = frames.setdefault(int(ts), ([], []))
            ids.append(number)
            pts.append(xy)
    return {ts: (ids, np.asarray(pts).reshape(-1, 2)) for ts, (ids, pts) in frames.items()}


def evaluate_tracking(
    pred: Annotations,
    pred_ego: EgoTrajectory,
    gt: Annotations,
    gt_ego: EgoTrajectory,
    max_distance_m: float = 2.0,
    categories: tuple[Category, ...] = DEFAULT_CATEGORIES,
) -> dict[str, dict[str, Any]]:
    """MOTA, MOTP, IDF1 and counts per public category.

    Args:
        pred: predicted tracks.
        pred_ego: the predicted log's ego poses.
        gt: ground-truth tracks.
        gt_ego: the ground-truth log's ego poses.
        max_distance_m: largest centre distance of a match.
        categories: categories to report.

    Returns:
        ``{category: {"MOTA": x, "MOTP": x, "IDF1": x, "IDSW": n, "FP": n, "FN": n, "GT": n, …}}``;
        categories without ground truth are left out.
    """
    import motmetrics as mm

    if max_distance_m <= 0:
        raise ValueError(f"max_distance_m must be positive, got {max_distance_m}")
    frames = np.union1d(gt.timestamps_ns, pred.timestamps_ns)
    out: dict[str, dict[str, Any]] = {}
    for category in categories:
        gt_frames = _per_frame(gt, gt_ego, category)
        if not gt_frames:
            continue
        pred_frames = _per_frame(pred, pred_ego, category)
        acc = mm.MOTAccumulator(auto_id=True)
        empty: tuple[list[int], np.ndarray] = ([], np.zeros((0, 2)))
        for ts in frames:
            gt_ids, gt_xy = gt_frames.get(int(ts), empty)
            pr_ids, pr_xy = pred_frames.get(int(ts), empty)
            dist = np.linalg.norm(gt_xy[:, None, :] - pr_xy[None, :, :], axis=2)
            dist[dist > max_distance_m] = np.nan  # motmetrics: NaN = cannot match
            acc.update(gt_ids, pr_ids, dist)
        summary = mm.metrics.create().compute(acc, metrics=list(METRICS), name=category.value)
        row = summary.iloc[0]
        figures: dict[str, Any] = {}
        for key in METRICS:
            value = row[key]
            figures[_PUBLIC_NAMES[key]] = int(value) if key.startswith("num_") or key == "mostly_tracked" else (
                None if not np.isfinite(value) else round(float(value), 4))
        out[category.value] = figures
    return out
