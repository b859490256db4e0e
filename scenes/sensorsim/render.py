"""Render the sensors of a log folder: LiDAR sweeps, camera frames, instance masks, calibration.

>>> report = render_log_sensors("out/sim/log_000")          # every frame at 10 Hz
>>> print(report.summary())

Frames are the log's annotation timestamps, plus the ego pose timestamps when poses come at the
frame rate (≤ 20 Hz; simulated logs), so that frames without any object get sensor data too.
Every file is written atomically. Objects are checked first: a box of non-positive (or non-finite)
size, or one that holds a sensor, stops the render with :class:`BadObjectError` naming the track
and frame, before anything is written.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from scenes import av2_io
from scenes.calibration import Calibration
from scenes.errors import LogFormatError
from scenes.geometry import SE3
from scenes.log import Log
from scenes.metadata import MAP_WITHHELD_KEY, METADATA_FILENAME
from scenes.sensorsim.appearance import Appearance
from scenes.sensorsim.camera import CameraRenderer
from scenes.sensorsim.config import LIDAR_SENSOR_NAME, SensorConfig
from scenes.sensorsim.errors import BadObjectError
from scenes.sensorsim.instance_masks import write_instance_mask, write_instance_track_ids
from scenes.sensorsim.lidar import cast_sweep
from scenes.sensorsim.objects import FrameObjects
from scenes.sensorsim.world import StaticWorld
from scenes.tracks import DenseTracks

#: Ego poses at most this far apart count as a frame-rate pose stream (simulated logs).
FRAME_RATE_POSE_PERIOD_NS = 50_000_000


@dataclass(frozen=True)
class RenderReport:
    """What :func:`render_log_sensors` wrote and how fast.

    Attributes:
        log_dir: the log.
        frames: frames rendered.
        sweeps_written: LiDAR sweeps written.
        camera_frames_written: camera frames (and masks) written.
        empty_camera_frames: camera frames in which no object is visible (written as such).
        mean_points_per_sweep: average number of LiDAR points.
        world_s: seconds spent building the static world.
        lidar_s: seconds spent simulating sweeps (without writing).
        camera_s: seconds spent rendering frames (without writing).
        write_s: seconds spent encoding and writing files.
    """

    log_dir: Path
    frames: int
    sweeps_written: int
    camera_frames_written: int
    empty_camera_frames: int
    mean_points_per_sweep: float
    world_s: float
    lidar_s: float
    camera_s: float
    write_s: float

    @property
    def sweeps_per_s(self) -> float:
        return self.sweeps_written / self.lidar_s if self.lidar_s > 0 else 0.0

    @property
    def frames_per_s(self) -> float:
        return self.camera_frames_written / self.camera_s if self.camera_s > 0 else 0.0

    def summary(self) -> str:
        return (f"{self.log_dir.name}: {self.frames} frames, {self.sweeps_written} sweeps "
                f"({self.mean_points_per_sweep:.0f} points each, {self.sweeps_per_s:.1f} sweeps/s), "
                f"{self.camera_frames_written} camera frames ({self.frames_per_s:.1f} frames/s, "
                f"{self.empty_camera_frames} with no object visible); world {self.world_s:.2f} s, "
                f"writing {self.write_s:.2f} s")


def check_objects(dense: DenseTracks, config: SensorConfig, path: Path) -> None:
    """Refuse boxes that cannot be rendered (vectorised over tracks × frames).

    Raises:
        BadObjectError: a box with non-positive or non-finite size, or a box that holds the LiDAR
            or the camera, naming the track and the first such frame.
    """
    valid = dense.valid
    size = dense.size_lwh_m
    bad_size = valid & ~(np.isfinite(size).all(axis=2) & (size > 0).all(axis=2))
    if bad_size.any():
        k, t = np.argwhere(bad_size)[0]
        names = ("length_m", "width_m", "height_m")
        dim = int(np.argmax(~(np.isfinite(size[k, t]) & (size[k, t] > 0))))
        raise BadObjectError(path, str(dense.track_ids[k]), int(t), int(dense.timestamps_ns[t]), names[dim],
                             f"box size must be positive, got {size[k, t].tolist()}")
    sensors = []
    if config.render_lidar:
        sensors.append((LIDAR_SENSOR_NAME, config.lidar.ego_SE3_sensor.translation))
    if config.render_camera:
        sensors.append((config.camera.name, config.camera.ego_SE3_sensor.translation))
    for name, origin in sensors:
        rel = origin - np.nan_to_num(dense.center_ego_xyz_m)  # (K, T, 3)
        yaw = np.nan_to_num(dense.yaw_ego_rad)
        c, s = np.cos(yaw), np.sin(yaw)
        local_x = c * rel[..., 0] + s * rel[..., 1]
        local_y = -s * rel[..., 0] + c * rel[..., 1]
        half = 0.5 * np.nan_to_num(size)
        inside = valid & (np.abs(local_x) <= half[..., 0]) & (np.abs(local_y) <= half[..., 1]) & (
            np.abs(rel[..., 2]) <= half[..., 2])
        if inside.any():
            k, t = np.argwhere(inside)[0]
            raise BadObjectError(path, str(dense.track_ids[k]), int(t), int(dense.timestamps_ns[t]), "tx_m",
                                 f"the box holds the sensor '{name}' (the object intersects the ego's sensor)")


def frame_timestamps(log: Log) -> NDArray[np.int64]:
    """(F,) the timestamps to render: annotation timestamps, plus frame-rate ego pose timestamps."""
    ts = log.timestamps_ns
    ego_ts = log.ego.timestamps_ns
    if ego_ts.shape[0] >= 2 and float(np.median(np.diff(ego_ts))) >= FRAME_RATE_POSE_PERIOD_NS:
        ts = np.union1d(ts, ego_ts)
    return np.asarray(ts, dtype=np.int64)


def sensor_calibration(config: SensorConfig, existing: Calibration | None = None) -> Calibration:
    """The simulated sensors' calibration, merged over an existing one (same names are replaced)."""
    extrinsics = dict(existing.ego_SE3_sensor) if existing else {}
    intrinsics = dict(existing.intrinsics) if existing else {}
    if config.render_lidar:
        extrinsics[LIDAR_SENSOR_NAME] = config.lidar.ego_SE3_sensor
    if config.render_camera:
        extrinsics[config.camera.name] = config.camera.ego_SE3_sensor
        intrinsics[config.camera.name] = config.camera.intrinsics
    return Calibration(extrinsics, intrinsics)


