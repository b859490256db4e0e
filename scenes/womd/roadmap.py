"""A Waymo Open Motion Dataset map as an Argoverse 2 vector map (city frame = the scenario's world frame).

WOMD and AV2 describe roads differently; what each AV2 element is made from:

- **Lane segments** from ``lane`` features. WOMD gives a lane's centre line only, so its two
  boundaries are derived. At each centre point the lane reaches, on each side, as far as the
  painted ``road_line`` that ``left_boundaries`` / ``right_boundaries`` names for that stretch of the
  lane (the distance from the centre point to that polyline), clamped to
  [:data:`MIN_HALF_WIDTH_M`, :data:`MAX_HALF_WIDTH_M`]. Points without a road line take the
  half-width of the nearest points that have one (along the lane); a side without any takes the other
  side's; a lane without any takes :data:`DEFAULT_HALF_WIDTH_M`. A ``road_edge`` named as the
  boundary bounds the lane but does not widen it (a kerb often lies beyond a parking strip): the
  half-width there is at most the distance to the edge. The boundaries are the centre line offset by
  these half-widths along its left normal. Mark types come from the boundary features
  (:data:`MARK_TYPES`; a road edge has no paint: ``NONE``). Successors and predecessors are
  ``exit_lanes`` and ``entry_lanes``; the left (right) neighbour is the left (right) neighbour lane
  that runs beside the longest stretch. ``is_intersection``: WOMD has no such flag, so a lane is in an
  intersection when its centre line crosses another lane's at an angle between
  :data:`CROSSING_MIN_ANGLE_RAD` and π − that angle (paths that cross are what makes a junction;
  lanes that merge, split or run beside one another, in either direction, do not count).
  ``lane_type`` is ``BIKE`` for bike lanes, else ``VEHICLE``.
- **Pedestrian crossings** from ``crosswalk`` polygons: edge1 and edge2 are the two opposite sides of
  a four-corner polygon with the larger total length (for other polygons, the long sides of the
  rectangle spanned by its principal axes).
- **Drivable areas** from ``road_edge`` features and ``driveway`` polygons: driveways are copied;
  the road surface is the lane polygons grown outward on a grid (:mod:`scenes.womd.drivable`), the
  growth stopping at road edges (so shoulders, parking strips and junction corners up to the kerb
  count, and nothing beyond a kerb does) or after 5 m. Each connected piece is one polygon; a hole
  (a traffic island) is kept out by a zero-width cut from the outline to it.
  Heights come from the nearest lane centre point.

``road_line`` features are used only through lane boundaries; ``stop_sign`` and ``speed_bump``
features have no AV2 counterpart and are counted, not converted.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from scenes.geometry import FloatArray, point_polyline_distance
from scenes.map import DrivableArea, LaneSegment, PedestrianCrossing, VectorMap
from scenes.womd.drivable import drivable_polygons
from scenes.womd.proto import LaneType, RoadLineType

#: Half-width of a lane without boundary features (a 3.6 m lane).
DEFAULT_HALF_WIDTH_M = 1.8
#: Bounds on a derived half-width: a boundary feature further away (a kerb beyond a parking strip)
#: does not widen the lane past this; a bike lane is not narrower than 1 m.
MIN_HALF_WIDTH_M = 0.5
MAX_HALF_WIDTH_M = 2.5
#: Lanes whose centre lines cross at an angle in [this, π − this] lie in an intersection.
CROSSING_MIN_ANGLE_RAD = np.deg2rad(30.0)
#: Spacing of the centre-line samples used to find crossings.
_CROSSING_STEP_M = 0.5

#: WOMD road-line types as AV2 lane mark types. A passing double yellow (dashed on one side) has no
#: side in WOMD; AV2's SOLID_DASH_YELLOW is the nearest.
MARK_TYPES: dict[int, str] = {
    RoadLineType.UNKNOWN: "UNKNOWN",
    RoadLineType.BROKEN_SINGLE_WHITE: "DASHED_WHITE",
    RoadLineType.SOLID_SINGLE_WHITE: "SOLID_WHITE",
    RoadLineType.SOLID_DOUBLE_WHITE: "DOUBLE_SOLID_WHITE",
    RoadLineType.BROKEN_SINGLE_YELLOW: "DASHED_YELLOW",
    RoadLineType.BROKEN_DOUBLE_YELLOW: "DOUBLE_DASH_YELLOW",
    RoadLineType.SOLID_SINGLE_YELLOW: "SOLID_YELLOW",
    RoadLineType.SOLID_DOUBLE_YELLOW: "DOUBLE_SOLID_YELLOW",
    RoadLineType.PASSING_DOUBLE_YELLOW: "SOLID_DASH_YELLOW",
}


@dataclass(frozen=True)
class Boundary:
    """A stretch of a lane (centre-point indices ``start``..``end``, inclusive) and the feature beside it."""

    start: int
    end: int
    feature_id: int
    boundary_type: int


@dataclass(frozen=True)
class Neighbor:
    """An adjacent lane in the same direction, beside centre points ``start``..``end`` of this one."""

    feature_id: int
    start: int
    end: int


@dataclass(frozen=True)
class WomdLane:
    """A WOMD lane centre.

    Attributes:
        id: feature id.
        centerline: (P, 3) centre points in travel order, world frame.
        lane_type: a :class:`~scenes.womd.proto.LaneType` value.
    """

    id: int
    centerline: FloatArray
    lane_type: int = LaneType.UNDEFINED
    entry_lanes: tuple[int, ...] = ()
    exit_lanes: tuple[int, ...] = ()
    left_boundaries: tuple[Boundary, ...] = ()
    right_boundaries: tuple[Boundary, ...] = ()
    left_neighbors: tuple[Neighbor, ...] = ()
    right_neighbors: tuple[Neighbor, ...] = ()


@dataclass(frozen=True)
class WomdMap:
    """The static map features of a scenario, by kind, keyed by feature id.

    Attributes:
        lanes: lane centres.
        road_lines: (N, 3) polylines with their :class:`~scenes.womd.proto.RoadLineType`.
        road_edges: (N, 3) polylines (kerbs, medians).
        crosswalks: (N, 3) closed polygons.
        driveways: (N, 3) closed polygons.
        other_counts: features of kinds with no AV2 counterpart (``stop_sign``, ``speed_bump``), counted.
    """

    lanes: dict[int, WomdLane] = field(default_factory=dict)
    road_lines: dict[int, tuple[int, FloatArray]] = field(default_factory=dict)
    road_edges: dict[int, FloatArray] = field(default_factory=dict)
    crosswalks: dict[int, FloatArray] = field(default_factory=dict)
    driveways: dict[int, FloatArray] = field(default_factory=dict)
    other_counts: dict[str, int] = field(default_factory=dict)


def _points(points: Iterable[Any]) -> FloatArray:
    """(N, 3) the ``MapPoint`` messages as an array."""
    return np.array([(p.x, p.y, p.z) for p in points], dtype=np.float64).reshape(-1, 3)


def womd_map_from_features(map_features: Iterable[Any]) -> WomdMap:
    """Collect the ``MapFeature`` messages of a scenario by kind."""
    result = WomdMap()
    for feature in map_features:
        kind = feature.WhichOneof("feature_data")
        fid = int(feature.id)
        if kind == "lane":
            lane = feature.lane
            result.lanes[fid] = WomdLane(
                id=fid,
                centerline=_points(lane.polyline),
                lane_type=int(lane.type),
                entry_lanes=tuple(int(i) for i in lane.entry_lanes),
                exit_lanes=tuple(int(i) for i in lane.exit_lanes),
                left_boundaries=tuple(Boundary(b.lane_start_index, b.lane_end_index, b.boundary_feature_id,
                                               b.boundary_type) for b in lane.left_boundaries),
                right_boundaries=tuple(Boundary(b.lane_start_index, b.lane_end_index, b.boundary_feature_id,
                                                b.boundary_type) for b in lane.right_boundaries),
                left_neighbors=tuple(Neighbor(n.feature_id, n.self_start_index, n.self_end_index)
                                     for n in lane.left_neighbors),
                right_neighbors=tuple(Neighbor(n.feature_id, n.self_start_index, n.self_end_index)
                                      for n in lane.right_neighbors),
            )
        elif kind == "road_line":
            result.road_lines[fid] = (int(feature.road_line.type), _points(feature.road_line.polyline))
        elif kind == "road_edge":
            result.road_edges[fid] = _points(feature.road_edge.polyline)
        elif kind == "crosswalk":
            result.crosswalks[fid] = _points(feature.crosswalk.polygon)
        elif kind == "driveway":
            result.driveways[fid] = _points(feature.driveway.polygon)
        else:
            name = kind or "unset"
            result.other_counts[name] = result.other_counts.get(name, 0) + 1
    return result


# ---------------------------------------------------------------------------------------------
# Lanes


def _left_normals(centerline_xy: FloatArray) -> FloatArray:
    """(P, 2) unit left normals of a polyline; ``centerline_xy``: (P, 2), P ≥ 2.

    Repeated points have no direction of their own and take that of the nearest earlier point
    that has one (or of the first one that has one).
    """
    tangent = np.gradient(centerline_xy, axis=0)
    norm = np.linalg.norm(tangent, axis=1)
    ok = norm > 1e-9
    if not ok.any():
        return np.tile([0.0, 1.0], (centerline_xy.shape[0], 1))
    index = np.where(ok, np.arange(len(ok)), 0)
    np.maximum.accumulate(index, out=index)
    index[: int(np.argmax(ok))] = int(np.argmax(ok))
    unit = tangent[index] / norm[index, None]
    return np.stack([-unit[:, 1], unit[:, 0]], axis=1)


def _side_distances(
    lane: WomdLane, boundaries: tuple[Boundary, ...], features: dict[int, FloatArray]
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """(P,) distance from each centre point to the boundary feature beside it on one side, and the
    (P,) mask of the points that have one. ``features``: polylines by feature id, (N, 3) each."""
    p = lane.centerline.shape[0]
    dist = np.zeros(p)
    known = np.zeros(p, dtype=bool)
    for b in boundaries:
        polyline = features.get(int(b.feature_id))
        lo, hi = max(0, int(b.start)), min(p - 1, int(b.end))
        if polyline is None or polyline.shape[0] == 0 or hi < lo:
            continue
        idx = np.arange(lo, hi + 1)
        dist[idx] = point_polyline_distance(lane.centerline[idx, :2], polyline[:, :2])
        known[idx] = True
    return dist, known


def _fill(values: FloatArray, known: NDArray[np.bool_]) -> FloatArray:
    """Unknown entries take the value of the nearest known ones (linear between, constant beyond)."""
    idx = np.arange(values.shape[0])
    return np.interp(idx, idx[known], values[known])


def lane_half_widths(lane: WomdLane, womd: WomdMap) -> tuple[FloatArray, FloatArray]:
    """(P,) left and (P,) right half-widths of a lane (see the module docstring for the rules)."""
    lines = {fid: line for fid, (_, line) in womd.road_lines.items()}
    p = lane.centerline.shape[0]
    by_line: list[FloatArray | None] = []
    caps: list[FloatArray] = []
    for boundaries in (lane.left_boundaries, lane.right_boundaries):
        line_dist, line_known = _side_distances(lane, boundaries, lines)
        edge_dist, edge_known = _side_distances(lane, boundaries, womd.road_edges)
        clamped = np.clip(line_dist, MIN_HALF_WIDTH_M, MAX_HALF_WIDTH_M)
        by_line.append(_fill(clamped, line_known) if line_known.any() else None)
        caps.append(np.where(edge_known, np.maximum(edge_dist, MIN_HALF_WIDTH_M), np.inf))
    default = np.full(p, DEFAULT_HALF_WIDTH_M)
    left, right = by_line
    left_out = left if left is not None else (right if right is not None else default)
    right_out = right if right is not None else (left if left is not None else default)
    return np.minimum(left_out, caps[0]), np.minimum(right_out, caps[1])


def _mark_type(boundaries: tuple[Boundary, ...], womd: WomdMap) -> str:
    """The AV2 mark type of the boundary feature beside the most centre points of one side."""
    points: dict[str, int] = {}
    for b in boundaries:
        if int(b.feature_id) in womd.road_edges:
            mark = "NONE"
        else:
            line = womd.road_lines.get(int(b.feature_id))
            code = int(b.boundary_type) or (line[0] if line is not None else 0)
            mark = MARK_TYPES.get(code, "UNKNOWN")
        points[mark] = points.get(mark, 0) + max(1, int(b.end) - int(b.start) + 1)
    return max(points, key=lambda m: points[m]) if points else "NONE"


def _widest_neighbor(neighbors: tuple[Neighbor, ...], lane_ids: set[int]) -> int | None:
    present = [n for n in neighbors if int(n.feature_id) in lane_ids]
    if not present:
        return None
    return int(max(present, key=lambda n: int(n.end) - int(n.start)).feature_id)


def _resample_with_heading(centerline_xy: FloatArray, step_m: float) -> tuple[FloatArray, FloatArray]:
    """(S, 2) points every ``step_m`` along a polyline and their (S,) headings."""
    seg = np.linalg.norm(np.diff(centerline_xy, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    if arc[-1] <= 0:
        return centerline_xy[:1], np.zeros(1)
    s = np.linspace(0.0, arc[-1], max(2, int(np.ceil(arc[-1] / step_m)) + 1))
    xy = np.stack([np.interp(s, arc, centerline_xy[:, d]) for d in range(2)], axis=1)
    tangent = np.gradient(xy, axis=0)
    return xy, np.arctan2(tangent[:, 1], tangent[:, 0])


def crossing_lanes(lanes: dict[int, WomdLane]) -> set[int]:
    """Ids of lanes whose centre line crosses another lane's at an angle of at least
    :data:`CROSSING_MIN_ANGLE_RAD` away from parallel and anti-parallel."""
    points, headings, owners = [], [], []
    for lane_id, lane in lanes.items():
        if lane.centerline.shape[0] < 2:
            continue
        xy, heading = _resample_with_heading(lane.centerline[:, :2], _CROSSING_STEP_M)
        points.append(xy)
        headings.append(heading)
        owners.append(np.full(xy.shape[0], lane_id, dtype=np.int64))
    if not points:
        return set()
    xy_all, heading_all, owner_all = np.concatenate(points), np.concatenate(headings), np.concatenate(owners)
    pairs = cKDTree(xy_all).query_pairs(_CROSSING_STEP_M, output_type="ndarray")  # (Q, 2)
    if pairs.shape[0] == 0:
        return set()
    i, j = pairs[:, 0], pairs[:, 1]
    diff = np.abs(np.angle(np.exp(1j * (heading_all[i] - heading_all[j]))))  # in [0, π]
    crossing = (owner_all[i] != owner_all[j]) & (diff >= CROSSING_MIN_ANGLE_RAD) & (
        diff <= np.pi - CROSSING_MIN_ANGLE_RAD)
    return {int(v) for v in np.concatenate([owner_all[i[crossing]], owner_all[j[crossing]]])}


def lane_segments(womd: WomdMap) -> dict[int, LaneSegment]:
    """AV2 lane segments of every lane with at least two centre points."""
    lanes = {fid: lane for fid, lane in womd.lanes.items() if lane.centerline.shape[0] >= 2}
    lane_ids = set(lanes)
    in_junction = crossing_lanes(lanes)
    segments: dict[int, LaneSegment] = {}
    for fid, lane in lanes.items():
        left_w, right_w = lane_half_widths(lane, womd)
        normal = _left_normals(lane.centerline[:, :2])
        offset = np.concatenate([normal, np.zeros((normal.shape[0], 1))], axis=1)  # (P, 3)
        segments[fid] = LaneSegment(
            id=fid,
            is_intersection=fid in in_junction,
            lane_type="BIKE" if lane.lane_type == LaneType.BIKE_LANE else "VEHICLE",
            left_lane_boundary=lane.centerline + offset * left_w[:, None],
            right_lane_boundary=lane.centerline - offset * right_w[:, None],
            left_lane_mark_type=_mark_type(lane.left_boundaries, womd),
            right_lane_mark_type=_mark_type(lane.right_boundaries, womd),
            successors=tuple(i for i in lane.exit_lanes if i in lane_ids),
            predecessors=tuple(i for i in lane.entry_lanes if i in lane_ids),
            left_neighbor_id=_widest_neighbor(lane.left_neighbors, lane_ids),
            right_neighbor_id=_widest_neighbor(lane.right_neighbors, lane_ids),
        )
    return segments


# ---------------------------------------------------------------------------------------------
# Crosswalks


def crossing_edges(polygon: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """The two long edges ((2, 3) each, same direction) of a crosswalk polygon, or None under 3 corners.

    ``polygon``: (N, 3) corners; a closing repeat of the first corner is ignored.
    """
    pts = np.asarray(polygon, dtype=np.float64)
    if pts.shape[0] >= 2 and np.allclose(pts[0], pts[-1]):
        pts = pts[:-1]
    if pts.shape[0] < 3:
        return None
    if pts.shape[0] == 4:
        side = np.linalg.norm(np.diff(np.concatenate([pts, pts[:1]]), axis=0)[:, :2], axis=1)  # (4,)
        if side[0] + side[2] >= side[1] + side[3]:
            return pts[[0, 1]], pts[[3, 2]]
        return pts[[1, 2]], pts[[0, 3]]
    center = pts[:, :2].mean(axis=0)
    _, _, vt = np.linalg.svd(pts[:, :2] - center)
    along, across = vt[0], vt[1]
    u = (pts[:, :2] - center) @ along
    v = (pts[:, :2] - center) @ across
    z = float(pts[:, 2].mean())

    def corner(a: float, b: float) -> FloatArray:
        xy = center + a * along + b * across
        return np.array([xy[0], xy[1], z])

    edge1 = np.stack([corner(u.min(), v.min()), corner(u.max(), v.min())])
    edge2 = np.stack([corner(u.min(), v.max()), corner(u.max(), v.max())])
    return edge1, edge2


def pedestrian_crossings(womd: WomdMap) -> dict[int, PedestrianCrossing]:
    result: dict[int, PedestrianCrossing] = {}
    for fid, polygon in womd.crosswalks.items():
        edges = crossing_edges(polygon)
        if edges is not None:
            result[fid] = PedestrianCrossing(fid, edges[0], edges[1])
    return result


# ---------------------------------------------------------------------------------------------
# Drivable areas


def drivable_areas(womd: WomdMap, segments: dict[int, LaneSegment]) -> dict[int, DrivableArea]:
    """Driveways plus the road surface between lanes and road edges, heights from the nearest lane point."""
    outlines = drivable_polygons([s.polygon()[:, :2] for s in segments.values()],
                                 [e[:, :2] for e in womd.road_edges.values()])
    areas: dict[int, DrivableArea] = {}
    for fid, polygon in womd.driveways.items():
        if polygon.shape[0] >= 3:
            areas[fid] = DrivableArea(fid, polygon)
    if not outlines:
        return areas
    centre = np.concatenate([womd.lanes[fid].centerline for fid in segments])
    tree = cKDTree(centre[:, :2])
    next_id = max([0, *womd.lanes, *womd.road_lines, *womd.road_edges, *womd.crosswalks, *womd.driveways]) + 1
    for k, outline in enumerate(outlines):
        _, nearest = tree.query(outline)
        areas[next_id + k] = DrivableArea(next_id + k, np.concatenate([outline, centre[nearest, 2:3]], axis=1))
    return areas


def vector_map_from_womd(womd: WomdMap) -> VectorMap:
    """The AV2 vector map of a WOMD map (see the module docstring for what each element is made from)."""
    segments = lane_segments(womd)
    return VectorMap(segments, pedestrian_crossings(womd), drivable_areas(womd, segments))
