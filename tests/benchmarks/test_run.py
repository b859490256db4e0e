"""The benchmark runner: `--only` updates results.json in place, keeping what it did not rerun."""

from __future__ import annotations

import json
import sys
import types
from pathlib import Path
from typing import Any

import pytest

from benchmarks import run as bench_run


def _module(figures: dict[str, Any], kept: tuple[str, ...] = ()) -> types.ModuleType:
    module = types.ModuleType("benchmarks.bench_fake")
    module.run = lambda quick: dict(figures)  # type: ignore[attr-defined]
    if kept:
        module.FIGURES_FROM_OTHER_RUNS = kept  # type: ignore[attr-defined]
    return module


def test_only_keeps_other_benchmarks_and_the_figures_of_other_runs(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "results.json"
    out.write_text(json.dumps({"benchmarks": {
        "other": {"speedup": 2.0},
        "fake": {"speedup": 1.0, "acceptance": {"R@5": 0.9}, "stale": 1},
    }}))
    monkeypatch.setattr(bench_run, "discover", lambda: ["bench_fake", "bench_other"])
    monkeypatch.setitem(sys.modules, "benchmarks.bench_fake", _module({"speedup": 1.5}, kept=("acceptance",)))
    assert bench_run.main(["--out", str(out), "--only", "fake"]) == 0
    results = json.loads(out.read_text())["benchmarks"]
    assert results["other"] == {"speedup": 2.0}  # not rerun: kept as it was
    fake = results["fake"]
    assert fake["speedup"] == 1.5 and fake["acceptance"] == {"R@5": 0.9}  # written by another run: kept
    assert "stale" not in fake  # a figure this run no longer makes goes
    # A figure of the other run that this run makes itself is this run's.
    monkeypatch.setitem(sys.modules, "benchmarks.bench_fake", _module({"acceptance": {"R@5": 0.5}},
                                                                      kept=("acceptance",)))
    bench_run.main(["--out", str(out), "--only", "fake"])
    assert json.loads(out.read_text())["benchmarks"]["fake"]["acceptance"] == {"R@5": 0.5}
