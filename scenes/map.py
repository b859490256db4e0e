"""The vector map of a log, in the city frame, in the Argoverse 2 map JSON schema.

``map/log_map_archive_<log_id>____<CITY>_city_<n>.json`` holds three dicts keyed by id (as strings):
``lane_segments``, ``pedestrian_crossings`` and ``drivable_areas``; polylines are lists of
``{"x", "y", "z"}`` points in metres.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from scenes.errors import MapFormatError
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
        area_boundary: (N, 3) polygon vertices in the city frame, as the file lists them: the first
            vertex is not repeated at the end (av2-api's ``DrivableArea.xyz`` appends it).
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
    def from_json_dict(data: object) -> VectorMap:
        """Parse the AV2 map JSON object.

        A missing section is an empty one. Raises :class:`~scenes.errors.MapFormatError` naming the
        key of every bad part (the top level, a section, an element, one of its fields, a point).
        """
        parser = _MapParser()
        if not isinstance(data, Mapping):
            raise MapFormatError([(None, "map JSON must be an object with 'lane_segments', 'pedestrian_crossings' "
                                         f"and 'drivable_areas', got {_kind(data)}", None)])
        lanes = {s.id: s for s in parser.section(data, "lane_segments", parser.lane)}
        crossings = {c.id: c for c in parser.section(data, "pedestrian_crossings", parser.crossing)}
        areas = {a.id: a for a in parser.section(data, "drivable_areas", parser.area)}
        if parser.errors:
            raise MapFormatError(parser.errors)
        return VectorMap(lanes, crossings, areas)


def _kind(value: object) -> str:
    """The JSON kind of a parsed value, for messages."""
    names = {dict: "an object", list: "a list", str: "a string", bool: "a boolean", type(None): "null"}
    return names.get(type(value), "a number" if isinstance(value, int | float) else type(value).__name__)


class _BadPart(Exception):
    """One bad part of a map element; the parser records it and goes on with the next element."""

    def __init__(self, key: str, message: str, row: int | None = None) -> None:
        super().__init__(message)
        self.key, self.message, self.row = key, message, row


T = TypeVar("T")


class _MapParser:
    """Parses the sections of a map JSON object, collecting every bad part with its key."""

    def __init__(self) -> None:
        self.errors: list[tuple[str | None, str, int | None]] = []

    def section(self, data: Mapping[str, Any], name: str, parse: Callable[[str, Mapping[str, Any]], T]) -> list[T]:
        items = data.get(name, {})
        if not isinstance(items, Mapping):
            self.errors.append((name, f"must be an object keyed by id, got {_kind(items)}", None))
            return []
        out = []
        for key, item in items.items():
            where = f"{name}[{key}]"
            try:
                if not isinstance(item, Mapping):
                    raise _BadPart(where, f"must be an object, got {_kind(item)}")
                out.append(parse(where, item))
            except _BadPart as bad:
                self.errors.append((bad.key, bad.message, bad.row))
        return out

    @staticmethod
    def required(where: str, item: Mapping[str, Any], name: str) -> Any:
        if name not in item:
            raise _BadPart(f"{where}.{name}", "missing key")
        return item[name]

    def boolean(self, where: str, item: Mapping[str, Any], name: str) -> bool:
        """``item[name]`` as a JSON boolean; anything else is a bad part named by its key."""
        value = self.required(where, item, name)
        if not isinstance(value, bool):
            raise _BadPart(f"{where}.{name}", f"must be true or false, got {_kind(value)}")
        return value

    @staticmethod
    def as_id(key: str, value: object) -> int:
        """An element id: a JSON integer, or a string of one (AV2 keys are strings)."""
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lstrip("-").isdigit():
            return int(value)
        raise _BadPart(key, f"must be an integer id, got {_kind(value)}")

    def integer(self, where: str, item: Mapping[str, Any], name: str) -> int:
        return self.as_id(f"{where}.{name}", self.required(where, item, name))

    def optional_id(self, where: str, item: Mapping[str, Any], name: str) -> int | None:
        value = item.get(name)
        return None if value is None else self.as_id(f"{where}.{name}", value)

    def ids(self, where: str, item: Mapping[str, Any], name: str) -> tuple[int, ...]:
        values = item.get(name) or []
        if not isinstance(values, list):
            raise _BadPart(f"{where}.{name}", f"must be a list of ids, got {_kind(values)}")
        return tuple(self.as_id(f"{where}.{name}[{i}]", v) for i, v in enumerate(values))

    def points(self, where: str, item: Mapping[str, Any], name: str) -> FloatArray:
        """(N, 3) polyline from a list of ``{"x", "y", "z"}`` points (z defaults to 0); N ≥ 1."""
        key = f"{where}.{name}"
        values = self.required(where, item, name)
        if not isinstance(values, list):
            raise _BadPart(key, f"must be a list of {{x, y, z}} points, got {_kind(values)}")
        if not values:
            raise _BadPart(key, "polyline has no points")
        try:  # the common, well-formed case in one pass; anything odd goes the slow way for its message
            rows = [(p["x"], p["y"], p.get("z", 0.0)) for p in values]
            if all(type(v) is float or type(v) is int for row in rows for v in row):
                return np.array(rows, dtype=np.float64)
        except (TypeError, KeyError, AttributeError):
            pass
        out = np.zeros((len(values), 3), dtype=np.float64)
        for row, point in enumerate(values):
            if not isinstance(point, Mapping):
                raise _BadPart(key, f"point must be an object with x, y, z, got {_kind(point)}", row)
            for axis, coord in enumerate("xyz"):
                value = point.get(coord, 0.0 if coord == "z" else None)
                if value is None:
                    raise _BadPart(key, f"point has no '{coord}'", row)
                if isinstance(value, bool) or not isinstance(value, int | float):
                    raise _BadPart(key, f"coordinate '{coord}' must be a number, got {_kind(value)}", row)
                out[row, axis] = value
        return out

    def lane(self, where: str, s: Mapping[str, Any]) -> LaneSegment:
        return LaneSegment(
            id=self.integer(where, s, "id"),
            is_intersection=self.boolean(where, s, "is_intersection"),
            lane_type=str(self.required(where, s, "lane_type")),
            left_lane_boundary=self.points(where, s, "left_lane_boundary"),
            right_lane_boundary=self.points(where, s, "right_lane_boundary"),
            left_lane_mark_type=str(s.get("left_lane_mark_type", "NONE")),
            right_lane_mark_type=str(s.get("right_lane_mark_type", "NONE")),
            successors=self.ids(where, s, "successors"),
            predecessors=self.ids(where, s, "predecessors"),
            left_neighbor_id=self.optional_id(where, s, "left_neighbor_id"),
            right_neighbor_id=self.optional_id(where, s, "right_neighbor_id"),
        )

    def crossing(self, where: str, c: Mapping[str, Any]) -> PedestrianCrossing:
        return PedestrianCrossing(self.integer(where, c, "id"), self.points(where, c, "edge1"),
                                  self.points(where, c, "edge2"))

    def area(self, where: str, a: Mapping[str, Any]) -> DrivableArea:
        return DrivableArea(self.integer(where, a, "id"), self.points(where, a, "area_boundary"))


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
