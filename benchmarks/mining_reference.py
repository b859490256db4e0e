"""Reference answers of scenario programs: plain per-object, per-frame Python loops over true boxes,
the simulator's behaviour labels and the map.

This is the ground truth of the mining benchmark and its speed baseline. It shares no code with
:mod:`scenarios`' vectorised evaluation or features (it reads only the program tree and writes a
:class:`scenarios.answer.LogAnswer`), so a disagreement between the two shows that one of them is
wrong. Every test is written again from its definition, one object and one frame at a time:

- **Kinds**: RefAV's groups of AV2 labels (:data:`KIND_LABELS`); ``any`` is every object but the ego.
- **Own behaviour** comes from ``behavior_labels.feather`` (the simulator's state, not the boxes):
  ``parked``, ``stopped`` (not parked), ``braking``, ``turning`` (left / right turn labels),
  ``changing_lanes``, ``blocked``, ``braking_for_leader``; ``moving``: labelled speed above
  ``min_mps``; ``accelerating``: the labelled speed rises by at least ``min_mps2`` over the second
  centred on the frame (clipped to the track), while above 0.5 m/s. An object without label rows
  (street furniture) has no behaviour flags and its speed from its box centres.
- **Map context**: ``at_intersection``: the box centre lies in a junction outline of
  ``junctions.feather`` (the simulator's junctions of three or more roads); ``near_intersection``:
  within ``within_m`` of such an outline; ``on_crosswalk``: in a pedestrian crossing of the map.
- **Relative to the ego** (the ego's box is AV2's, centred on its pose): the lane under a centre is
  the map's lane segment outside junctions whose outline holds it. ``ego_lane`` ``host``: the ego's
  lane segment; ``left`` / ``right``: the ego lane's left / right neighbour; ``oncoming``: a lane
  whose direction differs from the ego lane's by more than 135°, with the centre at most
  :data:`ONCOMING_LATERAL_M` to the side of the ego; ``approaching_ego``: moving, and the centre
  distance to the ego shrinks by at least 1 m/s (central difference).
- **Relations** (:mod:`scenarios.relations`' definitions): geometry in the subject's frame; the gap
  is the exact distance between the two rectangles (0 when they overlap). ``direction``: the other's
  centre beyond the subject's box on that side, within ``lateral_m`` of the box's sides and
  ``within_m`` of the box; ``near``; ``following`` (in front within ``within_m`` and ``lateral_m``,
  headings within 45°, the subject moving); ``same_lane``; ``crossed_by`` (the other's centre
  changes side of the subject's heading line between two frames, both inside the zone up to
  ``forward_m`` past the front and ``lateral_m`` aside; the pair's frames within ``window_s``
  count; a centre within :data:`ON_LINE_M` of the line is on neither side, so an object that walks
  along the line does not cross it at every rounding of its offset).
- **Composition and time** as :mod:`scenarios.program` states: ``Has`` with counts, negation and
  ``reverse``; ``Between`` (either kind on either side, boxes within 50 m); and / or / but not;
  ``Together``; ``ForAtLeast`` (a run lasts from its first frame to its last plus one frame
  interval); ``Then`` (the same object, the second starting after a frame of the first, within
  ``within_s``); ``While`` (the condition holds for any object at that frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

from scenarios import program as p
from scenarios.answer import LogAnswer
from scenes.behavior import EGO_TRACK_ID, read_behavior_labels, read_junctions
from scenes.categories import AV2_TO_CATEGORY, EGO_VEHICLE_LABEL
from scenes.geometry import quat_to_yaw, rotmat_to_quat
from scenes.log import Log

Grid = list[list[bool]]
T = TypeVar("T")
Params = dict[str, float | str]

#: The ego's box (length, width in metres): AV2's ego, a mid-size sedan.
EGO_LENGTH_M, EGO_WIDTH_M = 4.877, 1.852
#: An oncoming lane lies at most this far to the side of the ego.
ONCOMING_LATERAL_M = 10.0
#: A centre this close to the subject's heading line is on it, on neither side (it has not crossed).
ON_LINE_M = 0.001
#: Distances to a junction are resolved up to this far (farther ones read as infinite).
JUNCTION_MARGIN_M = 20.0
#: Cell size of the lookup grid of map polygons.
_CELL_M = 25.0
_VEHICLES = {"REGULAR_VEHICLE", "LARGE_VEHICLE", "BUS", "BOX_TRUCK", "TRUCK", "VEHICULAR_TRAILER", "TRUCK_CAB",
             "SCHOOL_BUS", "ARTICULATED_BUS", "MESSAGE_BOARD_TRAILER", "RAILED_VEHICLE"}
_VRU = {"PEDESTRIAN", "OFFICIAL_SIGNALER", "BICYCLIST", "BICYCLE", "WHEELED_RIDER", "MOTORCYCLIST", "MOTORCYCLE",
        "WHEELCHAIR", "STROLLER", "WHEELED_DEVICE"}
#: Kind → the AV2 labels it covers (``any``: all but the ego).
KIND_LABELS: dict[str, set[str]] = {
    "vehicle": _VEHICLES, "car": {"REGULAR_VEHICLE"},
    "truck": {"BOX_TRUCK", "TRUCK", "TRUCK_CAB", "LARGE_VEHICLE"}, "box_truck": {"BOX_TRUCK"},
    "bus": {"BUS", "ARTICULATED_BUS", "SCHOOL_BUS"}, "pedestrian": {"PEDESTRIAN", "OFFICIAL_SIGNALER"},
    "cyclist": {"BICYCLIST", "BICYCLE", "WHEELED_RIDER"}, "motorcycle": {"MOTORCYCLIST", "MOTORCYCLE"},
    "vulnerable_road_user": _VRU, "any": set(AV2_TO_CATEGORY), "ego": {EGO_VEHICLE_LABEL},
}
_FLAGS = ("parked", "stopped", "braking", "keeping_lane", "left_turn", "right_turn", "left_lane_change",
          "right_lane_change", "blocked_by", "braking_for")
_PREDICATE_DEFAULTS: dict[str, Params] = {
    "moving": {"min_mps": 0.5}, "stopped": {}, "parked": {}, "braking": {}, "accelerating": {"min_mps2": 0.65},
    "turning": {"direction": "any"}, "changing_lanes": {"direction": "any"}, "blocked": {},
    "braking_for_leader": {}, "at_intersection": {}, "near_intersection": {"within_m": 5.0}, "on_crosswalk": {},
    "ego_lane": {"lane": "host"}, "approaching_ego": {},
}
_RELATION_DEFAULTS: dict[str, Params] = {
    "direction": {"side": "front", "within_m": 50.0, "lateral_m": 1000.0}, "near": {"within_m": 10.0},
    "following": {"within_m": 25.0, "lateral_m": 1.5}, "same_lane": {"within_m": 50.0},
    "crossed_by": {"forward_m": 10.0, "lateral_m": 5.0, "window_s": 1.0},
}


class ReferenceError(ValueError):
    """A program the reference does not answer (a predicate or relation it does not define)."""


@dataclass
class ReferenceLog:
    """One log as the reference reads it: lists indexed ``[object][frame]``, the ego last.

    Attributes:
        log_id: the log.
        timestamps_ns: F annotation timestamps.
        time_s: F seconds since the first.
        track_ids, labels: K track ids and AV2 labels (``EGO_VEHICLE`` for the ego).
        valid: observed.
        x, y, yaw: box centre and heading in the city frame (NaN where not observed).
        z: box centre height.
        length, width, height: box size.
        speed: labelled speed (from the centres where the object has no label rows).
        flags: behaviour label → grid.
        lane: lane segment id under the centre (outside junctions), −1 off them.
        in_junction: in a junction outline; junction_m: distance to the nearest outline.
        on_crosswalk: on a pedestrian crossing.
        ego_lane: ``host``, ``left``, ``right``, ``oncoming`` or ``""``.
    """

    log_id: str
    timestamps_ns: list[int]
    time_s: list[float]
    track_ids: list[str]
    labels: list[str]
    valid: Grid
    x: list[list[float]]
    y: list[list[float]]
    z: list[list[float]]
    yaw: list[list[float]]
    length: list[list[float]]
    width: list[list[float]]
    height: list[list[float]]
    speed: list[list[float]]
    flags: dict[str, Grid]
    lane: list[list[int]]
    in_junction: Grid
    junction_m: list[list[float]]
    on_crosswalk: Grid
    ego_lane: list[list[str]]

    @property
    def num_objects(self) -> int:
        return len(self.track_ids)

    @property
    def num_frames(self) -> int:
        return len(self.timestamps_ns)


# ---------------------------------------------------------------------------------- plane geometry


def point_in_polygon(px: float, py: float, polygon: list[tuple[float, float]]) -> bool:
    """Whether (px, py) lies inside ``polygon`` (vertices in order), by counting edge crossings."""
    inside = False
    n = len(polygon)
    j = n - 1
    for i in range(n):
        xi, yi = polygon[i]
        xj, yj = polygon[j]
        if (yi > py) != (yj > py) and px < (xj - xi) * (py - yi) / (yj - yi) + xi:
            inside = not inside
        j = i
    return inside


def point_segment_distance(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    """Distance from (px, py) to the segment from (ax, ay) to (bx, by)."""
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, ((px - ax) * dx + (py - ay) * dy) / length2))
    return math.hypot(px - (ax + t * dx), py - (ay + t * dy))


def polygon_distance(px: float, py: float, polygon: list[tuple[float, float]]) -> float:
    """Distance from (px, py) to ``polygon``: 0 inside, else to its nearest edge."""
    if point_in_polygon(px, py, polygon):
        return 0.0
    best = math.inf
    for i in range(len(polygon)):
        ax, ay = polygon[i - 1]
        bx, by = polygon[i]
        best = min(best, point_segment_distance(px, py, ax, ay, bx, by))
    return best


def box_corners(x: float, y: float, yaw: float, length: float, width: float) -> list[tuple[float, float]]:
    """The four corners of a box, counter-clockwise from front-left."""
    c, s = math.cos(yaw), math.sin(yaw)
    out = []
    for fx, fy in ((0.5, 0.5), (-0.5, 0.5), (-0.5, -0.5), (0.5, -0.5)):
        lx, ly = fx * length, fy * width
        out.append((x + c * lx - s * ly, y + s * lx + c * ly))
    return out


def _segments_cross(a: tuple[float, float], b: tuple[float, float], c: tuple[float, float],
                    d: tuple[float, float]) -> bool:
    def side(p: tuple[float, float], q: tuple[float, float], r: tuple[float, float]) -> float:
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])

    return side(a, b, c) * side(a, b, d) < 0 and side(c, d, a) * side(c, d, b) < 0


def box_gap(first: list[tuple[float, float]], second: list[tuple[float, float]]) -> float:
    """The distance between two rectangles given by their corners: 0 where they overlap."""
    for px, py in first:
        if point_in_polygon(px, py, second):
            return 0.0
    for px, py in second:
        if point_in_polygon(px, py, first):
            return 0.0
    for i in range(4):
        for j in range(4):
            if _segments_cross(first[i - 1], first[i], second[j - 1], second[j]):
                return 0.0
    best = math.inf
    for one, other in ((first, second), (second, first)):
        for px, py in one:
            for i in range(4):
                ax, ay = other[i - 1]
                bx, by = other[i]
                best = min(best, point_segment_distance(px, py, ax, ay, bx, by))
    return best


def wrap(angle: float) -> float:
    """``angle`` wrapped to (−π, π]."""
    out = math.fmod(angle + math.pi, 2 * math.pi)
    if out <= 0:
        out += 2 * math.pi
    return out - math.pi


class _PolygonGrid:
    """Polygons bucketed by the grid cells their bounding boxes (grown by ``margin``) touch."""

    def __init__(self, polygons: list[tuple[int, list[tuple[float, float]]]], margin: float = 0.0) -> None:
        self.polygons = polygons
        self.cells: dict[tuple[int, int], list[int]] = {}
        for index, (_, polygon) in enumerate(polygons):
            xs = [p[0] for p in polygon]
            ys = [p[1] for p in polygon]
            for cx in range(math.floor((min(xs) - margin) / _CELL_M), math.floor((max(xs) + margin) / _CELL_M) + 1):
                for cy in range(math.floor((min(ys) - margin) / _CELL_M),
                                math.floor((max(ys) + margin) / _CELL_M) + 1):
                    self.cells.setdefault((cx, cy), []).append(index)

    def near(self, x: float, y: float) -> list[tuple[int, list[tuple[float, float]]]]:
        return [self.polygons[i] for i in self.cells.get((math.floor(x / _CELL_M), math.floor(y / _CELL_M)), [])]


# ---------------------------------------------------------------------------------- reading a log


def _central_rate(values: list[float], valid: list[bool], times: list[float], half_window_s: float) -> list[float]:
    """Rate of change of ``values`` per frame over the observed frames within ``half_window_s`` either side."""
    n = len(values)
    out = [0.0] * n
    for f in range(n):
        if not valid[f]:
            continue
        lo = f
        while lo - 1 >= 0 and valid[lo - 1] and times[f] - times[lo - 1] <= half_window_s + 1e-9:
            lo -= 1
        hi = f
        while hi + 1 < n and valid[hi + 1] and times[hi + 1] - times[f] <= half_window_s + 1e-9:
            hi += 1
        if hi > lo:
            out[f] = (values[hi] - values[lo]) / (times[hi] - times[lo])
    return out


def _lane_direction(centerline: list[tuple[float, float]], x: float, y: float) -> tuple[float, float]:
    """Unit direction of travel of the centre-line segment nearest (x, y)."""
    best, direction = math.inf, (1.0, 0.0)
    for i in range(1, len(centerline)):
        (ax, ay), (bx, by) = centerline[i - 1], centerline[i]
        d = point_segment_distance(x, y, ax, ay, bx, by)
        norm = math.hypot(bx - ax, by - ay)
        if d < best and norm > 0:
            best, direction = d, ((bx - ax) / norm, (by - ay) / norm)
    return direction


def load_reference_log(log_dir: Path | str) -> ReferenceLog:
    """Read one log for the reference: true boxes, ego poses, behaviour labels, junctions and map.

    Raises:
        LogFormatError: the log cannot be read.
    """
    log = Log.open(log_dir)
    dense = log.dense_tracks()
    ann = log.annotations
    label_of: dict[str, str] = {}
    for track, label in zip(ann.track_id.tolist(), ann.category.tolist()):
        label_of.setdefault(str(track), str(label))
    timestamps = [int(t) for t in dense.timestamps_ns.tolist()]
    t0 = timestamps[0] if timestamps else 0
    time_s = [(t - t0) * 1e-9 for t in timestamps]
    nf = len(timestamps)
    track_ids = [str(t) for t in dense.track_ids.tolist()] + [EGO_TRACK_ID]
    labels = [label_of.get(t, "UNKNOWN") for t in track_ids[:-1]] + [EGO_VEHICLE_LABEL]
    valid = [[bool(v) for v in row] for row in dense.valid.tolist()] + [[True] * nf]
    centres = dense.center_city_xyz_m.tolist()
    yaws = dense.yaw_city_rad.tolist()
    sizes = dense.size_lwh_m.tolist()
    ego_yaw = quat_to_yaw(rotmat_to_quat(dense.city_SE3_ego[:, :3, :3])).tolist() if nf else []
    ego_xyz = dense.city_SE3_ego[:, :3, 3].tolist()
    x = [[c[0] for c in row] for row in centres] + [[p[0] for p in ego_xyz]]
    y = [[c[1] for c in row] for row in centres] + [[p[1] for p in ego_xyz]]
    z = [[c[2] for c in row] for row in centres] + [[p[2] for p in ego_xyz]]
    yaw = [list(row) for row in yaws] + [list(ego_yaw)]
    length = [[s[0] for s in row] for row in sizes] + [[EGO_LENGTH_M] * nf]
    width = [[s[1] for s in row] for row in sizes] + [[EGO_WIDTH_M] * nf]
    height = [[s[2] for s in row] for row in sizes] + [[1.5] * nf]
    k = len(track_ids)

    # Behaviour labels, looked up per (timestamp, track).
    rows: dict[tuple[int, str], dict[str, object]] = {}
    table = read_behavior_labels(log.log_dir)
    if table is not None:
        for row in table.to_pylist():
            rows[(int(row["timestamp_ns"]), str(row["track_id"]))] = row
    flags: dict[str, Grid] = {name: [[False] * nf for _ in range(k)] for name in _FLAGS}
    speed = [[0.0] * nf for _ in range(k)]
    for o in range(k):
        labelled = [False] * nf
        for f in range(nf):
            row = rows.get((timestamps[f], track_ids[o]))
            if row is None or not valid[o][f]:
                continue
            labelled[f] = True
            speed[o][f] = float(row["speed_mps"])  # type: ignore[arg-type]
            for name in _FLAGS:
                flags[name][o][f] = bool(row[name])
        if not any(labelled):  # no label rows: the speed of its centres
            vx = _central_rate(x[o], valid[o], time_s, 0.1)
            vy = _central_rate(y[o], valid[o], time_s, 0.1)
            speed[o] = [math.hypot(a, b) if valid[o][f] else 0.0 for f, (a, b) in enumerate(zip(vx, vy))]

    # Map context.
    lanes: list[tuple[int, list[tuple[float, float]]]] = []
    crossings: list[tuple[int, list[tuple[float, float]]]] = []
    segments = {}
    vector_map = log.map
    if vector_map is not None:
        segments = dict(vector_map.lane_segments)
        for lane_id in sorted(segments):
            if not segments[lane_id].is_intersection:
                lanes.append((lane_id, [(float(p[0]), float(p[1])) for p in segments[lane_id].polygon().tolist()]))
        for crossing_id in sorted(vector_map.pedestrian_crossings):
            outline = vector_map.pedestrian_crossings[crossing_id].polygon().tolist()
            crossings.append((crossing_id, [(float(p[0]), float(p[1])) for p in outline]))
    junction_table = read_junctions(log.log_dir)
    junctions: list[tuple[int, list[tuple[float, float]]]] = []
    if junction_table is not None:
        for index, row in enumerate(junction_table.to_pylist()):
            if row["polygon_x_m"]:
                junctions.append((index, list(zip(row["polygon_x_m"], row["polygon_y_m"]))))
    lane_grid, crossing_grid = _PolygonGrid(lanes), _PolygonGrid(crossings)
    junction_grid = _PolygonGrid(junctions, JUNCTION_MARGIN_M)
    centerlines = {i: [(float(p[0]), float(p[1])) for p in s.centerline(20).tolist()] for i, s in segments.items()}

    lane = [[-1] * nf for _ in range(k)]
    in_junction = [[False] * nf for _ in range(k)]
    junction_m = [[math.inf] * nf for _ in range(k)]
    on_crosswalk = [[False] * nf for _ in range(k)]
    for o in range(k):
        for f in range(nf):
            if not valid[o][f]:
                continue
            px, py = x[o][f], y[o][f]
            for lane_id, polygon in lane_grid.near(px, py):
                if point_in_polygon(px, py, polygon):
                    lane[o][f] = lane_id
                    break
            for _, polygon in crossing_grid.near(px, py):
                if point_in_polygon(px, py, polygon):
                    on_crosswalk[o][f] = True
                    break
            for _, polygon in junction_grid.near(px, py):
                d = polygon_distance(px, py, polygon)
                junction_m[o][f] = min(junction_m[o][f], d)
            in_junction[o][f] = junction_m[o][f] == 0.0

    ego_lane = [[""] * nf for _ in range(k)]
    e = k - 1
    for f in range(nf):
        mine = lane[e][f]
        if mine < 0:
            continue
        segment = segments[mine]
        ex, ey = _lane_direction(centerlines[mine], x[e][f], y[e][f])
        for o in range(k - 1):
            theirs = lane[o][f]
            if not valid[o][f] or theirs < 0:
                continue
            if theirs == mine:
                ego_lane[o][f] = "host"
            elif theirs == segment.left_neighbor_id:
                ego_lane[o][f] = "left"
            elif theirs == segment.right_neighbor_id:
                ego_lane[o][f] = "right"
            else:
                ox, oy = _lane_direction(centerlines[theirs], x[o][f], y[o][f])
                dx, dy = x[o][f] - x[e][f], y[o][f] - y[e][f]
                lateral = -math.sin(yaw[e][f]) * dx + math.cos(yaw[e][f]) * dy
                if ex * ox + ey * oy < math.cos(math.radians(135.0)) and abs(lateral) <= ONCOMING_LATERAL_M:
                    ego_lane[o][f] = "oncoming"
    return ReferenceLog(log.log_id, timestamps, time_s, track_ids, labels, valid, x, y, z, yaw, length, width,
                        height, speed, flags, lane, in_junction, junction_m, on_crosswalk, ego_lane)


# ---------------------------------------------------------------------------------- evaluating a program


@dataclass
class _Sel:
    """Selected objects × frames, and the objects related to them."""

    sel: Grid
    related: Grid


def _params(defaults: dict[str, Params], name: str, given: tuple[tuple[str, float | str], ...]) -> Params:
    if name not in defaults:
        raise ReferenceError(f"the reference does not define {name!r} (it defines {', '.join(sorted(defaults))})")
    out = dict(defaults[name])
    for key, value in given:
        if key not in out:
            raise ReferenceError(f"{name}: unknown parameter {key!r}")
        out[key] = value if isinstance(out[key], str) else float(value)
    return out


class _Reference:
    """One program on one :class:`ReferenceLog`, node by node, with plain loops."""

    def __init__(self, log: ReferenceLog) -> None:
        self.log = log
        self.k, self.f = log.num_objects, log.num_frames
        intervals = sorted(b - a for a, b in zip(log.time_s, log.time_s[1:]))
        self.dt = intervals[len(intervals) // 2] if intervals else 0.0

    def grid(self, value: bool = False) -> Grid:
        return [[value] * self.f for _ in range(self.k)]

    def any_at(self, grid: Grid) -> list[bool]:
        return [any(grid[o][f] for o in range(self.k)) for f in range(self.f)]

    def eval(self, node: p.Node) -> _Sel:
        log, k, nf = self.log, self.k, self.f
        match node:
            case p.Objects(kind):
                if kind not in KIND_LABELS:
                    raise ReferenceError(f"the reference does not define the kind {kind!r}")
                covered = KIND_LABELS[kind]
                sel = self.grid()
                for o in range(k):
                    if log.labels[o] in covered and not (kind == "any" and log.labels[o] == EGO_VEHICLE_LABEL):
                        for f in range(nf):
                            sel[o][f] = log.valid[o][f]
                return _Sel(sel, self.grid())
            case p.Is(subject, predicate, params, negate):
                resolved = _params(_PREDICATE_DEFAULTS, predicate, params)
                child = self.eval(subject)
                holds = self.predicate(predicate, resolved)
                keep = self.grid()
                for o in range(k):
                    for f in range(nf):
                        keep[o][f] = log.valid[o][f] and (holds[o][f] != negate)
                return self.keep(child, keep)
            case p.Has():
                return self.relation(node)
            case p.Between(subject, left, right, lateral_m):
                return self.between(self.eval(subject), self.eval(left), self.eval(right), float(lateral_m))
            case p.AllOf(children):
                parts = [self.eval(c) for c in children]
                sel = self.grid()
                for o in range(k):
                    for f in range(nf):
                        sel[o][f] = all(part.sel[o][f] for part in parts)
                on = self.any_at(sel)
                related = self.grid()
                for o in range(k):
                    for f in range(nf):
                        related[o][f] = on[f] and any(part.related[o][f] for part in parts)
                return _Sel(sel, related)
            case p.AnyOf(children):
                parts = [self.eval(c) for c in children]
                sel, related = self.grid(), self.grid()
                for o in range(k):
                    for f in range(nf):
                        sel[o][f] = any(part.sel[o][f] for part in parts)
                        related[o][f] = any(part.related[o][f] for part in parts)
                return _Sel(sel, related)
            case p.Excluding(base, excluded):
                kept, out = self.eval(base), self.eval(excluded)
                return self.keep(kept, [[not out.sel[o][f] for f in range(nf)] for o in range(k)])
            case p.Together(child, min_count):
                part = self.eval(child)
                counts = [sum(part.sel[o][f] for o in range(k)) for f in range(nf)]
                return self.keep(part, [[counts[f] >= min_count for f in range(nf)] for _ in range(k)])
            case p.ForAtLeast(child, seconds):
                part = self.eval(child)
                return self.keep(part, self.runs_lasting(part.sel, float(seconds)))
            case p.Then(first, second, within_s):
                a, b = self.eval(first), self.eval(second)
                keep = self.then_within(a.sel, b.sel, float(within_s))
                on = self.any_at(keep)
                related = [[on[f] and (a.related[o][f] or b.related[o][f]) for f in range(nf)] for o in range(k)]
                return _Sel(keep, related)
            case p.While(child, condition):
                part, cond = self.eval(child), self.eval(condition)
                when = self.any_at(cond.sel)
                kept = self.keep(part, [list(when) for _ in range(k)])
                on = self.any_at(kept.sel)
                related = [[kept.related[o][f] or (cond.sel[o][f] and on[f]) for f in range(nf)] for o in range(k)]
                return _Sel(kept.sel, related)
        raise ReferenceError(f"not a program node: {node!r}")

    def keep(self, part: _Sel, mask: Grid) -> _Sel:
        """``part`` where ``mask`` holds; its related objects only at frames where something stays selected."""
        sel = [[part.sel[o][f] and mask[o][f] for f in range(self.f)] for o in range(self.k)]
        on = self.any_at(sel)
        return _Sel(sel, [[part.related[o][f] and on[f] for f in range(self.f)] for o in range(self.k)])

    # -- own state -------------------------------------------------------------------------------------
    def predicate(self, name: str, p: Params) -> Grid:
        log, k, nf = self.log, self.k, self.f
        out = self.grid()
        if name == "accelerating":
            for o in range(k):
                rate = _central_rate(log.speed[o], log.valid[o], log.time_s, 0.5)
                for f in range(nf):
                    out[o][f] = rate[f] >= float(p["min_mps2"]) and log.speed[o][f] > 0.5
            return out
        if name == "approaching_ego":
            e = k - 1
            for o in range(k - 1):
                distance = [math.hypot(log.x[o][f] - log.x[e][f], log.y[o][f] - log.y[e][f]) if log.valid[o][f]
                            else 0.0 for f in range(nf)]
                rate = _central_rate(distance, log.valid[o], log.time_s, 0.1)
                for f in range(nf):
                    out[o][f] = log.valid[o][f] and log.speed[o][f] > 0.5 and rate[f] <= -1.0
            return out
        for o in range(k):
            for f in range(nf):
                if not log.valid[o][f]:
                    continue
                flag = {n: log.flags[n][o][f] for n in _FLAGS}
                if name == "moving":
                    out[o][f] = log.speed[o][f] > float(p["min_mps"])
                elif name == "stopped":
                    out[o][f] = flag["stopped"] and not flag["parked"]
                elif name in ("parked", "braking"):
                    out[o][f] = flag[name]
                elif name == "blocked":
                    out[o][f] = flag["blocked_by"]
                elif name == "braking_for_leader":
                    out[o][f] = flag["braking_for"]
                elif name in ("turning", "changing_lanes"):
                    left, right = ("left_turn", "right_turn") if name == "turning" else \
                        ("left_lane_change", "right_lane_change")
                    way = p["direction"]
                    out[o][f] = (way in ("left", "any") and flag[left]) or (way in ("right", "any") and flag[right])
                elif name == "at_intersection":
                    out[o][f] = log.in_junction[o][f]
                elif name == "near_intersection":
                    out[o][f] = log.junction_m[o][f] <= float(p["within_m"])
                elif name == "on_crosswalk":
                    out[o][f] = log.on_crosswalk[o][f]
                elif name == "ego_lane":
                    lane = str(p["lane"])
                    here = log.ego_lane[o][f]
                    out[o][f] = here == lane or (lane == "adjacent" and here in ("left", "right"))
        return out

    # -- relations -------------------------------------------------------------------------------------
    def local(self, s: int, o: int, f: int) -> tuple[float, float]:
        """The other's centre in the subject's frame: (forward, left)."""
        log = self.log
        dx, dy = log.x[o][f] - log.x[s][f], log.y[o][f] - log.y[s][f]
        c, si = math.cos(log.yaw[s][f]), math.sin(log.yaw[s][f])
        return c * dx + si * dy, -si * dx + c * dy

    def gap(self, s: int, o: int, f: int) -> float:
        log = self.log
        return box_gap(box_corners(log.x[s][f], log.y[s][f], log.yaw[s][f], log.length[s][f], log.width[s][f]),
                       box_corners(log.x[o][f], log.y[o][f], log.yaw[o][f], log.length[o][f], log.width[o][f]))

    def in_direction(self, s: int, o: int, f: int, side: str, within_m: float, lateral_m: float) -> bool:
        """The other beyond the subject's box on ``side``, within ``lateral_m`` of its sides and ``within_m`` of it."""
        fwd, left = self.local(s, o, f)
        hl, hw = self.log.length[s][f] / 2, self.log.width[s][f] / 2
        if side == "front":
            ok = fwd > hl and abs(left) <= hw + lateral_m
        elif side == "behind":
            ok = fwd < -hl and abs(left) <= hw + lateral_m
        elif side == "left":
            ok = left > hw and abs(fwd) <= hl + lateral_m
        elif side == "right":
            ok = left < -hw and abs(fwd) <= hl + lateral_m
        elif side == "beside":
            ok = abs(left) > hw and abs(fwd) <= hl + lateral_m
        else:
            along = fwd > hl if side.startswith("front") else fwd < -hl
            ok = along and (left > hw if side.endswith("left") else left < -hw)
        return ok and self.gap(s, o, f) <= within_m

    def pair_frames(self, name: str, p: Params, s: int, o: int) -> list[bool]:
        """(F) the frames where ``o`` stands in relation ``name`` to ``s`` (both observed)."""
        log, nf = self.log, self.f
        both = [log.valid[s][f] and log.valid[o][f] for f in range(nf)]
        out = [False] * nf
        if name == "crossed_by":
            zone = [False] * nf
            lateral = [0.0] * nf
            for f in range(nf):
                if both[f]:
                    fwd, left = self.local(s, o, f)
                    lateral[f] = left
                    zone[f] = 0 < fwd <= log.length[s][f] / 2 + float(p["forward_m"]) \
                        and abs(left) <= log.width[s][f] / 2 + float(p["lateral_m"])
            side = [(v > ON_LINE_M) - (v < -ON_LINE_M) for v in lateral]  # 0: on the line, no side
            events = [f for f in range(1, nf) if zone[f] and zone[f - 1] and side[f] * side[f - 1] < 0]
            for f in range(nf):
                if both[f]:
                    out[f] = any(abs(log.time_s[f] - log.time_s[g]) <= float(p["window_s"]) for g in events)
            return out
        for f in range(nf):
            if not both[f]:
                continue
            if name == "direction":
                out[f] = self.in_direction(s, o, f, str(p["side"]), float(p["within_m"]), float(p["lateral_m"]))
            elif name == "near":
                out[f] = self.gap(s, o, f) <= float(p["within_m"])
            elif name == "following":
                rel = abs(wrap(log.yaw[o][f] - log.yaw[s][f]))
                out[f] = log.speed[s][f] > 0.5 and rel <= math.pi / 4 \
                    and self.in_direction(s, o, f, "front", float(p["within_m"]), float(p["lateral_m"]))
            elif name == "same_lane":
                out[f] = log.lane[s][f] >= 0 and log.lane[s][f] == log.lane[o][f] \
                    and self.gap(s, o, f) <= float(p["within_m"])
        return out

    def relation(self, node: p.Has) -> _Sel:
        k, nf = self.k, self.f
        resolved = _params(_RELATION_DEFAULTS, node.relation, node.params)
        subject, other = self.eval(node.subject), self.eval(node.other)
        subjects = [s for s in range(k) if any(subject.sel[s])]
        others = [o for o in range(k) if any(other.sel[o])]
        holds: dict[tuple[int, int], list[bool]] = {}
        for s in subjects:
            for o in others:
                if s != o:
                    frames = self.pair_frames(node.relation, resolved, s, o)
                    holds[(s, o)] = [frames[f] and subject.sel[s][f] and other.sel[o][f] for f in range(nf)]
        ok = self.grid()
        related_others, related_subjects = self.grid(), self.grid()
        for s in subjects:
            for f in range(nf):
                count = sum(1 for o in others if s != o and holds[(s, o)][f])
                if node.negate:
                    ok[s][f] = count == 0 and subject.sel[s][f]
                else:
                    ok[s][f] = count >= node.min_count and (node.max_count is None or count <= node.max_count)
                if ok[s][f] and not node.negate:
                    for o in others:
                        if s != o and holds[(s, o)][f]:
                            related_others[o][f] = True
                            related_subjects[s][f] = True
        if node.reverse:
            if node.negate:
                raise ReferenceError(f"{node.relation}: reverse() of a negated relation names no object")
            return _Sel(related_others, related_subjects)
        kept = self.keep(subject, ok)
        related = [[kept.related[o][f] or (related_others[o][f] and not kept.sel[o][f]) for f in range(nf)]
                   for o in range(k)]
        return _Sel(kept.sel, related)

    def between(self, subject: _Sel, left: _Sel, right: _Sel, lateral_m: float) -> _Sel:
        k, nf = self.k, self.f
        ok, related = self.grid(), self.grid()
        subjects = [s for s in range(k) if any(subject.sel[s])]
        for s in subjects:
            for f in range(nf):
                if not subject.sel[s][f]:
                    continue
                for first, second in ((left, right), (right, left)):
                    on_left = [o for o in range(k) if o != s and first.sel[o][f]
                               and self.in_direction(s, o, f, "left", 50.0, lateral_m)]
                    on_right = [o for o in range(k) if o != s and second.sel[o][f]
                                and self.in_direction(s, o, f, "right", 50.0, lateral_m)]
                    if on_left and on_right:
                        ok[s][f] = True
                        for o in on_left + on_right:
                            related[o][f] = True
        kept = self.keep(subject, ok)
        return _Sel(kept.sel, [[kept.related[o][f] or (related[o][f] and not kept.sel[o][f]) for f in range(nf)]
                               for o in range(k)])

    # -- time ------------------------------------------------------------------------------------------
    def runs_lasting(self, sel: Grid, seconds: float) -> Grid:
        t = self.log.time_s
        out = self.grid()
        for o in range(self.k):
            f = 0
            while f < self.f:
                if not sel[o][f]:
                    f += 1
                    continue
                end = f
                while end + 1 < self.f and sel[o][end + 1]:
                    end += 1
                if t[end] - t[f] + self.dt >= seconds - 1e-6:
                    for g in range(f, end + 1):
                        out[o][g] = True
                f = end + 1
        return out

    def then_within(self, first: Grid, second: Grid, within_s: float) -> Grid:
        t = self.log.time_s
        out = self.grid()
        for o in range(self.k):
            for f in range(self.f):
                if first[o][f]:
                    g = f + 1
                    while g < self.f and t[g] - t[f] <= within_s:
                        if second[o][g]:
                            out[o][f] = True
                            break
                        g += 1
                if second[o][f] and not out[o][f]:
                    g = f - 1
                    while g >= 0 and t[f] - t[g] <= within_s:
                        if first[o][g]:
                            out[o][f] = True
                            break
                        g -= 1
        return out


