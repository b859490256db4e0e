"""Export a SUMO network as an AV2 vector map (city frame) and a table of junction kinds.

Lanes open to road vehicles become lane segments; lanes inside junctions (SUMO's internal lanes)
become ``is_intersection`` segments linking the lanes they connect. Sidewalks and walking areas are
not lanes; SUMO crossings become pedestrian crossings. Drivable areas are each road's carriageway
plus each junction's outline. Ids are integers assigned in sorted SUMO-id order, so the same
network always gives the same map.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from scenes.behavior import JUNCTIONS_SCHEMA, JunctionKind
from scenes.geometry import FloatArray
from scenes.map import DrivableArea, LaneSegment, PedestrianCrossing, VectorMap
from scenes.sim.netparse import SumoLane, SumoNet


def offset_polyline(points_xy_m: FloatArray, offset_m: float) -> FloatArray:
    """Shift a polyline sideways, to the left for positive offsets.

    Args:
        points_xy_m: (N, 2) vertices, N ≥ 2.
        offset_m: signed distance to the left of the direction of travel.

    Returns:
        (N, 3) shifted vertices on the ground (z = 0), mitred at inner vertices.
    """
    pts = np.asarray(points_xy_m, dtype=np.float64)
    seg = np.diff(pts, axis=0)
    seg /= np.maximum(np.linalg.norm(seg, axis=1, keepdims=True), 1e-9)
    normals = np.stack([-seg[:, 1], seg[:, 0]], axis=1)  # (N-1, 2) left of each segment
    vertex_n = np.concatenate([normals[:1], normals[:-1] + normals[1:], normals[-1:]], axis=0)
    vertex_n /= np.maximum(np.linalg.norm(vertex_n, axis=1, keepdims=True), 1e-9)
    # Mitre: scale so that both adjacent segments end up offset_m away (capped at sharp corners).
    cos_half = np.ones(pts.shape[0])
    if pts.shape[0] > 2:
        cos_half[1:-1] = np.sum(vertex_n[1:-1] * normals[:-1], axis=1)
    scale = 1.0 / np.clip(cos_half, 0.5, 1.0)
    out = pts + vertex_n * (offset_m * scale)[:, None]
    return np.concatenate([out, np.zeros((out.shape[0], 1))], axis=1)


def _lane_type(lane: SumoLane) -> str:
    road = lane.allowed & {"passenger", "truck", "bus", "motorcycle", "bicycle"}
    if road == {"bicycle"}:
        return "BIKE"
    if road == {"bus"}:
        return "BUS"
    return "VEHICLE"


def _valid_shape(lane: SumoLane) -> bool:
    return lane.shape_xy_m.shape[0] >= 2 and float(np.linalg.norm(lane.shape_xy_m[-1] - lane.shape_xy_m[0])) > 1e-3


def lane_id_map(net: SumoNet) -> dict[str, int]:
    """SUMO lane id → AV2 lane segment id, for every road lane exported."""
    road = sorted(lid for lid, lane in net.lanes.items() if lane.is_road and _valid_shape(lane))
    return {lid: i + 1 for i, lid in enumerate(road)}


def export_map(net: SumoNet) -> VectorMap:
    """The AV2 vector map of a network, in the city frame (z = 0)."""
    ids = lane_id_map(net)
    successors: dict[str, set[str]] = {lid: set() for lid in ids}
    predecessors: dict[str, set[str]] = {lid: set() for lid in ids}
    for c in net.connections:
        # A connection through a junction goes lane → internal lane → lane; without one it is direct.
        hops = [c.from_lane, c.via_lane, c.to_lane] if c.via_lane else [c.from_lane, c.to_lane]
        for a, b in zip(hops[:-1], hops[1:]):
            if a in ids and b in ids:
                successors[a].add(b)
                predecessors[b].add(a)
    by_edge: dict[str, dict[int, str]] = {}
    for lid in ids:
        lane = net.lanes[lid]
        by_edge.setdefault(lane.edge_id, {})[lane.index] = lid
    segments: dict[int, LaneSegment] = {}
    for lid, sid in ids.items():
        lane = net.lanes[lid]
        internal = lane.edge_function == "internal"
        siblings = by_edge[lane.edge_id]
        # SUMO numbers lanes from the right: index + 1 is the left neighbour in the same direction.
        left = siblings.get(lane.index + 1) if not internal else None
        right = siblings.get(lane.index - 1) if not internal else None
        left_mark = "NONE" if internal else ("DASHED_WHITE" if left else "DOUBLE_SOLID_YELLOW")
        right_mark = "NONE" if internal else ("DASHED_WHITE" if right else "SOLID_WHITE")
        half = 0.5 * lane.width_m
        segments[sid] = LaneSegment(
            id=sid,
            is_intersection=internal,
            lane_type=_lane_type(lane),
            left_lane_boundary=offset_polyline(lane.shape_xy_m, half),
            right_lane_boundary=offset_polyline(lane.shape_xy_m, -half),
            left_lane_mark_type=left_mark,
            right_lane_mark_type=right_mark,
            successors=tuple(sorted(ids[s] for s in successors[lid])),
            predecessors=tuple(sorted(ids[p] for p in predecessors[lid])),
            left_neighbor_id=ids[left] if left else None,
            right_neighbor_id=ids[right] if right else None,
        )
    crossings: dict[int, PedestrianCrossing] = {}
    crossing_lanes = sorted(lid for lid, lane in net.lanes.items() if lane.edge_function == "crossing")
    for i, lid in enumerate(crossing_lanes):
        lane = net.lanes[lid]
        if not _valid_shape(lane):
            continue
        shape = lane.shape_xy_m[[0, -1]]
        half = 0.5 * lane.width_m
        crossings[i + 1] = PedestrianCrossing(i + 1, offset_polyline(shape, half), offset_polyline(shape, -half))
    areas: dict[int, DrivableArea] = {}
    next_id = 1
    for edge_id in sorted(by_edge):
        if net.edges[edge_id].function == "internal":
            continue
        lanes = by_edge[edge_id]
        outer = net.lanes[lanes[max(lanes)]]
        inner = net.lanes[lanes[min(lanes)]]
        left_edge = offset_polyline(outer.shape_xy_m, 0.5 * outer.width_m)
        right_edge = offset_polyline(inner.shape_xy_m, -0.5 * inner.width_m)
        areas[next_id] = DrivableArea(next_id, np.concatenate([left_edge, right_edge[::-1]], axis=0))
        next_id += 1
    for jid in sorted(net.junctions):
        junction = net.junctions[jid]
        if junction.type == "internal" or junction.shape_xy_m.shape[0] < 3:
            continue
        outline = junction.shape_xy_m
        areas[next_id] = DrivableArea(next_id, np.concatenate([outline, np.zeros((outline.shape[0], 1))], axis=1))
        next_id += 1
    return VectorMap(segments, crossings, areas)


def junction_table(net: SumoNet) -> pa.Table:
    """One row per junction with three or more arms (see :data:`scenes.behavior.JUNCTIONS_SCHEMA`)."""
    rows: dict[str, list[object]] = {name: [] for name in JUNCTIONS_SCHEMA.names}
    for jid, arms in sorted(net.junction_arms().items()):
        kind = JunctionKind.from_arms(arms)
        if kind is None:
            continue
        junction = net.junctions[jid]
        rows["junction_id"].append(jid)
        rows["kind"].append(kind.value)
        rows["num_arms"].append(arms)
        rows["center_x_m"].append(junction.x_m)
        rows["center_y_m"].append(junction.y_m)
        rows["polygon_x_m"].append(junction.shape_xy_m[:, 0].tolist())
        rows["polygon_y_m"].append(junction.shape_xy_m[:, 1].tolist())
    return pa.table(rows, schema=JUNCTIONS_SCHEMA)
