"""The quality benchmark measures the demo's recipe, with only the amount of data and of training changed."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import pytest

from benchmarks import bench_quality
from retrieval.demo_config import DemoConfig


def _captured(monkeypatch: pytest.MonkeyPatch) -> list[tuple[Path, DemoConfig]]:
    calls: list[tuple[Path, DemoConfig]] = []

    def measure(work: Path, config: DemoConfig, fresh: bool = True) -> dict[str, Any]:
        calls.append((work, config))
        return {}

    monkeypatch.setattr(bench_quality, "measure", measure)
    return calls


def test_full_run_is_the_demo_recipe_on_more_data(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = _captured(monkeypatch)
    bench_quality.run(quick=False)
    ((work, config),) = calls
    assert work == bench_quality.WORK
    assert (config.logs, config.extra_logs, config.epochs) == (
        bench_quality.LOGS, bench_quality.EXTRA_LOGS, bench_quality.EPOCHS)
    demo = DemoConfig()
    assert config.logs > demo.logs  # a larger set than the demo's
    changed = {k for k, v in asdict(config).items() if asdict(demo)[k] != v}
    assert changed <= {"logs", "extra_logs", "epochs"}  # every other setting is the demo's


def test_quick_run_is_the_quick_demo(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = _captured(monkeypatch)
    bench_quality.run(quick=True)
    ((_, config),) = calls
    quick = asdict(DemoConfig.quick())
    assert {k for k, v in asdict(config).items() if quick[k] != v} == {"logs"}
