"""Small hand-built scenes for the sensor simulation tests (CPU, offline, seeded)."""

from __future__ import annotations

import numpy as np
import pytest

from scenes.sensorsim.config import LidarConfig, WorldConfig
from scenes.sensorsim.world import StaticWorld


@pytest.fixture(scope="session")
def small_lidar() -> LidarConfig:
    """16 beams × 256 steps, no noise."""
    return LidarConfig(beams=16, azimuth_steps=256, range_noise_std_m=0.0, dropout_prob=0.0, intensity_noise_std=0.0)


@pytest.fixture(scope="session")
def dense_lidar() -> LidarConfig:
    """32 beams × 1024 steps, no noise: enough points on a box to check its surface."""
    return LidarConfig(beams=32, azimuth_steps=1024, range_noise_std_m=0.0, dropout_prob=0.0, intensity_noise_std=0.0)


@pytest.fixture(scope="session")
def bare_world() -> StaticWorld:
    """Flat ground at z = 0, no map; buildings kept 40 m away from the origin."""
    poses = np.eye(4)[None].repeat(2, axis=0)
    poses[1, 0, 3] = 1.0
    config = WorldConfig(raster_resolution_m=0.5, margin_m=30.0, building_setback_m=40.0)
    return StaticWorld.build(None, poses, config, np.random.default_rng(0))
