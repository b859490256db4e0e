"""Map context of objects, per (track, frame): lane, offset from its centre, intersection, crosswalk, junction kind.

The log's vector map (:class:`scenes.map.VectorMap`, AV2 and simulated maps alike) is rasterised
once per log in the city frame, over the area its tracks cover (plus ``map.margin_m``), at
``map.resolution_m``; every lookup is then an array gather, vectorised over tracks × frames:

- **lanes**: every lane segment outside junctions is cut into quads between successive vertices of
  its boundaries; the raster holds the quad under each cell. A quad knows its lane, its
  start on the centre line, its direction and its arc length from the lane's start, so a lookup
  gives the lane, the signed lateral offset from the centre line (left positive) and the lane
  heading without searching.
- **intersections**: the union of the ``is_intersection`` lane segments; its connected components
  (cells touching diagonally count) are the junctions.
- **crosswalks**: the union of the pedestrian crossings.
- **junction kind** (:class:`scenes.behavior.JunctionKind`, the simulator's vocabulary): the roads
  meeting at a junction are counted from the directions in which its lanes leave it (exiting lanes
  at their start, entering lanes reversed at their end); directions closer than ``map.arm_gap_deg``
  belong to one road. Three roads make a ``three_way``, four a ``four_way``. An object has a junction
  kind inside the junction and on a lane that enters it within ``map.junction_approach_m`` of the
  lane's end, as in the behaviour labels of simulated logs (queues at a stop line count).

A log without a map, or whose map has no lanes, has no context: :func:`map_context` returns None
and the caller reports the lane tags as null for the whole log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from captioning.config import MapConfig
from captioning.smoothing import BoolArray, IntArray
from scenes.behavior import JunctionKind
from scenes.geometry import FloatArray
from scenes.map import LaneSegment, VectorMap

#: Junction kinds in code order (index = code in :attr:`MapRaster.junction_kind`); −1 = none.
JUNCTION_KINDS: list[JunctionKind] = list(JunctionKind)
#: Fixed-point bits of polygon vertices handed to OpenCV (sub-cell accuracy).
_SHIFT = 4


@dataclass(frozen=True)
class MapRaster:
    """A log's map, rasterised for lookups (see the module docstring).

    Attributes:
        origin_xy_m: (2,) city position of the raster's corner cell (0, 0).
        resolution_m: cell size.
        quad: (H, W) int32 quad index under each cell, −1 off the lanes.
        junction: (H, W) int32 junction index, −1 outside intersections.
        crosswalk: (H, W) bool.
        quad_lane: (Q,) lane index of each quad.
        quad_start_xy_m: (Q, 2) start of each quad on its lane's centre line.
        quad_dir_xy: (Q, 2) unit direction of travel along the quad.
        quad_arc_m: (Q,) arc length of the quad's start from its lane's start.
        lane_ids: (L,) map ids of the lanes outside junctions.
        lane_left: (L,) index of the left neighbour lane (same direction), −1 when none.
        lane_right: (L,) index of the right neighbour lane, −1 when none.
        lane_length_m: (L,) centre-line length.
        lane_junction: (L,) junction the lane enters at its end, −1 when none.
        junction_kind: (J,) :data:`JUNCTION_KINDS` code of each junction, −1 for fewer than three roads.
        junction_arms: (J,) number of roads meeting at each junction.
    """

    origin_xy_m: FloatArray
    resolution_m: float
    quad: NDArray[np.int32]
    junction: NDArray[np.int32]
    crosswalk: BoolArray
    quad_lane: IntArray
    quad_start_xy_m: FloatArray
    quad_dir_xy: FloatArray
    quad_arc_m: FloatArray
    lane_ids: IntArray
    lane_left: IntArray
    lane_right: IntArray
    lane_length_m: FloatArray
    lane_junction: IntArray
    junction_kind: IntArray
    junction_arms: IntArray


@dataclass(frozen=True)
class MapLookup:
    """Map context of points; every array has the points' shape (...).

    Attributes:
        lane: lane index (into :attr:`MapRaster.lane_ids`), −1 off the lanes.
        lateral_m: signed offset from the lane's centre line, left positive; NaN off the lanes.
        lane_heading_rad: direction of travel of the lane; NaN off the lanes.
        to_lane_end_m: distance along the lane to its end; NaN off the lanes.
        junction: junction index, −1 outside intersections.
        crosswalk: on a pedestrian crossing.
    """

    lane: IntArray
    lateral_m: FloatArray
    lane_heading_rad: FloatArray
    to_lane_end_m: FloatArray
    junction: IntArray
    crosswalk: BoolArray


def _cells(points_xy_m: FloatArray, origin: FloatArray, resolution_m: float) -> NDArray[np.int32]:
    """(N, 2) city points → fixed-point pixel coordinates for :func:`cv2.fillPoly` (cell centres at integers)."""
    return np.asarray(np.round(((points_xy_m - origin) / resolution_m - 0.5) * (1 << _SHIFT)), dtype=np.int32)


def _lanes_within(vector_map: VectorMap, lo: FloatArray, hi: FloatArray) -> set[int]:
    """Ids of the lane segments whose boundaries' box meets the box ``lo``..``hi`` (one pass over all points)."""
    ids = list(vector_map.lane_segments)
    if not ids:
        return set()
    parts = [p for seg in vector_map.lane_segments.values() for p in (seg.left_lane_boundary, seg.right_lane_boundary)]
    sizes = np.array([len(p) for p in parts])
    points = np.concatenate(parts)[:, :2]
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    low = np.minimum.reduceat(points, starts).reshape(-1, 2, 2).min(axis=1)  # (lanes, 2)
    high = np.maximum.reduceat(points, starts).reshape(-1, 2, 2).max(axis=1)
    meets = (high >= lo).all(axis=1) & (low <= hi).all(axis=1)
    return {lid for lid, ok in zip(ids, meets.tolist()) if ok}