def reference_selection(program: p.Node, log: ReferenceLog) -> tuple[Grid, Grid]:
    """The (referred, related) objects × frames of ``program`` on ``log``, by the reference's loops.

    Raises:
        ReferenceError: the program uses a predicate, relation or kind the reference does not define.
    """
    result = _Reference(log).eval(program)
    return result.sel, result.related


def reference_answer(program: p.Node, log: ReferenceLog, description: str) -> LogAnswer:
    """The reference's answer as a :class:`LogAnswer` (referred objects score 1)."""
    referred, related = reference_selection(program, log)
    k, nf = log.num_objects, log.num_frames
    valid = np.asarray(log.valid, dtype=bool).reshape(k, nf)
    xyz = np.stack([np.asarray(log.x), np.asarray(log.y), np.asarray(log.z)], axis=-1).reshape(k, nf, 3)
    velocity = np.zeros((k, nf, 3))
    for o in range(k):
        velocity[o, :, 0] = _central_rate(log.x[o], log.valid[o], log.time_s, 0.1)
        velocity[o, :, 1] = _central_rate(log.y[o], log.valid[o], log.time_s, 0.1)
    size = np.stack([np.asarray(log.length), np.asarray(log.width), np.asarray(log.height)], axis=-1)
    referred_array = np.asarray(referred, dtype=bool).reshape(k, nf) & valid
    return LogAnswer(
        log_id=log.log_id, description=description, timestamps_ns=np.asarray(log.timestamps_ns, dtype=np.int64),
        track_ids=np.asarray(log.track_ids, dtype=np.str_), categories=np.asarray(log.labels, dtype=np.str_),
        valid=valid, referred=referred_array.astype(np.float32),
        related=np.asarray(related, dtype=bool).reshape(k, nf) & valid & ~referred_array,
        center_city_xyz_m=np.where(valid[..., None], xyz, np.nan), size_lwh_m=np.nan_to_num(size.reshape(k, nf, 3)),
        yaw_city_rad=np.nan_to_num(np.asarray(log.yaw, dtype=np.float64).reshape(k, nf)),
        velocity_city_mps=velocity, ego_city_xyz_m=xyz[-1],
    )


