"""Each object's own behaviour per frame, from its track in the city frame and the map only.

The vocabulary is that of the simulator's behaviour labels (:class:`scenes.behavior.BehaviorLabel`:
``parked, stopped, braking, keeping_lane, left_turn, right_turn, left_lane_change,
right_lane_change, blocked_by, braking_for``, plus ``speed_mps``), so that the rules give every log
with tracks the labels simulated logs carry. The labels are what the rules are measured against
(:mod:`captioning.agreement`), never an input. All thresholds are :class:`~captioning.config.BehaviorConfig`
keys; everything is vectorised over tracks × frames on the compact grid of :mod:`captioning.neighbors`.

Kinematics
----------
Box centres in the city frame (``city_SE3_ego · ego_SE3_object``), gaps bridged as for the
neighbour tags, are differentiated with a Savitzky–Golay window of ``behavior.window_s`` on each run
lasting at least ``behavior.min_run_s``: speed, its rate of change (``behavior.accel_window_s``) and
the heading (unwrapped along the track). Durations become frames at the log's own frame rate
(:mod:`captioning.frames`; a run needs two frames at least, so a 2 Hz log is tagged like a 10 Hz
one). Shorter runs get no own-behaviour tags (null), and a track without a longer run is reported as
skipped. Flicker is suppressed as for the other tags (``smoothing.min_run_s``).

Rules (vehicles: every category but pedestrians and ``other``; pedestrians can only stand)
-------------------------------------------------------------------------------------------
- standing: smoothed speed below ``stopped_speed_mps``. A vehicle's standing run is **parked** when
  most of it (``parked_off_lane_fraction``) lies off the travel lanes and outside intersections, or
  when it stands at the curb for ``parked_curb_min_s``; without a map, when it stands over its whole
  track for ``parked_no_map_min_s``. Any other standing frame is **stopped**.
- **braking**: a moving vehicle whose speed falls at ``braking_decel_mps2`` or faster.
- **left_turn / right_turn**: every frame of a vehicle's pass through an intersection whose heading
  changes by ``turn_min_deg`` or more to the left / right between entering and leaving (the front
  of the box decides where it is, as a lane does for a driver); without a map, a run of yaw rate
  above ``turn_yaw_rate_rps`` turning as far.
- **left_lane_change / right_lane_change**: a run of frames whose smoothed offset from the lane
  centre exceeds ``lane_change_offset_m``, during which the lane becomes its left / right neighbour.
- **keeping_lane**: a moving vehicle on a lane or going through an intersection, not turning,
  changing lanes or parked.
- **blocked_by / braking_for**: the leader is the nearest vehicle (the ego included) ahead within
  ``leader_half_width_m`` of the follower's heading line and heading within
  ``leader_max_heading_deg`` of it; a vehicle slower than ``blocked_speed_mps`` with its leader at
  most ``blocked_gap_m`` ahead bumper to bumper is blocked by it; a braking vehicle brakes for a
  leader within max(``braking_for_min_gap_m``, ``braking_for_headway_s`` × speed) that is slower or
  braking.

Without a map the lane tags (``keeping_lane``, lane changes) and the map context are null; the
caller states this once per log.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from captioning.config import CaptioningConfig
from captioning.frames import FrameCounts
from captioning.leaders import leader_tags, wrap_rad
from captioning.map_context import MapRaster, junction_kind_codes, lookup
from captioning.neighbors import TrackMotion
from captioning.object_motion import object_kinematics, scatter_to_log_grid
from captioning.smoothing import (
    BoolArray,
    IntArray,
    frame_derivative,
    suppress_flicker,
)
from captioning.tags import ACTIONS, CONTEXTS, NO_TAG, Context
from scenes.behavior import BehaviorLabel
from scenes.categories import Category
from scenes.geometry import FloatArray

#: The labels in column order (index into the last axis of :attr:`BehaviorTags.flags`).
LABELS: list[BehaviorLabel] = list(BehaviorLabel)
_I = {label: i for i, label in enumerate(LABELS)}
#: Labels that need lanes from a map: null on logs without one.
MAP_LABELS: frozenset[BehaviorLabel] = frozenset(
    {BehaviorLabel.KEEPING_LANE, BehaviorLabel.LEFT_LANE_CHANGE, BehaviorLabel.RIGHT_LANE_CHANGE}
)
#: Categories that never drive: they can stand, nothing more.
NON_VEHICLES = frozenset({Category.PEDESTRIAN.value, Category.OTHER.value})
#: Categories whose tags carry the context whatever they do (the crosswalk matters to them).
CONTEXT_CATEGORIES = frozenset({Category.PEDESTRIAN.value, Category.CYCLIST.value})
#: Why a track gets no own-behaviour tags (:func:`skip_short_reason` fills it in).
SKIP_SHORT = "no run of {seconds:g} s ({frames} frames at {rate}) of observed frames for own-behaviour tags " \
    "(behavior.min_run_s)"
#: Said once for a log whose map has no lanes (or that has no map).
NO_MAP_NOTE = "no map with lanes: keeping_lane, lane changes and map context are null"


def skip_short_reason(config: CaptioningConfig, frames: FrameCounts) -> str:
    """:data:`SKIP_SHORT` for a log whose durations in frames are ``frames``: the key, its seconds and its frames."""
    return SKIP_SHORT.format(seconds=config.behavior.min_run_s, frames=frames.behavior_min_run, rate=frames.describe())


@dataclass(frozen=True)
class BehaviorTags:
    """Own behaviour and map context on the (K, T) log grid.

    Attributes:
        flags: (K, T, len(LABELS)) bool; meaningful where :attr:`known`.
        known_cell: (K, T) cells with own-behaviour tags (observed, in a long enough run).
        label_known: (len(LABELS),) labels computed on this log (the lane tags need a map).
        speed_mps: (K, T) smoothed speed, NaN where unknown.
        at_intersection: (K, T) bool, inside an intersection (the box front for vehicles).
        on_crosswalk: (K, T) bool, on a pedestrian crossing.
        junction_kind: (K, T) int8 :data:`~captioning.map_context.JUNCTION_KINDS` code, −1 none.
        has_map: whether the context (and the lane tags) could be computed.
        taggable: (K,) tracks with at least one run long enough for the tags.
        action: (K, T) int8 :data:`~captioning.tags.ACTIONS` code of the action that enters the unified
            tags (the first that holds), −1 none.
        context: (K, T) int8 :data:`~captioning.tags.CONTEXTS` code entering the tags, −1 none: for
            objects that stand or brake, and for pedestrians and cyclists.
    """

    flags: NDArray[np.bool_]
    known_cell: BoolArray
    label_known: BoolArray
    speed_mps: FloatArray
    at_intersection: BoolArray
    on_crosswalk: BoolArray
    junction_kind: NDArray[np.int8]
    has_map: bool
    taggable: BoolArray
    action: NDArray[np.int8]
    context: NDArray[np.int8]

    @staticmethod
    def empty(k: int, t: int, has_map: bool) -> BehaviorTags:
        """Tags of a log without frames or without tracks."""
        none = np.zeros((k, t), dtype=bool)
        codes = np.full((k, t), NO_TAG, np.int8)
        return BehaviorTags(np.zeros((k, t, len(LABELS)), bool), none, np.ones(len(LABELS), bool),
                            np.full((k, t), np.nan), none, none, codes, has_map, np.zeros(k, bool), codes, codes)

    @property
    def known(self) -> NDArray[np.bool_]:
        """(K, T, len(LABELS)) False where a tag is null (unobserved, too short a run, no map)."""
        return np.asarray(self.known_cell[..., None] & self.label_known, dtype=bool)

    def flag(self, label: BehaviorLabel) -> BoolArray:
        """(K, T) the label where known, False elsewhere."""
        i = _I[label]
        return np.asarray(self.flags[..., i] & self.known_cell & self.label_known[i], dtype=bool)


@dataclass(frozen=True)
class _Runs:
    """Runs of True along axis 1 of a (K, L) mask, over its True cells only (sparse masks stay cheap).

    Attributes:
        cells: (N,) flat indices of the True cells, in order.
        run: (N,) run of each cell.
        first: (R,) flat index of each run's first cell; ``last`` its last.
    """

    cells: IntArray
    run: IntArray
    first: IntArray
    last: IntArray

    @staticmethod
    def of(mask: BoolArray) -> _Runs:
        width = mask.shape[1]
        cells = np.flatnonzero(mask)
        new = np.ones(cells.size, dtype=bool)
        new[1:] = (cells[1:] != cells[:-1] + 1) | (cells[1:] % width == 0)  # a run never spans two rows
        run = np.cumsum(new) - 1
        ends = np.r_[new[1:], True] if cells.size else new
        return _Runs(cells, run, cells[new], cells[ends])

    @property
    def count(self) -> int:
        return int(self.first.size)

    def total(self, values: NDArray[np.generic]) -> FloatArray:
        """(R,) each run's sum of (K, L) ``values``."""
        return np.asarray(np.bincount(self.run, weights=values.ravel()[self.cells], minlength=self.count), np.float64)

    def paint(self, per_run: BoolArray, shape: tuple[int, ...]) -> BoolArray:
        """(K, L) cells of the runs where (R,) ``per_run`` holds."""
        out = np.zeros(shape, dtype=bool)
        out.ravel()[self.cells] = per_run[self.run]
        return out


