"""Behaviour labels from the simulator's state (definitions in :class:`scenes.behavior.BehaviorLabel`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from scenes.behavior import (
    BLOCKED_GAP_M,
    BLOCKED_SPEED_MPS,
    BRAKING_ACCEL_MPS2,
    BRAKING_FOR_HEADWAY_S,
    BRAKING_FOR_MIN_GAP_M,
    JUNCTION_APPROACH_M,
    LANE_CHANGE_OFFSET_M,
    STOPPED_SPEED_MPS,
    BehaviorLabel,
)
from scenes.sim.netparse import SumoNet
from scenes.sim.runner import STOPSTATE_PARKING, ObjectRows

BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class LaneInfo:
    """What labelling needs to know about lanes.

    Attributes:
        direction: internal lane → direction of its connection (s, l, r, L, R, t).
        junction: internal lane → the junction it lies in; road lane → the junction it leads to.
        length_m: road lane → its length.
    """

    direction: dict[str, str]
    junction: dict[str, str]
    length_m: dict[str, float]

    @staticmethod
    def from_net(net: SumoNet) -> LaneInfo:
        direction: dict[str, str] = {}
        for c in net.connections:
            # Internal lanes are reached as the ``via`` of a connection, whose direction they carry;
            # the second half of a split turn is the ``via`` of a connection leaving an internal lane.
            if c.via_lane is not None:
                direction.setdefault(c.via_lane, c.direction)
        junction: dict[str, str] = {}
        length: dict[str, float] = {}
        for lid, lane in net.lanes.items():
            if lane.junction_id is not None:
                junction[lid] = lane.junction_id
            elif lane.edge_function == "" and lane.edge_id in net.edges:
                junction[lid] = net.edges[lane.edge_id].to_junction
                length[lid] = lane.length_m
        return LaneInfo(direction, junction, length)


@dataclass(frozen=True)
class Labels:
    """Per-row labels, aligned with the rows they were computed from.

    Attributes:
        flags: label → (N,) booleans, one entry per :class:`BehaviorLabel`.
        leader_id: (N,) the vehicle it is blocked by or brakes for ("" when neither).
        junction_id: (N,) the junction it is inside or about to enter ("" elsewhere).
    """

    flags: dict[BehaviorLabel, BoolArray]
    leader_id: NDArray[np.str_]
    junction_id: NDArray[np.str_]


def _lookup(keys: NDArray[np.str_], table: dict[str, str]) -> NDArray[np.str_]:
    uniq, inverse = np.unique(keys, return_inverse=True)
    values = np.array([table.get(str(k), "") for k in uniq], dtype=np.str_)
    return values[inverse] if uniq.size else np.zeros(0, dtype=np.str_)


def _lookup_float(keys: NDArray[np.str_], table: dict[str, float]) -> NDArray[np.float64]:
    uniq, inverse = np.unique(keys, return_inverse=True)
    values = np.array([table.get(str(k), np.inf) for k in uniq], dtype=np.float64)
    return values[inverse] if uniq.size else np.zeros(0, dtype=np.float64)


def compute_labels(rows: ObjectRows, lanes: LaneInfo) -> Labels:
    """Label every row. Rows may be in any order; lane changes are found along each object's track."""
    n = rows.step.shape[0]
    vehicle = ~rows.is_person
    speed = rows.speed_mps
    parked = vehicle & ((rows.stop_state & STOPSTATE_PARKING) != 0)
    moving = speed >= STOPPED_SPEED_MPS
    stopped = ~parked & ~moving
    braking = vehicle & moving & (rows.accel_mps2 <= BRAKING_ACCEL_MPS2)
    internal = vehicle & np.char.startswith(rows.lane_id, ":")
    direction = _lookup(rows.lane_id, lanes.direction)
    left_turn = internal & np.isin(direction, ["l", "L"])
    right_turn = internal & np.isin(direction, ["r", "R"])
    # At a junction: inside it, or on a road lane within JUNCTION_APPROACH_M of the junction it enters.
    lane_length = _lookup_float(rows.lane_id, lanes.length_m)
    approaching = vehicle & ~internal & (lane_length - rows.lane_pos_m <= JUNCTION_APPROACH_M)
    junction_id = np.where(internal | approaching, _lookup(rows.lane_id, lanes.junction), "")

    left_change, right_change = _lane_changes(rows, vehicle & ~internal & ~parked)
    straight = ~internal | (direction == "s")
    keeping = vehicle & straight & ~parked & moving & ~left_change & ~right_change & (rows.lane_id != "")

    has_leader = vehicle & ~parked & (rows.leader_id != "")
    blocked = has_leader & (speed < BLOCKED_SPEED_MPS) & (rows.leader_gap_m <= BLOCKED_GAP_M)
    reach = np.maximum(BRAKING_FOR_MIN_GAP_M, BRAKING_FOR_HEADWAY_S * speed)
    with np.errstate(invalid="ignore"):
        leader_slower_or_braking = (rows.leader_speed_mps < speed) | (rows.leader_accel_mps2 <= BRAKING_ACCEL_MPS2)
    braking_for = braking & has_leader & (rows.leader_gap_m <= reach) & leader_slower_or_braking
    leader_id = np.where(blocked | braking_for, rows.leader_id, "")

    flags = {
        BehaviorLabel.PARKED: parked,
        BehaviorLabel.STOPPED: stopped,
        BehaviorLabel.BRAKING: braking,
        BehaviorLabel.KEEPING_LANE: keeping,
        BehaviorLabel.LEFT_TURN: left_turn,
        BehaviorLabel.RIGHT_TURN: right_turn,
        BehaviorLabel.LEFT_LANE_CHANGE: left_change,
        BehaviorLabel.RIGHT_LANE_CHANGE: right_change,
        BehaviorLabel.BLOCKED_BY: blocked,
        BehaviorLabel.BRAKING_FOR: braking_for,
    }
    assert all(v.shape == (n,) for v in flags.values())
    return Labels(flags, np.asarray(leader_id, dtype=np.str_), np.asarray(junction_id, dtype=np.str_))


