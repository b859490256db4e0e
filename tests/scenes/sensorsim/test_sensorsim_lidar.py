"""LiDAR ray casting: points lie on the surfaces they hit, nearer objects occlude farther ones."""

from __future__ import annotations

import numpy as np

from scenes.geometry import SE3
from scenes.sensorsim.config import LidarConfig
from scenes.sensorsim.lidar import STATIC_INSTANCE, cast_sweep
from scenes.sensorsim.objects import FrameObjects
from scenes.sensorsim.world import StaticWorld

NOTHING = FrameObjects.from_boxes([])


def _box_local(points: np.ndarray, center: tuple[float, float, float], yaw: float) -> np.ndarray:
    rel = points - np.asarray(center)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], rel[:, 2]], axis=1)


def test_points_from_a_box_lie_on_its_surface(bare_world: StaticWorld, dense_lidar: LidarConfig) -> None:
    center, size, yaw = (12.0, 3.0, 1.6), (8.0, 2.5, 3.2), 0.4
    objects = FrameObjects.from_boxes([("truck", center, size, yaw)])
    returns = cast_sweep(bare_world, objects, SE3.identity(), dense_lidar, np.random.default_rng(0))
    xyz = returns.sweep.xyz_m.astype(np.float64)
    on_box = returns.track_index == 0
    assert on_box.sum() > 100
    local = _box_local(xyz[on_box], center, yaw)
    half = 0.5 * np.array(size)
    tol = 2e-3
    assert np.all(np.abs(local) <= half + tol), "a point of the box lies outside it"
    # On the surface: some coordinate sits on a face.
    gap_to_face = np.min(half - np.abs(local), axis=1)
    assert np.all(gap_to_face <= tol), "a point of the box lies inside it, not on its surface"
    # The box faces the sensor with the sides nearest to it: no point on the far faces.
    sensor = np.array([dense_lidar.mount_x_m, 0.0, dense_lidar.mount_height_m])
    sensor_local = _box_local(sensor[None], center, yaw)[0]
    for axis in range(2):
        far_face = np.abs(local[:, axis] + np.sign(sensor_local[axis]) * half[axis]) <= tol
        assert not far_face.any()
    # Everything else is ground (z = 0), outside the box.
    rest = xyz[returns.track_index == STATIC_INSTANCE]
    assert np.allclose(rest[:, 2], 0.0, atol=tol)
    under = np.all(np.abs(_box_local(rest, center, yaw)[:, :2]) < half[:2] - 0.02, axis=1)
    assert not under.any(), "a ray went through the box to the ground beneath it"


def test_pedestrian_shape_stays_inside_its_box(bare_world: StaticWorld, dense_lidar: LidarConfig) -> None:
    center, size, yaw = (6.0, -2.0, 0.88), (0.6, 0.6, 1.8), 0.0
    returns = cast_sweep(bare_world, FrameObjects.from_boxes([("pedestrian", center, size, yaw)]), SE3.identity(),
                         dense_lidar, np.random.default_rng(0))
    local = _box_local(returns.sweep.xyz_m[returns.track_index == 0].astype(np.float64), center, yaw)
    assert local.shape[0] > 20
    assert np.all(np.abs(local) <= 0.5 * np.array(size) + 2e-3)
    # A round shape: points on the sides lie near the inscribed circle, not in the box corners.
    radial = np.hypot(local[:, 0], local[:, 1])
    assert np.all(radial <= 0.5 * 0.6 / np.cos(np.pi / 8) + 2e-3)


def test_nearer_object_occludes_farther_one(bare_world: StaticWorld, dense_lidar: LidarConfig) -> None:
    near = ("bus", (10.0, 0.0, 1.6), (3.0, 6.0, 3.2), 0.0)
    far = ("car", (25.0, 0.0, 0.75), (4.5, 1.9, 1.5), 0.0)
    rng = np.random.default_rng(0)
    alone = cast_sweep(bare_world, FrameObjects.from_boxes([far]), SE3.identity(), dense_lidar, rng)
    assert (alone.track_index == 0).sum() > 20
    both = cast_sweep(bare_world, FrameObjects.from_boxes([far, near]), SE3.identity(), dense_lidar, rng)
    assert (both.track_index == 0).sum() == 0, "the far car is hidden behind the bus"
    assert (both.track_index == 1).sum() > 100
    # The shadow of the bus holds no ground points either.
    xyz = both.sweep.xyz_m.astype(np.float64)
    behind = (xyz[:, 0] > 12.0) & (xyz[:, 0] < 40.0) & (np.abs(xyz[:, 1]) < 1.0) & (both.track_index == -1)
    assert not behind.any()


