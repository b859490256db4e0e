"""The vector map of a log, in the city frame, in the Argoverse 2 map JSON schema.

``map/log_map_archive_<log_id>____<CITY>_city_<n>.json`` holds three dicts keyed by id (as strings):
``lane_segments``, ``pedestrian_crossings`` and ``drivable_areas``; polylines are lists of
``{"x", "y", "z"}`` points in metres.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from scenes.geometry import FloatArray


def _points(array: Any) -> FloatArray:
    pts = np.asarray(array, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"expected (N, 3) points, got shape {pts.shape}")
    out = pts.copy()
    out.setflags(write=False)
    return out


def _store_points(element: object, *names: str) -> None:
    """Store the named fields of a frozen map element as read-only (N, 3) float arrays."""
    for name in names:
        object.__setattr__(element, name, _points(getattr(element, name)))


def _outline(first: FloatArray, second: FloatArray) -> FloatArray:
    """(N + M, 3) closed outline: the polyline ``first``, then ``second`` reversed."""
    return np.concatenate([first, second[::-1]], axis=0)


@dataclass(frozen=True)
class LaneSegment:
    """A lane segment: two boundaries walked in the direction of travel.

    Attributes:
        id: segment id.
        is_intersection: whether the segment lies inside a junction.
        lane_type: ``VEHICLE``, ``BIKE`` or ``BUS``.
        left_lane_boundary: (N, 3) left boundary in the city frame, in travel order.
        right_lane_boundary: (M, 3) right boundary in the city frame, in travel order.
        left_lane_mark_type: paint type of the left boundary (e.g. ``DASHED_WHITE``, ``NONE``).
        right_lane_mark_type: paint type of the right boundary.
        successors: ids of the segments this one leads into.
        predecessors: ids of the segments leading into this one.
        left_neighbor_id: adjacent segment on the left (same direction), if any.
        right_neighbor_id: adjacent segment on the right, if any.
    """

    id: int
    is_intersection: bool
    lane_type: str
    left_lane_boundary: FloatArray
    right_lane_boundary: FloatArray
    left_lane_mark_type: str = "NONE"
    right_lane_mark_type: str = "NONE"
    successors: tuple[int, ...] = ()
    predecessors: tuple[int, ...] = ()
    left_neighbor_id: int | None = None
    right_neighbor_id: int | None = None

    def __post_init__(self) -> None:
        _store_points(self, "left_lane_boundary", "right_lane_boundary")
        object.__setattr__(self, "successors", tuple(int(s) for s in self.successors))
        object.__setattr__(self, "predecessors", tuple(int(p) for p in self.predecessors))

    def centerline(self, num_points: int = 10) -> FloatArray:
        """(num_points, 3) centre line, the mean of both boundaries resampled by arc length."""
        left = resample_polyline(self.left_lane_boundary, num_points)
        right = resample_polyline(self.right_lane_boundary, num_points)
        return 0.5 * (left + right)

    def polygon(self) -> FloatArray:
        """(N + M, 3) closed outline: the left boundary then the right one reversed."""
        return _outline(self.left_lane_boundary, self.right_lane_boundary)


@dataclass(frozen=True)
class PedestrianCrossing:
    """A crosswalk given by its two long edges.

    Attributes:
        id: crossing id.
        edge1: (2, 3) first edge in the city frame.
        edge2: (2, 3) second edge in the city frame.
    """

    id: int
    edge1: FloatArray
    edge2: FloatArray

    def __post_init__(self) -> None:
        _store_points(self, "edge1", "edge2")

    def polygon(self) -> FloatArray:
        """(4, 3) outline: edge1 then edge2 reversed."""
        return _outline(self.edge1, self.edge2)


@dataclass(frozen=True)
class DrivableArea:
    """A polygon of drivable surface.

    Attributes:
        id: area id.
        area_boundary: (N, 3) polygon vertices in the city frame.
    """

    id: int
    area_boundary: FloatArray

    def __post_init__(self) -> None:
        _store_points(self, "area_boundary")


@dataclass(frozen=True)
class VectorMap:
    """Lane segments, pedestrian crossings and drivable areas of one log, keyed by id."""

    lane_segments: Mapping[int, LaneSegment] = field(default_factory=dict)
    pedestrian_crossings: Mapping[int, PedestrianCrossing] = field(default_factory=dict)
    drivable_areas: Mapping[int, DrivableArea] = field(default_factory=dict)

    def to_json_dict(self) -> dict[str, Any]:
        """The AV2 map JSON object."""

        def pts(array: FloatArray) -> list[dict[str, float]]:
            return [{"x": float(x), "y": float(y), "z": float(z)} for x, y, z in array]

        return {
            "pedestrian_crossings": {
                str(c.id): {"edge1": pts(c.edge1), "edge2": pts(c.edge2), "id": c.id}
                for c in self.pedestrian_crossings.values()
            },
            "lane_segments": {
                str(s.id): {
                    "id": s.id,
                    "is_intersection": bool(s.is_intersection),
                    "lane_type": s.lane_type,
                    "left_lane_boundary": pts(s.left_lane_boundary),
                    "left_lane_mark_type": s.left_lane_mark_type,
                    "right_lane_boundary": pts(s.right_lane_boundary),
                    "right_lane_mark_type": s.right_lane_mark_type,
                    "successors": list(s.successors),
                    "predecessors": list(s.predecessors),
                    "right_neighbor_id": s.right_neighbor_id,
                    "left_neighbor_id": s.left_neighbor_id,
                }
                for s in self.lane_segments.values()
            },
            "drivable_areas": {
                str(a.id): {"area_boundary": pts(a.area_boundary), "id": a.id}
                for a in self.drivable_areas.values()
            },
        }

    @staticmethod
    def from_json_dict(data: Mapping[str, Any]) -> VectorMap:
        """Parse the AV2 map JSON object. Raises ``KeyError``/``ValueError`` naming the element."""

        def pts(items: list[Mapping[str, float]]) -> FloatArray:
            return np.array([[p["x"], p["y"], p.get("z", 0.0)] for p in items], dtype=np.float64).reshape(-1, 3)

        lanes: dict[int, LaneSegment] = {}
        for key, s in data.get("lane_segments", {}).items():
            try:
                lanes[int(s["id"])] = LaneSegment(
                    id=int(s["id"]),
                    is_intersection=bool(s["is_intersection"]),
                    lane_type=str(s["lane_type"]),
                    left_lane_boundary=pts(s["left_lane_boundary"]),
                    right_lane_boundary=pts(s["right_lane_boundary"]),
                    left_lane_mark_type=str(s.get("left_lane_mark_type", "NONE")),
                    right_lane_mark_type=str(s.get("right_lane_mark_type", "NONE")),
                    successors=tuple(s.get("successors") or ()),
                    predecessors=tuple(s.get("predecessors") or ()),
                    left_neighbor_id=s.get("left_neighbor_id"),
                    right_neighbor_id=s.get("right_neighbor_id"),
                )
            except (KeyError, ValueError, TypeError) as exc:
                raise ValueError(f"lane_segments[{key}]: {exc!r}") from exc
        crossings: dict[int, PedestrianCrossing] = {}
        for key, c in data.get("pedestrian_crossings", {}).items():
            try:
                crossings[int(c["id"])] = PedestrianCrossing(int(c["id"]), pts(c["edge1"]), pts(c["edge2"]))
            except (KeyError, ValueError, TypeError) as exc:
                raise ValueError(f"pedestrian_crossings[{key}]: {exc!r}") from exc
        areas: dict[int, DrivableArea] = {}
        for key, a in data.get("drivable_areas", {}).items():
            try:
                areas[int(a["id"])] = DrivableArea(int(a["id"]), pts(a["area_boundary"]))
            except (KeyError, ValueError, TypeError) as exc:
                raise ValueError(f"drivable_areas[{key}]: {exc!r}") from exc
        return VectorMap(lanes, crossings, areas)


def resample_polyline(points_xyz: FloatArray, num_points: int) -> FloatArray:
    """Resample a polyline to evenly spaced points by arc length.

    Args:
        points_xyz: (N, 3) polyline vertices, N ≥ 1.
        num_points: number of output points, ≥ 2.

    Returns:
        (num_points, 3) points from the first vertex to the last.
    """
    pts = np.asarray(points_xyz, dtype=np.float64)
    if pts.shape[0] == 1:
        return np.repeat(pts, num_points, axis=0)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    if arc[-1] <= 0:
        return np.repeat(pts[:1], num_points, axis=0)
    targets = np.linspace(0.0, arc[-1], num_points)
    return np.stack([np.interp(targets, arc, pts[:, d]) for d in range(3)], axis=1)
