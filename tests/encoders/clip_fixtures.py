"""A small synthetic log with every sensor the clips stage reads, for tests and benchmarks.

The scene (city frame, metres): the ego drives along +x at a constant speed on a straight two-lane
road with a crossing and an intersection ahead; ``lead`` drives ahead and changes from the left
lane into the ego's lane; ``parked`` stands at the right kerb; ``follower`` drives behind the ego
(never in the front camera). The front camera image, its 16-bit instance masks, the LiDAR sweeps
(ground, a wall along the road, points inside every box) and the vector map are all drawn from
the same boxes, so tests can check where an object must appear.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa

from encoders.clips.config import BevClipConfig, CameraClipConfig, ClipsConfig
from scenes import av2_io
from scenes.calibration import Calibration, CameraIntrinsics
from scenes.geometry import SE3, FloatArray
from scenes.map import DrivableArea, LaneSegment, PedestrianCrossing, VectorMap
from scenes.metadata import LogMetadata
from scenes.sensors import LidarSweep
from scenes.tracks import Annotations, EgoTrajectory

#: Clips fine enough for the geometric checks (a 160 × 96 camera, 0.5 m BEV cells, 16 frames): the
#: defaults' coarser grid, the recommended model's, hides the movements and positions they measure.
FINE_CLIPS = ClipsConfig(frames_per_clip=16, previews=False, camera=CameraClipConfig(width_px=160, height_px=96),
                         bev=BevClipConfig(resolution_m=0.5))

CAMERA_NAME = "ring_front_center"
FRAME_PERIOD_NS = 100_000_000
START_NS = 1_000_000_000
#: Camera pose in the ego frame: 1.5 m ahead of the rear axle, 1.6 m up, looking along +x.
EGO_SE3_CAMERA = SE3(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.array([1.5, 0.0, 1.6]))
INTRINSICS = CameraIntrinsics(CAMERA_NAME, 450.0, 450.0, 320.0, 180.0, 640, 360)
WALL_Y_M = 12.0


@dataclass(frozen=True)
class SyntheticTrack:
    """City-frame boxes of one track over the frames: (F, 3) centres, (F,) yaws, (3,) size."""

    track_id: str
    category: str
    center_city_xyz_m: FloatArray
    yaw_city_rad: FloatArray
    size_lwh_m: FloatArray
    color_bgr: tuple[int, int, int]


def synthetic_scene(num_frames: int, ego_speed_mps: float) -> tuple[EgoTrajectory, list[SyntheticTrack]]:
    """The ego trajectory and the tracks of the synthetic scene."""
    t_s = np.arange(num_frames) * FRAME_PERIOD_NS * 1e-9
    ego_x = ego_speed_mps * t_s
    ego = EgoTrajectory.from_xy_yaw(
        START_NS + np.arange(num_frames) * FRAME_PERIOD_NS, np.stack([ego_x, np.zeros(num_frames)], 1),
        np.zeros(num_frames),
    )
    frac = np.clip(t_s / max(t_s[-1], 1e-9), 0.0, 1.0)
    lead_y = 3.5 * (1.0 - np.clip((frac - 0.3) / 0.4, 0.0, 1.0))
    lead = np.stack([ego_x + 14.0, lead_y, np.full(num_frames, 0.8)], 1)
    lead_yaw = np.arctan2(np.gradient(lead_y), np.maximum(np.gradient(lead[:, 0]), 1e-3))
    parked = np.tile([[25.0, -4.0, 0.8]], (num_frames, 1))
    follower = np.stack([ego_x - 12.0, np.zeros(num_frames), np.full(num_frames, 0.8)], 1)
    size = np.array([4.5, 1.9, 1.6])
    tracks = [
        SyntheticTrack("lead", "REGULAR_VEHICLE", lead, lead_yaw, size, (40, 40, 220)),
        SyntheticTrack("parked", "REGULAR_VEHICLE", parked, np.zeros(num_frames), size, (220, 120, 30)),
        SyntheticTrack("follower", "REGULAR_VEHICLE", follower, np.zeros(num_frames), size, (30, 200, 30)),
    ]
    return ego, tracks


def _box_corners(center: FloatArray, yaw: float, size: FloatArray) -> FloatArray:
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    local = signs * 0.5 * size
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return np.asarray(local @ rot.T + center, dtype=np.float64)


def synthetic_map() -> VectorMap:
    """A straight road along +x: two lanes in 50 m segments, a crossing at x = 40 m, a junction at 60–80 m."""

    def line(x0: float, x1: float, y: float) -> FloatArray:
        xs = np.linspace(x0, x1, 6)
        return np.stack([xs, np.full(6, y), np.zeros(6)], 1)

    lanes: dict[int, LaneSegment] = {}
    lane_id = 1
    for x0 in np.arange(-100.0, 600.0, 20.0):
        for y_right, y_left in ((-1.75, 1.75), (1.75, 5.25)):
            junction = bool(60.0 <= x0 < 80.0)
            lanes[lane_id] = LaneSegment(lane_id, junction, "VEHICLE", line(x0, x0 + 20.0, y_left),
                                         line(x0, x0 + 20.0, y_right), "DASHED_WHITE", "SOLID_WHITE")
            lane_id += 1
    crossing = PedestrianCrossing(1, np.array([[40.0, -6.0, 0.0], [40.0, 8.0, 0.0]]),
                                  np.array([[44.0, -6.0, 0.0], [44.0, 8.0, 0.0]]))
    area = DrivableArea(1, np.array([[-100.0, -6.0, 0.0], [600.0, -6.0, 0.0], [600.0, 8.0, 0.0], [-100.0, 8.0, 0.0]]))
    return VectorMap(lanes, {1: crossing}, {1: area})


def write_synthetic_log(
    out_dir: Path | str,
    log_id: str = "synthetic_0000",
    num_frames: int = 40,
    ego_speed_mps: float = 5.0,
    with_camera: bool = True,
    with_lidar: bool = True,
    seed: int = 0,
) -> Path:
    """Write the synthetic log ``out_dir/log_id`` and return its folder."""
    rng = np.random.default_rng(seed)
    log_dir = Path(out_dir) / log_id
    log_dir.mkdir(parents=True, exist_ok=True)
    ego, tracks = synthetic_scene(num_frames, ego_speed_mps)
    ego_SE3_city = [ego.city_SE3_ego(i).inverse() for i in range(num_frames)]
    rows_ts, rows_id, rows_cat, rows_c, rows_s, rows_yaw = [], [], [], [], [], []
    for f in range(num_frames):
        for tr in tracks:
            rows_ts.append(int(ego.timestamps_ns[f]))
            rows_id.append(tr.track_id)
            rows_cat.append(tr.category)
            rows_c.append(ego_SE3_city[f].transform_points(tr.center_city_xyz_m[f : f + 1])[0])
            rows_s.append(tr.size_lwh_m)
            rows_yaw.append(tr.yaw_city_rad[f])  # the ego's yaw is 0
    ann = Annotations.from_yaw(np.array(rows_ts), rows_id, rows_cat, np.array(rows_c), np.array(rows_s),
                               np.array(rows_yaw))
    av2_io.write_annotations(log_dir, ann)
    av2_io.write_ego_poses(log_dir, ego)
    av2_io.write_map(log_dir, synthetic_map(), log_id)
    av2_io.write_calibration(log_dir, Calibration({CAMERA_NAME: EGO_SE3_CAMERA}, {CAMERA_NAME: INTRINSICS}))
    av2_io.write_metadata(log_dir, LogMetadata(log_id, "synthetic", "SIM", {"time_of_day": "night", "weather": "rain"}))
    if with_lidar:
        gx, gy = np.meshgrid(np.arange(-30.0, 70.0, 1.0), np.arange(-25.0, 25.0, 1.0))
        ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
        for f in range(num_frames):
            ex = float(ego.translation_m[f, 0])
            wx = np.arange(ex - 30.0, ex + 70.0, 0.25)
            heights = np.tile([0.5, 1.2, 2.0, 2.8], wx.size)
            wall_city = np.stack([np.repeat(wx, 4), np.full(wx.size * 4, WALL_Y_M), heights], 1)
            parts = [ground, ego_SE3_city[f].transform_points(wall_city)]
            for tr in tracks:
                u = rng.uniform(-0.5, 0.5, size=(150, 3)) * tr.size_lwh_m
                c, s = np.cos(tr.yaw_city_rad[f]), np.sin(tr.yaw_city_rad[f])
                pts = np.stack([c * u[:, 0] - s * u[:, 1], s * u[:, 0] + c * u[:, 1], u[:, 2]], 1)
                parts.append(ego_SE3_city[f].transform_points(pts + tr.center_city_xyz_m[f]))
            xyz = np.concatenate(parts).astype(np.float32)
            n = xyz.shape[0]
            av2_io.write_lidar_sweep(log_dir, LidarSweep(int(ego.timestamps_ns[f]), xyz, np.full(n, 50, np.uint8),
                                                         np.zeros(n, np.uint8), np.zeros(n, np.int32)))
    if with_camera:
        _write_camera(log_dir, ego, ego_SE3_city, tracks)
    return log_dir


def _write_camera(log_dir: Path, ego: EgoTrajectory, ego_SE3_city: list[SE3], tracks: list[SyntheticTrack]) -> None:
    cam_SE3_ego = EGO_SE3_CAMERA.inverse()
    # The instance ids list deliberately uses another order than the log's sorted track ids.
    instance_ids = [tr.track_id for tr in tracks][::-1]
    mask_dir = log_dir / av2_io.CAMERAS_DIR / f"{CAMERA_NAME}_instance"
    mask_dir.mkdir(parents=True, exist_ok=True)
    (log_dir / av2_io.CAMERAS_DIR / "instance_track_ids.json").write_text(json.dumps(instance_ids))
    h, w = INTRINSICS.height_px, INTRINSICS.width_px
    for f in range(len(ego)):
        image = np.zeros((h, w, 3), np.uint8)
        image[: h // 2] = (200, 170, 120)
        image[h // 2 :] = (90, 90, 90)
        mask = np.zeros((h, w), np.uint16)
        drawn = []
        for tr in tracks:
            corners_ego = ego_SE3_city[f].transform_points(
                _box_corners(tr.center_city_xyz_m[f], float(tr.yaw_city_rad[f]), tr.size_lwh_m))
            cam = cam_SE3_ego.transform_points(corners_ego)
            if (cam[:, 2] <= 0.5).any():
                continue
            uv = np.stack([INTRINSICS.fx_px * cam[:, 0] / cam[:, 2] + INTRINSICS.cx_px,
                           INTRINSICS.fy_px * cam[:, 1] / cam[:, 2] + INTRINSICS.cy_px], 1)
            drawn.append((float(cam[:, 2].mean()), tr, uv))
        for _depth, tr, uv in sorted(drawn, key=lambda d: -d[0]):
            hull = cv2.convexHull(np.round(uv).astype(np.int32))
            cv2.fillConvexPoly(image, hull, tr.color_bgr)
            cv2.fillConvexPoly(mask, hull, instance_ids.index(tr.track_id) + 1)
        ts = int(ego.timestamps_ns[f])
        av2_io.write_camera_frame(log_dir, CAMERA_NAME, ts, image)
        cv2.imwrite(str(mask_dir / f"{ts}.png"), mask)


def synthetic_captions(log_dirs: list[Path], first_frame: int = 5, last_frame: int = 34) -> pa.Table:
    """captions.parquet rows: one per track of each synthetic log over a frame window, plus a host row."""
    rows = []
    for log_dir in log_dirs:
        ts = START_NS + np.arange(first_frame, last_frame + 1) * FRAME_PERIOD_NS
        for track_id, caption in (("lead", "a car in the left lane moves into the host lane"),
                                  ("parked", "a parked car on the right"),
                                  ("follower", "a car follows behind"),
                                  ("ego", "the host drives at constant speed")):
            rows.append({
                "log_id": log_dir.name, "track_id": track_id, "category": "car",
                "start_ns": int(ts[0]), "end_ns": int(ts[-1]),
                "tags": ["left:approach"] if track_id == "lead" else ["right:stationary"],
                "caption": caption, "canonical_caption": caption,
                "paraphrases": [f"{caption} (paraphrase {i})" for i in range(2)],
                "window": "whole", "num_frames": int(ts.shape[0]), "host_tags": ["cruising:heading_straight"],
            })
    return pa.Table.from_pylist(rows)


#: Lane, motion and own action of each synthetic track in the frame tags (no map context): ``lead`` is in
#: the left lane for the first half of the log, then in the ego's lane.
SYNTHETIC_FRAME_TAGS = {"parked": ("right", "stationary", "parked"), "follower": ("host", "constant", "none")}


def synthetic_frame_tags(log_dirs: list[Path], num_frames: int) -> pa.Table:
    """frame_tags.parquet rows of the synthetic logs (the columns the clips stage reads)."""
    rows = []
    for log_dir in log_dirs:
        for f in range(num_frames):
            t = START_NS + f * FRAME_PERIOD_NS
            rows.append({"log_id": log_dir.name, "timestamp_ns": t, "track_id": "ego", "lane": None, "motion": None,
                         "host_motion": "cruising", "host_direction": "heading_straight", "action": None,
                         "context": None})
            tags = {"lead": ("left" if f < num_frames // 2 else "host", "approach", "none"), **SYNTHETIC_FRAME_TAGS}
            for track_id, (lane, motion, action) in tags.items():
                rows.append({"log_id": log_dir.name, "timestamp_ns": t, "track_id": track_id, "lane": lane,
                             "motion": motion, "host_motion": None, "host_direction": None, "action": action,
                             "context": "none"})
    return pa.Table.from_pylist(rows)
