"""Ground-truth tag rasters of a log on the clip stage's BEV grid.

For a log with F frames (its annotation timestamps, the frames of ``CLIPS_DIR/logs/<log_id>/``),
:func:`rasterize_targets` gives ``(F, A, H, W)`` float32 targets in the order of
:data:`~encoders.tagging.attributes.ATTRIBUTES` (definitions in :mod:`encoders.tagging.attributes`):
box coverage for densities (4 × 4 samples per cell), the behaviour flags and speed of vehicles
inside their box footprint (a cell belongs to a box when its centre does), and the junction kinds
from ``junctions.feather`` over each junction's area: its outline and the last
:data:`~scenes.behavior.JUNCTION_APPROACH_M` metres of the lanes entering it.

Every operation is vectorised over boxes × frames; only junction outlines are drawn one by one.
:mod:`encoders.tagging.targets` writes the rasters into the clips folder.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from encoders.tagging.attributes import ATTRIBUTES, BEHAVIOR_ATTRIBUTES, JUNCTION_ATTRIBUTES, Attribute, TagError
from scenes import av2_io
from scenes.behavior import EGO_TRACK_ID, JUNCTION_APPROACH_M, read_behavior_labels, read_junctions
from scenes.bev import BevGrid, box_samples
from scenes.categories import VEHICLE_CATEGORIES, Category
from scenes.log import Log
from scenes.map import VectorMap, resample_polyline
from scenes.tracks import DenseTracks

#: Frames rasterised at once (bounds the supersampled scratch memory).
_CHUNK_FRAMES = 32
_VEHICLES = frozenset(c.value for c in VEHICLE_CATEGORIES)


@dataclass(frozen=True)
class BehaviorGrid:
    """Behaviour labels on the dense (K, F) grid of a log.

    Attributes:
        flags: (K, F, L) bool, one channel per :data:`BEHAVIOR_ATTRIBUTES`; false where unlabelled.
        speed_mps: (K, F) speed, NaN where unlabelled.
        leader_index: (K, F) index into the tracks of ``leader_id``, −1 when none (or the ego).
        ego_flags: (F, L) bool, the ego's own labels.
        ego_leader_index: (F,) index of the ego's leader, −1 when none.
    """

    flags: NDArray[np.bool_]
    speed_mps: NDArray[np.float64]
    leader_index: NDArray[np.int64]
    ego_flags: NDArray[np.bool_]
    ego_leader_index: NDArray[np.int64]


def behavior_grid(log_dir: Path, dense: DenseTracks) -> BehaviorGrid:
    """Join ``behavior_labels.feather`` onto the dense tracks (vectorised).

    Raises:
        TagError: the log has no behaviour labels.
    """
    table = read_behavior_labels(log_dir)
    if table is None:
        raise TagError(f"{log_dir}: the log has no behaviour labels (behavior_labels.feather); "
                       "tag targets need a simulated log")
    k, f = dense.valid.shape
    ts = table.column("timestamp_ns").to_numpy()
    tid = np.asarray(table.column("track_id").to_numpy(zero_copy_only=False)).astype(str)
    fi = np.searchsorted(dense.timestamps_ns, ts)
    fi_c = np.clip(fi, 0, max(f - 1, 0))
    on_frame = (f > 0) & (dense.timestamps_ns[fi_c] == ts) if f else np.zeros(ts.shape, bool)
    ids = np.asarray(dense.track_ids).astype(str)
    order = np.argsort(ids)
    pos = np.clip(np.searchsorted(ids[order], tid), 0, max(k - 1, 0))
    ki = order[pos] if k else np.zeros(tid.shape, np.int64)
    is_track = (ids[ki] == tid) if k else np.zeros(tid.shape, bool)
    is_ego = tid == EGO_TRACK_ID
    cols = np.stack([table.column(a.value).to_numpy(zero_copy_only=False) for a in BEHAVIOR_ATTRIBUTES], axis=1)
    cols = cols.astype(bool)
    speed = table.column("speed_mps").to_numpy().astype(np.float64)
    leader = np.asarray(table.column("leader_id").fill_null("").to_numpy(zero_copy_only=False)).astype(str)
    lpos = np.clip(np.searchsorted(ids[order], leader), 0, max(k - 1, 0))
    lk = order[lpos] if k else np.zeros(leader.shape, np.int64)
    lfound = (ids[lk] == leader) & (leader != "") if k else np.zeros(leader.shape, bool)
    lidx = np.where(lfound, lk, -1)

    flags = np.zeros((k, f, len(BEHAVIOR_ATTRIBUTES)), bool)
    spd = np.full((k, f), np.nan)
    lead = np.full((k, f), -1, np.int64)
    m = on_frame & is_track
    flags[ki[m], fi_c[m]] = cols[m]
    spd[ki[m], fi_c[m]] = speed[m]
    lead[ki[m], fi_c[m]] = lidx[m]
    ego_flags = np.zeros((f, len(BEHAVIOR_ATTRIBUTES)), bool)
    ego_lead = np.full(f, -1, np.int64)
    e = on_frame & is_ego
    ego_flags[fi_c[e]] = cols[e]
    ego_lead[fi_c[e]] = lidx[e]
    return BehaviorGrid(flags, spd, lead, ego_flags, ego_lead)


def _boxes(dense: DenseTracks, frames: NDArray[np.int64], keep: NDArray[np.bool_]) -> tuple[NDArray[np.int64], ...]:
    """(track, frame) pairs of valid boxes among ``frames`` of the tracks in ``keep``."""
    sub = dense.valid[:, frames] & keep[:, None]
    kk, jj = np.nonzero(sub)
    return kk, frames[jj], jj


def _samples(grid: BevGrid, dense: DenseTracks, kk: NDArray[np.int64], ff: NDArray[np.int64],
             s: int) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Sub-cell samples inside boxes (kk, ff): (box index, fine row, fine column)."""
    if kk.shape[0] == 0:
        z = np.zeros(0, np.int64)
        return z, z, z
    centers = dense.center_ego_xyz_m[kk, ff, :2]
    sizes = dense.size_lwh_m[kk, ff, :2]
    yaws = dense.yaw_ego_rad[kk, ff]
    return box_samples(grid, centers, sizes, yaws, s)