def _lane_changes(rows: ObjectRows, eligible: BoolArray) -> tuple[BoolArray, BoolArray]:
    """Rows inside a left / right lane change (see :attr:`BehaviorLabel.LEFT_LANE_CHANGE`)."""
    n = rows.step.shape[0]
    left = np.zeros(n, dtype=bool)
    right = np.zeros(n, dtype=bool)
    if n < 2:
        return left, right
    order = np.lexsort((rows.step, rows.sumo_id))
    sid = rows.sumo_id[order]
    step = rows.step[order]
    edge = np.char.rpartition(rows.lane_id[order], "_")[:, 0]
    index = rows.lane_index[order]
    off = eligible[order] & (np.abs(rows.lateral_m[order]) > LANE_CHANGE_OFFSET_M)
    cont = np.zeros(n, dtype=bool)  # row continues the previous row of the same track on the same road
    cont[1:] = (sid[1:] == sid[:-1]) & (step[1:] == step[:-1] + 1) & (edge[1:] == edge[:-1])
    run_start = off & ~(cont & np.r_[False, off[:-1]])
    run_id = np.cumsum(run_start) - 1  # valid where off
    event = np.zeros(n, dtype=np.int64)  # +1: moved one lane left, −1: right
    event[1:] = np.where(cont[1:] & off[1:] & off[:-1], np.sign(index[1:] - index[:-1]), 0)
    if not off.any():
        return left, right
    num_runs = int(run_id[off].max()) + 1
    run_dir = np.bincount(run_id[off], weights=event[off], minlength=num_runs)
    row_dir = np.where(off, run_dir[np.clip(run_id, 0, None)], 0.0)
    left[order] = row_dir > 0
    right[order] = row_dir < 0
    return left, right
