"""Logs as the mining benchmark's reference reads them: true boxes, the simulator's behaviour labels and the
map, as plain lists indexed ``[object][frame]``, and the plain geometry its tests use.

Shares no code with :mod:`scenarios`' features (see :mod:`benchmarks.mining_reference`). Map context:
``in_junction``: the box centre lies in a junction outline of ``junctions.feather`` (the simulator's
junctions of three or more roads); ``junction_m``: the distance to the nearest such outline;
``crosswalk_m``: the distance from the centre to the nearest pedestrian crossing of the map (0 inside
one; resolved up to :data:`CROSSWALK_MARGIN_M`); ``lane``: the map's lane segment
outside junctions whose outline holds the centre. ``ego_lane``: ``host`` on the ego's lane segment,
``left`` / ``right`` on its left / right neighbour, ``oncoming`` on a lane whose direction differs from
the ego lane's by more than 135° with the centre at most :data:`ONCOMING_LATERAL_M` to the side of the
ego. Speeds are the labelled ones where the simulator has them, else from box centres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

from scenes.behavior import EGO_TRACK_ID, read_behavior_labels, read_junctions
from scenes.categories import EGO_VEHICLE_LABEL
from scenes.geometry import quat_to_yaw, rotmat_to_quat
from scenes.log import Log

Grid = list[list[bool]]
T = TypeVar("T")

#: The ego's box (length, width in metres): AV2's ego, a mid-size sedan.
EGO_LENGTH_M, EGO_WIDTH_M = 4.877, 1.852
#: An oncoming lane lies at most this far to the side of the ego.
ONCOMING_LATERAL_M = 10.0
#: Distances to a junction are resolved up to this far (farther ones read as infinite).
JUNCTION_MARGIN_M = 20.0
#: Distances to a crossing are resolved up to this far (farther ones read as infinite).
CROSSWALK_MARGIN_M = 2.0
#: Cell size of the lookup grid of map polygons.
_CELL_M = 25.0
#: The simulator's behaviour labels the reference reads.
FLAGS = ("parked", "stopped", "braking", "keeping_lane", "left_turn", "right_turn", "left_lane_change",
         "right_lane_change", "blocked_by", "braking_for")


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
        crosswalk_m: distance to the nearest pedestrian crossing (0 on one).
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
    crosswalk_m: list[list[float]]
    ego_lane: list[list[str]]

    @property
    def num_objects(self) -> int:
        return len(self.track_ids)

    @property
    def num_frames(self) -> int:
        return len(self.timestamps_ns)

    def local(self, s: int, o: int, f: int) -> tuple[float, float]:
        """Object ``o``'s centre in object ``s``'s frame at frame ``f``: (forward, left) metres."""
        dx, dy = self.x[o][f] - self.x[s][f], self.y[o][f] - self.y[s][f]
        c, si = math.cos(self.yaw[s][f]), math.sin(self.yaw[s][f])
        return c * dx + si * dy, -si * dx + c * dy

    def gap(self, s: int, o: int, f: int) -> float:
        """The distance between the boxes of objects ``s`` and ``o`` at frame ``f`` (0 where they overlap)."""
        return box_gap(self.corners(s, f), self.corners(o, f))

    def corners(self, o: int, f: int) -> list[tuple[float, float]]:
        return box_corners(self.x[o][f], self.y[o][f], self.yaw[o][f], self.length[o][f], self.width[o][f])

    def in_direction(self, s: int, o: int, f: int, side: str, within_m: float, lateral_m: float) -> bool:
        """Whether object ``o`` is beyond object ``s``'s box on ``side`` at frame ``f``, within ``lateral_m``
        of its sides and ``within_m`` of it."""
        fwd, left = self.local(s, o, f)
        hl, hw = self.length[s][f] / 2, self.width[s][f] / 2
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


def central_rate(values: list[float], valid: list[bool], times: list[float], half_window_s: float) -> list[float]:
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
    flags: dict[str, Grid] = {name: [[False] * nf for _ in range(k)] for name in FLAGS}
    speed = [[0.0] * nf for _ in range(k)]
    for o in range(k):
        labelled = [False] * nf
        for f in range(nf):
            row = rows.get((timestamps[f], track_ids[o]))
            if row is None or not valid[o][f]:
                continue
            labelled[f] = True
            speed[o][f] = float(row["speed_mps"])  # type: ignore[arg-type]
            for name in FLAGS:
                flags[name][o][f] = bool(row[name])
        if not any(labelled):  # no label rows: the speed of its centres
            vx = central_rate(x[o], valid[o], time_s, 0.1)
            vy = central_rate(y[o], valid[o], time_s, 0.1)
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
    lane_grid, crossing_grid = _PolygonGrid(lanes), _PolygonGrid(crossings, CROSSWALK_MARGIN_M)
    junction_grid = _PolygonGrid(junctions, JUNCTION_MARGIN_M)
    centerlines = {i: [(float(p[0]), float(p[1])) for p in s.centerline(20).tolist()] for i, s in segments.items()}

    lane = [[-1] * nf for _ in range(k)]
    in_junction = [[False] * nf for _ in range(k)]
    junction_m = [[math.inf] * nf for _ in range(k)]
    crosswalk_m = [[math.inf] * nf for _ in range(k)]
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
                crosswalk_m[o][f] = min(crosswalk_m[o][f], polygon_distance(px, py, polygon))
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
                        height, speed, flags, lane, in_junction, junction_m, crosswalk_m, ego_lane)



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
        pick(log.in_junction), pick(log.junction_m), pick(log.crosswalk_m), pick(log.ego_lane),
    )
