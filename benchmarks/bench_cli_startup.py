"""Start-up of the command line: whole ``scenesearch`` processes against a bare ``import torch, faiss``.

A search from the command line is one short process, so what it costs is mostly what it imports and
loads before the query runs. Each command below runs as its own process, interleaved with the
baseline ``python -c "import torch, faiss"`` in the same run, after one uncounted run of each with
Python's bytecode cache on (as for an installed package), and the figures are the medians of
their wall time, CPU time (user + system, of the process and its children) and peak memory, with
each command's ratio to the baseline's:

- ``search``: ``scenesearch search MODEL_INDEX "…"`` (the query compiled to a scenario program, the
  trained model ranking; target ≤ 2× the baseline);
- ``search_captions``: the same with ``--captions`` (rule-caption ranking; target ≤ 1.5×);
- ``search_caption_index``: ``scenesearch search CAPTION_INDEX "…"`` (an index of rule captions alone);
- ``similar``: ``scenesearch similar MODEL_INDEX "#1"`` (clip → clip, by rank of the last search).

The indexes are built here, small: ``scenesearch simulate --logs 2 --duration-s 15 --seed 5
--no-sensors``, ``caption``, ``index --captions``; then ``clips`` (BEV from the boxes), a model
trained for two steps (``train --preset tiny --set model.text.kind=pretrained``: the tiny towers with
the recommended recipe's text tower, the frozen all-MiniLM-L6-v2 that every text query loads) and
``index``.
Start-up depends on what loads, not on how well the model ranks, so two steps suffice. Where the
demo's index exists (``demo_out``, or ``SCENESEARCH_DEMO_DIR``) the commands are measured on it too.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from benchmarks.processes import measure_process

QUERY = "a car in the left lane approaches, then moves into the ego lane"
BASELINE = (sys.executable, "-c", "import torch, faiss")
TARGETS = {"search": 2.0, "search_captions": 1.5}


def _scenesearch(*args: str | Path) -> list[str]:
    return [sys.executable, "-m", "retrieval.cli", *(str(a) for a in args)]


def _build(root: Path) -> dict[str, Path]:
    """The small model index and caption index of the module docstring, under ``root``."""
    logs, captions, clips, run = root / "logs", root / "captions", root / "clips", root / "run"

    def scenesearch(*args: str | Path) -> None:
        subprocess.run(_scenesearch(*args), check=True, capture_output=True, cwd=Path(__file__).parent.parent)

    scenesearch("simulate", "--out", logs, "--logs", "2", "--duration-s", "15", "--seed", "5", "--no-sensors")
    log_dirs = sorted(p for p in logs.iterdir() if p.is_dir())
    scenesearch("caption", *log_dirs, "--out", captions)
    scenesearch("index", "--captions", captions, "--out", root / "caption_index")
    scenesearch("clips", *log_dirs, "--captions", captions, "--out", clips, "--bev-source", "boxes")
    scenesearch("train", clips, "--out", run, "--preset", "tiny", "--set", "model.text.kind=pretrained",
                "--set", "max_steps_per_epoch=2", "--epochs", "1", "--device", "cpu")
    scenesearch("index", run, clips, "--out", root / "model_index", "--device", "cpu")
    return {"model_index": root / "model_index", "caption_index": root / "caption_index"}


def measure(commands: Mapping[str, Sequence[str]], repeats: int, env: dict[str, str]) -> dict[str, Any]:
    """Each command and the baseline ``repeats`` times, interleaved, after one uncounted run of each; medians
    and ratios to the baseline."""
    samples: dict[str, list[tuple[float, float, float]]] = {"baseline": [], **{name: [] for name in commands}}
    for argv in (BASELINE, *commands.values()):  # one run each, not counted: bytecode and page cache warm
        measure_process(argv, env)
    for _ in range(repeats):
        samples["baseline"].append(measure_process(BASELINE, env))
        for name, argv in commands.items():
            samples[name].append(measure_process(argv, env))
    medians = {name: (statistics.median(s[0] for s in runs), statistics.median(s[1] for s in runs),
                      max(s[2] for s in runs)) for name, runs in samples.items()}
    base_wall, base_cpu, _ = medians["baseline"]
    out: dict[str, Any] = {}
    for name, (wall, cpu, rss) in medians.items():
        out[name] = {"wall_s": round(wall, 3), "cpu_s": round(cpu, 3), "peak_rss_mib": round(rss),
                     "wall_ratio": round(wall / base_wall, 2), "cpu_ratio": round(cpu / base_cpu, 2)}
        if name in TARGETS:
            out[name]["target_ratio"] = TARGETS[name]
            out[name]["target_met_wall"] = bool(wall / base_wall <= TARGETS[name])
            out[name]["target_met_cpu"] = bool(cpu / base_cpu <= TARGETS[name])
    return out


def _commands(model_index: Path, caption_index: Path | None) -> dict[str, list[str]]:
    out = {"search": _scenesearch("search", model_index, QUERY),
           "search_captions": _scenesearch("search", model_index, QUERY, "--captions"),
           "similar": _scenesearch("similar", model_index, "#1")}
    if caption_index is not None:
        out["search_caption_index"] = _scenesearch("search", caption_index, QUERY)
    return out


def run(quick: bool = False) -> dict[str, Any]:
    repeats = 3 if quick else 5
    with tempfile.TemporaryDirectory(prefix="bench_cli_startup_") as tmp:
        root = Path(tmp)
        # The commands remember their last search in the user's cache folder: one of the benchmark's own.
        # Bytecode is cached, as it is for an installed package (pip compiles it): an environment that
        # turns the cache off would charge every command for compiling the package each time.
        env = {**{k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"},
               "XDG_CACHE_HOME": str(root / "cache"), "COLUMNS": "100"}
        start = time.perf_counter()
        built = _build(root)
        build_s = time.perf_counter() - start
        results: dict[str, Any] = {
            "query": QUERY, "repeats": repeats, "build_s": round(build_s, 1),
            "index": "simulated, 2 logs of 15 s; model: tiny preset, 2 training steps, all-MiniLM-L6-v2 text tower",
            "small_index": measure(_commands(built["model_index"], built["caption_index"]), repeats, env)}
        demo = Path(os.environ.get("SCENESEARCH_DEMO_DIR", "demo_out")) / "index"
        if (demo / "manifest.json").is_file():
            results["demo_index"] = {"index": str(demo), **measure(_commands(demo, None), repeats, env)}
        else:
            results["demo_index"] = {"skipped": f"no demo index at {demo}"}
    return results


if __name__ == "__main__":
    import json

    print(json.dumps(run(quick="--quick" in sys.argv), indent=2))
