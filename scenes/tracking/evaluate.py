"""Tracking metrics of a predicted log against a ground-truth log, by category: CLEAR-MOT, IDF1, HOTA.

Similarity. Boxes are compared by the planar distance ``d`` of their centres in the city frame
(frames matched by timestamp), turned into a similarity in [0, 1]::

    s = max(0, 1 − d / (2 · max_distance_m))

so that the 0.5 threshold of CLEAR-MOT and IDF1 in TrackEval is exactly ``d ≤ max_distance_m``
(default 2 m), and HOTA's thresholds α = 0.05, 0.10, …, 0.95 are distances from
1.9 · max_distance_m down to 0.1 · max_distance_m.

Definitions (those of TrackEval, which the KITTI benchmark uses):

- CLEAR-MOT. Per frame, a Hungarian assignment of pairs with s ≥ 0.5 that first keeps the pairs
  of the previous frame and then maximises the similarity. MOTA = 1 − (FN + FP + IDSW) / GT, where
  an ID switch is a ground-truth object matched to another predicted track than the last time it
  was matched. MOTP is reported in metres here (the mean centre distance of matched pairs; lower is
  better); LocA is its similarity form.
- IDF1 = 2 IDTP / (2 IDTP + IDFP + IDFN), with the one-to-one assignment of ground-truth to
  predicted tracks that maximises the frames they match (s ≥ 0.5).
- HOTA = mean over α of sqrt(DetA_α · AssA_α). DetA_α = TP / (TP + FN + FP) with a per-frame
  assignment that maximises similarity weighted by how well the two tracks align over the whole
  log; AssA_α = mean over TP pairs of TPA / (TPA + FNA + FPA) for that pair's two tracks. DetA, AssA
  and LocA are reported as their means over α too.

Ignore rules (:class:`IgnoreRules`, filled for KITTI by :mod:`scenes.tracking.kitti_protocol`)
are applied first, per frame and category, as TrackEval's KITTI preprocessing does: predicted and
ground-truth boxes (distractors included) are matched at s ≥ 0.5; a predicted box matched to a
distractor is dropped; an unmatched predicted box is dropped when it lies mostly inside an ignore
region or is too small in the image; then the distractors are dropped. What remains is scored.

Counts add up over logs (:meth:`TrackingCounts.__add__`), so a split is scored as one, as the
benchmarks do.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from scenes.categories import EGO_VEHICLE_LABEL, Category
from scenes.geometry import FloatArray
from scenes.tracks import Annotations, EgoTrajectory

#: Categories reported by default: the classes of KITTI's tracking benchmark.
DEFAULT_CATEGORIES = (Category.CAR, Category.PEDESTRIAN, Category.CYCLIST)

#: Similarity at which CLEAR-MOT, IDF1 and the ignore rules count a pair as a match (TrackEval's).
MATCH_SIMILARITY = 0.5
#: HOTA's localisation thresholds α: 0.05, 0.10, …, 0.95.
HOTA_ALPHAS = np.linspace(0.05, 0.95, 19)
# TrackEval compares similarities with this slack, so that s = α on a grid point counts as a match.
_EPS = float(np.finfo(float).eps)


def similarity(distance_m: NDArray[np.floating], max_distance_m: float) -> FloatArray:
    """(…) similarity ``max(0, 1 − d / (2 · max_distance_m))`` of centre distances (…)."""
    return np.maximum(0.0, 1.0 - np.asarray(distance_m, dtype=np.float64) / (2.0 * max_distance_m))


@dataclass(frozen=True)
class IgnoreRules:
    """Boxes a benchmark neither rewards nor penalises (KITTI: ``DontCare`` regions, neighbouring
    classes, truncated or occluded objects, boxes too small in the image).

    Attributes:
        gt_distractor: (N_gt,) per ground-truth row: used to absorb predictions, never counted. A
            predicted box matched to it is dropped; left unmatched it is no miss.
        pred_box_px: (N_pred, 4) image box ``x1 y1 x2 y2`` of each predicted row; zero-sized when
            the box is out of view.
        region_timestamp_ns: (M,) timestamp of each ignore region.
        region_box_px: (M, 4) ignore regions ``x1 y1 x2 y2`` in the same image.
        min_height_px: an unmatched predicted box this tall or less is dropped.
        max_region_overlap: an unmatched predicted box with more than this fraction of its area in
            one ignore region is dropped.
    """

    gt_distractor: NDArray[np.bool_]
    pred_box_px: FloatArray
    region_timestamp_ns: NDArray[np.int64]
    region_box_px: FloatArray
    min_height_px: float = 25.0
    max_region_overlap: float = 0.5

    def select(self, gt_rows: NDArray[np.bool_], pred_rows: NDArray[np.bool_]) -> IgnoreRules:
        """The rules for a subset of rows. ``gt_rows``: (N_gt,), ``pred_rows``: (N_pred,) masks."""
        return IgnoreRules(self.gt_distractor[gt_rows], self.pred_box_px[pred_rows], self.region_timestamp_ns,
                           self.region_box_px, self.min_height_px, self.max_region_overlap)


def _zeros_alpha() -> FloatArray:
    return np.zeros(HOTA_ALPHAS.size)


@dataclass(frozen=True, eq=False)
class TrackingCounts:
    """Sufficient statistics of one category over one or more logs; ``+`` pools logs.

    Attributes:
        tp, fn, fp, idsw: CLEAR-MOT counts (matches at s ≥ 0.5).
        distance_sum_m: sum of the centre distances of the CLEAR-MOT matches (for MOTP).
        gt_tracks: ground-truth tracks scored; mostly_tracked: those matched in more than 80 % of
            their frames.
        idtp, idfn, idfp: identity counts of IDF1.
        hota_tp, hota_fn, hota_fp: (19,) per-α HOTA counts.
        hota_assa_weighted: (19,) AssA_α · TP_α (pools over logs as TrackEval's weighted mean).
        hota_loca_weighted: (19,) sum of the similarities of the HOTA matches at each α.
        ignored_gt: ground-truth rows dropped as distractors.
        ignored_pred_distractor: predicted rows dropped for matching a distractor.
        ignored_pred_region: unmatched predicted rows dropped inside an ignore region.
        ignored_pred_small: unmatched predicted rows dropped as too small in the image.
    """

    tp: int = 0
    fn: int = 0
    fp: int = 0
    idsw: int = 0
    distance_sum_m: float = 0.0
    gt_tracks: int = 0
    mostly_tracked: int = 0
    idtp: int = 0
    idfn: int = 0
    idfp: int = 0
    hota_tp: FloatArray = field(default_factory=_zeros_alpha)
    hota_fn: FloatArray = field(default_factory=_zeros_alpha)
    hota_fp: FloatArray = field(default_factory=_zeros_alpha)
    hota_assa_weighted: FloatArray = field(default_factory=_zeros_alpha)
    hota_loca_weighted: FloatArray = field(default_factory=_zeros_alpha)
    ignored_gt: int = 0
    ignored_pred_distractor: int = 0
    ignored_pred_region: int = 0
    ignored_pred_small: int = 0

    def __add__(self, other: TrackingCounts) -> TrackingCounts:
        return TrackingCounts(**{f.name: getattr(self, f.name) + getattr(other, f.name) for f in fields(self)})

    @property
    def num_gt(self) -> int:
        return self.tp + self.fn

    def figures(self) -> dict[str, Any]:
        """Public figures: ``{"MOTA": x, "MOTP": metres, "IDF1": x, "HOTA": x, "DetA": x, …}``.

        Ratios without a denominator (no match, no ground truth) are None.
        """
        def ratio(num: float, den: float) -> float | None:
            return round(float(num) / float(den), 4) if den > 0 else None

        tp_a = self.hota_tp
        det_a = tp_a / np.maximum(1.0, tp_a + self.hota_fn + self.hota_fp)
        ass_a = self.hota_assa_weighted / np.maximum(1.0, tp_a)
        loc_a = np.where(tp_a > 0, self.hota_loca_weighted / np.maximum(1.0, tp_a), 1.0)  # TrackEval: 1 when empty
        hota = np.sqrt(det_a * ass_a)
        scored = self.num_gt + self.fp > 0
        return {
            "MOTA": ratio(self.num_gt - self.fn - self.fp - self.idsw, self.num_gt),
            "MOTP": ratio(self.distance_sum_m, self.tp),
            "IDF1": ratio(2 * self.idtp, 2 * self.idtp + self.idfp + self.idfn),
            "HOTA": round(float(hota.mean()), 4) if scored else None,
            "DetA": round(float(det_a.mean()), 4) if scored else None,
            "AssA": round(float(ass_a.mean()), 4) if scored else None,
            "LocA": round(float(loc_a.mean()), 4) if scored else None,
            "IDSW": self.idsw,
            "TP": self.tp,
            "FP": self.fp,
            "FN": self.fn,
            "GT": self.num_gt,
            "precision": ratio(self.tp, self.tp + self.fp),
            "recall": ratio(self.tp, self.num_gt),
            "MT": self.mostly_tracked,
            "GT_tracks": self.gt_tracks,
            "ignored_GT": self.ignored_gt,
            "ignored_pred": self.ignored_pred_distractor + self.ignored_pred_region + self.ignored_pred_small,
            "ignored_pred_distractor": self.ignored_pred_distractor,
            "ignored_pred_region": self.ignored_pred_region,
            "ignored_pred_small": self.ignored_pred_small,
        }


@dataclass(frozen=True)
class _Side:
    """The boxes of one side (ground truth or prediction) for one category, ordered by frame.

    Attributes:
        frame: (N,) index of each box's frame in the evaluation's frame list.
        track: (N,) contiguous track number, 0 … tracks − 1.
        xy_m: (N, 2) city-frame centres.
        tracks: number of distinct tracks.
    """

    frame: NDArray[np.int64]
    track: NDArray[np.int64]
    xy_m: FloatArray
    tracks: int

    @staticmethod
    def build(frame: NDArray[np.int64], track_id: NDArray[np.str_], xy_m: FloatArray) -> tuple[_Side, NDArray[np.intp]]:
        """The side from unordered rows, and the order it put them in (to align per-row flags)."""
        order = np.argsort(frame, kind="stable")
        names, track = np.unique(track_id[order], return_inverse=True)
        return _Side(frame[order], track.reshape(-1).astype(np.int64), xy_m[order], int(names.size)), order

    def bounds(self, frames: int) -> NDArray[np.int64]:
        """(frames + 1,) row offsets: frame f holds rows ``bounds[f]:bounds[f + 1]``."""
        return np.searchsorted(self.frame, np.arange(frames + 1)).astype(np.int64)


def _city_xy(annotations: Annotations, ego: EgoTrajectory) -> FloatArray:
    """(N, 2) box centres in the city frame."""
    if len(annotations) == 0:
        return np.zeros((0, 2))
    ego_at = ego.interpolate(annotations.timestamp_ns)
    city = np.einsum("nij,nj->ni", ego_at.rotation, annotations.center_xyz_m) + ego_at.translation_m
    return np.asarray(city[:, :2], dtype=np.float64)


def _box_ioa(boxes: FloatArray, regions: FloatArray) -> FloatArray:
    """(N, M) fraction of each box's area inside each region. ``boxes``: (N, 4), ``regions``: (M, 4)."""
    w = np.minimum(boxes[:, None, 2], regions[None, :, 2]) - np.maximum(boxes[:, None, 0], regions[None, :, 0])
    h = np.minimum(boxes[:, None, 3], regions[None, :, 3]) - np.maximum(boxes[:, None, 1], regions[None, :, 1])
    inter = np.clip(w, 0.0, None) * np.clip(h, 0.0, None)
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    return np.where(area[:, None] > 0, inter / np.maximum(area[:, None], 1e-12), 0.0)


# One frame where both sides have boxes: their rows on each side, (n_gt, n_pred) distances and similarities.
_Block = tuple[slice, slice, FloatArray, FloatArray]


def _frame_blocks(gt: _Side, pred: _Side, frames: int, max_distance_m: float) -> list[_Block]:
    """Per frame where both sides have boxes: their rows on each side, and the (n_gt, n_pred)
    distances and similarities."""
    gb, pb = gt.bounds(frames), pred.bounds(frames)
    blocks = []
    for f in np.flatnonzero((np.diff(gb) > 0) & (np.diff(pb) > 0)):
        g, p = slice(gb[f], gb[f + 1]), slice(pb[f], pb[f + 1])
        dist = np.linalg.norm(gt.xy_m[g, None] - pred.xy_m[None, p], axis=2)
        blocks.append((g, p, dist, similarity(dist, max_distance_m)))
    return blocks


def _threshold_match(sim: FloatArray) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Rows and columns of the assignment maximising similarity among pairs with s ≥ 0.5."""
    score = np.where(sim >= MATCH_SIMILARITY - _EPS, sim, 0.0)
    rows, cols = linear_sum_assignment(-score)
    ok = score[rows, cols] > _EPS
    return rows[ok], cols[ok]


def _apply_ignore_rules(
    gt: _Side, gt_distractor: NDArray[np.bool_], pred: _Side, pred_box_px: FloatArray,
    regions_by_frame: list[FloatArray], rules: IgnoreRules, max_distance_m: float, frames: int,
) -> tuple[NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]]:
    """Rows to keep on each side, and the counts of what was dropped and why."""
    drop_distractor = np.zeros(pred.frame.size, dtype=bool)
    unmatched = np.ones(pred.frame.size, dtype=bool)
    for g, p, _, sim in _frame_blocks(gt, pred, frames, max_distance_m):  # one assignment per frame, no memory
        rows, cols = _threshold_match(sim)
        matched = np.arange(p.start, p.stop)[cols]
        unmatched[matched] = False
        drop_distractor[matched[gt_distractor[g][rows]]] = True
    height = pred_box_px[:, 3] - pred_box_px[:, 1]
    small = unmatched & (height <= rules.min_height_px + _EPS)
    in_region = np.zeros(pred.frame.size, dtype=bool)
    candidates = np.flatnonzero(unmatched & ~small)
    for f in np.unique(pred.frame[candidates]):
        rows = candidates[pred.frame[candidates] == f]
        if regions_by_frame[f].shape[0]:
            overlap = _box_ioa(pred_box_px[rows], regions_by_frame[f])
            in_region[rows] = (overlap > rules.max_region_overlap + _EPS).any(axis=1)
    keep_pred = ~(drop_distractor | small | in_region)
    counts = {"ignored_gt": int(gt_distractor.sum()), "ignored_pred_distractor": int(drop_distractor.sum()),
              "ignored_pred_region": int(in_region.sum()), "ignored_pred_small": int(small.sum())}
    return ~gt_distractor, keep_pred, counts


def _renumber(side: _Side, keep: NDArray[np.bool_]) -> _Side:
    kept_tracks, track = np.unique(side.track[keep], return_inverse=True)
    return _Side(side.frame[keep], track.reshape(-1).astype(np.int64), side.xy_m[keep], int(kept_tracks.size))


def _score(gt: _Side, pred: _Side, frames: int, max_distance_m: float) -> dict[str, Any]:
    """CLEAR-MOT, identity and HOTA counts of one category (see the module docstring)."""
    n_gt, n_pr = gt.tracks, pred.tracks
    # Per frame with both sides present: the track numbers of the rows and columns, and the blocks.
    blocks = [(gt.track[g], pred.track[p], dist, sim)
              for g, p, dist, sim in _frame_blocks(gt, pred, frames, max_distance_m)]
    gt_count = np.bincount(gt.track, minlength=n_gt).astype(np.float64)
    pred_count = np.bincount(pred.track, minlength=n_pr).astype(np.float64)

    # CLEAR-MOT: frames where one side is empty are all misses or all false positives, and (as in
    # TrackEval) leave the previous frame's pairs in place for the next frame's preference.
    tp = idsw = 0
    distance_sum = 0.0
    matched_frames = np.zeros(n_gt)
    last_pred = np.full(n_gt, -1)  # the predicted track each object was last matched to
    prev_pred = np.full(n_gt, -1)  # … in the previous frame with both sides present
    for g_ids, p_ids, dist, sim in blocks:
        # Keeping last frame's pair outweighs any similarity (≤ 1); then the closest pairs win.
        score = 1000.0 * (p_ids[None, :] == prev_pred[g_ids][:, None]) + sim
        score[sim < MATCH_SIMILARITY - _EPS] = 0.0
        rows, cols = linear_sum_assignment(-score)
        ok = score[rows, cols] > _EPS
        rows, cols = rows[ok], cols[ok]
        mg, mp = g_ids[rows], p_ids[cols]
        idsw += int(((last_pred[mg] >= 0) & (last_pred[mg] != mp)).sum())
        last_pred[mg] = mp
        prev_pred[:] = -1
        prev_pred[mg] = mp
        matched_frames[mg] += 1
        tp += int(rows.size)
        distance_sum += float(dist[rows, cols].sum())
    fn = int(gt.frame.size) - tp
    fp = int(pred.frame.size) - tp
    tracked = matched_frames[gt_count > 0] / gt_count[gt_count > 0]

    # IDF1: frames each (object, track) pair matches at s ≥ 0.5, then the best one-to-one assignment.
    potential = np.zeros((n_gt, n_pr))
    for g_ids, p_ids, _, sim in blocks:
        gi, pi = np.nonzero(sim >= MATCH_SIMILARITY - _EPS)
        np.add.at(potential, (g_ids[gi], p_ids[pi]), 1.0)
    idtp = 0
    if n_gt and n_pr:
        rows, cols = linear_sum_assignment(-potential)
        idtp = int(potential[rows, cols].sum())

    # HOTA: global alignment of each (object, track) pair, then per-frame matching weighted by it.
    alphas = HOTA_ALPHAS.size
    hota_tp, hota_loca = np.zeros(alphas), np.zeros(alphas)
    assa_weighted = np.zeros(alphas)
    if blocks:
        soft = np.zeros((n_gt, n_pr))
        for g_ids, p_ids, _, sim in blocks:
            denom = sim.sum(0)[None, :] + sim.sum(1)[:, None] - sim
            share = np.where(denom > _EPS, sim / np.maximum(denom, _EPS), 0.0)
            np.add.at(soft, (g_ids[:, None], p_ids[None, :]), share)
        alignment = soft / (gt_count[:, None] + pred_count[None, :] - soft)
        keys = []  # one (α, object, track) key per match, counted below: few pairs ever match
        for g_ids, p_ids, _, sim in blocks:
            rows, cols = linear_sum_assignment(-(alignment[g_ids[:, None], p_ids[None, :]] * sim))
            s = sim[rows, cols]
            hit = s[None, :] >= HOTA_ALPHAS[:, None] - _EPS  # (alphas, matches)
            hota_tp += hit.sum(1)
            hota_loca += (hit * s[None, :]).sum(1)
            a_idx, m_idx = np.nonzero(hit)
            keys.append((a_idx * n_gt + g_ids[rows[m_idx]]) * n_pr + p_ids[cols[m_idx]])
        pairs, tpa = np.unique(np.concatenate(keys), return_counts=True)
        pair_alpha, pair = np.divmod(pairs, n_gt * n_pr)
        pair_gt, pair_pred = np.divmod(pair, n_pr)
        # AssA_α · TP_α = Σ over matches of TPA / (TPA + FNA + FPA) of the match's pair.
        assa = tpa * tpa / np.maximum(1.0, gt_count[pair_gt] + pred_count[pair_pred] - tpa)
        assa_weighted = np.asarray(np.bincount(pair_alpha, weights=assa, minlength=alphas), dtype=np.float64)
    return {
        "tp": tp, "fn": fn, "fp": fp, "idsw": idsw, "distance_sum_m": distance_sum,
        "gt_tracks": int((gt_count > 0).sum()), "mostly_tracked": int((tracked > 0.8).sum()),  # > 80 %, as KITTI
        "idtp": idtp, "idfn": int(gt.frame.size) - idtp, "idfp": int(pred.frame.size) - idtp,
        "hota_tp": hota_tp, "hota_fn": gt.frame.size - hota_tp, "hota_fp": pred.frame.size - hota_tp,
        "hota_assa_weighted": assa_weighted, "hota_loca_weighted": hota_loca,
    }


def tracking_counts(
    pred: Annotations,
    pred_ego: EgoTrajectory,
    gt: Annotations,
    gt_ego: EgoTrajectory,
    max_distance_m: float = 2.0,
    categories: tuple[Category, ...] = DEFAULT_CATEGORIES,
    ignore: IgnoreRules | None = None,
) -> dict[Category, TrackingCounts]:
    """Counts per category of one log, to pool over logs or turn into figures.

    Args:
        pred: predicted tracks.
        pred_ego: the predicted log's ego poses.
        gt: ground-truth tracks.
        gt_ego: the ground-truth log's ego poses.
        max_distance_m: largest centre distance of a CLEAR-MOT / IDF1 match (similarity 0.5).
        categories: categories to score; a row's category is its public category.
        ignore: ignore rules aligned with the rows of ``pred`` and ``gt``; None scores every box.

    Returns:
        One entry per category, also those without ground truth (their predictions are false
        positives when pooled with other logs).
    """
    if not max_distance_m > 0:
        raise ValueError(f"max_distance_m must be positive, got {max_distance_m}")
    if ignore is not None and (ignore.gt_distractor.shape != (len(gt),) or ignore.pred_box_px.shape != (len(pred), 4)):
        raise ValueError(f"ignore rules cover {ignore.gt_distractor.shape[0]} ground-truth and "
                         f"{ignore.pred_box_px.shape[0]} predicted rows, the logs have {len(gt)} and {len(pred)}")
    gt_rows, pred_rows = gt.category != EGO_VEHICLE_LABEL, pred.category != EGO_VEHICLE_LABEL
    if ignore is not None:
        ignore = ignore.select(gt_rows, pred_rows)
    gt, pred = gt.select(gt_rows), pred.select(pred_rows)
    timestamps = np.union1d(gt.timestamp_ns, pred.timestamp_ns)
    frames = int(timestamps.size)
    gt_frame = np.searchsorted(timestamps, gt.timestamp_ns).astype(np.int64)
    pred_frame = np.searchsorted(timestamps, pred.timestamp_ns).astype(np.int64)
    gt_xy, pred_xy = _city_xy(gt, gt_ego), _city_xy(pred, pred_ego)
    gt_category, pred_category = gt.public_category, pred.public_category
    regions_by_frame: list[FloatArray] = []
    if ignore is not None:
        on_frame = np.isin(ignore.region_timestamp_ns, timestamps)
        region_frame = np.searchsorted(timestamps, ignore.region_timestamp_ns[on_frame])
        region_box = ignore.region_box_px[on_frame]
        regions_by_frame = [region_box[region_frame == f] for f in range(frames)]
    out: dict[Category, TrackingCounts] = {}
    for category in categories:
        g_mask, p_mask = gt_category == category, pred_category == category
        g_side, g_order = _Side.build(gt_frame[g_mask], gt.track_id[g_mask], gt_xy[g_mask])
        p_side, p_order = _Side.build(pred_frame[p_mask], pred.track_id[p_mask], pred_xy[p_mask])
        ignored: dict[str, Any] = {}
        if ignore is not None:
            keep_gt, keep_pred, ignored = _apply_ignore_rules(
                g_side, ignore.gt_distractor[g_mask][g_order], p_side, ignore.pred_box_px[p_mask][p_order],
                regions_by_frame, ignore, max_distance_m, frames)
            g_side, p_side = _renumber(g_side, keep_gt), _renumber(p_side, keep_pred)
        out[category] = TrackingCounts(**_score(g_side, p_side, frames, max_distance_m), **ignored)
    return out


def evaluate_tracking(
    pred: Annotations,
    pred_ego: EgoTrajectory,
    gt: Annotations,
    gt_ego: EgoTrajectory,
    max_distance_m: float = 2.0,
    categories: tuple[Category, ...] = DEFAULT_CATEGORIES,
    ignore: IgnoreRules | None = None,
) -> dict[str, dict[str, Any]]:
    """MOTA, MOTP (metres), IDF1, HOTA (DetA, AssA, LocA) and counts per public category of one log.

    Args: as :func:`tracking_counts`.

    Returns:
        ``{category: {"MOTA": x, "MOTP": x, "IDF1": x, "HOTA": x, "IDSW": n, "FP": n, "FN": n, …}}``;
        categories without scored ground truth are left out.
    """
    counts = tracking_counts(pred, pred_ego, gt, gt_ego, max_distance_m, categories, ignore)
    return {category.value: c.figures() for category, c in counts.items() if c.num_gt > 0}
