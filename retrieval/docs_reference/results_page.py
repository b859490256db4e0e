"""``docs/results.md``: every figure of ``benchmarks/results.json`` (written by ``make bench``)."""

from __future__ import annotations

import ast
import json
from pathlib import Path
from typing import Any

from retrieval.docs_reference.markdown import GENERATED, cell, code, page, rst, table

#: Retrieval benchmarks whose figures are named ``<source>_<metric>``: shown as one table each.
SOURCES = ("model", "hybrid", "rule_captions", "bag_of_frames", "random")
METRICS = ("R@1", "R@5", "mAP", "temporal_order_accuracy", "freeform_precision@10")


def _flat(value: Any, prefix: str = "") -> list[tuple[str, Any]]:
    if isinstance(value, dict):
        out = []
        for key in sorted(value):
            out += _flat(value[key], f"{prefix}.{key}" if prefix else str(key))
        return out
    return [(prefix, value)]


def _number(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}" if abs(value) < 1e6 else f"{value:.6g}"
    if isinstance(value, list | dict):
        return json.dumps(value, sort_keys=True)
    return json.dumps(value) if isinstance(value, bool) or value is None else str(value)


def _summary(name: str) -> str:
    """The first line of ``benchmarks/bench_<name>.py``'s docstring (read, not imported)."""
    path = Path(__file__).resolve().parents[2] / "benchmarks" / f"bench_{name}.py"
    if not path.is_file():
        return ""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    return rst(" ".join(doc.partition("\n\n")[0].split()))


def _versus(figures: dict[str, Any]) -> list[str]:
    rows = []
    for metric in METRICS:
        values = [figures.get(f"{source}_{metric}") for source in SOURCES]
        if any(isinstance(v, int | float) for v in values):
            rows.append([metric] + ["" if v is None else _number(v) for v in values])
    return [*table(["figure", *SOURCES], rows), ""] if rows else []


def markdown(results_path: Path) -> str:
    """The page (Markdown) for the results file at ``results_path``."""
    results = json.loads(results_path.read_text(encoding="utf-8"))
    machine = results.get("machine", {})
    benchmarks = results.get("benchmarks", {})
    lines = ["# Benchmark results", "", GENERATED, "",
             "Every figure of `benchmarks/results.json`, as `make bench` (or "
             "`python -m benchmarks.run --only NAME`) last wrote it; each benchmark's figures are ratios "
             "against a baseline measured in the same run, next to the raw numbers. How each was reached "
             "and what it means: [research notes](research/README.md); how to run them: "
             "[benchmarks guide](guide/benchmarks.md).", "",
             "Machine of the last run: " + ", ".join(f"{k} {cell(v)}" for k, v in sorted(machine.items())) + ".",
             "A benchmark run with `--only` keeps the other benchmarks' figures from earlier runs, so "
             "sections may come from different runs (the git history of `benchmarks/results.json` says when).", ""]
    lines += table(["benchmark", "what it measures"],
                   [[f"[`{name}`](#{name})", _summary(name)] for name in sorted(benchmarks)])
    lines.append("")
    for name in sorted(benchmarks):
        figures = benchmarks[name]
        lines += [f"## {name}", ""]
        if summary := _summary(name):
            lines += [summary, ""]
        if isinstance(figures, dict):
            lines += _versus(figures)
        lines += [*table(["figure", "value"], [[code(k), _number(v)] for k, v in _flat(figures)]), ""]
    return page(lines)