def replicate(log: ReferenceLog, copies: int, offset_m: float) -> ReferenceLog:
    """``log`` with its objects (not the ego) repeated ``copies`` times, copy c shifted by ``c·offset_m``
    along x and its track ids suffixed ``#c``: a busier log for timing."""
    objects = range(log.num_objects - 1)
    order = [o for _ in range(copies) for o in objects] + [log.num_objects - 1]
    shift = [c * offset_m for c in range(copies) for _ in objects] + [0.0]
    suffix = [f"#{c}" if c else "" for c in range(copies) for _ in objects] + [""]

    def pick(grid: list[list[T]]) -> list[list[T]]:
        return [list(grid[o]) for o in order]

    return ReferenceLog(
        log.log_id, list(log.timestamps_ns), list(log.time_s), [log.track_ids[o] + s for o, s in zip(order, suffix)],
        [log.labels[o] for o in order], pick(log.valid), [[v + d for v in log.x[o]] for o, d in zip(order, shift)],
        pick(log.y), pick(log.z), pick(log.yaw), pick(log.length), pick(log.width), pick(log.height),
        pick(log.speed), {name: pick(grid) for name, grid in log.flags.items()}, pick(log.lane),
        pick(log.in_junction), pick(log.junction_m), pick(log.on_crosswalk), pick(log.ego_lane),
    )


__all__ = ["KIND_LABELS", "ReferenceError", "ReferenceLog", "load_reference_log", "reference_answer",
           "reference_selection", "replicate"]
