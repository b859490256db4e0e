import pytest

from scenes.sim.config import NetworkKind, SimulationConfig, TrackerNoiseConfig


def test_default_config_round_trips_yaml() -> None:
    config = SimulationConfig()
    assert SimulationConfig.from_yaml(config.to_yaml()) == config


def test_custom_config_round_trips_yaml() -> None:
    config = SimulationConfig(
        logs=3, duration_s=12.5, seed=7, network=NetworkKind.SPIDER, tracker_noise=True,
        noise=TrackerNoiseConfig(center_std_m=0.3, miss_probability=0.2, max_range_m=50.0),
        sensors=False, cache_dir="/tmp/x",
    )
    text = config.to_yaml()
    assert "spider" in text
    back = SimulationConfig.from_yaml(text)
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


def test_unknown_yaml_keys_are_refused() -> None:
    with pytest.raises(ValueError, match="bogus"):
        SimulationConfig.from_yaml("logs: 2\nbogus: 1\n")
    with pytest.raises(ValueError, match="jitter"):
        SimulationConfig.from_yaml("noise: {jitter: 1}\n")


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
