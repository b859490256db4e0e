"""Captioning config: YAML round trip, unknown keys, contradictions."""

from __future__ import annotations

import re
import typing
from pathlib import Path

import pytest

import scenesearch_base.config
from captioning.config import (
    DEFAULT_CONFIG_PATH,
    CaptioningConfig,
    NeighborConfig,
    SegmentsConfig,
    WindowStrategy,
)
from captioning.errors import CaptioningError, ConfigError
from scenesearch_base.config import YamlConfig


def test_default_round_trips_through_yaml(tmp_path: Path) -> None:
    config = CaptioningConfig()
    config.to_yaml(tmp_path / "c.yaml")
    assert CaptioningConfig.from_yaml(tmp_path / "c.yaml") == config


def test_shipped_default_file_equals_the_defaults() -> None:
    assert CaptioningConfig.from_yaml(DEFAULT_CONFIG_PATH) == CaptioningConfig()


def test_custom_round_trips_through_yaml(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(
        "host: {yaw_rate_rps: 0.2}\nneighbor: {lateral_deg: [50, 130], oncoming_min_deg: 160}\n"
        "windows: {strategy: sliding, length_s: 4, stride_s: 1}\nsmoothing: {window_s: 0.7}\n"
    )
    config = CaptioningConfig.from_yaml(path)
    assert config.host.yaw_rate_rps == 0.2
    assert config.neighbor.lateral_deg == (50.0, 130.0)
    assert config.windows.strategy is WindowStrategy.SLIDING
    assert config.smoothing.window_s == 0.7
    config.to_yaml(tmp_path / "again.yaml")
    assert CaptioningConfig.from_yaml(tmp_path / "again.yaml") == config


def test_unknown_keys_are_all_listed(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("host: {speed: 1}\nneighbour: {}\n")
    with pytest.raises(ConfigError, match=r"host\.speed.*neighbour|neighbour.*host\.speed") as info:
        CaptioningConfig.from_yaml(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("data", "fragment"),
    [
        ({"neighbor": {"lateral_deg": [120, 60]}}, "lateral_deg"),
        ({"neighbor": {"oncoming_min_deg": 100}}, "oncoming_min_deg"),
        ({"host": {"accel_mps2": -1}}, "host.accel_mps2"),
        ({"segments": {"min_s": 5, "max_s": 2}}, "exceeds"),
        ({"smoothing": {"window_s": 0}}, r"smoothing\.window_s"),
        ({"smoothing": {"max_gap_s": -0.1}}, r"smoothing\.max_gap_s"),
        ({"behavior": {"min_run_s": float("nan")}}, r"behavior\.min_run_s"),
        ({"smoothing": {"polyorder": 0}}, "polyorder"),
        ({"windows": {"strategy": "random"}}, "strategy"),
        ({"windows": {"strategy": "sliding", "length_s": 2, "stride_s": 3}},
         r"stride_s \(3.*exceeds windows\.length_s"),
        ({"host": {"yaw_rate_rps": "fast"}}, "yaw_rate_rps"),
        ({"neighbor": {"lateral_deg": 60}}, "lateral_deg"),
    ],
)
def test_contradictions_are_config_errors(data: dict, fragment: str) -> None:
    with pytest.raises(ConfigError, match=fragment):
        CaptioningConfig.from_dict(data)


def test_dataclass_construction_is_validated_too() -> None:
    with pytest.raises(ConfigError):
        CaptioningConfig(neighbor=NeighborConfig(host_lane_half_width_m=float("nan")))
    with pytest.raises(ConfigError, match="twice"):
        CaptioningConfig(segments=SegmentsConfig(min_s=1.0, max_s=1.5))


def test_config_error_is_a_value_error_for_the_cli() -> None:
    assert issubclass(ConfigError, ValueError)
    assert issubclass(ConfigError, CaptioningError) and issubclass(ConfigError, scenesearch_base.config.ConfigError)


#: The parts of the captioning config, by key.
PARTS: dict[str, type[YamlConfig]] = {name: hint for name, hint in typing.get_type_hints(CaptioningConfig).items()
                                      if isinstance(hint, type) and issubclass(hint, YamlConfig)}
#: Every bounded size of the captioning config, with its dotted key.
BOUNDED_KEYS = [(f"{name}.{key}", bound) for name, part in PARTS.items() for key, bound in part.upper_bounds.items()]
#: Other values of its part a size needs at its bound (a segment's maximum is at least twice its minimum).
AT_BOUND_COMPANIONS = {"segments.min_s": {"max_s": 10_000}, "windows.stride_s": {"length_s": 3600}}


def test_the_windows_and_counts_are_bounded_and_documented() -> None:
    bounded = {name for name, part in PARTS.items() if part.upper_bounds}
    assert bounded == {"smoothing", "segments", "windows", "text", "behavior", "map"}
    assert all("Upper bounds:" in (PARTS[name].__doc__ or "") for name in bounded)


@pytest.mark.parametrize(("path", "bound"), BOUNDED_KEYS, ids=[path for path, _ in BOUNDED_KEYS])
def test_a_size_above_its_bound_is_refused_naming_the_key(path: str, bound: float) -> None:
    part, key = path.split(".")
    pattern = rf"^c\.yaml: key '{re.escape(path)}': \S+ is above its upper bound {re.escape(f'{bound:g}')}$"
    with pytest.raises(ConfigError, match=pattern):
        CaptioningConfig.from_dict({part: {key: bound + 1}}, source="c.yaml")


@pytest.mark.parametrize(("path", "bound"), BOUNDED_KEYS, ids=[path for path, _ in BOUNDED_KEYS])
def test_a_size_at_its_bound_is_accepted(path: str, bound: float) -> None:
    part, key = path.split(".")
    config = CaptioningConfig.from_dict({part: {key: bound, **AT_BOUND_COMPANIONS.get(path, {})}})
    assert getattr(getattr(config, part), key) == bound
