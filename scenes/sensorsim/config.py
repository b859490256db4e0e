"""Configuration of the sensor simulation: frozen dataclasses, serialised as YAML by :mod:`scenesearch_base.config`.

Sensor mounting positions are in the ego frame (x forward, y left, z up, origin on the ground
under the rear axle). They are recorded in the log's calibration as ``ego_SE3_sensor`` under the
names :data:`LIDAR_SENSOR_NAME` and :attr:`CameraConfig.name`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from scenes.calibration import CameraIntrinsics
from scenes.config import ScenesConfig
from scenes.geometry import SE3
from scenesearch_base.config import check_at_least, check_positive

#: Calibration name of the simulated LiDAR (the AV2 name of the roof LiDAR).
LIDAR_SENSOR_NAME = "up_lidar"


@dataclass(frozen=True)
class LidarConfig(ScenesConfig):
    """A spinning multi-beam LiDAR on the roof.

    Attributes:
        beams: number of lasers, spread evenly over ``vertical_fov_deg``; beam 0 is the highest.
        vertical_fov_deg: (lowest, highest) elevation in degrees, 0 = horizontal.
        azimuth_steps: firings per revolution.
        max_range_m: returns farther than this are dropped.
        min_range_m: returns nearer than this are dropped.
        mount_x_m: sensor position along the ego x axis.
        mount_height_m: sensor height above the ground.
        spin_period_s: one revolution; ``offset_ns`` grows with the firing's azimuth over it.
        range_noise_std_m: standard deviation of the Gaussian range noise.
        dropout_prob: chance that a return is lost.
        intensity_noise_std: standard deviation of the intensity noise (0–255 scale).
        ego_box_lwh_m: the ego's own body, which blocks rays (length, width, height of a car shape:
            a body and a cabin); (0, 0, 0) for none.
        ego_box_center_x_m: centre of the ego's body along the ego x axis.

    Upper bounds: ``beams`` 256 (``laser_number`` is a uint8), ``azimuth_steps`` 16384.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"beams": 256, "azimuth_steps": 16_384}

    beams: int = 64
    vertical_fov_deg: tuple[float, float] = (-25.0, 15.0)
    azimuth_steps: int = 1024
    max_range_m: float = 100.0
    min_range_m: float = 0.5
    mount_x_m: float = 1.35
    mount_height_m: float = 1.9
    spin_period_s: float = 0.1
    range_noise_std_m: float = 0.02
    dropout_prob: float = 0.02
    intensity_noise_std: float = 4.0
    ego_box_lwh_m: tuple[float, float, float] = (4.8, 1.9, 1.5)
    ego_box_center_x_m: float = 1.4

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "vertical_fov_deg", tuple(float(v) for v in self.vertical_fov_deg))
        object.__setattr__(self, "ego_box_lwh_m", tuple(float(v) for v in self.ego_box_lwh_m))
        if len(self.vertical_fov_deg) != 2 or not self.vertical_fov_deg[0] < self.vertical_fov_deg[1]:
            raise ValueError(f"LidarConfig.vertical_fov_deg must be (low, high) with low < high, got "
                             f"{self.vertical_fov_deg}")
        if not (self.beams >= 1 and self.azimuth_steps >= 4):
            raise ValueError(f"LidarConfig needs beams >= 1 and azimuth_steps >= 4, got {self.beams}, "
                             f"{self.azimuth_steps}")
        check_positive("LidarConfig", max_range_m=self.max_range_m, mount_height_m=self.mount_height_m,
                        spin_period_s=self.spin_period_s)
        if not 0 <= self.min_range_m < self.max_range_m:
            raise ValueError(f"LidarConfig.min_range_m must be in [0, max_range_m), got {self.min_range_m}")
        if self.range_noise_std_m < 0 or self.intensity_noise_std < 0:
            raise ValueError("LidarConfig noise standard deviations must be >= 0")
        if not 0.0 <= self.dropout_prob < 1.0:
            raise ValueError(f"LidarConfig.dropout_prob must be in [0, 1), got {self.dropout_prob}")
        if len(self.ego_box_lwh_m) != 3 or min(self.ego_box_lwh_m) < 0:
            raise ValueError(f"LidarConfig.ego_box_lwh_m must be three sizes >= 0, got {self.ego_box_lwh_m}")

    @property
    def ego_SE3_sensor(self) -> SE3:
        """Extrinsics: the sensor frame is the ego frame shifted to the mount point."""
        return SE3(np.eye(3), np.array([self.mount_x_m, 0.0, self.mount_height_m]))

    @property
    def elevations_rad(self) -> np.ndarray:
        """(beams,) beam elevations, highest first."""
        low, high = np.deg2rad(self.vertical_fov_deg)
        return np.linspace(high, low, self.beams) if self.beams > 1 else np.array([0.5 * (low + high)])


