"""Sensor simulation speed on one core: LiDAR sweeps/s and camera frames/s for a busy scene.

Scene: the synthetic crossroad log (:mod:`scenes.sensorsim.synthetic`) with 64 objects (cars,
trucks, a bus, cyclists, pedestrians), a 64-beam × 1024-step LiDAR and a 640 × 360 camera. Ray
casting, OpenCV and the BLAS run on one thread. Targets: ≥ 20 sweeps/s and ≥ 50 frames/s.

Baselines, in the same run:

- LiDAR, same output: the same sweep without ray culling (every ray cast into both scenes: no
  per-object angular windows, no rays dropped up front for the ego's own body, which is then cast
  as an object).
- LiDAR, ranges only: one ray-casting scene holding the static world *and* the frame's objects,
  rebuilt for every sweep, returning only ranges (no intensities, noise or ids). This is a lower
  bound of that design's cost; it grows with the size of the world, while ours does not.
- Camera: the instance mask by ray casting every pixel against the same world and objects (a
  z-buffer by rays, no shading), instead of painter's-order polygon filling.

Encoding and writing (feather, JPEG, 16-bit PNG) is timed separately. Rates are given per CPU
second of this process (``time.process_time``, everything single-threaded, so one core's worth of
work, robust to other load on the machine) and per wall-clock second.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2
import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from scenes import av2_io
from scenes.geometry import SE3
from scenes.log import Log
from scenes.sensorsim.appearance import Appearance
from scenes.sensorsim.camera import CameraRenderer
from scenes.sensorsim.config import LidarConfig, SensorConfig
from scenes.sensorsim.instance_masks import write_instance_mask
from scenes.sensorsim.lidar import _ray_pattern, cast_sweep
from scenes.sensorsim.objects import BOX_SHAPE, FrameObjects, build_object_mesh
from scenes.sensorsim.synthetic import write_synthetic_log
from scenes.sensorsim.world import StaticWorld, _kerb_mesh, o3d_tensor


def _static_triangles(world: StaticWorld) -> tuple[np.ndarray, np.ndarray]:
    """The static world as one (V, 3) / (F, 3) mesh in the city frame (ground, kerbs, buildings)."""
    g = world.ground_z_m
    ground_v = np.array([[-1e4, -1e4, g], [1e4, -1e4, g], [1e4, 1e4, g], [-1e4, 1e4, g]])
    verts, tris = [ground_v], [np.array([[0, 1, 2], [0, 2, 3]])]
    offset = 4
    if len(world.kerbs):
        kv, kt = _kerb_mesh(world.kerbs, g, world.kerb_height_m)
        verts.append(kv)
        tris.append(kt + offset)
        offset += kv.shape[0]
    if len(world.buildings):
        bv = world.buildings.corners().reshape(-1, 3)
        bt = (BOX_SHAPE.triangles[None] + 8 * np.arange(len(world.buildings))[:, None, None]).reshape(-1, 3)
        verts.append(bv)
        tris.append(bt + offset)
    return np.concatenate(verts), np.concatenate(tris)


def _rebuilt_scene(static_v: np.ndarray, static_t: np.ndarray, objects: FrameObjects, pose: SE3) -> Any:
    mesh = build_object_mesh(objects)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d_tensor(static_v.astype(np.float32)), o3d_tensor(static_t.astype(np.uint32)))
    if mesh.triangles.shape[0]:
        v_city = pose.transform_points(mesh.vertices.astype(np.float64))
        scene.add_triangles(o3d_tensor(v_city.astype(np.float32)), o3d_tensor(mesh.triangles))
    return scene


def _baseline_sweep(static_v: np.ndarray, static_t: np.ndarray, objects: FrameObjects, pose: SE3,
                    config: SensorConfig) -> int:
    scene = _rebuilt_scene(static_v, static_t, objects, pose)
    dirs = _ray_pattern(config.lidar).directions @ np.ascontiguousarray(pose.rotation.T)
    origin = pose.transform_points(np.array([[config.lidar.mount_x_m, 0.0, config.lidar.mount_height_m]]))[0]
    rays = np.concatenate([np.broadcast_to(origin, dirs.shape), dirs], axis=1).astype(np.float32)
    hit = scene.cast_rays(o3d_tensor(rays), nthreads=1)
    t = hit["t_hit"].numpy()
    return int((np.isfinite(t) & (t <= config.lidar.max_range_m)).sum())


def _baseline_mask(static_v: np.ndarray, static_t: np.ndarray, objects: FrameObjects, pose: SE3,
                   config: SensorConfig, pixel_dirs_cam: np.ndarray) -> np.ndarray:
    scene = _rebuilt_scene(static_v, static_t, objects, pose)
    city_SE3_cam = pose.compose(config.camera.ego_SE3_sensor)
    dirs = pixel_dirs_cam @ np.ascontiguousarray(city_SE3_cam.rotation.T)
    rays = np.concatenate([np.broadcast_to(city_SE3_cam.translation, dirs.shape), dirs], axis=1).astype(np.float32)
    hit = scene.cast_rays(o3d_tensor(rays), nthreads=1)
    geometry = hit["geometry_ids"].numpy()
    return (geometry == 1).reshape(config.camera.height_px, config.camera.width_px)


def run(quick: bool = False) -> dict[str, Any]:
    cv2.setNumThreads(1)
    frames = 5 if quick else 20
    config = SensorConfig()  # 64 × 1024 LiDAR, 640 × 360 camera
    with tempfile.TemporaryDirectory() as tmp:
        log_dir = write_synthetic_log(Path(tmp) / "busy", num_frames=frames, num_objects=64, seed=1)
        log = Log.open(log_dir)
        dense = log.dense_tracks()
        poses = [SE3.from_matrix(m) for m in dense.city_SE3_ego]
        objects = [FrameObjects.at_frame(dense, f) for f in range(frames)]
        t0 = time.perf_counter()
        world = StaticWorld.build(log.map, dense.city_SE3_ego, config.world, np.random.default_rng(0))
        world_s = time.perf_counter() - t0
        renderer = CameraRenderer(world, config.camera, Appearance.from_metadata(log.metadata.appearance),
                                  [str(t) for t in dense.track_ids], [str(c) for c in dense.categories])

        # Warm up (ray pattern cache, background cache), then time.
        cast_sweep(world, objects[0], poses[0], config.lidar, np.random.default_rng(0), 0, nthreads=1)
        renderer.render(objects[0], poses[0], np.random.default_rng(0))

        t0, c0 = time.perf_counter(), time.process_time()
        sweeps = [cast_sweep(world, objects[f], poses[f], config.lidar, np.random.default_rng(f),
                             int(dense.timestamps_ns[f]), nthreads=1) for f in range(frames)]
        lidar_wall_s, lidar_s = time.perf_counter() - t0, time.process_time() - c0
        t0, c0 = time.perf_counter(), time.process_time()
        images = [renderer.render(objects[f], poses[f], np.random.default_rng(f)) for f in range(frames)]
        camera_wall_s, camera_s = time.perf_counter() - t0, time.process_time() - c0

        c0 = time.process_time()
        for f in range(frames):
            av2_io.write_lidar_sweep(log_dir, sweeps[f].sweep)
        lidar_write_s = time.process_time() - c0
        c0 = time.process_time()
        for f in range(frames):
            ts = int(dense.timestamps_ns[f])
            av2_io.write_camera_frame(log_dir, config.camera.name, ts, images[f][0])
            write_instance_mask(log_dir, config.camera.name, ts, images[f][1])
        camera_write_s = time.process_time() - c0

        import scenes.sensorsim.lidar as lidar_module

        unculled = dataclasses.replace(config.lidar, ego_box_lwh_m=(0.0, 0.0, 0.0))
        ego = lidar_module.ego_body(config.lidar)
        everything = lidar_module.rays_near_boxes
        def every_ray(objects: FrameObjects, config: LidarConfig) -> NDArray[np.bool_]:
            return np.ones(config.azimuth_steps * config.beams, dtype=bool)

        lidar_module.rays_near_boxes = every_ray
        try:
            with_ego = [FrameObjects(np.r_[o.track_index, -1], np.r_[o.categories, ego.categories],
                                     np.r_[o.center_xyz_m, ego.center_xyz_m], np.r_[o.yaw_rad, ego.yaw_rad],
                                     np.r_[o.size_lwh_m, ego.size_lwh_m]) for o in objects]
            c0 = time.process_time()
            for f in range(frames):
                cast_sweep(world, with_ego[f], poses[f], unculled, np.random.default_rng(f), 0, nthreads=1)
            unculled_s = time.process_time() - c0
        finally:
            lidar_module.rays_near_boxes = everything

        static_v, static_t = _static_triangles(world)
        base_frames = max(2, frames // 4)
        c0 = time.process_time()
        for f in range(base_frames):
            _baseline_sweep(static_v, static_t, objects[f], poses[f], config)
        base_lidar_s = time.process_time() - c0
        k_inv = np.linalg.inv(config.camera.intrinsics.K)
        u, v = np.meshgrid(np.arange(config.camera.width_px, dtype=np.float64),
                           np.arange(config.camera.height_px, dtype=np.float64))
        pixel_dirs = np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3) @ np.ascontiguousarray(k_inv.T)
        c0 = time.process_time()
        for f in range(base_frames):
            _baseline_mask(static_v, static_t, objects[f], poses[f], config, pixel_dirs)
        base_camera_s = time.process_time() - c0

    sweeps_per_s = frames / lidar_s
    frames_per_s = frames / camera_s
    base_sweeps_per_s = base_frames / base_lidar_s
    base_frames_per_s = base_frames / base_camera_s
    return {
        "objects": 64,
        "objects_per_frame": round(float(np.mean([len(o) for o in objects])), 1),
        "lidar": f"{config.lidar.beams} beams x {config.lidar.azimuth_steps} steps",
        "camera": f"{config.camera.width_px}x{config.camera.height_px}",
        "static_triangles": int(static_t.shape[0]),
        "points_per_sweep": round(float(np.mean([len(s.sweep) for s in sweeps])), 0),
        "visible_objects_per_frame": round(float(np.mean([len(np.unique(m)) - 1 for _, m in images])), 1),
        "world_build_s": round(world_s, 3),
        "lidar_sweeps_per_s": round(sweeps_per_s, 1),
        "camera_frames_per_s": round(frames_per_s, 1),
        "lidar_sweeps_per_wall_s": round(frames / lidar_wall_s, 1),
        "camera_frames_per_wall_s": round(frames / camera_wall_s, 1),
        "lidar_write_sweeps_per_s": round(frames / lidar_write_s, 1),
        "camera_write_frames_per_s": round(frames / camera_write_s, 1),
        "baseline_lidar_unculled_sweeps_per_s": round(frames / unculled_s, 1),
        "baseline_lidar_rebuilt_scene_ranges_only_sweeps_per_s": round(base_sweeps_per_s, 1),
        "baseline_camera_raycast_mask_frames_per_s": round(base_frames_per_s, 1),
        "lidar_speedup_vs_unculled": round(sweeps_per_s / (frames / unculled_s), 2),
        "lidar_speedup_vs_rebuilt_ranges_only": round(sweeps_per_s / base_sweeps_per_s, 2),
        "camera_speedup_vs_baseline": round(frames_per_s / base_frames_per_s, 2),
        "targets": {"lidar_sweeps_per_s": 20, "camera_frames_per_s": 50},
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2))