def box_coverage(grid: BevGrid, dense: DenseTracks, keep: NDArray[np.bool_], frames: NDArray[np.int64],
                 supersample: int = 4) -> NDArray[np.float32]:
    """Fraction of each cell covered by the union of the kept tracks' boxes.

    Args:
        grid: the BEV grid.
        dense: the log's tracks.
        keep: (K,) which tracks count.
        frames: (N,) frame indices.
        supersample: samples per cell side.

    Returns:
        (N, H, W) float32 in [0, 1].
    """
    s = int(supersample)
    h, w = grid.shape
    kk, ff, jj = _boxes(dense, frames, keep)
    b, r, c = _samples(grid, dense, kk, ff, s)
    # Union of the boxes: each sub-cell sample counts once, however many boxes hold it.
    fine = np.unique((jj[b] * (h * s) + r) * (w * s) + c)
    n, rem = np.divmod(fine, (h * s) * (w * s))
    rr, cc = np.divmod(rem, w * s)
    cells = (n * h + rr // s) * w + cc // s
    counts = np.bincount(cells, minlength=frames.shape[0] * h * w).astype(np.float32)
    return np.asarray(counts.reshape(frames.shape[0], h, w) / np.float32(s * s), dtype=np.float32)


def box_values(grid: BevGrid, dense: DenseTracks, keep: NDArray[np.bool_], frames: NDArray[np.int64],
               values: NDArray[np.floating]) -> NDArray[np.float32]:
    """Per-box values written into the cells whose centre lies in the box (max where boxes overlap).

    Args:
        grid: the BEV grid.
        dense: the log's tracks.
        keep: (K,) which tracks count.
        frames: (N,) frame indices.
        values: (K, F, C) values per (track, frame); NaN counts as 0.

    Returns:
        (N, C, H, W) float32.
    """
    h, w = grid.shape
    vals = np.nan_to_num(np.asarray(values, dtype=np.float32))
    out = np.zeros((frames.shape[0], vals.shape[2], h, w), np.float32)
    kk, ff, jj = _boxes(dense, frames, keep)
    b, r, c = _samples(grid, dense, kk, ff, 1)
    if b.shape[0] == 0:
        return out
    v = vals[kk[b], ff[b]]  # (S, C)
    si, ci = np.nonzero(v)
    np.maximum.at(out, (jj[b][si], ci, r[si], c[si]), v[si, ci])
    return out


def approach_strips(vector_map: VectorMap, outlines_xy_m: Sequence[NDArray[np.floating]],
                    approach_m: float) -> list[list[NDArray[np.float64]]]:
    """Per junction outline, the last ``approach_m`` metres of every lane entering it, as (N, 2) city
    polygons.

    A lane enters a junction when one of its successors is an intersection lane whose midpoint lies
    inside the junction's outline; a lane shorter than ``approach_m`` continues onto its
    non-intersection predecessors, so each strip reaches back ``approach_m`` along the road.
    """
    lanes = vector_map.lane_segments
    outlines = [np.asarray(o, np.float32).reshape(-1, 1, 2) for o in outlines_xy_m]
    # Each intersection lane's midpoint, computed once for every outline.
    midpoints = {lid: seg.centerline(3)[1, :2] for lid, seg in lanes.items() if seg.is_intersection}
    out: list[list[NDArray[np.float64]]] = []
    for outline in outlines:
        inside = [lid for lid, mid in midpoints.items()
                  if cv2.pointPolygonTest(outline, (float(mid[0]), float(mid[1])), False) >= 0]
        entering = {p for lid in inside for p in lanes[lid].predecessors
                    if p in lanes and not lanes[p].is_intersection}
        out.append(_lane_tails(vector_map, sorted(entering), float(approach_m)))
    return out


def _lane_tails(vector_map: VectorMap, lane_ids: Sequence[int], length_m: float) -> list[NDArray[np.float64]]:
    """The last ``length_m`` metres (by arc length) of each lane, continued onto its
    non-intersection predecessors where a lane is shorter; (N, 2) polygons."""
    lanes = vector_map.lane_segments
    strips: list[NDArray[np.float64]] = []
    frontier = [(lid, length_m) for lid in lane_ids]
    seen: set[int] = set()
    while frontier:
        lid, remaining = frontier.pop()
        if lid in seen or remaining <= 0:
            continue
        seen.add(lid)
        seg = lanes[lid]
        length = float(np.linalg.norm(np.diff(seg.centerline(16)[:, :2], axis=0), axis=1).sum())
        n = max(2, int(np.ceil(length)) + 1)  # about one point per metre
        left, right = resample_polyline(seg.left_lane_boundary, n), resample_polyline(seg.right_lane_boundary, n)
        keep = np.linspace(0.0, length, n) >= length - remaining
        if keep.sum() >= 2:
            strips.append(np.concatenate([left[keep, :2], right[keep, :2][::-1]]))
        if length < remaining:
            back = [p for p in seg.predecessors if p in lanes and not lanes[p].is_intersection]
            frontier += [(p, remaining - length) for p in back]
    return strips


def junction_masks(log_dir: Path, grid: BevGrid, city_SE3_ego: NDArray[np.floating],
                   kinds: Sequence[str], approach_m: float = JUNCTION_APPROACH_M) -> NDArray[np.float32]:
    """Junction areas of each kind in every frame's ego grid.

    A junction's area is its outline and the last ``approach_m`` metres of the lanes entering it
    (the simulator's behaviour labels put a vehicle "at" a junction on the same stretch, see
    :data:`scenes.behavior.JUNCTION_APPROACH_M`): vehicles queueing at a junction are at it.
    Without a map only the outlines are drawn.

    Args:
        log_dir: the log (reads ``junctions.feather``, absent → zeros, and the vector map).
        grid: the BEV grid.
        city_SE3_ego: (F, 4, 4) ego poses.
        kinds: junction kinds, e.g. ``("three_way", "four_way")``.
        approach_m: length of the approach strips; 0 for outlines only.

    Returns:
        (F, len(kinds), H, W) float32, 1 where the cell centre is in a junction area of that kind.
    """
    poses = np.asarray(city_SE3_ego, dtype=np.float64)
    f = poses.shape[0]
    h, w = grid.shape
    out = np.zeros((f, len(kinds), h, w), np.float32)
    table = read_junctions(log_dir)
    if table is None or table.num_rows == 0 or f == 0:
        return out
    kind_col = [str(x) for x in table.column("kind").to_pylist()]
    xs = table.column("polygon_x_m").to_pylist()
    ys = table.column("polygon_y_m").to_pylist()
    polys = [np.stack([np.asarray(x, float), np.asarray(y, float)], 1) for x, y in zip(xs, ys)]
    map_path = av2_io.find_map_file(Path(log_dir)) if approach_m > 0 else None
    vector_map = av2_io.read_map(map_path) if map_path is not None else None
    chosen = [(poly, kind) for poly, kind in zip(polys, kind_col) if kind in kinds and poly.shape[0] >= 3]
    strips = (approach_strips(vector_map, [poly for poly, _ in chosen], approach_m) if vector_map is not None
              else [[] for _ in chosen])
    areas = [(kind, [poly, *tails]) for (poly, kind), tails in zip(chosen, strips)]
    pts = np.concatenate([p for _, ps in areas for p in ps]) if areas else np.zeros((0, 2))
    if pts.shape[0] == 0:
        return out
    res = 0.5 * grid.resolution_m
    origin = pts.min(axis=0) - 1.0
    size = np.ceil((pts.max(axis=0) + 1.0 - origin) / res).astype(int) + 1
    city = np.zeros((len(kinds), int(size[1]), int(size[0])), np.uint8)
    for kind, shapes in areas:
        for shape in shapes:
            px = np.round(((shape - origin) / res - 0.5) * 16).astype(np.int32)
            cv2.fillPoly(city[list(kinds).index(kind)], [px], 1, lineType=cv2.LINE_8, shift=4)
    cells = grid.cell_centers_xy().reshape(-1, 2)  # (H*W, 2) ego x, y
    for lo in range(0, f, _CHUNK_FRAMES):
        p = poses[lo : lo + _CHUNK_FRAMES]
        xy = np.einsum("fij,nj->fni", p[:, :2, :2], cells) + p[:, None, :2, 3]  # (n, H*W, 2) city
        ij = np.floor((xy - origin) / res).astype(np.int64)
        ok = (ij[..., 0] >= 0) & (ij[..., 0] < city.shape[2]) & (ij[..., 1] >= 0) & (ij[..., 1] < city.shape[1])
        col, row = np.where(ok, ij[..., 0], 0), np.where(ok, ij[..., 1], 0)
        vals = city[:, row, col] * ok[None]  # (kinds, n, H*W)
        out[lo : lo + _CHUNK_FRAMES] = np.moveaxis(vals, 0, 1).reshape(-1, len(kinds), h, w)
    return out


def rasterize_targets(log: Log, grid: BevGrid, dense: DenseTracks | None = None,
                      frames: NDArray[np.int64] | None = None,
                      behavior: BehaviorGrid | None = None) -> NDArray[np.float32]:
    """Ground truth of every attribute of :data:`ATTRIBUTES` for a log's frames.

    Args:
        log: the log (needs ``behavior_labels.feather``; ``junctions.feather`` when present).
        grid: the BEV grid (the clip stage's).
        dense: the log's dense tracks (computed when not given).
        frames: (N,) frame indices (default: all F).
        behavior: the behaviour on the dense grid (default: the log's behaviour labels).

    Returns:
        (N, A, H, W) float32.

    Raises:
        TagError: the log has no behaviour labels (and none are given).
    """
    dense = log.dense_tracks() if dense is None else dense
    f = dense.timestamps_ns.shape[0]
    frames = np.arange(f, dtype=np.int64) if frames is None else np.asarray(frames, dtype=np.int64)
    beh = behavior_grid(log.log_dir, dense) if behavior is None else behavior
    cats = np.asarray(dense.categories).astype(str)
    vehicle = np.isin(cats, list(_VEHICLES))
    pedestrian = cats == Category.PEDESTRIAN.value
    h, w = grid.shape
    out = np.zeros((frames.shape[0], len(ATTRIBUTES), h, w), np.float32)
    idx = {a: i for i, a in enumerate(ATTRIBUTES)}
    speed_ch = idx[Attribute.VEHICLE_SPEED]
    beh_ch = [idx[a] for a in BEHAVIOR_ATTRIBUTES]
    per_box = np.concatenate([beh.flags.astype(np.float32), np.nan_to_num(beh.speed_mps)[..., None]], axis=2)
    for lo in range(0, frames.shape[0], _CHUNK_FRAMES):
        fr = frames[lo : lo + _CHUNK_FRAMES]
        sl = slice(lo, lo + fr.shape[0])
        out[sl, idx[Attribute.VEHICLE_DENSITY]] = box_coverage(grid, dense, vehicle, fr)
        out[sl, idx[Attribute.PEDESTRIAN_DENSITY]] = box_coverage(grid, dense, pedestrian, fr)
        vals = box_values(grid, dense, vehicle, fr, per_box)  # (n, L + 1, H, W)
        out[sl, beh_ch] = vals[:, :-1]
        out[sl, speed_ch] = vals[:, -1]
    kinds = tuple(a.value for a in JUNCTION_ATTRIBUTES)
    out[:, [idx[a] for a in JUNCTION_ATTRIBUTES]] = junction_masks(log.log_dir, grid, dense.city_SE3_ego[frames], kinds)
    return out