@dataclass(frozen=True)
class CameraConfig(ScenesConfig):
    """A forward-looking pinhole camera (no distortion).

    Attributes:
        name: the camera's name in the calibration and under ``sensors/cameras/``.
        width_px: image width.
        height_px: image height.
        horizontal_fov_deg: horizontal field of view; square pixels.
        mount_x_m: position along the ego x axis.
        mount_y_m: position along the ego y axis.
        mount_height_m: height above the ground.
        pitch_deg: downward tilt of the optical axis.
        jpeg_quality: quality of the written JPEGs.
        max_distance_m: buildings and objects farther than this are not drawn.

    Upper bounds: ``width_px`` and ``height_px`` 4096.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"width_px": 4096, "height_px": 4096}

    name: str = "ring_front_center"
    width_px: int = 640
    height_px: int = 360
    horizontal_fov_deg: float = 90.0
    mount_x_m: float = 1.6
    mount_y_m: float = 0.0
    mount_height_m: float = 1.5
    pitch_deg: float = 2.0
    jpeg_quality: int = 90
    max_distance_m: float = 150.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (self.width_px >= 8 and self.height_px >= 8):
            raise ValueError(f"CameraConfig image must be at least 8×8, got {self.width_px}×{self.height_px}")
        if not 1.0 <= self.horizontal_fov_deg <= 170.0:
            raise ValueError(f"CameraConfig.horizontal_fov_deg must be in [1, 170], got {self.horizontal_fov_deg}")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"CameraConfig.jpeg_quality must be in [1, 100], got {self.jpeg_quality}")
        if not self.name or "/" in self.name:
            raise ValueError(f"CameraConfig.name must be a plain folder name, got {self.name!r}")
        check_positive("CameraConfig", mount_height_m=self.mount_height_m, max_distance_m=self.max_distance_m)

    @property
    def intrinsics(self) -> CameraIntrinsics:
        fx = 0.5 * self.width_px / math.tan(math.radians(0.5 * self.horizontal_fov_deg))
        return CameraIntrinsics(self.name, fx, fx, 0.5 * self.width_px, 0.5 * self.height_px,
                                self.width_px, self.height_px)

    @property
    def ego_SE3_sensor(self) -> SE3:
        """Extrinsics: camera axes (x right, y down, z forward) in the ego frame, tilted down by the pitch."""
        # Columns: the camera's x, y, z axes written in the ego frame, before the pitch.
        level = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
        p = math.radians(self.pitch_deg)
        # Nose down by p: a rotation about the ego +y axis by +p.
        pitch = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0], [-math.sin(p), 0.0, math.cos(p)]])
        return SE3(pitch @ level, np.array([self.mount_x_m, self.mount_y_m, self.mount_height_m]))


@dataclass(frozen=True)
class WorldConfig(ScenesConfig):
    """The static world built from the map: kerbs, sidewalks and building blocks.

    Attributes:
        raster_resolution_m: cell size of the ground material raster (road, paint, sidewalk).
        margin_m: the world extends this far beyond the ego's path.
        kerb_height_m: height of the kerbs along the edges of the drivable area.
        sidewalk_width_m: width of the sidewalk strip beside the drivable area.
        building_setback_m: buildings keep at least this distance from the drivable area.
        building_spacing_m: pitch of the lattice that building footprints are placed on.
        building_size_m: (smallest, largest) footprint side.
        building_height_m: (lowest, highest) building height.
        lane_mark_width_m: width of painted lane boundaries.

    Upper bounds: ``margin_m`` 1000 (the ground raster grows with the square of the world's extent).
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"margin_m": 1000}

    raster_resolution_m: float = 0.1
    margin_m: float = 120.0
    kerb_height_m: float = 0.15
    sidewalk_width_m: float = 4.0
    building_setback_m: float = 6.0
    building_spacing_m: float = 16.0
    building_size_m: tuple[float, float] = (8.0, 14.0)
    building_height_m: tuple[float, float] = (6.0, 30.0)
    lane_mark_width_m: float = 0.15

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "building_size_m", tuple(float(v) for v in self.building_size_m))
        object.__setattr__(self, "building_height_m", tuple(float(v) for v in self.building_height_m))
        check_positive("WorldConfig", raster_resolution_m=self.raster_resolution_m, margin_m=self.margin_m,
                        building_spacing_m=self.building_spacing_m, lane_mark_width_m=self.lane_mark_width_m)
        check_at_least("WorldConfig", 0, kerb_height_m=self.kerb_height_m, sidewalk_width_m=self.sidewalk_width_m,
                       building_setback_m=self.building_setback_m)
        for name in ("building_size_m", "building_height_m"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"WorldConfig.{name} must be (low, high) with 0 < low <= high, got {(lo, hi)}")


@dataclass(frozen=True)
class SensorConfig(ScenesConfig):
    """Everything the sensor simulation of one log needs.

    Attributes:
        lidar: the LiDAR.
        camera: the front camera.
        world: the static world built from the map.
        seed: seeds noise, dropout and building placement; same seed, same bytes.
        render_lidar: write LiDAR sweeps.
        render_camera: write camera frames and instance masks.
    """

    lidar: LidarConfig = field(default_factory=LidarConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    seed: int = 0
    render_lidar: bool = True
    render_camera: bool = True
