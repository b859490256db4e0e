"""The part of the public Waymo Open Motion Dataset schema that the importer reads.

``scenario.proto`` and ``map.proto`` (waymo-open-dataset, ``waymo_open_dataset/protos/``) define a
``Scenario``; this module declares, in Python, only the messages and fields read here, under the
public field numbers, and builds message classes from that declaration with ``protobuf``. Every
other field (traffic-signal states, prediction targets, LiDAR, camera tokens, …) is skipped by the
parser as an unknown field. Enum fields are declared as ``int32`` (the same varint on the wire), so
a value added to the dataset later reads as its number instead of vanishing.

Declared (message: field = number)::

    Scenario:        timestamps_seconds = 1 (repeated double), tracks = 2, scenario_id = 5,
                     sdc_track_index = 6, map_features = 8, current_time_index = 10
    Track:           id = 1, object_type = 2, states = 3
    ObjectState:     center_x/y/z = 2/3/4 (double), length/width/height = 5/6/7, heading = 8,
                     velocity_x/y = 9/10 (float), valid = 11
    MapFeature:      id = 1; one of lane = 3, road_line = 4, road_edge = 5, stop_sign = 7,
                     crosswalk = 8, speed_bump = 9, driveway = 10
    MapPoint:        x/y/z = 1/2/3
    LaneCenter:      speed_limit_mph = 1, type = 2, interpolating = 3, polyline = 8,
                     entry_lanes = 9, exit_lanes = 10, left_neighbors = 11, right_neighbors = 12,
                     left_boundaries = 13, right_boundaries = 14
    BoundarySegment: lane_start_index = 1, lane_end_index = 2, boundary_feature_id = 3, boundary_type = 4
    LaneNeighbor:    feature_id = 1, self_start_index = 2, self_end_index = 3
    RoadLine, RoadEdge: type = 1, polyline = 2
    StopSign:        lane = 1, position = 2
    Crosswalk, SpeedBump, Driveway: polygon = 1
"""

from __future__ import annotations

import functools
from enum import IntEnum
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import DecodeError, Message

_PACKAGE = "scenesearch.womd"
_F = descriptor_pb2.FieldDescriptorProto


class ObjectType(IntEnum):
    """``Track.ObjectType``."""

    UNSET = 0
    VEHICLE = 1
    PEDESTRIAN = 2
    CYCLIST = 3
    OTHER = 4


class LaneType(IntEnum):
    """``LaneCenter.LaneType``."""

    UNDEFINED = 0
    FREEWAY = 1
    SURFACE_STREET = 2
    BIKE_LANE = 3


class RoadLineType(IntEnum):
    """``RoadLine.RoadLineType`` (also ``BoundarySegment.boundary_type``)."""

    UNKNOWN = 0
    BROKEN_SINGLE_WHITE = 1
    SOLID_SINGLE_WHITE = 2
    SOLID_DOUBLE_WHITE = 3
    BROKEN_SINGLE_YELLOW = 4
    BROKEN_DOUBLE_YELLOW = 5
    SOLID_SINGLE_YELLOW = 6
    SOLID_DOUBLE_YELLOW = 7
    PASSING_DOUBLE_YELLOW = 8


#: (name, number, type, label, message type or None, packed) per field of each message.
_FieldSpec = tuple[str, int, int, int, str | None, bool]
_OPT, _REP = _F.LABEL_OPTIONAL, _F.LABEL_REPEATED
_DOUBLE, _FLOAT, _BOOL, _INT32, _INT64, _STRING, _MSG = (
    _F.TYPE_DOUBLE, _F.TYPE_FLOAT, _F.TYPE_BOOL, _F.TYPE_INT32, _F.TYPE_INT64, _F.TYPE_STRING, _F.TYPE_MESSAGE,
)