def test_sweep_layout_timing_and_ranges(bare_world: StaticWorld) -> None:
    config = LidarConfig(beams=16, azimuth_steps=256, max_range_m=40.0, range_noise_std_m=0.0, dropout_prob=0.0)
    sweep = cast_sweep(bare_world, NOTHING, SE3.identity(), config, np.random.default_rng(0), 123).sweep
    assert sweep.timestamp_ns == 123
    origin = np.array([config.mount_x_m, 0.0, config.mount_height_m])
    rng_m = np.linalg.norm(sweep.xyz_m - origin, axis=1)
    assert rng_m.max() <= 40.0 + 1e-3 and rng_m.min() >= config.min_range_m
    assert sweep.laser_number.max() < 16
    assert sweep.offset_ns.min() >= 0 and sweep.offset_ns.max() < 100_000_000
    # Beam 0 is the highest: on flat ground, lower beams land nearer.
    beams = np.unique(sweep.laser_number)
    mean_range = np.array([rng_m[sweep.laser_number == b].mean() for b in beams])
    ground_beams = beams >= 8  # below the horizon
    assert np.all(np.diff(mean_range[ground_beams]) < 0)
    # The sensor spins clockwise from behind: azimuth falls as the offset grows.
    az = np.unwrap(np.arctan2(sweep.xyz_m[:, 1] - 0.0, sweep.xyz_m[:, 0] - origin[0]))
    order = np.argsort(sweep.offset_ns, kind="stable")
    assert np.corrcoef(sweep.offset_ns[order], az[order])[0, 1] < -0.99
    # The ego's own body hides the ground right around it.
    near = (np.abs(sweep.xyz_m[:, 0] - config.ego_box_center_x_m) < 2.0) & (np.abs(sweep.xyz_m[:, 1]) < 0.9)
    assert not near.any()


def test_noise_dropout_and_seed(bare_world: StaticWorld, small_lidar: LidarConfig) -> None:
    noisy = LidarConfig(beams=16, azimuth_steps=256, range_noise_std_m=0.05, dropout_prob=0.5)
    a = cast_sweep(bare_world, NOTHING, SE3.identity(), noisy, np.random.default_rng(7)).sweep
    b = cast_sweep(bare_world, NOTHING, SE3.identity(), noisy, np.random.default_rng(7)).sweep
    clean = cast_sweep(bare_world, NOTHING, SE3.identity(), small_lidar, np.random.default_rng(7)).sweep
    assert np.array_equal(a.xyz_m, b.xyz_m) and np.array_equal(a.intensity, b.intensity)
    assert 0.4 < len(a) / len(clean) < 0.6
    # Ground returns: the true range of beam b is mount height / sin(−elevation_b).
    origin = np.array([noisy.mount_x_m, 0.0, noisy.mount_height_m])
    measured = np.linalg.norm(a.xyz_m.astype(np.float64) - origin, axis=1)
    elevation = noisy.elevations_rad[a.laser_number]
    down = elevation < -0.05
    residual = measured[down] - noisy.mount_height_m / np.sin(-elevation[down])
    assert abs(residual.mean()) < 0.01
    assert 0.04 < residual.std() < 0.06


def test_ego_pose_moves_the_world_not_the_objects(bare_world: StaticWorld, small_lidar: LidarConfig) -> None:
    # Objects are given in the ego frame; the static world follows the pose.
    objects = FrameObjects.from_boxes([("truck", (10.0, 0.0, 1.6), (4.0, 2.5, 3.2), 0.0)])
    pose = SE3.from_yaw(0.7, np.array([0.5, 0.2, 0.0]))
    moved = cast_sweep(bare_world, objects, pose, small_lidar, np.random.default_rng(0))
    still = cast_sweep(bare_world, objects, SE3.identity(), small_lidar, np.random.default_rng(0))
    on_a = moved.sweep.xyz_m[moved.track_index == 0]
    on_b = still.sweep.xyz_m[still.track_index == 0]
    assert on_a.shape == on_b.shape and np.allclose(on_a, on_b, atol=1e-4)


def test_ray_prefilter_keeps_every_ray_that_hits_an_object() -> None:
    import open3d as o3d

    from scenes.sensorsim.lidar import _ray_pattern, rays_near_boxes
    from scenes.sensorsim.objects import build_object_mesh

    rng = np.random.default_rng(3)
    config = LidarConfig(beams=32, azimuth_steps=512, ego_box_lwh_m=(0.0, 0.0, 0.0))
    n = 40
    rows = []
    for i in range(n):
        kind = ["car", "truck", "pedestrian", "cyclist", "bus"][i % 5]
        size = {"car": (4.5, 1.9, 1.5), "truck": (8.0, 2.5, 3.5), "pedestrian": (0.6, 0.6, 1.8),
                "cyclist": (1.8, 0.7, 1.7), "bus": (12.0, 2.6, 3.2)}[kind]
        r, a = rng.uniform(4.0, 60.0), rng.uniform(-np.pi, np.pi)
        center = (1.35 + r * np.cos(a), r * np.sin(a), rng.uniform(0.3, 3.0))
        rows.append((kind, center, size, float(rng.uniform(-np.pi, np.pi))))
    rows.append(("truck", (-8.0, 0.0, 1.0), (3.0, 30.0, 2.0), 0.0))  # spans the seam behind the sensor
    objects = FrameObjects.from_boxes(rows)
    mesh = build_object_mesh(objects)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices), o3d.core.Tensor(mesh.triangles))
    dirs = _ray_pattern(config).directions
    origin = np.array([config.mount_x_m, 0.0, config.mount_height_m])
    rays = np.concatenate([np.broadcast_to(origin, dirs.shape), dirs], axis=1).astype(np.float32)
    hit = np.isfinite(scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy())
    near = rays_near_boxes(objects, config)
    assert hit.sum() > 1000
    assert not (hit & ~near).any(), "a ray that hits an object was filtered out"
    assert near.mean() < 0.9
