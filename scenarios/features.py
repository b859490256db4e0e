"""Per-log features of every object (and the ego) on the log's frame grid: what scenario programs read.

A program never opens a log: it reads one :class:`LogFeatures` per log, built once from the log's
tracks, ego poses and map and the captioning rules (:func:`build_features`), and cached beside the
captions (:mod:`scenarios.cache`). Everything is an array over K objects × F frames; the ego is the
last row (track id ``ego``, label ``EGO_VEHICLE``), so that relations to the ego are relations like
any other.

Frames, units and conventions: positions, headings and velocities are in the city frame (x, y in
metres; yaw about +z, radians); boxes are sized ``(length, width, height)`` per track; where an
object is not observed, ``valid`` is false and its values are NaN (or zero for flags).

Flags (:data:`FLAGS`) come from the captioning rules (:mod:`captioning.behavior`; the ego's from its
host tags): own behaviour (parked, stopped, braking, turns, lane changes, blocked, braking for a
leader); map context (intersection, on a crosswalk, within :data:`AT_CROSSWALK_M` of one, lane types)
is read at each object's centre.
``ego_lane`` is the object's lane relative to the ego's (:class:`captioning.tags.Lane`): on a log with
a map, from the lane segments under the two centres (the same segment, its left or right neighbour,
or a lane of the other direction within :data:`ONCOMING_LATERAL_M` to the side) and, for crossing
traffic, the captioning's lateral lanes; without a map, the captioning's lane tags; −1 where nothing says.
``lane`` indexes the lane segment under each object (−1 off the lanes), so two objects share a lane
where their indices are equal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from captioning.config import CaptioningConfig
from captioning.map_context import MapLookup, MapRaster, lookup, rasterize_map
from captioning.pipeline import LogCaptions, caption_log
from captioning.tags import HOST_DIRECTIONS, HOST_MOTIONS, LANES, HostDirection, HostMotion, Lane
from scenes.behavior import BehaviorLabel
from scenes.categories import EGO_VEHICLE_LABEL
from scenes.geometry import point_polyline_distance, points_in_polygon, quat_to_yaw, rotmat_to_quat
from scenes.log import Log
from scenes.map import VectorMap

#: Flag bits of :attr:`LogFeatures.flags`, in bit order.
FLAGS: tuple[str, ...] = (
    "parked", "stopped", "braking", "at_crosswalk", "left_turn", "right_turn", "left_lane_change",
    "right_lane_change", "blocked_by", "braking_for", "at_intersection", "on_crosswalk", "on_lane",
    "in_bike_lane", "in_bus_lane", "accelerating_host",
)
#: ``at_crosswalk``: the centre lies within this distance of a pedestrian crossing (inside it included),
#: as RefAV's ``at_pedestrian_crossing``: where pedestrians wait at the kerb to cross.
AT_CROSSWALK_M = 1.0
#: The ego's box (length, width, height in metres): a mid-size sedan, as AV2's ego.
EGO_SIZE_LWH_M = (4.877, 1.852, 1.5)
EGO_TRACK_ID = "ego"
#: Rule labels that become flags of the same name.
_BEHAVIOR_FLAGS = [label for label in BehaviorLabel if label.value in FLAGS]


def flag_bit(name: str) -> int:
    """The bit of flag ``name`` in :attr:`LogFeatures.flags`."""
    return 1 << FLAGS.index(name)


@dataclass(frozen=True)
class LogFeatures:
    """Everything scenario programs read of one log (see the module docstring).

    Attributes:
        log_id: the log.
        timestamps_ns: (F,) annotation timestamps, increasing.
        track_ids: (K,) track ids; the last is the ego's.
        labels: (K,) dataset labels (AV2 vocabulary, e.g. ``REGULAR_VEHICLE``; ``EGO_VEHICLE``).
        categories: (K,) public categories (``car``, ...; ``ego``).
        valid: (K, F) observed.
        xy_m: (K, F, 2) float32 box centres, city frame.
        z_m: (K, F) float32 box centre heights, city frame.
        yaw_rad: (K, F) float32 headings, city frame.
        size_lwh_m: (K, 3) float32 box size of each track (its median).
        velocity_mps: (K, F, 2) float32 velocities, city frame.
        speed_mps: (K, F) float32 smoothed speeds.
        accel_mps2: (K, F) float32 rate of change of the speed.
        flags: (K, F) uint16 bits of :data:`FLAGS`.
        ego_lane: (K, F) int8 lane relative to the ego, −1 untagged.
        lane: (K, F) int32 lane index, −1 off the lanes.
        to_junction_m: (K, F) float32 distance along the lane to the junction it enters (0 inside one,
            inf where the lane enters none or off the lanes).
        has_map: whether the log has a map with lanes (map flags and ``lane`` mean something).
        time_of_day: the log's lighting (``day``, ``dusk``, ``night``) where its metadata says, else ``unknown``.
        weather: the log's weather (``clear``, ``rain``, ``fog``, ``snow``) where known, else ``unknown``.
    """

    log_id: str
    timestamps_ns: NDArray[np.int64]
    track_ids: NDArray[np.str_]
    labels: NDArray[np.str_]
    categories: NDArray[np.str_]
    valid: NDArray[np.bool_]
    xy_m: NDArray[np.float32]
    z_m: NDArray[np.float32]
    yaw_rad: NDArray[np.float32]
    size_lwh_m: NDArray[np.float32]
    velocity_mps: NDArray[np.float32]
    speed_mps: NDArray[np.float32]
    accel_mps2: NDArray[np.float32]
    flags: NDArray[np.uint16]
    ego_lane: NDArray[np.int8]
    lane: NDArray[np.int32]
    to_junction_m: NDArray[np.float32]
    has_map: bool
    time_of_day: str = "unknown"
    weather: str = "unknown"

    @property
    def nbytes(self) -> int:
        """Bytes of its arrays (what a process keeping it in memory holds)."""
        return sum(v.nbytes for v in vars(self).values() if isinstance(v, np.ndarray))

    @property
    def num_objects(self) -> int:
        """K, the ego included."""
        return int(self.track_ids.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.timestamps_ns.shape[0])

    @property
    def ego_index(self) -> int:
        return self.num_objects - 1

    @property
    def time_s(self) -> NDArray[np.float64]:
        """(F,) seconds since the first frame."""
        return (self.timestamps_ns - self.timestamps_ns[0]).astype(np.float64) * 1e-9 if self.num_frames else \
            np.zeros(0)

    def flag(self, name: str) -> NDArray[np.bool_]:
        """(K, F) where flag ``name`` holds (never where the object is not observed)."""
        return ((self.flags & flag_bit(name)) != 0) & self.valid


def time_derivative(values: NDArray[np.float64], valid: NDArray[np.bool_], t_s: NDArray[np.float64]
                     ) -> NDArray[np.float64]:
    """(K, F, ...) derivative over time of ``values`` (K, F, ...), central where both neighbours are
    observed, one-sided at the ends of a run, 0 for isolated frames."""
    k, f = valid.shape
    if f < 2:
        return np.zeros_like(values)
    extra = (1,) * (values.ndim - 2)
    prev_ok = np.zeros_like(valid)
    next_ok = np.zeros_like(valid)
    prev_ok[:, 1:] = valid[:, 1:] & valid[:, :-1]
    next_ok[:, :-1] = valid[:, :-1] & valid[:, 1:]
    # Each frame's neighbours by shifting (a frame without an observed neighbour stands for it), not by
    # gathering with index arrays: the same values at a fraction of the cost on (K, F, 2) arrays.
    before = np.concatenate([values[:, :1], values[:, :-1]], axis=1)
    after = np.concatenate([values[:, 1:], values[:, -1:]], axis=1)
    t_before = np.concatenate([t_s[:1], t_s[:-1]])
    t_after = np.concatenate([t_s[1:], t_s[-1:]])
    lo_ok, hi_ok = prev_ok.reshape(k, f, *extra), next_ok.reshape(k, f, *extra)
    diff = np.where(hi_ok, after, values) - np.where(lo_ok, before, values)
    dt = np.where(next_ok, t_after, t_s) - np.where(prev_ok, t_before, t_s)  # (K, F)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = diff / np.where(dt > 0, dt, np.inf).reshape(k, f, *extra)
    return np.where(valid.reshape(k, f, *extra), np.nan_to_num(out), 0.0)


def _track_labels(log: Log, track_ids: NDArray[np.str_]) -> NDArray[np.str_]:
    """(K,) the dataset label of each track (its first row's)."""
    ann = log.annotations
    ids, first = np.unique(ann.track_id, return_index=True)
    label_of = dict(zip(ids.tolist(), ann.category[first].tolist()))
    return np.asarray([label_of.get(str(t), "UNKNOWN") for t in track_ids], dtype=np.str_)


def build_features(log: Log, config: CaptioningConfig | None = None,
                   captions: LogCaptions | None = None) -> LogFeatures:
    """The features of one log (see the module docstring).

    Args:
        log: the log.
        config: the captioning rules' thresholds (default: the defaults).
        captions: the log's captioning result when the caller has it already.
    """
    config = config or CaptioningConfig()
    dense = log.dense_tracks()
    rules = captions if captions is not None else caption_log(log, config)
    ts = dense.timestamps_ns.astype(np.int64)
    f = ts.shape[0]
    t_s = (ts - ts[0]).astype(np.float64) * 1e-9 if f else np.zeros(0)
    k = dense.track_ids.shape[0]

    # Objects, then the ego as the last row.
    ego_xyz = dense.city_SE3_ego[:, :3, 3]
    ego_yaw = quat_to_yaw(rotmat_to_quat(dense.city_SE3_ego[:, :3, :3])) if f else np.zeros(0)
    valid = np.concatenate([dense.valid, np.ones((1, f), dtype=bool)])
    xyz = np.concatenate([dense.center_city_xyz_m, ego_xyz[None]], axis=0)
    yaw = np.concatenate([dense.yaw_city_rad, ego_yaw[None]], axis=0)
    size = np.nanmedian(np.where(dense.valid[..., None], dense.size_lwh_m, np.nan), axis=1) if f and k else \
        np.zeros((k, 3))
    size = np.concatenate([np.nan_to_num(size), np.asarray([EGO_SIZE_LWH_M])], axis=0)
    velocity = time_derivative(np.nan_to_num(xyz[..., :2]), valid, t_s)
    speed = np.linalg.norm(velocity, axis=-1)
    behavior = rules.behavior
    if behavior is not None:  # the rules' smoothed speeds where they have them
        smooth = np.concatenate([behavior.speed_mps, np.full((1, f), np.nan)])
        speed = np.where(np.isfinite(smooth), smooth, speed)
    accel = time_derivative(speed, valid, t_s)

    flags = np.zeros((k + 1, f), dtype=np.uint16)

    def put(name: str, mask: NDArray[np.bool_]) -> None:
        nonlocal flags
        flags |= np.where(mask, flag_bit(name), 0).astype(np.uint16)

    if behavior is not None:
        labels = [label.value for label in BehaviorLabel]
        for label in _BEHAVIOR_FLAGS:
            column = behavior.flags[..., labels.index(label.value)] & behavior.known_cell
            put(label.value, np.concatenate([column, np.zeros((1, f), bool)]))
    _put_host_flags(rules, put, k)

    lane = np.full((k + 1, f), -1, dtype=np.int32)
    to_junction = np.full((k + 1, f), np.inf, dtype=np.float64)
    has_map = False
    map_lanes: NDArray[np.int8] | None = None
    vector_map = log.map
    if vector_map is not None and vector_map.lane_segments:
        raster = rasterize_map(vector_map, np.nan_to_num(xyz[..., :2][valid]), config.map)
        if raster is not None:
            has_map = True
            found = lookup(raster, np.where(valid[..., None], xyz[..., :2], np.nan))
            lane = found.lane.astype(np.int32)
            on_lane = lane >= 0
            enters = np.where(on_lane, raster.lane_junction[np.maximum(lane, 0)], -1) if raster.lane_junction.size \
                else np.full(lane.shape, -1)
            to_junction = np.where(found.junction >= 0, 0.0,
                                   np.where(enters >= 0, np.nan_to_num(found.to_lane_end_m, nan=np.inf), np.inf))
            put("on_lane", on_lane | (found.junction >= 0))
            types = {int(i): s.lane_type.upper() for i, s in vector_map.lane_segments.items()}
            lane_type = np.asarray([types.get(int(i), "VEHICLE") for i in raster.lane_ids], dtype=np.str_)
            if lane_type.size:
                of_lane = lane_type[np.maximum(lane, 0)]
                put("in_bike_lane", on_lane & (of_lane == "BIKE"))
                put("in_bus_lane", on_lane & (of_lane == "BUS"))
            # Where an object is on the map is where its centre is, for every kind (the behaviour rules
            # look at a vehicle's front instead, to tag it as it enters an intersection).
            put("at_intersection", found.junction >= 0)
            # Exactly, from the crossings' outlines: the raster's crosswalk cells take in the cells an
            # outline touches, up to a cell beyond it, where pedestrians wait at the kerb.
            crossing_m = crossing_distance_m(vector_map, np.nan_to_num(xyz[..., :2], nan=np.inf), AT_CROSSWALK_M)
            put("on_crosswalk", valid & (crossing_m == 0.0))
            put("at_crosswalk", valid & (crossing_m <= AT_CROSSWALK_M))
            map_lanes = map_ego_lane(raster, found, np.where(valid[..., None], xyz[..., :2], np.nan), ego_yaw)

    ego_lane = np.full((k + 1, f), -1, dtype=np.int8)
    nb = rules.neighbors
    ego_lane[:k] = np.where(nb.tagged, nb.lane, -1)
    if map_lanes is not None:  # the map says which lane an object is in better than its offset from the ego;
        # crossing traffic has no lane of the ego's, so its tag (the lateral lanes) stays
        lateral = np.isin(ego_lane, [LANES.index(m) for m in (Lane.LEFT_LATERAL, Lane.RIGHT_LATERAL,
                                                               Lane.HOST_LATERAL)])
        ego_lane = np.where(map_lanes >= 0, map_lanes, np.where(lateral, ego_lane, -1)).astype(np.int8)

    track_ids = np.asarray([*map(str, dense.track_ids), EGO_TRACK_ID], dtype=np.str_)
    appearance = log.metadata.appearance
    return LogFeatures(
        log_id=log.log_id, timestamps_ns=ts, track_ids=track_ids,
        labels=np.asarray([*_track_labels(log, dense.track_ids), EGO_VEHICLE_LABEL], dtype=np.str_),
        categories=np.asarray([*map(str, dense.categories), "ego"], dtype=np.str_),
        valid=valid, xy_m=np.where(valid[..., None], xyz[..., :2], np.nan).astype(np.float32),
        z_m=np.where(valid, xyz[..., 2], np.nan).astype(np.float32),
        yaw_rad=np.where(valid, yaw, np.nan).astype(np.float32), size_lwh_m=size.astype(np.float32),
        velocity_mps=velocity.astype(np.float32), speed_mps=np.where(valid, speed, 0.0).astype(np.float32),
        accel_mps2=accel.astype(np.float32), flags=np.where(valid, flags, 0).astype(np.uint16),
        ego_lane=ego_lane, lane=np.where(valid, lane, -1).astype(np.int32),
        to_junction_m=np.where(valid, to_junction, np.inf).astype(np.float32), has_map=has_map,
        time_of_day=str(appearance.get("time_of_day", "unknown")), weather=str(appearance.get("weather", "unknown")),
    )


def crossing_distance_m(vector_map: VectorMap, xy_m: NDArray[np.floating], within_m: float) -> NDArray[np.float64]:
    """(...,) distance from each point (..., 2) to the nearest of the map's pedestrian crossings: 0 inside
    one, the distance to its outline up to ``within_m``, inf beyond. Only the points in a crossing's
    bounding box grown by ``within_m`` are measured."""
    distance_m = np.full(xy_m.shape[:-1], np.inf)
    for crossing in vector_map.pedestrian_crossings.values():
        polygon = crossing.polygon()[:, :2]
        lo, hi = polygon.min(axis=0) - within_m, polygon.max(axis=0) + within_m
        box = np.all((xy_m >= lo) & (xy_m <= hi), axis=-1) & (distance_m > 0.0)
        if not box.any():
            continue
        points = xy_m[box]
        outline = np.concatenate([polygon, polygon[:1]])  # closed
        here = np.where(points_in_polygon(points, polygon), 0.0, point_polyline_distance(points, outline))
        distance_m[box] = np.minimum(distance_m[box], np.where(here <= within_m, here, np.inf))
    return distance_m


#: An oncoming lane's object lies at most this far to the side of the ego.
ONCOMING_LATERAL_M = 10.0


def map_ego_lane(raster: MapRaster, found: MapLookup, xy_m: NDArray[np.float64], ego_yaw_rad: NDArray[np.float64]
                 ) -> NDArray[np.int8]:
    """(K+1, F) :data:`captioning.tags.LANES` code of each object's lane relative to the ego's, from the map.

    Args:
        raster: the log's map raster.
        found: (K+1, F) its lookup at the objects' centres, the ego last.
        xy_m: (K+1, F, 2) city positions, NaN where unobserved.
        ego_yaw_rad: (F,) the ego's heading.

    The same lane segment is the host lane, the segment's left / right neighbour the left / right lane;
    a lane whose direction differs from the ego lane's by more than 135° and whose object is at most
    :data:`ONCOMING_LATERAL_M` to the side of the ego is oncoming. −1 elsewhere, the ego's own row, and
    wherever the ego or the object is off the lanes (in an intersection).
    """
    lane = found.lane
    ego = lane[-1]  # (F,)
    mine = np.maximum(ego, 0)[None, :]
    on = (lane >= 0) & (ego >= 0)[None, :]
    host = on & (lane == ego[None, :])
    left = on & ~host & (lane == raster.lane_left[mine])
    right = on & ~host & ~left & (lane == raster.lane_right[mine])
    gap = np.angle(np.exp(1j * (found.lane_heading_rad - found.lane_heading_rad[-1][None, :])))
    dx, dy = (xy_m - xy_m[-1][None]).transpose(2, 0, 1)  # (K+1, F) each
    lateral = -np.sin(ego_yaw_rad)[None, :] * dx + np.cos(ego_yaw_rad)[None, :] * dy
    with np.errstate(invalid="ignore"):
        oncoming = on & ~(host | left | right) & (np.abs(gap) > np.radians(135.0)) \
            & (np.abs(lateral) <= ONCOMING_LATERAL_M)
    codes = np.full(lane.shape, -1, dtype=np.int8)
    for mask, member in ((host, Lane.HOST), (left, Lane.LEFT), (right, Lane.RIGHT), (oncoming, Lane.ONCOMING)):
        codes[mask] = LANES.index(member)
    codes[-1] = -1
    return codes


def _put_host_flags(rules: LogCaptions, put: Callable[[str, NDArray[np.bool_]], None], k: int) -> None:
    """The ego's flags from its host tags: standing, accelerating and steering. Its braking is read from its
    speed, as every object's is (``braking``'s ``min_mps2``): the host tag "decelerating" takes in gentler
    slowing than a brake."""
    row = np.arange(k + 1)[:, None] == k
    for name, codes, member, members in (
        ("stopped", rules.host_motion, HostMotion.STATIONARY, HOST_MOTIONS),
        ("accelerating_host", rules.host_motion, HostMotion.ACCELERATING, HOST_MOTIONS),
        ("left_turn", rules.host_direction, HostDirection.STEERING_LEFT, HOST_DIRECTIONS),
        ("right_turn", rules.host_direction, HostDirection.STEERING_RIGHT, HOST_DIRECTIONS),
    ):
        put(name, row & (codes == list(members).index(member))[None, :])
