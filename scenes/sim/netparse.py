"""Read a SUMO ``.net.xml`` into plain arrays: lanes, connections and junctions.

SUMO coordinates are metres in a planar frame with x east and y north; that frame is the city
frame of the simulated logs (z = 0 is the ground).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenes.geometry import FloatArray
from scenes.sim.errors import SimulationError

#: Every vehicle class SUMO knows that moves on roads; lanes allowing none of them are not roads.
ROAD_CLASSES = frozenset({"passenger", "truck", "bus", "motorcycle", "bicycle", "delivery", "taxi", "coach"})
ALL_CLASSES = ROAD_CLASSES | {"pedestrian", "private", "emergency", "authority", "army", "vip", "hov",
                              "evehicle", "trailer", "tram", "rail_urban", "rail", "rail_electric",
                              "rail_fast", "ship", "custom1", "custom2", "moped", "scooter", "container",
                              "cable_car", "subway", "aircraft", "wheelchair", "drone"}
DEFAULT_LANE_WIDTH_M = 3.2


def parse_shape(text: str) -> FloatArray:
    """(N, 2) points of a SUMO ``shape`` attribute ("x,y x,y ...")."""
    pts = [tuple(float(v) for v in p.split(",")[:2]) for p in text.split()]
    return np.asarray(pts, dtype=np.float64).reshape(-1, 2)


@dataclass(frozen=True)
class SumoLane:
    """One lane. ``shape_xy_m``: (N, 2) centre line in travel order."""

    id: str
    edge_id: str
    index: int
    width_m: float
    shape_xy_m: FloatArray
    allowed: frozenset[str]
    edge_function: str  # "" (road), "internal", "crossing", "walkingarea"

    @property
    def length_m(self) -> float:
        """Length of the centre line."""
        return float(np.sum(np.linalg.norm(np.diff(self.shape_xy_m, axis=0), axis=1)))

    @property
    def is_road(self) -> bool:
        return self.edge_function in ("", "internal") and bool(self.allowed & ROAD_CLASSES)

    @property
    def junction_id(self) -> str | None:
        """The junction an internal lane lies in (``:J_3_0`` → ``J``)."""
        if not self.edge_id.startswith(":"):
            return None
        return self.edge_id[1:].rsplit("_", 1)[0]


@dataclass(frozen=True)
class SumoConnection:
    from_lane: str
    to_lane: str
    via_lane: str | None
    direction: str  # s, l, r, L, R, t


@dataclass(frozen=True)
class SumoJunction:
    """A junction. ``shape_xy_m``: (N, 2) outline (may be empty)."""

    id: str
    type: str
    x_m: float
    y_m: float
    shape_xy_m: FloatArray


@dataclass(frozen=True)
class SumoEdge:
    id: str
    from_junction: str
    to_junction: str
    function: str


@dataclass(frozen=True)
class SumoNet:
    """A parsed network."""

    lanes: dict[str, SumoLane]
    edges: dict[str, SumoEdge]
    connections: list[SumoConnection]
    junctions: dict[str, SumoJunction]

    def junction_arms(self) -> dict[str, int]:
        """For each real junction, the number of distinct neighbouring junctions joined by roads."""
        road_edges = {lane.edge_id for lane in self.lanes.values() if lane.is_road and lane.edge_function == ""}
        neighbours: dict[str, set[str]] = {j: set() for j, jn in self.junctions.items() if jn.type != "internal"}
        for edge_id in road_edges:
            e = self.edges[edge_id]
            if e.from_junction in neighbours and e.to_junction in neighbours:
                neighbours[e.from_junction].add(e.to_junction)
                neighbours[e.to_junction].add(e.from_junction)
        return {j: len(n) for j, n in neighbours.items()}

    def road_edges(self, vclass: str) -> list[str]:
        """Sorted ids of normal edges with a lane open to ``vclass``."""
        return sorted(
            {lane.edge_id for lane in self.lanes.values() if lane.edge_function == "" and vclass in lane.allowed}
        )

    def connected_edges(self, vclass: str) -> list[str]:
        """Sorted ids of the edges open to ``vclass`` in the largest strongly connected part of the
        network: from each, every other can be reached and left again (no dead ends, no islands)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        edges = self.road_edges(vclass)
        index = {e: i for i, e in enumerate(edges)}
        lane_edge = {lid: lane.edge_id for lid, lane in self.lanes.items() if vclass in lane.allowed}
        pairs = {
            (index[lane_edge[c.from_lane]], index[lane_edge[c.to_lane]])
            for c in self.connections
            if lane_edge.get(c.from_lane) in index and lane_edge.get(c.to_lane) in index
        }
        if not edges:
            return []
        rows = np.array([p[0] for p in pairs], dtype=np.int64)
        cols = np.array([p[1] for p in pairs], dtype=np.int64)
        graph = coo_matrix((np.ones(len(pairs)), (rows, cols)), shape=(len(edges), len(edges)))
        _, label = connected_components(graph, directed=True, connection="strong")
        largest = np.argmax(np.bincount(label))
        return [e for e, lab in zip(edges, label) if lab == largest]

    def road_length_m(self, vclass: str) -> float:
        """Total length of the edges open to ``vclass`` (each direction counted)."""
        length: dict[str, float] = {}
        for lane in self.lanes.values():
            if lane.edge_function == "" and vclass in lane.allowed:
                # Lanes of one edge are about as long as each other: count the edge once.
                length[lane.edge_id] = lane.length_m
        return float(sum(length.values()))


def _allowed(lane: ET.Element) -> frozenset[str]:
    allow = lane.get("allow")
    if allow is not None:
        return frozenset(allow.split()) if allow != "all" else ALL_CLASSES
    disallow = lane.get("disallow")
    if disallow is not None:
        return ALL_CLASSES - frozenset(disallow.split())
    return ALL_CLASSES


def read_net(path: Path) -> SumoNet:
    """Parse a ``.net.xml``. Raises :class:`SimulationError` naming the file when it is unreadable."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise SimulationError(f"{path}: unreadable SUMO network: {exc}") from exc
    lanes: dict[str, SumoLane] = {}
    edges: dict[str, SumoEdge] = {}
    for edge in root.iter("edge"):
        function = edge.get("function", "")
        edges[edge.get("id", "")] = SumoEdge(edge.get("id", ""), edge.get("from", ""), edge.get("to", ""), function)
        for lane in edge.iter("lane"):
            lane_id = lane.get("id", "")
            lanes[lane_id] = SumoLane(
                id=lane_id,
                edge_id=edge.get("id", ""),
                index=int(lane.get("index", "0")),
                width_m=float(lane.get("width", DEFAULT_LANE_WIDTH_M)),
                shape_xy_m=parse_shape(lane.get("shape", "")),
                allowed=_allowed(lane),
                edge_function=function,
            )
    connections = [
        SumoConnection(
            from_lane=f"{c.get('from')}_{c.get('fromLane')}",
            to_lane=f"{c.get('to')}_{c.get('toLane')}",
            via_lane=c.get("via"),
            direction=c.get("dir", "s"),
        )
        for c in root.iter("connection")
    ]
    junctions = {
        j.get("id", ""): SumoJunction(
            id=j.get("id", ""),
            type=j.get("type", ""),
            x_m=float(j.get("x", "0")),
            y_m=float(j.get("y", "0")),
            shape_xy_m=parse_shape(j.get("shape", "")),
        )
        for j in root.iter("junction")
    }
    return SumoNet(lanes, edges, connections, junctions)
