"""A small hand-built log (no simulator needed): a four-lane road with a crossroad.

Used to exercise the sensor simulation in tests, benchmarks and the README images. The map is a
straight east-west road (two lanes each way, 3.5 m lanes) crossed by a north-south road at
``x = 100 m``, with crosswalks on all four sides of the junction. The ego drives east in the right
lane; cars, trucks, a bus, cyclists and pedestrians move around it at constant velocity.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scenes import av2_io
from scenes.categories import CATEGORY_TO_AV2, Category
from scenes.geometry import FloatArray, wrap_angle_rad
from scenes.map import DrivableArea, LaneSegment, PedestrianCrossing, VectorMap
from scenes.metadata import LogMetadata
from scenes.tracks import Annotations, EgoTrajectory

LANE_WIDTH_M = 3.5
JUNCTION_X_M = 100.0
HALF_ROAD_M = 2 * LANE_WIDTH_M
FRAME_PERIOD_NS = 100_000_000


def _line(x0: float, y0: float, x1: float, y1: float, n: int = 2) -> FloatArray:
    t = np.linspace(0.0, 1.0, n)[:, None]
    return np.c_[x0 + t * (x1 - x0), y0 + t * (y1 - y0), np.zeros(n)]


def crossroad_map() -> VectorMap:
    """The crossroad map in the city frame."""
    lanes: dict[int, LaneSegment] = {}
    next_id = 1
    jx, h = JUNCTION_X_M, HALF_ROAD_M
    # East-west road: lanes k = 0 (inner) and 1 (outer) per direction, before and after the junction.
    for x0, x1, inter in ((-150.0, jx - h, False), (jx - h, jx + h, True), (jx + h, 350.0, False)):
        for k in range(2):
            inner, outer = k * LANE_WIDTH_M, (k + 1) * LANE_WIDTH_M
            left_mark = "DOUBLE_SOLID_YELLOW" if k == 0 else "DASHED_WHITE"
            right_mark = "DASHED_WHITE" if k == 0 else "SOLID_WHITE"
            # Eastbound (drives +x, on y < 0): left boundary nearer the centre.
            lanes[next_id] = LaneSegment(next_id, inter, "VEHICLE", _line(x0, -inner, x1, -inner, 8),
                                         _line(x0, -outer, x1, -outer, 8), left_mark, right_mark)
            next_id += 1
            lanes[next_id] = LaneSegment(next_id, inter, "VEHICLE", _line(x1, inner, x0, inner, 8),
                                         _line(x1, outer, x0, outer, 8), left_mark, right_mark)
            next_id += 1
    # North-south road.
    for y0, y1 in ((-150.0, -h), (h, 150.0)):
        for k in range(2):
            inner, outer = k * LANE_WIDTH_M, (k + 1) * LANE_WIDTH_M
            left_mark = "DOUBLE_SOLID_YELLOW" if k == 0 else "DASHED_WHITE"
            right_mark = "DASHED_WHITE" if k == 0 else "SOLID_WHITE"
            lanes[next_id] = LaneSegment(next_id, False, "VEHICLE", _line(jx + inner, y0, jx + inner, y1, 8),
                                         _line(jx + outer, y0, jx + outer, y1, 8), left_mark, right_mark)
            next_id += 1
            lanes[next_id] = LaneSegment(next_id, False, "VEHICLE", _line(jx - inner, y1, jx - inner, y0, 8),
                                         _line(jx - outer, y1, jx - outer, y0, 8), left_mark, right_mark)
            next_id += 1
    areas = {
        1: DrivableArea(1, np.concatenate([_line(-150.0, -h, 350.0, -h), _line(350.0, h, -150.0, h)])),
        2: DrivableArea(2, np.concatenate([_line(jx - h, -150.0, jx + h, -150.0),
                                           _line(jx + h, 150.0, jx - h, 150.0)])),
    }
    crossings = {}
    for i, (a, b) in enumerate(((jx - h - 4.0, jx - h - 1.0), (jx + h + 1.0, jx + h + 4.0))):
        crossings[i + 1] = PedestrianCrossing(i + 1, _line(a, -h, a, h), _line(b, -h, b, h))
    for i, (a, b) in enumerate(((-h - 4.0, -h - 1.0), (h + 1.0, h + 4.0))):
        crossings[i + 3] = PedestrianCrossing(i + 3, _line(jx - h, a, jx + h, a), _line(jx - h, b, jx + h, b))
    return VectorMap(lanes, crossings, areas)


_SIZES: dict[Category, tuple[float, float, float]] = {
    Category.CAR: (4.5, 1.9, 1.5),
    Category.TRUCK: (8.0, 2.5, 3.2),
    Category.BUS: (12.0, 2.6, 3.2),
    Category.PEDESTRIAN: (0.6, 0.6, 1.75),
    Category.CYCLIST: (1.8, 0.7, 1.7),
}


def write_synthetic_log(
    log_dir: Path | str,
    num_frames: int = 20,
    num_objects: int = 24,
    seed: int = 0,
    ego_speed_mps: float = 8.0,
    time_of_day: str = "day",
    weather: str = "clear",
    ego_start_x_m: float = 20.0,
) -> Path:
    """Write a crossroad log (annotations, poses, map, metadata) at 10 Hz; no sensor data.

    Objects are spread over the road ahead of and around the ego; none comes within 1 m of it.

    Returns:
        The log folder.
    """
    rng = np.random.default_rng(seed)
    log_dir = Path(log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    ts = 1_000_000_000_000 + FRAME_PERIOD_NS * np.arange(num_frames, dtype=np.int64)
    t_s = (ts - ts[0]) * 1e-9
    ego_xy = np.c_[ego_start_x_m + ego_speed_mps * t_s, np.full(num_frames, -1.75)]
    ego = EgoTrajectory.from_xy_yaw(ts, ego_xy, np.zeros(num_frames))

    pool = [Category.CAR] * 6 + [Category.TRUCK, Category.BUS] + [Category.PEDESTRIAN] * 3 + [Category.CYCLIST]
    kinds = [pool[k] for k in rng.integers(0, len(pool), size=num_objects)]
    start = np.zeros((num_objects, 2))
    velocity = np.zeros((num_objects, 2))
    for i, kind in enumerate(kinds):
        if kind in (Category.PEDESTRIAN,):
            side = rng.choice([-1.0, 1.0])
            start[i] = [rng.uniform(15.0, 120.0), side * rng.uniform(HALF_ROAD_M + 1.5, HALF_ROAD_M + 3.5)]
            velocity[i] = [rng.choice([-1.0, 1.0]) * rng.uniform(0.8, 1.6), 0.0]
        elif kind == Category.CYCLIST:
            start[i] = [rng.uniform(25.0, 110.0), -HALF_ROAD_M + 0.8]
            velocity[i] = [rng.uniform(3.0, 6.0), 0.0]
        else:
            lane = rng.integers(0, 4)
            y = [-1.75, -5.25, 1.75, 5.25][lane]
            heading = 1.0 if y < 0 else -1.0
            start[i] = [rng.uniform(-40.0, 160.0), y]
            velocity[i] = [heading * rng.uniform(0.0, 12.0), 0.0]
    # Keep clear of the ego's lane near the ego, and apart from each other.
    pos0 = start.copy()
    for i in range(num_objects):
        for _ in range(50):
            near_ego = np.any(np.hypot(*(start[i] + velocity[i] * t_s[:, None] - ego_xy).T) < 7.0)
            clash = any(np.hypot(*(start[i] - start[j])) < 9.0 for j in range(i))
            if not near_ego and not clash:
                break
            start[i, 0] += 9.0
        pos0[i] = start[i]
    rows_t, rows_id, rows_cat, rows_c, rows_s, rows_y = [], [], [], [], [], []
    colors: dict[str, list[int]] = {}
    for i, kind in enumerate(kinds):
        tid = f"{kind.value}-{i:03d}"
        size = np.array(_SIZES[kind]) * rng.uniform(0.9, 1.1, 3)
        city_xy = pos0[i] + velocity[i] * t_s[:, None]
        yaw_city = np.arctan2(velocity[i, 1], velocity[i, 0]) if np.any(velocity[i]) else (
            0.0 if pos0[i, 1] < 0 else np.pi)
        rel = city_xy - ego_xy  # ego yaw is 0: the ego frame is the city frame shifted
        rows_t.append(ts)
        rows_id += [tid] * num_frames
        rows_cat += [CATEGORY_TO_AV2[kind]] * num_frames
        rows_c.append(np.c_[rel, np.full(num_frames, 0.5 * size[2])])
        rows_s.append(np.tile(size, (num_frames, 1)))
        rows_y.append(np.full(num_frames, float(wrap_angle_rad(yaw_city))))
        colors[tid] = [int(c) for c in rng.integers(20, 235, 3)]
    ann = Annotations.from_yaw(np.concatenate(rows_t), rows_id, rows_cat, np.concatenate(rows_c),
                               np.concatenate(rows_s), np.concatenate(rows_y))
    av2_io.write_annotations(log_dir, ann)
    av2_io.write_ego_poses(log_dir, ego)
    av2_io.write_map(log_dir, crossroad_map(), log_dir.name)
    av2_io.write_metadata(log_dir, LogMetadata(
        log_id=log_dir.name, source="synthetic", city_name="SIM",
        appearance={"time_of_day": time_of_day, "weather": weather, "vehicle_colors": colors},
    ))
    return log_dir