def _turned_rad(runs: _Runs, yaw_rad: FloatArray) -> FloatArray:
    """(R,) heading change over each run: the sum of its wrapped steps from one cell to the next."""
    if runs.count == 0:
        return np.zeros(0)
    flat = yaw_rad.ravel()
    inner = np.r_[False, runs.run[1:] == runs.run[:-1]]  # cells with a predecessor in their run
    step = np.zeros(runs.cells.size)
    c = runs.cells[inner]
    step[inner] = wrap_rad(flat[c] - flat[c - 1])
    return np.asarray(np.bincount(runs.run, weights=np.nan_to_num(step), minlength=runs.count), np.float64)


def _parked(
    still: BoolArray, enough: BoolArray, t_s: FloatArray, off_lane: BoolArray | None, curb: BoolArray | None,
    config: CaptioningConfig,
) -> BoolArray:
    """Standing vehicle cells whose standing run counts as parked (module docstring).

    Args:
        still: (K, L) standing vehicle cells.
        enough: (K, L) cells with own-behaviour tags (for "the whole track" without a map).
        off_lane, curb: (K, L) cells off the travel lanes / at the curb; None without a map.
    """
    b = config.behavior
    runs = _Runs.of(still)
    if runs.count == 0:
        return np.zeros(still.shape, dtype=bool)
    flat_t = t_s.ravel()
    duration = flat_t[runs.last] - flat_t[runs.first]
    size = np.bincount(runs.run, minlength=runs.count)
    if off_lane is not None and curb is not None:
        off = runs.total(off_lane) / size
        at_curb = runs.total(curb) / size
        per_run = (off >= b.parked_off_lane_fraction) | ((duration >= b.parked_curb_min_s) & (at_curb >= 0.5))
    else:
        width = still.shape[1]
        row = runs.first // width
        first_col = np.argmax(enough, axis=1)[row]
        last_col = (width - 1 - np.argmax(enough[:, ::-1], axis=1))[row]
        whole = (runs.first % width <= first_col) & (runs.last % width >= last_col)
        per_run = whole & (duration >= b.parked_no_map_min_s)
    return runs.paint(per_run, still.shape)


