"""A spinning multi-beam LiDAR, simulated by ray casting with open3d.

Every firing casts ``beams`` rays at once; the sensor turns clockwise seen from above (like a
Velodyne), starting behind the vehicle, and one revolution takes ``spin_period_s``: ``offset_ns``
of a point is the time of its firing within the revolution. The world is frozen at the sweep
timestamp, i.e. points come out motion-compensated to that instant, as AV2 sweeps are.

Two scenes are cast per sweep: the static world (built once per log, city frame) and a small scene
of the frame's objects (rebuilt every frame, ego frame); the nearer hit wins, so objects occlude the
world and each other for free. Two cullings keep the cost down: rays that the ego's own body blocks
are found once per configuration (the body is fixed to the sensor) and never cast, and only rays
inside some object's angular window are cast into the object scene.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from scenes.geometry import SE3, FloatArray
from scenes.sensors import LidarSweep
from scenes.sensorsim.config import LidarConfig
from scenes.sensorsim.ground import GROUND_REFLECTIVITY
from scenes.sensorsim.objects import OBJECT_REFLECTIVITY, FrameObjects, build_object_mesh
from scenes.sensorsim.world import BUILDING_REFLECTIVITY, KERB_REFLECTIVITY, StaticKind, StaticWorld, o3d_tensor

#: Instance value of points on the static world.
STATIC_INSTANCE = -1


@dataclass(frozen=True)
class LidarReturns:
    """A simulated sweep with the object each point hit.

    Attributes:
        sweep: the sweep in the ego frame, as written to ``sensors/lidar/<ns>.feather``.
        track_index: (N,) index into the log's track list of the object each point lies on,
            :data:`STATIC_INSTANCE` for the static world.
        rays_cast: number of rays cast.
    """

    sweep: LidarSweep
    track_index: NDArray[np.int64]
    rays_cast: int


@dataclass(frozen=True)
class _RayPattern:
    directions: FloatArray  # (R, 3) unit directions in the sensor frame, firing-major
    beam: NDArray[np.uint8]  # (R,)
    offset_ns: NDArray[np.int32]  # (R,)
    grid_index: NDArray[np.int64]  # (R,) index of each ray in the full (firing, beam) grid
    num_grid: int  # firings × beams


def ego_body(config: LidarConfig) -> FrameObjects:
    """The ego's own body as a car shape (body and cabin) in the ego frame."""
    length, width, height = config.ego_box_lwh_m
    return FrameObjects.from_boxes([("car", (config.ego_box_center_x_m, 0.0, 0.5 * height), (length, width, height),
                                     0.0)])


@lru_cache(maxsize=8)
def _ray_pattern(config: LidarConfig) -> _RayPattern:
    """The firing pattern, without the rays that the ego's own body blocks (fixed to the sensor, so
    found once per configuration by casting against the body alone)."""
    elevation = config.elevations_rad  # (B,)
    steps = config.azimuth_steps
    firing = np.arange(steps)
    azimuth = np.pi - 2.0 * np.pi * (firing + 0.5) / steps  # clockwise from behind
    el, az = np.meshgrid(elevation, azimuth, indexing="xy")  # (A, B)
    dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1).reshape(-1, 3)
    beam = np.tile(np.arange(config.beams, dtype=np.uint8), steps)
    offset = np.repeat((firing * (config.spin_period_s * 1e9 / steps)).astype(np.int32), config.beams)
    open_rays = np.ones(dirs.shape[0], dtype=bool)
    if min(config.ego_box_lwh_m) > 0:
        body = build_object_mesh(ego_body(config))
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d_tensor(body.vertices), o3d_tensor(body.triangles))
        rays = np.empty((dirs.shape[0], 6), np.float32)
        rays[:, :3] = [config.mount_x_m, 0.0, config.mount_height_m]
        rays[:, 3:] = dirs
        open_rays = ~np.isfinite(scene.cast_rays(o3d_tensor(rays))["t_hit"].numpy())
    grid_index = np.flatnonzero(open_rays)
    out = (dirs[grid_index], beam[grid_index], offset[grid_index], grid_index)
    for array in out:
        array.setflags(write=False)
    return _RayPattern(*out, num_grid=dirs.shape[0])


def _track_gain(track_index: NDArray[np.int64]) -> FloatArray:
    """(N,) a fixed per-track reflectivity factor in [0.75, 1.25] (paint, clothing)."""
    frac = np.mod(np.sin(track_index.astype(np.float64) * 12.9898 + 1.0) * 43758.5453, 1.0)
    return 0.75 + 0.5 * frac


