"""The static world built from a map: kerbs, buildings clear of the road, ground materials."""

from __future__ import annotations

import numpy as np
import pytest

from scenes.geometry import SE3
from scenes.sensorsim.config import LidarConfig, WorldConfig
from scenes.sensorsim.ground import GroundMaterial
from scenes.sensorsim.lidar import STATIC_INSTANCE, cast_sweep
from scenes.sensorsim.objects import FrameObjects
from scenes.sensorsim.synthetic import HALF_ROAD_M, JUNCTION_X_M, crossroad_map
from scenes.sensorsim.world import StaticWorld

WORLD = WorldConfig(raster_resolution_m=0.1, margin_m=50.0)


@pytest.fixture(scope="module")
def crossroad_world() -> StaticWorld:
    poses = np.eye(4)[None].repeat(2, axis=0)
    poses[:, 0, 3] = [40.0, 60.0]
    poses[:, 1, 3] = -1.75
    return StaticWorld.build(crossroad_map(), poses, WORLD, np.random.default_rng(0))


def test_ground_materials_follow_the_map(crossroad_world: StaticWorld) -> None:
    at = crossroad_world.raster.material_at
    assert at(np.array([[50.0, -1.75]]))[0] == GroundMaterial.ROAD
    assert at(np.array([[50.0, 0.0]]))[0] == GroundMaterial.YELLOW_PAINT  # double solid centre line
    assert at(np.array([[50.0, -HALF_ROAD_M - 2.0]]))[0] == GroundMaterial.SIDEWALK
    assert at(np.array([[50.0, -HALF_ROAD_M - 10.0]]))[0] == GroundMaterial.TERRAIN
    # Dashed lane divider at y = −3.5: both paint and gaps along it.
    divider = at(np.c_[np.linspace(20.0, 80.0, 601), np.full(601, -3.5)])
    assert 0.2 < np.mean(divider == GroundMaterial.WHITE_PAINT) < 0.5
    # Zebra crossing before the junction: bars across the road direction, alternating along y.
    x_cross = JUNCTION_X_M - HALF_ROAD_M - 2.5
    across = at(np.c_[np.full(141, x_cross), np.linspace(-7.0, 7.0, 141)])
    assert 0.3 < np.mean(across == GroundMaterial.CROSSWALK) < 0.7
    along = at(np.c_[np.linspace(x_cross - 1.0, x_cross + 1.0, 21), np.full(21, -0.9)])
    assert np.all(along == along[0])


def test_buildings_keep_clear_of_the_road(crossroad_world: StaticWorld) -> None:
    b = crossroad_world.buildings
    assert len(b) > 10
    lo = b.center_xyz_m[:, :2] - 0.5 * b.size_lwh_m[:, :2]
    hi = b.center_xyz_m[:, :2] + 0.5 * b.size_lwh_m[:, :2]
    # Sample every footprint and check it against the drivable raster.
    t = np.linspace(0.0, 1.0, 9)
    u, v = np.meshgrid(t, t)
    samples = lo[:, None, :] + np.stack([u.ravel(), v.ravel()], axis=1)[None] * (hi - lo)[:, None, :]
    raster = crossroad_world.raster
    cr = np.floor(raster.city_to_cell(samples.reshape(-1, 2)) + 0.5).astype(int)
    h, w = raster.drivable.shape
    inside = (cr[:, 0] >= 0) & (cr[:, 0] < w) & (cr[:, 1] >= 0) & (cr[:, 1] < h)
    assert not raster.drivable[cr[inside, 1], cr[inside, 0]].any()
    # Set back from the east-west road (|y| ≤ 7 m) by at least the setback.
    ew = (lo[:, 0] < JUNCTION_X_M - HALF_ROAD_M) & (hi[:, 0] < JUNCTION_X_M - HALF_ROAD_M)
    gap = np.minimum(np.abs(lo[ew, 1]), np.abs(hi[ew, 1])) - HALF_ROAD_M
    assert gap.min() >= WORLD.building_setback_m - 0.2
    assert np.allclose(b.center_xyz_m[:, 2], 0.5 * b.size_lwh_m[:, 2])  # standing on the ground


def test_lidar_sees_kerbs_buildings_and_paint(crossroad_world: StaticWorld) -> None:
    config = LidarConfig(beams=32, azimuth_steps=1024, range_noise_std_m=0.0, dropout_prob=0.0,
                         intensity_noise_std=0.0)
    pose = SE3.from_yaw(0.0, np.array([60.0, -1.75, 0.0]))
    returns = cast_sweep(crossroad_world, FrameObjects.empty(), pose, config, np.random.default_rng(0))
    assert np.all(returns.track_index == STATIC_INSTANCE)
    xyz = returns.sweep.xyz_m.astype(np.float64)
    city = pose.transform_points(xyz)
    low = (city[:, 2] > 0.02) & (city[:, 2] < WORLD.kerb_height_m + 1e-3)
    on_main = np.abs(np.abs(city[:, 1]) - HALF_ROAD_M) < 0.3
    on_side = np.abs(np.abs(city[:, 0] - JUNCTION_X_M) - HALF_ROAD_M) < 0.3
    assert (low & (on_main | on_side)).sum() > 50, "kerbs along the road edges"
    # No kerb across the carriageway, where drivable polygons meet at the junction.
    inside_main = (np.abs(city[:, 1]) < HALF_ROAD_M - 0.5) & (np.abs(city[:, 0] - JUNCTION_X_M) > HALF_ROAD_M + 0.5)
    inside_side = np.abs(city[:, 0] - JUNCTION_X_M) < HALF_ROAD_M - 0.5
    assert not (low & (inside_main | inside_side)).any()
    tall = city[:, 2] > 1.0
    assert tall.sum() > 100  # building walls
    ground = np.abs(city[:, 2]) < 1e-3
    material = crossroad_world.raster.material_at(city[ground, :2])
    intensity = returns.sweep.intensity[ground].astype(float)
    paint = np.isin(material, [GroundMaterial.WHITE_PAINT, GroundMaterial.YELLOW_PAINT, GroundMaterial.CROSSWALK])
    road = material == GroundMaterial.ROAD
    assert paint.sum() > 20 and road.sum() > 1000
    assert np.median(intensity[paint]) > 3 * np.median(intensity[road])
