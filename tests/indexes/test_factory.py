import math
from pathlib import Path

import pytest

import scenesearch_base.config
from indexes.errors import ConfigError, IndexesError, MemoryBudgetError
from indexes.factory import AutoConfig, choose_factory, ivf_lists, train_points


def test_small_collections_are_exact() -> None:
    assert choose_factory(1_000, 256).factory == "Flat"
    assert choose_factory(20_000, 256).factory == "Flat"


def test_mid_size_uses_hnsw_and_large_uses_ivf() -> None:
    assert choose_factory(100_000, 256).factory == "HNSW32"
    choice = choose_factory(1_000_000, 256)
    assert choice.factory == "IVF4096,Flat"
    assert choice.train_points >= 39 * 4096


@pytest.mark.parametrize("n", [400_000, 1_000_000, 5_000_000, 50_000_000])
def test_ivf_lists_follow_the_guideline(n: int) -> None:
    k = ivf_lists(n, AutoConfig())
    assert 2 * math.sqrt(n) <= k <= 16 * math.sqrt(n)  # power of two nearest 4·√N
    assert k & (k - 1) == 0


def test_large_k_uses_an_hnsw_quantizer() -> None:
    assert choose_factory(50_000_000, 256).factory.startswith("IVF32768_HNSW32,")


def test_tight_memory_compresses_with_opq_pq() -> None:
    n, d = 1_000_000, 256
    choice = choose_factory(n, d, memory_budget_bytes=n * 100)
    assert choice.factory.startswith("OPQ") and ",PQ" in choice.factory
    assert choice.estimated_bytes <= n * 100
    # A budget that fits the raw vectors keeps them.
    assert choose_factory(n, d, memory_budget_bytes=n * 2000).factory == "IVF4096,Flat"
    # Memory decides against HNSW even for mid-size collections.
    assert not choose_factory(100_000, d, memory_budget_bytes=100_000 * 1100).factory.startswith("HNSW")


def test_impossible_budget_is_an_error() -> None:
    with pytest.raises(MemoryBudgetError, match="do not fit"):
        choose_factory(1_000_000, 256, memory_budget_bytes=1_000_000)


def test_train_points_enough_per_list() -> None:
    config = AutoConfig()
    assert train_points("IVF1024,Flat", 10_000_000, config) == 39 * 1024
    assert train_points("IVF1024,Flat", 5_000, config) == 5_000
    assert train_points("HNSW32", 10_000, config) == 0


def test_auto_config_round_trips_yaml(tmp_path: Path) -> None:
    config = AutoConfig(flat_max_n=5, target_recall=0.9, tune_queries=123)
    config.to_yaml(tmp_path / "auto.yaml")
    assert AutoConfig.from_yaml(tmp_path / "auto.yaml") == config
    assert AutoConfig.from_yaml_text(AutoConfig().to_yaml_text()) == AutoConfig()
    with pytest.raises(ConfigError, match=r"unknown keys nprobe \(known at top level: flat_max_n"):
        AutoConfig.from_yaml_text("nprobe: 3\n")
    (tmp_path / "auto.yaml").write_text("tune_k: ten\n")
    with pytest.raises(ConfigError, match=r"auto\.yaml: key 'tune_k': expected an integer, got 'ten'"):
        AutoConfig.from_yaml(tmp_path / "auto.yaml")
    with pytest.raises(ConfigError, match="target_recall"):
        AutoConfig(target_recall=1.5)
    assert issubclass(ConfigError, scenesearch_base.config.ConfigError) and issubclass(ConfigError, IndexesError)