def _box_windows(centers: FloatArray, sizes: FloatArray, yaws: FloatArray, sensor: FloatArray,
                 ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
    """Angular windows of upright boxes seen from ``sensor`` (conservative).

    Returns:
        (N,) azimuth of the window centre, (N,) half-width of the azimuth window, (N,) lowest and
        (N,) highest elevation, and (N,) whether the box footprint surrounds the sensor (all azimuths).
    """
    rel = centers - sensor  # (N, 3)
    c, s = np.cos(yaws), np.sin(yaws)
    half = 0.5 * sizes
    corner_sign = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=np.float64)
    lx = corner_sign[None, :, 0] * half[:, None, 0]
    ly = corner_sign[None, :, 1] * half[:, None, 1]
    cx = rel[:, None, 0] + c[:, None] * lx - s[:, None] * ly  # (N, 4)
    cy = rel[:, None, 1] + s[:, None] * lx + c[:, None] * ly
    az_c = np.arctan2(rel[:, 1], rel[:, 0])
    d = np.mod(np.arctan2(cy, cx) - az_c[:, None] + np.pi, 2 * np.pi) - np.pi
    half_az = np.max(np.abs(d), axis=1)
    # Horizontal distance from the sensor to the footprint (0 inside): elevation extremes.
    sx = np.abs(c * -rel[:, 0] + s * -rel[:, 1]) - half[:, 0]
    sy = np.abs(-s * -rel[:, 0] + c * -rel[:, 1]) - half[:, 1]
    surrounds = (sx <= 0) & (sy <= 0)
    dist = np.hypot(np.maximum(sx, 0), np.maximum(sy, 0))
    z_lo, z_hi = rel[:, 2] - half[:, 2], rel[:, 2] + half[:, 2]
    el_lo = np.arctan2(z_lo, np.where(z_lo < 0, dist, np.hypot(np.abs(rel[:, 0]), np.abs(rel[:, 1])) + half.sum(1)))
    el_hi = np.arctan2(z_hi, np.where(z_hi > 0, dist, np.hypot(np.abs(rel[:, 0]), np.abs(rel[:, 1])) + half.sum(1)))
    return az_c, half_az, el_lo, el_hi, surrounds


def rays_near_boxes(objects: FrameObjects, config: LidarConfig) -> NDArray[np.bool_]:
    """(A · B,) rays of the full firing grid that pass inside the angular window of any object.

    Vectorised with a 2-D difference array over (firing, beam): each object adds its window.
    """
    steps, beams = config.azimuth_steps, config.beams
    sensor = np.array([config.mount_x_m, 0.0, config.mount_height_m])
    if len(objects) == 0:
        return np.zeros(steps * beams, dtype=bool)
    az_c, half_az, el_lo, el_hi, surrounds = _box_windows(objects.center_xyz_m, objects.size_lwh_m, objects.yaw_rad,
                                                          sensor)
    # Firing j looks at azimuth π − 2π (j + ½) / steps; beam b at elevation high − b · step.
    step_az = 2 * np.pi / steps
    j_center = (np.pi - az_c) / step_az - 0.5
    j_half = np.where(surrounds, steps, half_az / step_az + 1.5)
    j0 = np.floor(j_center - j_half).astype(np.int64)
    j1 = np.ceil(j_center + j_half).astype(np.int64) + 1  # exclusive
    full = (j1 - j0) >= steps
    j0 = np.where(full, 0, j0)
    j1 = np.where(full, steps, j1)
    low, high = np.deg2rad(config.vertical_fov_deg)
    step_el = (high - low) / max(beams - 1, 1)
    b0 = np.clip(np.floor((high - el_hi) / step_el) - 1, 0, beams).astype(np.int64)
    b1 = np.clip(np.ceil((high - el_lo) / step_el) + 2, 0, beams).astype(np.int64)
    # Split windows that wrap around the seam into two.
    start = np.mod(j0, steps)
    length = j1 - j0
    first_len = np.minimum(length, steps - start)
    a0 = np.concatenate([start, np.zeros_like(start)])
    a1 = np.concatenate([start + first_len, length - first_len])
    bb0 = np.concatenate([b0, b0])
    bb1 = np.concatenate([b1, b1])
    keep = (a1 > a0) & (bb1 > bb0)
    diff = np.zeros((steps + 1, beams + 1), np.int32)
    np.add.at(diff, (a0[keep], bb0[keep]), 1)
    np.add.at(diff, (a0[keep], bb1[keep]), -1)
    np.add.at(diff, (a1[keep], bb0[keep]), -1)
    np.add.at(diff, (a1[keep], bb1[keep]), 1)
    covered = np.cumsum(np.cumsum(diff, axis=0), axis=1)[:steps, :beams] > 0
    return covered.reshape(-1)  # firing-major, like the ray pattern


