"""The demo's sizes and seeds: what DemoConfig refuses before any stage runs."""

from __future__ import annotations

import pytest

from retrieval.demo_config import DemoConfig


def test_invalid_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="logs must be at least 1"):
        DemoConfig(logs=0)
    with pytest.raises(ValueError, match="test_fraction must lie in"):
        DemoConfig(test_fraction=0.9)
    with pytest.raises(ValueError, match="map_less_share must lie in"):
        DemoConfig(map_less_share=2.0)
    with pytest.raises(ValueError, match="extra_networks: unknown network kind 'ring'"):
        DemoConfig(extra_networks=("grid", "ring"))
    with pytest.raises(ValueError, match="extra_networks must name one or more distinct layouts"):
        DemoConfig(extra_networks=("grid", "grid"))
    with pytest.raises(ValueError, match="extra_networks must name one or more distinct layouts"):
        DemoConfig(extra_networks=())
    with pytest.raises(ValueError, match="extra_logs must be at least 0"):
        DemoConfig(extra_logs=-1)
    with pytest.raises(ValueError, match="val_logs must be at least 0"):
        DemoConfig(val_logs=-1)
    with pytest.raises(ValueError, match="workers must be at least 0"):
        DemoConfig(workers=-1)


def test_quick_is_a_valid_config() -> None:
    quick = DemoConfig.quick()
    assert quick.logs < DemoConfig().logs and quick.train_preset == "tiny" and quick.epochs == 1
