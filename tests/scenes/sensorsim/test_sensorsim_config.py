"""Sensor configuration: YAML round trip, validation, and calibration conventions."""

from __future__ import annotations

import re

import numpy as np
import pytest

from scenes.errors import ConfigError
from scenes.sensorsim.config import CameraConfig, LidarConfig, SensorConfig, WorldConfig
from tests.realdata import REALDATA

AV2_LOG = REALDATA / "av2" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"


def test_yaml_round_trip() -> None:
    config = SensorConfig(
        lidar=LidarConfig(beams=32, vertical_fov_deg=(-30.0, 10.0), azimuth_steps=2048, dropout_prob=0.1),
        camera=CameraConfig(width_px=320, height_px=180, horizontal_fov_deg=70.0, pitch_deg=4.0),
        world=WorldConfig(building_height_m=(5.0, 12.0), kerb_height_m=0.2),
        seed=42,
        render_camera=False,
    )
    text = config.to_yaml_text()
    back = SensorConfig.from_yaml_text(text)
    assert back == config
    assert SensorConfig.from_yaml_text(SensorConfig().to_yaml_text()) == SensorConfig()
    small = SensorConfig.from_yaml_text("seed: 3\nlidar: {beams: 8}\n")
    assert small == SensorConfig(seed=3, lidar=LidarConfig(beams=8))


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("lidar: {beamz: 3}", "unknown keys"),
        ("colour: red", "unknown keys"),
        ("lidar: {vertical_fov_deg: [10, -10]}", "vertical_fov_deg"),
        ("lidar: {dropout_prob: 1.5}", "dropout_prob"),
        ("lidar: {beams: 300}", "beams"),
        ("camera: {width_px: 0}", "at least 8"),
        ("camera: {name: a/b}", "name"),
        ("world: {building_size_m: [10, 5]}", "building_size_m"),
        ("- 1\n- 2", "mapping"),
    ],
)
def test_bad_values_are_refused(text: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SensorConfig.from_yaml_text(text)


def test_camera_extrinsics_and_intrinsics() -> None:
    camera = CameraConfig(width_px=640, height_px=360, horizontal_fov_deg=90.0, pitch_deg=0.0)
    rot = camera.ego_SE3_sensor.rotation
    assert np.allclose(rot @ [0, 0, 1], [1, 0, 0])  # optical axis → ego forward
    assert np.allclose(rot @ [1, 0, 0], [0, -1, 0])  # image right → ego right (−y)
    assert np.allclose(rot @ [0, 1, 0], [0, 0, -1])  # image down → ego down
    k = camera.intrinsics
    assert k.fx_px == pytest.approx(320.0) and k.cx_px == 320.0 and k.cy_px == 180.0
    tilted = CameraConfig(pitch_deg=10.0).ego_SE3_sensor.rotation @ [0, 0, 1]
    assert tilted[2] == pytest.approx(-np.sin(np.radians(10.0)))  # pitched down


def test_camera_axes_match_a_real_av2_calibration() -> None:
    if not AV2_LOG.is_dir():
        pytest.skip(f"real AV2 log not found at {AV2_LOG}")
    from scenes.av2_io import read_calibration

    real = read_calibration(AV2_LOG).ego_SE3_sensor["ring_front_center"].rotation
    ours = CameraConfig(pitch_deg=0.0).ego_SE3_sensor.rotation
    angle = np.degrees(np.arccos(np.clip((np.trace(real.T @ ours) - 1) / 2, -1, 1)))
    assert angle < 2.0


BOUNDED_KEYS = [(part, key, bound) for part, cls in (("lidar", LidarConfig), ("camera", CameraConfig),
                                                      ("world", WorldConfig))
                for key, bound in cls.upper_bounds.items()]


def test_the_sizes_are_bounded_and_documented() -> None:
    assert {(p, k) for p, k, _ in BOUNDED_KEYS} >= {("lidar", "beams"), ("lidar", "azimuth_steps"),
                                                     ("camera", "width_px"), ("camera", "height_px")}
    for cls in (LidarConfig, CameraConfig, WorldConfig):
        assert "Upper bounds:" in (cls.__doc__ or "")


@pytest.mark.parametrize(("part", "key", "bound"), BOUNDED_KEYS, ids=[f"{p}.{k}" for p, k, _ in BOUNDED_KEYS])
def test_a_size_above_its_bound_is_refused_naming_the_key(part: str, key: str, bound: float) -> None:
    pattern = rf"^sensors\.yaml: key '{part}\.{key}': \S+ is above its upper bound {re.escape(f'{bound:g}')}$"
    with pytest.raises(ConfigError, match=pattern):
        SensorConfig.from_dict({part: {key: bound + 1}}, source="sensors.yaml")


@pytest.mark.parametrize(("part", "key", "bound"), BOUNDED_KEYS, ids=[f"{p}.{k}" for p, k, _ in BOUNDED_KEYS])
def test_a_size_at_its_bound_is_accepted(part: str, key: str, bound: float) -> None:
    assert getattr(getattr(SensorConfig.from_dict({part: {key: bound}}), part), key) == bound