def cast_sweep(
    world: StaticWorld,
    objects: FrameObjects,
    city_SE3_ego: SE3,
    config: LidarConfig,
    rng: np.random.Generator,
    timestamp_ns: int = 0,
    nthreads: int = 0,
) -> LidarReturns:
    """Simulate one sweep and keep, per point, the object it hit.

    Args:
        world: the log's static world.
        objects: the frame's objects in the ego frame.
        city_SE3_ego: the ego pose at the sweep.
        config: the LiDAR.
        rng: draws range noise, dropout and intensity noise.
        timestamp_ns: the sweep's timestamp.
        nthreads: ray-casting threads (0: all cores).
    """
    pattern = _ray_pattern(config)
    dirs_ego = pattern.directions  # the sensor frame is the ego frame shifted to the mount point
    origin_ego = np.array([config.mount_x_m, 0.0, config.mount_height_m])
    n_rays = dirs_ego.shape[0]

    origin_city = city_SE3_ego.transform_points(origin_ego[None])[0]
    # A contiguous right operand: OpenBLAS is pathologically slow on (N, 3) @ (3, 3).T when threaded.
    dirs_city = dirs_ego @ np.ascontiguousarray(city_SE3_ego.rotation.T)
    rays = np.empty((n_rays, 6), np.float32)
    rays[:, :3] = origin_city
    rays[:, 3:] = dirs_city
    hit_s = world.scene.cast_rays(o3d_tensor(rays), nthreads=nthreads)
    t_static = hit_s["t_hit"].numpy().astype(np.float64)
    geom = hit_s["geometry_ids"].numpy()
    prim_s = hit_s["primitive_ids"].numpy()
    normal_s = hit_s["primitive_normals"].numpy()

    mesh = build_object_mesh(objects)
    t_dyn = np.full(n_rays, np.inf)
    owner = np.full(n_rays, STATIC_INSTANCE - 1, dtype=np.int64)
    normal_d = np.zeros((n_rays, 3), np.float32)
    if mesh.triangles.shape[0]:
        dyn = o3d.t.geometry.RaycastingScene()
        dyn.add_triangles(o3d_tensor(mesh.vertices), o3d_tensor(mesh.triangles))
        # Only rays inside some object's angular window can hit an object.
        sub = np.flatnonzero(rays_near_boxes(objects, config)[pattern.grid_index])
        sub_rays = np.empty((sub.shape[0], 6), np.float32)
        sub_rays[:, :3] = origin_ego
        sub_rays[:, 3:] = dirs_ego[sub]
        hit_d = dyn.cast_rays(o3d_tensor(sub_rays), nthreads=nthreads)
        t_sub = hit_d["t_hit"].numpy()
        hit = np.isfinite(t_sub)
        t_dyn[sub] = t_sub
        owner[sub[hit]] = mesh.owner[hit_d["primitive_ids"].numpy()[hit].astype(np.int64)]
        normal_d[sub] = hit_d["primitive_normals"].numpy()

    on_object = t_dyn < t_static
    t_hit = np.where(on_object, t_dyn, t_static)
    keep = np.isfinite(t_hit) & (t_hit >= config.min_range_m) & (t_hit <= config.max_range_m)
    if config.dropout_prob > 0:
        keep &= rng.random(n_rays) >= config.dropout_prob
    idx = np.flatnonzero(keep)
    t_keep = t_hit[idx]
    if config.range_noise_std_m > 0:
        t_keep = np.maximum(t_keep + rng.normal(0.0, config.range_noise_std_m, idx.shape[0]), 0.0)
    xyz_ego = origin_ego + dirs_ego[idx] * t_keep[:, None]

    # Intensity: reflectivity of what was hit, dimmed at grazing incidence.
    obj = on_object[idx]
    track_index = np.full(idx.shape[0], STATIC_INSTANCE, dtype=np.int64)
    frame_obj = owner[idx[obj]]
    track_index[obj] = objects.track_index[frame_obj]
    reflect = np.zeros(idx.shape[0])
    per_object = np.array([OBJECT_REFLECTIVITY.get(str(c), 50.0) for c in objects.categories])
    reflect[obj] = per_object[frame_obj] * _track_gain(track_index[obj]) if frame_obj.size else 0.0
    st = ~obj
    g = geom[idx[st]]
    st_reflect = np.full(g.shape[0], KERB_REFLECTIVITY)
    ground = g == StaticKind.GROUND
    if ground.any():
        hit_city = origin_city + dirs_city[idx[st][ground]] * t_hit[idx[st][ground], None]
        st_reflect[ground] = GROUND_REFLECTIVITY[world.raster.material_at(hit_city[:, :2])]
    building = g == StaticKind.BUILDING
    if building.any() and len(world.buildings):
        bid = np.minimum(prim_s[idx[st][building]].astype(np.int64) // 12, len(world.buildings) - 1)
        st_reflect[building] = BUILDING_REFLECTIVITY * world.buildings.shade[bid]
    reflect[st] = st_reflect
    cos_inc = np.empty(idx.shape[0])
    cos_inc[obj] = np.abs(np.einsum("ij,ij->i", normal_d[idx[obj]], dirs_ego[idx[obj]]))
    cos_inc[st] = np.abs(np.einsum("ij,ij->i", normal_s[idx[st]], dirs_city[idx[st]]))
    intensity = reflect * (0.35 + 0.65 * cos_inc)
    if config.intensity_noise_std > 0:
        intensity = intensity + rng.normal(0.0, config.intensity_noise_std, idx.shape[0])
    sweep = LidarSweep(
        timestamp_ns=int(timestamp_ns),
        xyz_m=xyz_ego.astype(np.float32),
        intensity=np.clip(np.round(intensity), 0, 255).astype(np.uint8),
        laser_number=pattern.beam[idx].copy(),
        offset_ns=pattern.offset_ns[idx].copy(),
    )
    return LidarReturns(sweep, track_index, n_rays)