def _lane_changes(
    on_lane: BoolArray, lane: IntArray, lateral_m: FloatArray, raster: MapRaster, threshold_m: float
) -> tuple[BoolArray, BoolArray]:
    """Runs of off-centre frames in which the lane becomes its left / right neighbour (module docstring)."""
    with np.errstate(invalid="ignore"):
        off = on_lane & (np.abs(lateral_m) > threshold_m)
    runs = _Runs.of(off)
    if runs.count == 0:
        return off, off
    inner = np.r_[False, runs.run[1:] == runs.run[:-1]]
    flat_lane = lane.ravel()
    now = flat_lane[runs.cells]
    before = np.where(inner, flat_lane[np.maximum(runs.cells - 1, 0)], -1)
    safe = np.maximum(before, 0)
    left = inner & (raster.lane_left[safe] >= 0) & (now == raster.lane_left[safe])
    right = inner & (raster.lane_right[safe] >= 0) & (now == raster.lane_right[safe])
    net = np.bincount(runs.run, weights=left.astype(np.float64) - right, minlength=runs.count)
    return runs.paint(net > 0, off.shape), runs.paint(net < 0, off.shape)


def behavior_tags(
    timestamps_ns: IntArray,
    motion: TrackMotion,
    length_m: FloatArray | None,
    categories: NDArray[np.str_],
    city_SE3_ego: FloatArray,
    raster: MapRaster | None,
    config: CaptioningConfig,
    ego_speed_mps: FloatArray | None = None,
    ego_accel_mps2: FloatArray | None = None,
) -> BehaviorTags:
    """Own-behaviour tags and map context (see the module docstring).

    Args:
        timestamps_ns: (T,) frame timestamps.
        motion: the tracks gathered, bridged and differentiated (:func:`captioning.neighbors.track_motion`),
            K tracks.
        length_m: (K, T) box lengths (None: points, gaps measured between centres).
        categories: (K,) public categories.
        city_SE3_ego: (T, 4, 4) ego poses (the ego is a leader like any vehicle).
        raster: the log's rasterised map, None without lanes.
        ego_speed_mps: (T,) the ego's speed (for braking for the ego; None: never).
        ego_accel_mps2: (T,) the ego's acceleration.
    """
    b = config.behavior
    grid = motion.grid
    k, t = grid.frame.shape[0], timestamps_ns.shape[0]
    t_s = motion.t_s
    kin = object_kinematics(motion, city_SE3_ego, config)
    enough, speed, accel_mps2, yaw = kin.enough, kin.speed_mps, kin.accel_mps2, kin.yaw_rad
    taggable = np.asarray((enough & grid.valid).any(axis=1), dtype=bool)
    vehicle = ~np.isin(np.asarray(categories).astype(str), list(NON_VEHICLES))  # (K,)
    vehicle_cell = vehicle[:, None] & enough
    # City frame: one rigid transform of the host-compensated centres.
    first = motion.positions[..., :2]
    r, o = motion.city_SE3_first[:2, :2], motion.city_SE3_first[:2, 3]
    xy = np.empty(first.shape)
    xy[..., 0] = r[0, 0] * first[..., 0] + r[0, 1] * first[..., 1] + o[0]
    xy[..., 1] = r[1, 0] * first[..., 0] + r[1, 1] * first[..., 1] + o[1]
    frames = FrameCounts.of(config, motion.interval_s)
    w, p, m = frames.behavior_window, frames.behavior_polyorder, frames.min_run
    with np.errstate(invalid="ignore"):
        moving_code = np.where(enough, (speed >= b.stopped_speed_mps).astype(np.int64), NO_TAG)
    moving = suppress_flicker(moving_code, m) == 1

    # Map context at the front of vehicles' boxes (the centre of anything else).
    length = np.zeros(enough.shape) if length_m is None else np.nan_to_num(grid.gather(length_m))
    has_map = raster is not None
    off_lane = curb = None
    if raster is not None:
        half = np.where(vehicle_cell, 0.5 * length, 0.0)
        smooth = frame_derivative(xy, enough, w, p, order=0)
        front = smooth + half[..., None] * np.stack([np.cos(yaw), np.sin(yaw)], axis=2)
        found = lookup(raster, np.where(enough[..., None], front, np.nan))
        in_junction = enough & (found.junction >= 0)
        on_lane = enough & (found.lane >= 0) & ~in_junction
        crosswalk = enough & found.crosswalk
        kind = np.where(enough, junction_kind_codes(raster, found, config.map.junction_approach_m), NO_TAG)
        lateral = found.lateral_m
        no_left = raster.lane_left[np.maximum(found.lane, 0)] < 0
        no_right = raster.lane_right[np.maximum(found.lane, 0)] < 0
        with np.errstate(invalid="ignore"):
            curb = on_lane & (((lateral >= b.parked_curb_offset_m) & no_left)
                              | ((lateral <= -b.parked_curb_offset_m) & no_right))
        off_lane = enough & ~on_lane & ~in_junction
    else:
        in_junction = on_lane = crosswalk = np.zeros_like(enough)
        kind = np.full(enough.shape, NO_TAG, dtype=np.int64)

    # Parked or stopped; braking.
    still = enough & ~moving
    parked = _parked(still & vehicle_cell, enough, t_s, off_lane, curb, config)
    stopped = still & ~parked
    with np.errstate(invalid="ignore"):
        braking_code = np.where(vehicle_cell, (moving & (accel_mps2 <= -b.braking_decel_mps2)).astype(np.int64),
                                NO_TAG)
    braking = suppress_flicker(braking_code, m) == 1

    # Turns: through an intersection, or (without a map) along a run of high yaw rate.
    if has_map:
        turning = vehicle_cell & in_junction
    else:
        turning = vehicle_cell & (np.abs(np.nan_to_num(kin.yaw_rate_rps)) >= b.turn_yaw_rate_rps)
    runs = _Runs.of(turning)
    turned = _turned_rad(runs, yaw)
    turn_min = np.radians(b.turn_min_deg)
    left_turn = runs.paint(turned >= turn_min, turning.shape)
    right_turn = runs.paint(turned <= -turn_min, turning.shape)

    # Lane changes and keeping the lane.
    if raster is not None:
        lane_ok = vehicle_cell & on_lane & ~parked
        left_change, right_change = _lane_changes(lane_ok, found.lane, lateral, raster, b.lane_change_offset_m)
    else:
        left_change = right_change = np.zeros_like(enough)
    keeping = (vehicle_cell & moving & ~parked & ~left_change & ~right_change & ~left_turn & ~right_turn
               & (on_lane | in_junction))

    blocked, braking_for = leader_tags(grid, vehicle_cell & ~parked, braking, xy, yaw, length, speed,
                                        city_SE3_ego, config, ego_speed_mps, ego_accel_mps2)
    compact = {
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
    # The action and context that enter the unified tags (captioning.tags): the first action that holds;
    # a context for objects that stand or brake and for those on foot or on a bicycle.
    action = np.full(enough.shape, NO_TAG, dtype=np.int8)
    for code in range(len(ACTIONS) - 1, -1, -1):
        action[compact[ACTIONS[code]]] = code
    context = np.where(crosswalk, CONTEXTS.index(Context.ON_CROSSWALK),
                       np.where(in_junction, CONTEXTS.index(Context.AT_INTERSECTION), NO_TAG)).astype(np.int8)
    on_foot = np.isin(np.asarray(categories).astype(str), list(CONTEXT_CATEGORIES))[:, None]
    carries = parked | stopped | braking | on_foot
    context[~carries] = NO_TAG
    # One scatter of everything boolean: the labels, then where the tags are known, then the context.
    stacked = np.stack([compact[label] for label in LABELS] + [enough, in_junction, crosswalk], axis=2)
    stacked &= enough[..., None]
    shape = (k, t)
    n_labels = len(LABELS)
    grid_bools = scatter_to_log_grid(grid, stacked, shape, False)
    label_known = np.array([has_map or label not in MAP_LABELS for label in LABELS])
    return BehaviorTags(
        flags=grid_bools[..., :n_labels],
        known_cell=grid_bools[..., n_labels],
        label_known=label_known,
        speed_mps=scatter_to_log_grid(grid, speed, shape, np.nan),
        at_intersection=grid_bools[..., n_labels + 1],
        on_crosswalk=grid_bools[..., n_labels + 2],
        junction_kind=scatter_to_log_grid(grid, kind.astype(np.int8), shape, np.int8(NO_TAG)),
        has_map=has_map,
        taggable=taggable,
        action=scatter_to_log_grid(grid, action, shape, np.int8(NO_TAG)),
        context=scatter_to_log_grid(grid, context, shape, np.int8(NO_TAG)),
    )