def _groups(counts: IntArray) -> tuple[IntArray, IntArray]:
    """Polylines of ``counts`` (P,) vertices laid end to end: (N,) polyline of each vertex, (P,) first vertex."""
    starts = np.r_[0, np.cumsum(counts)[:-1]].astype(np.int64)
    return np.repeat(np.arange(counts.size), counts), starts


def _resample_many(points: FloatArray, counts: IntArray, num_points: IntArray) -> FloatArray:
    """Resample many polylines at once to evenly spaced points by arc length (what
    :func:`scenes.map.resample_polyline` does for one).

    Args:
        points: (N, D) the polylines' vertices laid end to end.
        counts: (P,) vertices of each polyline (≥ 1).
        num_points: (P,) points wanted from each (≥ 2).

    Returns:
        (sum(num_points), D) the resampled polylines, end to end.
    """
    group, starts = _groups(counts)
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    step[starts[1:] - 1] = 0.0  # no arc across the joint of two polylines
    arc = np.r_[0.0, np.cumsum(step)]
    arc -= arc[starts][group]
    total = arc[starts + counts - 1]
    # One interpolation for all: polyline p occupies [2p, 2p + 1] of a shared non-decreasing axis.
    axis = 2.0 * group + arc / np.where(total > 0, total, 1.0)[group]
    out_group, out_starts = _groups(num_points)
    frac = (np.arange(out_group.size) - out_starts[out_group]) / (num_points[out_group] - 1)
    target = 2.0 * out_group + np.where(total[out_group] > 0, frac, 0.0)
    return np.stack([np.interp(target, axis, points[:, d]) for d in range(points.shape[1])], axis=1)


def _paired_boundaries(segs: list[LaneSegment]) -> tuple[FloatArray, FloatArray, IntArray]:
    """Left and right boundaries of lane segments with paired vertices, end to end.

    Quads need paired vertices: a segment whose boundaries have different vertex counts has both
    resampled to the larger count, walked in step by arc length; the others keep their vertices.

    Returns:
        left (N, 2), right (N, 2), and (P,) vertices per segment.
    """
    n_left = np.array([len(s.left_lane_boundary) for s in segs], dtype=np.int64)
    n_right = np.array([len(s.right_lane_boundary) for s in segs], dtype=np.int64)
    counts = np.maximum(n_left, n_right)
    uneven = n_left != n_right
    group, starts = _groups(counts)
    paired = []
    for boundaries, n in ((np.concatenate([s.left_lane_boundary for s in segs]), n_left),
                          (np.concatenate([s.right_lane_boundary for s in segs]), n_right)):
        out = np.empty((int(counts.sum()), 3))
        keep = ~uneven[group]
        src_group, src_starts = _groups(n)
        out[keep] = boundaries[(src_starts[group] + np.arange(group.size) - starts[group])[keep]]
        if uneven.any():
            # The uneven segments' rows of ``out`` lie in segment order, as the resampled rows come out.
            out[~keep] = _resample_many(boundaries[uneven[src_group]], n[uneven], counts[uneven])
        paired.append(out[:, :2])
    return paired[0], paired[1], counts


