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
from scenes.map import LaneSegment, VectorMap, resample_polyline

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


def _midline(seg: LaneSegment) -> FloatArray:
    """(5, 2) points along a lane segment (ends, quarter points of its chord-averaged boundaries, middle
    vertex): cheap samples for telling which junction it lies in."""
    left, right = seg.left_lane_boundary[:, :2], seg.right_lane_boundary[:, :2]
    ends = 0.5 * (left[[0, -1]] + right[[0, -1]])
    middle = 0.5 * (left[len(left) // 2] + right[len(right) // 2])
    quarter = ends[0] + np.array([[0.25], [0.5], [0.75]]) * (ends[1] - ends[0])
    return np.asarray(np.concatenate([ends, quarter[[0, 2]], middle[None]]), dtype=np.float64)


def _overlaps(points_xy_m: FloatArray, lo: FloatArray, hi: FloatArray) -> bool:
    """Whether the box around ``points_xy_m`` (N, 2) meets the box ``lo``..``hi``."""
    return bool((points_xy_m.max(axis=0) >= lo).all() and (points_xy_m.min(axis=0) <= hi).all())


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
    quad_lane: list[IntArray] = []
    starts: list[FloatArray] = []
    dirs: list[FloatArray] = []
    arcs: list[FloatArray] = []
    lengths = np.full(len(road_ids), np.nan)
    num_quads = 0
    for i, lid in enumerate(road_ids):
        if lid not in near:
            continue
        seg = lanes[lid]
        left, right = seg.left_lane_boundary[:, :2], seg.right_lane_boundary[:, :2]
        if len(left) != len(right):
            # Quads need paired vertices; boundaries walked in step are paired by arc length.
            n = max(len(left), len(right))
            left, right = resample_polyline(seg.left_lane_boundary, n)[:, :2], resample_polyline(
                seg.right_lane_boundary, n)[:, :2]
        center = 0.5 * (left + right)
        step = np.diff(center, axis=0)
        norm = np.linalg.norm(step, axis=1)
        keep = np.flatnonzero(norm > 1e-6)
        arc = np.r_[0.0, np.cumsum(norm)]
        lengths[i] = arc[-1]
        polys = _cells(np.stack([left[keep], left[keep + 1], right[keep + 1], right[keep]], axis=1), lo, res)
        for j in range(keep.size):
            cv2.fillPoly(quad, [polys[j]], num_quads + j, lineType=cv2.LINE_8, shift=_SHIFT)
        num_quads += keep.size
        quad_lane.append(np.full(keep.size, i, dtype=np.int64))
        starts.append(center[keep])
        dirs.append(step[keep] / norm[keep, None])
        arcs.append(arc[keep])
    intersection_ids = sorted(lid for lid in near if lanes[lid].is_intersection)
    for lid in intersection_ids:
        cv2.fillPoly(inter, [_cells(lanes[lid].polygon()[:, :2], lo, res)], 1, lineType=cv2.LINE_8, shift=_SHIFT)
    for crossing in vector_map.pedestrian_crossings.values():
        poly = crossing.polygon()[:, :2]
        if _overlaps(poly, lo, hi):
            cv2.fillPoly(crosswalk, [_cells(poly, lo, res)], 1, lineType=cv2.LINE_8, shift=_SHIFT)

    count, components = cv2.connectedComponents(inter, connectivity=8)
    junction = (components.astype(np.int32) - 1).astype(np.int32)  # background 0 → −1
    num_junctions = int(count) - 1
    # Which junction each intersection lane lies in: the most common component along its centre line.
    members: list[list[int]] = [[] for _ in range(num_junctions)]
    lane_junction = np.full(len(road_ids), -1, dtype=np.int64)
    for lid in intersection_ids:
        seg = lanes[lid]
        cells = np.floor((_midline(seg) - lo) / res).astype(np.int64)
        inside = (cells[:, 0] >= 0) & (cells[:, 0] < shape[1]) & (cells[:, 1] >= 0) & (cells[:, 1] < shape[0])
        found = junction[cells[inside, 1], cells[inside, 0]]
        found = found[found >= 0]
        if found.size == 0:
            continue
        j = int(np.bincount(found).argmax())
        members[j].append(lid)
        for p in seg.predecessors:
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
        crosswalk=crosswalk.astype(bool),
        quad_lane=np.concatenate(quad_lane) if quad_lane else np.zeros(0, np.int64),
        quad_start_xy_m=np.concatenate(starts) if starts else np.zeros((0, 2)),
        quad_dir_xy=np.concatenate(dirs) if dirs else np.zeros((0, 2)),
        quad_arc_m=np.concatenate(arcs) if arcs else np.zeros(0),
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
