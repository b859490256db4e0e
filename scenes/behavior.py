"""Behaviour labels: what each object does at each timestamp, and what kind of junction it is in.

A simulated log carries ground truth beside its AV2 files, taken from the traffic simulator's own
state rather than inferred from boxes:

``<log>/behavior_labels.feather``: one row per (timestamp_ns, track_id), the ego included under
track id :data:`EGO_TRACK_ID`. Columns (see :data:`BEHAVIOR_SCHEMA`)::

    timestamp_ns        int64
    track_id            string    same ids as annotations.feather, or "ego"
    parked ... braking_for   bool one column per :class:`BehaviorLabel` value
    speed_mps           float64   speed along the direction of travel
    leader_id           string?   the vehicle that blocks it or that it brakes for (null otherwise)
    junction_id         string?   the junction it is in or about to enter (null elsewhere, see below)

``<log>/junctions.feather``: one row per junction with three or more arms, in the city frame::

    junction_id         string
    kind                string    a :class:`JunctionKind` value
    num_arms            int64     number of distinct neighbouring junctions joined by roads
    center_x_m, center_y_m  float64
    polygon_x_m, polygon_y_m  list<float64>   outline vertices

Together they give the 15 attributes of spatio-temporal tagging: the ten labels below, speed,
3-way and 4-way junction (join ``junction_id``), and vehicle and pedestrian density (which derive
from the boxes). Readers return None when a file is absent, as for real logs.
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import pyarrow as pa
import pyarrow.feather as feather

from scenes.errors import LogFormatError, Problem
from scenesearch_base.atomic import atomic_path

BEHAVIOR_FILENAME = "behavior_labels.feather"
JUNCTIONS_FILENAME = "junctions.feather"

#: Track id of the ego's own rows in the behaviour labels (the ego has no box in annotations).
EGO_TRACK_ID = "ego"

#: Below this speed an object counts as standing still.
STOPPED_SPEED_MPS = 0.2
#: A moving object brakes when its longitudinal acceleration is at or below this value.
BRAKING_ACCEL_MPS2 = -1.0
#: A vehicle is blocked when slower than this ...
BLOCKED_SPEED_MPS = 0.5
#: ... and its leader (a vehicle on its route ahead) is at most this far away, bumper to bumper.
BLOCKED_GAP_M = 10.0
#: A braking vehicle brakes *for* its leader when the gap is at most
#: max(BRAKING_FOR_MIN_GAP_M, BRAKING_FOR_HEADWAY_S * speed) and the leader is slower or braking.
BRAKING_FOR_MIN_GAP_M = 15.0
BRAKING_FOR_HEADWAY_S = 3.0
#: A vehicle is *at* a junction (``junction_id`` set) when inside it or on a road lane at most this far
#: from the lane's end where it enters the junction (queues and waiting at the stop line count).
JUNCTION_APPROACH_M = 20.0
#: A vehicle's lateral offset from its lane's centre line above this marks a lane change in progress.
LANE_CHANGE_OFFSET_M = 0.05


class BehaviorLabel(StrEnum):
    """Per-(timestamp, track) behaviours. The values are the column names of the labels file.

    Definitions, evaluated from the simulator state at each timestamp:

    - ``parked``: the vehicle is stopped at a parking place (off the travel lanes) and will stay.
    - ``stopped``: not parked and speed < :data:`STOPPED_SPEED_MPS` (queued, waiting at a light,
      a pedestrian standing).
    - ``braking``: speed ≥ :data:`STOPPED_SPEED_MPS` and acceleration ≤ :data:`BRAKING_ACCEL_MPS2`.
    - ``keeping_lane``: a vehicle moving (speed ≥ :data:`STOPPED_SPEED_MPS`) along a road lane or
      straight through a junction, not changing lanes. Pedestrians never keep a lane.
    - ``left_turn`` / ``right_turn``: the vehicle is inside a junction on a connection that turns
      left / right (the simulator's connection direction, sharp or not); ``junction_id`` names the
      junction, whose kind is in ``junctions.feather``.
    - ``left_lane_change`` / ``right_lane_change``: the vehicle is moving sideways between two lanes
      of the same road: every frame of the contiguous run in which its offset from the lane centre
      exceeds :data:`LANE_CHANGE_OFFSET_M` and during which its lane index changes (towards the
      left / right lane in its direction of travel).
    - ``blocked_by``: a vehicle slower than :data:`BLOCKED_SPEED_MPS` whose leader (the next vehicle
      on its route, ``leader_id``) is within :data:`BLOCKED_GAP_M`.
    - ``braking_for``: ``braking`` while its leader is within
      max(:data:`BRAKING_FOR_MIN_GAP_M`, :data:`BRAKING_FOR_HEADWAY_S` × speed) and slower than
      it or braking itself; ``leader_id`` names the leader.
    """

    PARKED = "parked"
    STOPPED = "stopped"
    BRAKING = "braking"
    KEEPING_LANE = "keeping_lane"
    LEFT_TURN = "left_turn"
    RIGHT_TURN = "right_turn"
    LEFT_LANE_CHANGE = "left_lane_change"
    RIGHT_LANE_CHANGE = "right_lane_change"
    BLOCKED_BY = "blocked_by"
    BRAKING_FOR = "braking_for"


class JunctionKind(StrEnum):
    """Junction kind by the number of roads meeting there (distinct neighbouring junctions)."""

    THREE_WAY = "three_way"
    FOUR_WAY = "four_way"
    #: Five or more arms (the centre of a spider network).
    MULTI_WAY = "multi_way"

    @staticmethod
    def from_arms(num_arms: int) -> JunctionKind | None:
        """The kind of a junction with ``num_arms`` arms; None below three (bends, dead ends)."""
        if num_arms < 3:
            return None
        if num_arms == 3:
            return JunctionKind.THREE_WAY
        if num_arms == 4:
            return JunctionKind.FOUR_WAY
        return JunctionKind.MULTI_WAY


BEHAVIOR_SCHEMA = pa.schema(
    [pa.field("timestamp_ns", pa.int64(), nullable=False), pa.field("track_id", pa.string(), nullable=False)]
    + [pa.field(label.value, pa.bool_(), nullable=False) for label in BehaviorLabel]
    + [
        pa.field("speed_mps", pa.float64(), nullable=False),
        pa.field("leader_id", pa.string()),
        pa.field("junction_id", pa.string()),
    ]
)

JUNCTIONS_SCHEMA = pa.schema(
    [
        pa.field("junction_id", pa.string(), nullable=False),
        pa.field("kind", pa.string(), nullable=False),
        pa.field("num_arms", pa.int64(), nullable=False),
        pa.field("center_x_m", pa.float64(), nullable=False),
        pa.field("center_y_m", pa.float64(), nullable=False),
        pa.field("polygon_x_m", pa.list_(pa.float64())),
        pa.field("polygon_y_m", pa.list_(pa.float64())),
    ]
)


def _check_schema(path: Path, table: pa.Table, schema: pa.Schema) -> None:
    problems: list[Problem] = []
    for f in schema:
        if f.name not in table.column_names:
            problems.append(Problem(path, "column is missing", field=f.name))
        elif not table.schema.field(f.name).type.equals(f.type):
            problems.append(
                Problem(path, f"has type {table.schema.field(f.name).type}, expected {f.type}", field=f.name)
            )
    if problems:
        raise LogFormatError(problems)


def _write(path: Path, table: pa.Table, schema: pa.Schema) -> Path:
    _check_schema(path, table, schema)
    table = table.select(schema.names)
    with atomic_path(path) as tmp:
        feather.write_feather(table, tmp, compression="lz4")
    return path


def _read(path: Path, schema: pa.Schema) -> pa.Table | None:
    if not path.is_file():
        return None
    try:
        table = feather.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise LogFormatError.single(path, f"unreadable feather file (truncated or corrupt?): {exc}") from exc
    _check_schema(path, table, schema)
    return table


def write_behavior_labels(log_dir: Path | str, table: pa.Table) -> Path:
    """Write ``behavior_labels.feather`` atomically, rows in the given order.

    Raises:
        LogFormatError: when a column of :data:`BEHAVIOR_SCHEMA` is missing or mistyped.
    """
    return _write(Path(log_dir) / BEHAVIOR_FILENAME, table, BEHAVIOR_SCHEMA)


def read_behavior_labels(log_dir: Path | str) -> pa.Table | None:
    """The log's behaviour labels, or None when the log has none (real logs).

    Raises:
        LogFormatError: naming the file and column when the file is unreadable or malformed.
    """
    return _read(Path(log_dir) / BEHAVIOR_FILENAME, BEHAVIOR_SCHEMA)


def write_junctions(log_dir: Path | str, table: pa.Table) -> Path:
    """Write ``junctions.feather`` atomically (see :data:`JUNCTIONS_SCHEMA`)."""
    return _write(Path(log_dir) / JUNCTIONS_FILENAME, table, JUNCTIONS_SCHEMA)


def read_junctions(log_dir: Path | str) -> pa.Table | None:
    """The log's junction kinds, or None when absent."""
    return _read(Path(log_dir) / JUNCTIONS_FILENAME, JUNCTIONS_SCHEMA)