def _midlines(segs: list[LaneSegment]) -> FloatArray:
    """(P, 5, 2) points along each lane segment (ends, quarter points of its chord-averaged boundaries,
    middle vertex): cheap samples for telling which junction it lies in."""
    def samples(side: str) -> FloatArray:
        counts = np.array([len(getattr(s, side)) for s in segs], dtype=np.int64)
        points = np.concatenate([getattr(s, side) for s in segs])[:, :2]
        _, starts = _groups(counts)
        return points[np.stack([starts, starts + counts - 1, starts + counts // 2], axis=1)]  # (P, 3, 2)

    both = 0.5 * (samples("left_lane_boundary") + samples("right_lane_boundary"))
    first, last, middle = both[:, 0], both[:, 1], both[:, 2]
    quarter = first[:, None] + np.array([0.25, 0.75])[None, :, None] * (last - first)[:, None]
    return np.concatenate([first[:, None], last[:, None], quarter, middle[:, None]], axis=1)


def _fill_union(canvas: NDArray[np.uint8], polygons: list[FloatArray], origin: FloatArray, resolution_m: float) -> None:
    """Set the cells of the union of ``polygons`` (each (N, ≥2), city frame) to 1: one call per polygon,
    because a single :func:`cv2.fillPoly` over several fills even-odd and would leave overlaps empty."""
    if not polygons:
        return
    sizes = np.array([len(p) for p in polygons])
    for poly in np.split(_cells(np.concatenate(polygons)[:, :2], origin, resolution_m), np.cumsum(sizes)[:-1]):
        cv2.fillPoly(canvas, [poly], 1, lineType=cv2.LINE_8, shift=_SHIFT)


def _boxes_meet(polygons: list[FloatArray], lo: FloatArray, hi: FloatArray) -> list[bool]:
    """Whether the box around each polygon ((N, ≥2), city frame) meets the box ``lo``..``hi``."""
    if not polygons:
        return []
    points = np.concatenate(polygons)[:, :2]
    starts = np.r_[0, np.cumsum([len(p) for p in polygons])[:-1]]
    high, low = np.maximum.reduceat(points, starts), np.minimum.reduceat(points, starts)
    meets = np.logical_and((high >= lo).all(axis=1), (low <= hi).all(axis=1))
    return [bool(m) for m in np.atleast_1d(meets)]


def _end_direction_rad(seg: LaneSegment, at_start: bool) -> float:
    """Direction of travel at a lane segment's start or end, from the boundaries' first or last pieces."""
    left, right = seg.left_lane_boundary[:, :2], seg.right_lane_boundary[:, :2]
    d = (left[1] - left[0] + right[1] - right[0]) if at_start else (left[-1] - left[-2] + right[-1] - right[-2])
    return math.atan2(float(d[1]), float(d[0]))


def _junction_arms(
    vector_map: VectorMap, members: list[list[int]], lane_index: dict[int, int], gap_deg: float
) -> IntArray:
    """Roads meeting at each junction, from the outward directions of the lanes entering and leaving it.

    Args:
        members: per junction, the map ids of its intersection lanes.
        lane_index: map id → index of the lanes outside junctions.
    """
    lanes = vector_map.lane_segments
    arms = np.zeros(len(members), dtype=np.int64)
    for j, ids in enumerate(members):
        outward: list[float] = []
        for lid in ids:
            seg = lanes[lid]
            # Entering lanes point inwards at their end: reversed, they point outwards along their road.
            outward += [_end_direction_rad(lanes[p], False) + math.pi for p in seg.predecessors if p in lane_index]
            outward += [_end_direction_rad(lanes[s], True) for s in seg.successors if s in lane_index]
        if not outward:
            continue
        angles = np.sort(np.mod(np.asarray(outward), 2 * math.pi))
        gaps = np.diff(np.r_[angles, angles[0] + 2 * math.pi])
        arms[j] = max(int((gaps > math.radians(gap_deg)).sum()), 1)
    return arms


def rasterize_map(vector_map: VectorMap, center_city_xy_m: FloatArray, config: MapConfig) -> MapRaster | None:
    """Rasterise the part of ``vector_map`` around the given positions.

    Args:
        vector_map: the log's map.
        center_city_xy_m: (N, 2) positions the raster must cover (finite; e.g. all observed centres).

    Returns:
        The raster, or None when the map has no lane segments or there are no positions.
    """
    pts = np.asarray(center_city_xy_m, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not vector_map.lane_segments or pts.shape[0] == 0:
        return None
    res = float(config.resolution_m)
    lo = pts.min(axis=0) - config.margin_m
    hi = pts.max(axis=0) + config.margin_m
    shape = (math.ceil((hi[1] - lo[1]) / res) + 1, math.ceil((hi[0] - lo[0]) / res) + 1)
    quad = np.full(shape, -1, dtype=np.int32)
    inter = np.zeros(shape, dtype=np.uint8)
    crosswalk = np.zeros(shape, dtype=np.uint8)

    lanes = vector_map.lane_segments
    # Only lanes reaching into the covered area are drawn (a city map may be far larger than a log).
    near = _lanes_within(vector_map, lo, hi)
    road_ids = sorted(lid for lid, s in lanes.items() if not s.is_intersection)
    lane_index = {lid: i for i, lid in enumerate(road_ids)}
    lengths = np.full(len(road_ids), np.nan)
    drawn = np.array([i for i, lid in enumerate(road_ids) if lid in near], dtype=np.int64)
    quad_lane = np.zeros(0, np.int64)
    starts = dirs = np.zeros((0, 2))
    arcs = np.zeros(0)
    if drawn.size:
        left, right, counts = _paired_boundaries([lanes[road_ids[i]] for i in drawn])
        group, first = _groups(counts)
        center = 0.5 * (left + right)
        step = np.diff(center, axis=0)
        norm = np.linalg.norm(step, axis=1)
        last = first + counts - 1
        norm[last[:-1]] = 0.0  # the step from one lane's end to the next lane's start is no piece of either
        arc = np.r_[0.0, np.cumsum(norm)]
        arc -= arc[first][group]
        lengths[drawn] = arc[last]
        keep = np.flatnonzero(norm > 1e-6)  # quad k spans vertices k, k + 1 of one lane
        quad_lane = drawn[group[keep]]
        starts, dirs, arcs = center[keep], step[keep] / norm[keep, None], arc[keep]
        polys = _cells(np.stack([left[keep], left[keep + 1], right[keep + 1], right[keep]], axis=1), lo, res)
        for j, poly in enumerate(polys):
            cv2.fillPoly(quad, [poly], j, lineType=cv2.LINE_8, shift=_SHIFT)
    intersection_ids = sorted(lid for lid in near if lanes[lid].is_intersection)
    _fill_union(inter, [lanes[lid].polygon() for lid in intersection_ids], lo, res)
    crossings = [c.polygon() for c in vector_map.pedestrian_crossings.values()]
    _fill_union(crosswalk, [p for p, ok in zip(crossings, _boxes_meet(crossings, lo, hi)) if ok], lo, res)

    count, components = cv2.connectedComponents(inter, connectivity=8, ltype=cv2.CV_32S)
    junction = np.asarray(components, dtype=np.int32)
    junction -= 1  # background 0 → −1
    num_junctions = int(count) - 1
    # Which junction each intersection lane lies in: the most common component along its centre line.
    members: list[list[int]] = [[] for _ in range(num_junctions)]
    lane_junction = np.full(len(road_ids), -1, dtype=np.int64)
    if intersection_ids:
        cells = np.floor((_midlines([lanes[lid] for lid in intersection_ids]) - lo) / res).astype(np.int64)
        inside = (cells[..., 0] >= 0) & (cells[..., 0] < shape[1]) & (cells[..., 1] >= 0) & (cells[..., 1] < shape[0])
        found = np.where(inside, junction[np.where(inside, cells[..., 1], 0), np.where(inside, cells[..., 0], 0)], -1)
        # The most common junction among a lane's samples, the lowest index on ties (I, 5) → (I,).
        votes = ((found[:, :, None] == found[:, None, :]) & (found[:, None, :] >= 0)).sum(axis=2)
        best = np.argmax(votes * (num_junctions + 1) - found, axis=1)
        lane_in = np.take_along_axis(found, best[:, None], axis=1)[:, 0]
        lane_in[votes.max(axis=1) == 0] = -1
        for lid, j in zip(intersection_ids, lane_in.tolist()):
            if j < 0:
                continue
            members[j].append(lid)
            for p in lanes[lid].predecessors:
                if p in lane_index:
                    lane_junction[lane_index[p]] = j
    arms = _junction_arms(vector_map, members, lane_index, config.arm_gap_deg)
    kinds = np.array([JUNCTION_KINDS.index(k) if (k := JunctionKind.from_arms(int(a))) is not None else -1
                      for a in arms], dtype=np.int64)

    def neighbor(lid: int, side: str) -> int:
        other = getattr(lanes[lid], side)
        return lane_index.get(int(other), -1) if other is not None else -1

    return MapRaster(
        origin_xy_m=lo,
        resolution_m=res,
        quad=quad,
        junction=junction,
        crosswalk=crosswalk.view(bool),  # 0/1 bytes
        quad_lane=quad_lane,
        quad_start_xy_m=starts,
        quad_dir_xy=dirs,
        quad_arc_m=arcs,
        lane_ids=np.asarray(road_ids, dtype=np.int64),
        lane_left=np.array([neighbor(lid, "left_neighbor_id") for lid in road_ids], dtype=np.int64),
        lane_right=np.array([neighbor(lid, "right_neighbor_id") for lid in road_ids], dtype=np.int64),
        lane_length_m=lengths,
        lane_junction=lane_junction,
        junction_kind=kinds,
        junction_arms=arms,
    )


def lookup(raster: MapRaster, points_xy_m: FloatArray) -> MapLookup:
    """Map context of city points (NaN points and points outside the raster have none).

    Args:
        points_xy_m: (..., 2) city positions.
    """
    pts = np.asarray(points_xy_m, dtype=np.float64)
    shape = pts.shape[:-1]
    cell = np.floor((pts - raster.origin_xy_m) / raster.resolution_m)
    h, w = raster.quad.shape
    inside = np.isfinite(cell).all(axis=-1)
    col = np.where(inside, cell[..., 0], -1)
    row = np.where(inside, cell[..., 1], -1)
    inside &= (col >= 0) & (col < w) & (row >= 0) & (row < h)
    col_i = np.where(inside, col, 0).astype(np.int64)
    row_i = np.where(inside, row, 0).astype(np.int64)
    q = np.where(inside, raster.quad[row_i, col_i], -1)
    on_lane = q >= 0
    qi = np.maximum(q, 0)
    if raster.quad_lane.size == 0:
        on_lane = np.zeros(shape, dtype=bool)
        nan = np.full(shape, np.nan)
        lane = np.full(shape, -1, dtype=np.int64)
        lateral, heading, to_end = nan, nan.copy(), nan.copy()
    else:
        d = pts - raster.quad_start_xy_m[qi]
        u = raster.quad_dir_xy[qi]
        along = d[..., 0] * u[..., 0] + d[..., 1] * u[..., 1]
        lateral = np.where(on_lane, u[..., 0] * d[..., 1] - u[..., 1] * d[..., 0], np.nan)
        heading = np.where(on_lane, np.arctan2(u[..., 1], u[..., 0]), np.nan)
        lane = np.where(on_lane, raster.quad_lane[qi], -1)
        to_end = np.where(on_lane, raster.lane_length_m[np.maximum(lane, 0)] - raster.quad_arc_m[qi] - along, np.nan)
    junction = np.where(inside, raster.junction[row_i, col_i], -1).astype(np.int64)
    crosswalk = inside & raster.crosswalk[row_i, col_i]
    return MapLookup(lane=lane.astype(np.int64), lateral_m=lateral, lane_heading_rad=heading,
                     to_lane_end_m=to_end, junction=junction, crosswalk=crosswalk)


def junction_kind_codes(raster: MapRaster, found: MapLookup, approach_m: float) -> IntArray:
    """:data:`JUNCTION_KINDS` code of the junction each point is in, or approaches on a lane entering it
    within ``approach_m`` of the lane's end; −1 elsewhere.
    """
    kinds = raster.junction_kind
    if kinds.size == 0:
        return np.full(found.junction.shape, -1, dtype=np.int64)
    inside = np.where(found.junction >= 0, kinds[np.maximum(found.junction, 0)], -1)
    entering = np.where(found.lane >= 0, raster.lane_junction[np.maximum(found.lane, 0)], -1)
    with np.errstate(invalid="ignore"):
        near = (entering >= 0) & (found.to_lane_end_m <= approach_m)
    approach = np.where(near, kinds[np.maximum(entering, 0)], -1)
    return np.where(inside >= 0, inside, approach).astype(np.int64)