_MESSAGES: dict[str, list[_FieldSpec]] = {
    "MapPoint": [("x", 1, _DOUBLE, _OPT, None, False), ("y", 2, _DOUBLE, _OPT, None, False),
                 ("z", 3, _DOUBLE, _OPT, None, False)],
    "ObjectState": [
        ("center_x", 2, _DOUBLE, _OPT, None, False), ("center_y", 3, _DOUBLE, _OPT, None, False),
        ("center_z", 4, _DOUBLE, _OPT, None, False), ("length", 5, _FLOAT, _OPT, None, False),
        ("width", 6, _FLOAT, _OPT, None, False), ("height", 7, _FLOAT, _OPT, None, False),
        ("heading", 8, _FLOAT, _OPT, None, False), ("velocity_x", 9, _FLOAT, _OPT, None, False),
        ("velocity_y", 10, _FLOAT, _OPT, None, False), ("valid", 11, _BOOL, _OPT, None, False),
    ],
    "Track": [("id", 1, _INT32, _OPT, None, False), ("object_type", 2, _INT32, _OPT, None, False),
              ("states", 3, _MSG, _REP, "ObjectState", False)],
    "BoundarySegment": [
        ("lane_start_index", 1, _INT32, _OPT, None, False), ("lane_end_index", 2, _INT32, _OPT, None, False),
        ("boundary_feature_id", 3, _INT64, _OPT, None, False), ("boundary_type", 4, _INT32, _OPT, None, False),
    ],
    "LaneNeighbor": [
        ("feature_id", 1, _INT64, _OPT, None, False), ("self_start_index", 2, _INT32, _OPT, None, False),
        ("self_end_index", 3, _INT32, _OPT, None, False),
    ],
    "LaneCenter": [
        ("speed_limit_mph", 1, _DOUBLE, _OPT, None, False), ("type", 2, _INT32, _OPT, None, False),
        ("interpolating", 3, _BOOL, _OPT, None, False), ("polyline", 8, _MSG, _REP, "MapPoint", False),
        ("entry_lanes", 9, _INT64, _REP, None, True), ("exit_lanes", 10, _INT64, _REP, None, True),
        ("left_neighbors", 11, _MSG, _REP, "LaneNeighbor", False),
        ("right_neighbors", 12, _MSG, _REP, "LaneNeighbor", False),
        ("left_boundaries", 13, _MSG, _REP, "BoundarySegment", False),
        ("right_boundaries", 14, _MSG, _REP, "BoundarySegment", False),
    ],
    "RoadLine": [("type", 1, _INT32, _OPT, None, False), ("polyline", 2, _MSG, _REP, "MapPoint", False)],
    "RoadEdge": [("type", 1, _INT32, _OPT, None, False), ("polyline", 2, _MSG, _REP, "MapPoint", False)],
    "StopSign": [("lane", 1, _INT64, _REP, None, False), ("position", 2, _MSG, _OPT, "MapPoint", False)],
    "Crosswalk": [("polygon", 1, _MSG, _REP, "MapPoint", False)],
    "SpeedBump": [("polygon", 1, _MSG, _REP, "MapPoint", False)],
    "Driveway": [("polygon", 1, _MSG, _REP, "MapPoint", False)],
    "MapFeature": [
        ("id", 1, _INT64, _OPT, None, False), ("lane", 3, _MSG, _OPT, "LaneCenter", False),
        ("road_line", 4, _MSG, _OPT, "RoadLine", False), ("road_edge", 5, _MSG, _OPT, "RoadEdge", False),
        ("stop_sign", 7, _MSG, _OPT, "StopSign", False), ("crosswalk", 8, _MSG, _OPT, "Crosswalk", False),
        ("speed_bump", 9, _MSG, _OPT, "SpeedBump", False), ("driveway", 10, _MSG, _OPT, "Driveway", False),
    ],
    "Scenario": [
        ("timestamps_seconds", 1, _DOUBLE, _REP, None, False), ("tracks", 2, _MSG, _REP, "Track", False),
        ("scenario_id", 5, _STRING, _OPT, None, False), ("sdc_track_index", 6, _INT32, _OPT, None, False),
        ("map_features", 8, _MSG, _REP, "MapFeature", False), ("current_time_index", 10, _INT32, _OPT, None, False),
    ],
}

#: The ``feature_data`` one-of of ``MapFeature``: the kinds of map feature, by field name.
MAP_FEATURE_KINDS = ("lane", "road_line", "road_edge", "stop_sign", "crosswalk", "speed_bump", "driveway")


def _file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    proto = descriptor_pb2.FileDescriptorProto(
        name="scenesearch/womd_scenario.proto", package=_PACKAGE, syntax="proto2"
    )
    for message_name, fields in _MESSAGES.items():
        message = proto.message_type.add(name=message_name)
        if message_name == "MapFeature":
            message.oneof_decl.add(name="feature_data")
        for name, number, type_, label, type_name, packed in fields:
            field = message.field.add(name=name, number=number, type=type_, label=label)
            if type_name is not None:
                field.type_name = f".{_PACKAGE}.{type_name}"
            if packed:
                field.options.packed = True
            if message_name == "MapFeature" and name in MAP_FEATURE_KINDS:
                field.oneof_index = 0
    return proto


@functools.cache
def _pool() -> descriptor_pool.DescriptorPool:
    # A private pool: a Waymo schema installed in the process's default pool cannot clash with it.
    pool = descriptor_pool.DescriptorPool()
    pool.Add(_file_descriptor())
    return pool


@functools.cache
def _message_class(name: str) -> Any:
    return message_factory.GetMessageClass(_pool().FindMessageTypeByName(f"{_PACKAGE}.{name}"))


def message_class(name: str) -> Any:
    """The generated class of one declared message (``"Scenario"``, ``"Track"``, …)."""
    if name not in _MESSAGES:
        raise KeyError(f"message {name!r} is not declared (known: {', '.join(_MESSAGES)})")
    return _message_class(name)


def parse_scenario(data: bytes) -> Message:
    """Decode one serialised ``Scenario``.

    Raises:
        google.protobuf.message.DecodeError: ``data`` is not a valid protobuf message.
    """
    scenario: Message = message_class("Scenario")()
    scenario.ParseFromString(data)
    return scenario


__all__ = [
    "MAP_FEATURE_KINDS",
    "DecodeError",
    "LaneType",
    "ObjectType",
    "RoadLineType",
    "message_class",
    "parse_scenario",
]