def render_log_sensors(log_dir: Path | str, config: SensorConfig | None = None, progress: bool = True,
                       nthreads: int = 0) -> RenderReport:
    """Render and write every frame's LiDAR sweep, camera frame and instance mask of a log.

    Args:
        log_dir: a log folder with annotations, ego poses and (optionally) a map and metadata.
        config: sensors, world and seed.
        progress: show a progress bar on stderr.
        nthreads: ray-casting threads (0: all cores).

    Raises:
        BadObjectError: an object cannot be rendered (named with its track and frame).
        LogFormatError: the log cannot be read.
    """
    config = config or SensorConfig()
    log_dir = Path(log_dir)
    log = Log.open(log_dir)
    if log.map is None and log.metadata.extra.get(MAP_WITHHELD_KEY):
        # Rendering on bare ground would silently give other sensor data than the log was made with.
        raise LogFormatError.single(log_dir / METADATA_FILENAME, "the simulator withheld this log's map, which its "
                                    "sensors were rendered from; simulate the log again to render them anew",
                                    field=f"extra.{MAP_WITHHELD_KEY}")
    dense = log.dense_tracks()
    check_objects(dense, config, log_dir / av2_io.ANNOTATIONS_FILENAME)
    frames = frame_timestamps(log)
    poses = log.ego.interpolate(frames).matrices  # (F, 4, 4)
    dense_index = {int(t): i for i, t in enumerate(dense.timestamps_ns)}

    start = time.perf_counter()
    world = StaticWorld.build(log.map, poses, config.world, np.random.default_rng([config.seed, 0x5EED]))
    world_s = time.perf_counter() - start
    track_ids = [str(t) for t in dense.track_ids]
    renderer = None
    if config.render_camera:
        appearance = Appearance.from_metadata(log.metadata.appearance, source=str(log_dir / METADATA_FILENAME))
        renderer = CameraRenderer(world, config.camera, appearance, track_ids, [str(c) for c in dense.categories],
                                  seed=config.seed)
    write_start = time.perf_counter()
    av2_io.write_calibration(log_dir, sensor_calibration(config, log.calibration))
    if config.render_camera:
        write_instance_track_ids(log_dir, track_ids)
    write_s = time.perf_counter() - write_start

    lidar_s = camera_s = 0.0
    sweeps = cams = empty = points = 0
    bar = tqdm(total=frames.shape[0], desc=f"sensors {log_dir.name}", unit="frame", file=sys.stderr,
               disable=not progress)
    for f in range(frames.shape[0]):
        ts = int(frames[f])
        rng = np.random.default_rng([config.seed, f])
        objects = FrameObjects.at_frame(dense, dense_index[ts]) if ts in dense_index else FrameObjects.empty()
        pose = SE3.from_matrix(poses[f])
        if config.render_lidar:
            t0 = time.perf_counter()
            returns = cast_sweep(world, objects, pose, config.lidar, rng, ts, nthreads)
            t1 = time.perf_counter()
            av2_io.write_lidar_sweep(log_dir, returns.sweep)
            lidar_s += t1 - t0
            write_s += time.perf_counter() - t1
            sweeps += 1
            points += len(returns.sweep)
        if renderer is not None:
            t0 = time.perf_counter()
            image, mask = renderer.render(objects, pose, rng)
            t1 = time.perf_counter()
            av2_io.write_camera_frame(log_dir, config.camera.name, ts, image, config.camera.jpeg_quality)
            write_instance_mask(log_dir, config.camera.name, ts, mask)
            camera_s += t1 - t0
            write_s += time.perf_counter() - t1
            cams += 1
            empty += int(not mask.any())
        bar.update(1)
    bar.close()
    return RenderReport(log_dir, int(frames.shape[0]), sweeps, cams, empty, points / sweeps if sweeps else 0.0,
                        world_s, lidar_s, camera_s, write_s)
