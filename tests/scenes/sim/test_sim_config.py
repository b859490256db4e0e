import re
from pathlib import Path

import pytest

import scenesearch_base.config
from scenes.errors import ConfigError, ScenesError
from scenes.sim.config import MAX_STEPS_PER_LOG, NetworkKind, SimulationConfig, TrackerNoiseConfig


def test_default_config_round_trips_yaml() -> None:
    config = SimulationConfig()
    assert SimulationConfig.from_yaml_text(config.to_yaml_text()) == config


def test_custom_config_round_trips_yaml() -> None:
    config = SimulationConfig(
        logs=3, duration_s=12.5, seed=7, network=NetworkKind.SPIDER, tracker_noise=True,
        noise=TrackerNoiseConfig(center_std_m=0.3, miss_probability=0.2, max_range_m=50.0),
        sensors=False, cache_dir="/tmp/x",
    )
    text = config.to_yaml_text()
    assert "spider" in text
    back = SimulationConfig.from_yaml_text(text)
    assert back == config
    assert isinstance(back.network, NetworkKind)
    assert isinstance(back.noise, TrackerNoiseConfig)


def test_network_given_as_string_is_parsed() -> None:
    assert SimulationConfig(network="random").network is NetworkKind.RANDOM  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"logs": 0}, "logs"),
        ({"duration_s": 0.0}, "duration_s"),
        ({"duration_s": -3.0}, "duration_s"),
        ({"warmup_s": -1.0}, "warmup_s"),
        ({"egos_per_run": 0}, "egos_per_run"),
    ],
)
def test_bad_values_name_the_field(kwargs: dict, field: str) -> None:
    with pytest.raises(ValueError, match=field):
        SimulationConfig(**kwargs)


def test_unknown_network_kind_lists_the_choices() -> None:
    with pytest.raises(ValueError, match="grid, spider, random"):
        SimulationConfig(network="hexagon")  # type: ignore[arg-type]


def test_unknown_yaml_keys_are_refused_naming_file_and_key(tmp_path: Path) -> None:
    path = tmp_path / "sim.yaml"
    path.write_text("logs: 2\nbogus: 1\n")
    with pytest.raises(ConfigError, match=f"^{path}: unknown keys bogus"):
        SimulationConfig.from_yaml(path)
    with pytest.raises(ConfigError, match="unknown keys noise.jitter"):
        SimulationConfig.from_yaml_text("noise: {jitter: 1}\n")


def test_config_file_errors_are_scenes_and_common_config_errors(tmp_path: Path) -> None:
    path = tmp_path / "sim.yaml"
    SimulationConfig(logs=3).to_yaml(path)
    assert SimulationConfig.from_yaml(path) == SimulationConfig(logs=3)
    path.write_text("logs: three\n")
    with pytest.raises(ConfigError, match="key 'logs': expected an integer") as info:
        SimulationConfig.from_yaml(path)
    assert isinstance(info.value, ScenesError) and isinstance(info.value, scenesearch_base.config.ConfigError)
    with pytest.raises(ConfigError, match="key 'network': expected one of 'grid', 'spider', 'random'"):
        SimulationConfig.from_yaml_text("network: hexagon\n")


def test_noise_config_validates() -> None:
    with pytest.raises(ValueError, match="miss_probability"):
        TrackerNoiseConfig(miss_probability=1.5)
    with pytest.raises(ValueError, match="max_range_m"):
        TrackerNoiseConfig(max_range_m=0.0)


def test_window_arithmetic() -> None:
    config = SimulationConfig(logs=9, egos_per_run=4)
    assert config.num_egos == 4
    assert config.num_windows == 3
    assert SimulationConfig(logs=2, egos_per_run=4).num_egos == 2


BOUNDED_KEYS = [("", key, bound) for key, bound in SimulationConfig.upper_bounds.items()] + [
    ("noise.", key, bound) for key, bound in TrackerNoiseConfig.upper_bounds.items()]


def _at(prefix: str, key: str, value: float) -> dict:
    return {prefix.rstrip("."): {key: value}} if prefix else {key: value}


def test_the_sizes_are_bounded_and_documented() -> None:
    assert {"logs", "duration_s", "egos_per_run", "parked_vehicles", "vehicles_per_s_per_km"} <= set(
        SimulationConfig.upper_bounds)
    for cls in (SimulationConfig, TrackerNoiseConfig):
        assert "Upper bounds:" in (cls.__doc__ or "")


@pytest.mark.parametrize(("prefix", "key", "bound"), BOUNDED_KEYS, ids=[p + k for p, k, _ in BOUNDED_KEYS])
def test_a_size_above_its_bound_is_refused_naming_the_key(prefix: str, key: str, bound: float) -> None:
    pattern = rf"^sim\.yaml: key '{re.escape(prefix + key)}': \S+ is above its upper bound {re.escape(f'{bound:g}')}$"
    with pytest.raises(ConfigError, match=pattern):
        SimulationConfig.from_dict(_at(prefix, key, bound + 1), source="sim.yaml")


@pytest.mark.parametrize(("prefix", "key", "bound"), BOUNDED_KEYS, ids=[p + k for p, k, _ in BOUNDED_KEYS])
def test_a_size_at_its_bound_is_accepted(prefix: str, key: str, bound: float) -> None:
    config = SimulationConfig.from_dict(_at(prefix, key, bound))
    assert getattr(config.noise if prefix else config, key) == bound


def test_the_steps_of_a_log_are_bounded() -> None:
    assert SimulationConfig(duration_s=3600.0, step_s=0.01)  # an hour at 100 Hz
    with pytest.raises(ConfigError, match=rf"key 'step_s': .* above the upper bound {MAX_STEPS_PER_LOG}"):
        SimulationConfig(duration_s=3600.0, step_s=0.001)
