"""Scale-out on Ray: per-log stages and batch embedding with 2 workers against 1, Ray's per-task
overhead, and what each stage costs per log-second (the cost model of ``docs/research/ray-scale.md``).

Logs: simulated (``scenesearch simulate``; full: 20 logs of 6 s with rendered LiDAR and camera,
quick: 4 logs of 4 s without sensors), cached between runs. Stages: ``caption``
(:func:`captioning.batch.caption_logs`), ``clips`` (:func:`encoders.clips.build.build_clips`,
no stored previews, as the command's default) and ``embed`` (every view of every clip with an
untrained model of the default size; ``--quick``: the tiny preset, a smoke run: serially by
:class:`retrieval.embedding.ModelEmbedder`, on Ray Data by :class:`retrieval.embedding.RayDataEmbedder`).
Each stage runs three ways in the same run, as the commands run them (on a local Ray runtime of as
many CPUs as workers; its start, ``ray_start_s``, and the first tasks' imports are left out):

- ``serial``: in this process, no Ray (torch's default threads while embedding): the baseline;
- ``ray_1``: Ray with 1 worker (1 actor of 1 thread while embedding);
- ``ray_2``: Ray with 2 workers.

Figures: ``speedup_2_vs_1`` (``ray_1`` / ``ray_2`` wall time of the three stages; target ≥ 1.6)
and ``speedup_2_vs_serial``, per stage and in total; the embedding's share includes starting
its actors (a model load each). ``overhead``: caption + clips (no previews) of 8 logs of 2 s,
serially and on Ray with 1 warm worker, in 9 adjacent pairs (alternating which runs first). The
serial run is held to one thread (torch, BLAS, OpenMP), as Ray holds a task of 1 CPU, so that the
figure is what Ray adds and not the second core a serial run's numerics use:
``overhead_fraction`` = the median over pairs of ray_1 / serial − 1 (target < 0.10; pairs cancel
the load of the moment); ``overhead_fraction_vs_all_threads`` the same against a serial run with
torch's default threads, run after each pair,
``overhead_fraction_best_of_each``, ``per_item_ms`` (what Ray adds to one log's task, from the best
of each; tiny logs share Ray tasks, see :mod:`scenesearch_base.ray_runner`), ``empty_task_ms`` (a Ray task
doing nothing, round trip included, one item per task) and ``fraction_on_benchmark_logs`` (that
per-item time against the serial caption + clips time of one of the benchmark's logs). ``cost``:
log-seconds per CPU-second of each stage (serial, CPU time of this process, which holds all of it),
from log to index (``log_to_index``: the three stages), and the same with the clips stage writing a
stored preview per clip, measured in the same run (``clips_stored_previews``,
``log_to_index_stored_previews``: what the command did by default before previews were drawn when
shown), and the CPU-hours 10,000 hours of logs take. ``memory``: the serial embedding again, in a fresh
process with glibc's default malloc and in one with the settings of :mod:`scenesearch_base.memory` (from its
environment, as Ray workers and launched processes get them), wall seconds (the model loaded before
timing) and their ratio.
``weight_layout``: the serial embedding's CPU seconds with the convolution weights channels-last, as
:func:`encoders.inference.load_model` lays them out, and in torch's default layout (alternated, best of
two each), and their ratio. ``embed_batch``: the serial embedding's CPU seconds in batches of 32 clips and of
:data:`encoders.config.EMBED_BATCH_CLIPS` (alternated, best of two each) and their ratio;
``cost.log_to_index_batch_32`` is ``log_to_index`` with the embedding's CPU seconds raised by
their difference, the baseline of the same run. ``thread_spin``: the serial embedding in a fresh process with libgomp's
default spin of idle threads and with the shorter one the commands set (:mod:`scenesearch_base.threads`),
wall and CPU seconds (alternated, best of two each) and their ratios (> 1: cheaper with the short spin).
``load_average`` says how busy the machine was; other work on it slows the parallel runs most.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch

from encoders.config import EMBED_BATCH_CLIPS

WORK = Path(__file__).resolve().parent / "_work" / "scale"
HOURS = 10_000
#: Serial / Ray pairs of the overhead measurement.
PAIRS = 9


def _simulated(out: Path, logs: int, duration_s: float, sensors: bool) -> tuple[list[Path], dict[str, float]]:
    """Simulated logs, cached; with the CPU seconds simulating them took (SUMO, labels, sensors)."""
    import json

    from retrieval.commands.simulate import post_log_hooks
    from scenes.sim import SimulationConfig, simulate_tracks_and_map

    marker = out / ".done.json"
    if marker.is_file():
        return sorted(p for p in out.iterdir() if p.is_dir()), json.loads(marker.read_text())
    shutil.rmtree(out, ignore_errors=True)
    config = SimulationConfig(logs=logs, duration_s=duration_s, seed=0, sensors=sensors,
                              cache_dir=str(WORK / "netcache"))
    result = simulate_tracks_and_map(config, out, post_log=post_log_hooks(config))
    figures = {"cpu_s": result.cpu_s, "sumo_cpu_s": result.sumo_cpu_s, "log_s": logs * duration_s}
    marker.write_text(json.dumps(figures))
    return sorted(Path(p) for p in result.log_dirs), figures


def _untrained_run(run_dir: Path, clips_dir: Path, name: str = "recommended") -> Path:
    """A run folder holding a model of the preset's size with its initial weights: embedding costs
    the same as with trained ones."""
    from safetensors.torch import save_file

    from encoders.data import ClipDataset
    from encoders.model import DualEncoder
    from encoders.presets import preset
    from encoders.train import resolve_channels
    from scenesearch_base.atomic import atomic_write_text

    run_dir.mkdir(parents=True, exist_ok=True)  # made anew each run: the model's code may have changed
    config = resolve_channels(preset(name).train, ClipDataset(clips_dir, as_uint8=True)[0])
    model = DualEncoder(config.model)
    save_file({k: v.detach().contiguous() for k, v in model.saved_state_dict().items()},
              str(run_dir / "model.safetensors"), metadata={"format": "scenesearch.DualEncoder"})
    atomic_write_text(run_dir / "config.json", config.to_json())
    return run_dir


def _timed(fn: Callable[[], Any]) -> tuple[float, float]:
    """(wall seconds, CPU seconds of this process)."""
    wall, cpu = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - wall, time.process_time() - cpu


def _stages(logs: list[Path], root: Path, run_dir: Path | None, execution: Any, previews: bool,
            tag: str) -> dict[str, tuple[float, float]]:
    """Caption, clips and (with a run) embedding of ``logs`` under ``execution``: stage → (wall, CPU)."""
    from captioning.batch import caption_logs
    from captioning.outputs import write_outputs
    from encoders.clips.build import build_clips
    from encoders.clips.config import ClipsConfig
    from retrieval.embedding import ModelEmbedder, RayDataEmbedder

    out: dict[str, tuple[float, float]] = {}
    captions, clips = root / f"captions_{tag}", root / f"clips_{tag}"
    shutil.rmtree(clips, ignore_errors=True)
    results: list[Any] = []

    def caption() -> None:
        batch = caption_logs(logs, execution=execution)
        results.extend(batch.results)
        write_outputs(captions, batch.results)

    out["caption"] = _timed(caption)
    config = replace(ClipsConfig(), previews=previews)
    out["clips"] = _timed(lambda: build_clips(logs, captions, clips, config, reuse=False, execution=execution))
    if run_dir is not None:
        embedder = (ModelEmbedder(run_dir) if execution is None
                    else RayDataEmbedder(run_dir, execution, root / f"shards_{tag}"))
        out["embed"] = _timed(lambda: embedder.embed_clips(clips, view="fused"))
    return out


@contextlib.contextmanager
def _threads(n: int) -> Iterator[None]:
    """Torch's and the native thread pools (BLAS, OpenMP) limited to ``n`` threads inside the block."""
    from threadpoolctl import threadpool_limits

    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        with threadpool_limits(limits=n):
            yield
    finally:
        torch.set_num_threads(before)


#: Embeds a clips folder serially in a fresh process, the model loaded first; prints the embedding's
#: wall and CPU seconds.
_EMBED_CHILD = """
import sys, time
from retrieval.embedding import ModelEmbedder
embedder = ModelEmbedder(sys.argv[1])
_ = embedder.model
start, cpu = time.perf_counter(), time.process_time()
embedder.embed_clips(sys.argv[2], view="fused")
print(time.perf_counter() - start, time.process_time() - cpu)
"""


def _embed_in_child(run_dir: Path, clips: Path, env: dict[str, str]) -> tuple[float, float]:
    """(wall, CPU) seconds of :data:`_EMBED_CHILD` run in a fresh process with ``env``."""
    done = subprocess.run([sys.executable, "-c", _EMBED_CHILD, str(run_dir), str(clips)], env=env,
                          capture_output=True, text=True, check=True)
    wall, cpu = (float(x) for x in done.stdout.strip().splitlines()[-1].split())
    return wall, cpu


def _embed_with_malloc(run_dir: Path, clips: Path) -> dict[str, float]:
    """The serial embedding in a fresh process with glibc's default malloc, then with the settings
    of :mod:`scenesearch_base.memory`: wall seconds each and the ratio."""
    from scenesearch_base.memory import malloc_tunables

    base = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
    out: dict[str, float] = {}
    for name, env in (("default_malloc_s", base), ("kept_memory_s", base | {"GLIBC_TUNABLES": malloc_tunables()})):
        out[name] = round(_embed_in_child(run_dir, clips, env)[0], 2)
    out["speedup"] = _ratio(out["default_malloc_s"], out["kept_memory_s"])
    return out


def _thread_spin(run_dir: Path, clips: Path) -> dict[str, float]:
    """The serial embedding in a fresh process with libgomp's default spin of idle threads (300,000
    checks) and with :data:`scenesearch_base.threads.SPIN_COUNT`, alternated, best of two each: wall
    and CPU seconds (the model loaded before timing) and their ratios."""
    from scenesearch_base.threads import SPIN_COUNT, SPIN_VARIABLE

    base = {k: v for k, v in os.environ.items() if k != SPIN_VARIABLE}
    best = {name: (float("inf"), float("inf")) for name in ("default_spin", "short_spin")}
    for _ in range(2):
        for name, spin in (("default_spin", 300_000), ("short_spin", SPIN_COUNT)):
            wall, cpu = _embed_in_child(run_dir, clips, base | {SPIN_VARIABLE: str(spin)})
            best[name] = (min(best[name][0], wall), min(best[name][1], cpu))
    out = {f"{name}_{kind}_s": round(value[i], 2) for name, value in best.items()
           for i, kind in enumerate(("wall", "cpu"))}
    out["cpu_ratio"] = _ratio(best["default_spin"][1], best["short_spin"][1])
    out["wall_ratio"] = _ratio(best["default_spin"][0], best["short_spin"][0])
    return out


#: The ``embed_batch`` figure of the default batch.
BATCH_NOW = f"batch_{EMBED_BATCH_CLIPS}_cpu_s"


def _alternated_cpu(clips: Path, setups: dict[str, Callable[[], Any]]) -> dict[str, float]:
    """CPU seconds of embedding ``clips`` serially with each setup's embedder (its model loaded before
    timing), the setups alternated, best of two each, rounded, and the first's over the second's."""
    best = dict.fromkeys(setups, float("inf"))
    for _ in range(2):
        for name, setup in setups.items():
            embedder = setup()
            best[name] = min(best[name], _timed(partial(embedder.embed_clips, clips, view="fused"))[1])
    first, second = best.values()
    return {name: round(value, 2) for name, value in best.items()} | {"speedup": _ratio(first, second)}


def _loaded(run_dir: Path, batch_size: int = EMBED_BATCH_CLIPS, default_layout: bool = False) -> Any:
    """A :class:`ModelEmbedder` of ``run_dir`` with its model loaded (``default_layout``: the convolution
    weights in torch's default layout instead of channels-last)."""
    from retrieval.embedding import ModelEmbedder

    embedder = ModelEmbedder(run_dir, batch_size=batch_size)
    model = embedder.model  # loaded here, not inside the timing
    if default_layout:
        model.to(memory_format=torch.contiguous_format)
    return embedder


def _weight_layout(run_dir: Path, clips: Path) -> dict[str, float]:
    """CPU seconds of embedding ``clips`` serially with channels-last convolution weights (as loaded)
    and with torch's default layout, alternated, best of two each (the model loaded before timing)."""
    return _alternated_cpu(clips, {"default_layout_cpu_s": lambda: _loaded(run_dir, default_layout=True),
                                   "channels_last_cpu_s": lambda: _loaded(run_dir)})


def _batch_size(run_dir: Path, clips: Path) -> dict[str, float]:
    """CPU seconds of embedding ``clips`` serially in batches of 32 clips (the default until
    :data:`encoders.config.EMBED_BATCH_CLIPS`) and of that many, alternated, best of two each (the
    model loaded before timing)."""
    return _alternated_cpu(clips, {"batch_32_cpu_s": lambda: _loaded(run_dir, batch_size=32),
                                   BATCH_NOW: lambda: _loaded(run_dir)})


def _noop(item: int) -> int:
    return item


def _ratio(a: float, b: float) -> float:
    return round(a / b, 3) if b > 0 else 0.0


def run(quick: bool) -> dict[str, Any]:
    import ray

    from scenesearch_base.ray_cluster import Execution
    from scenesearch_base.ray_runner import run_tasks

    os.environ.setdefault("RAY_DATA_LOG_LEVEL", "ERROR")
    WORK.mkdir(parents=True, exist_ok=True)
    n_logs, duration_s, sensors = (4, 4.0, False) if quick else (20, 6.0, True)
    logs, sim = _simulated(WORK / f"logs_{n_logs}x{duration_s:g}_{'s' if sensors else 'n'}", n_logs, duration_s,
                           sensors)
    tiny, _ = _simulated(WORK / "tiny_8x2", 8, 2.0, False)
    scratch = WORK / "runs"
    shutil.rmtree(scratch, ignore_errors=True)
    scratch.mkdir()

    load_before = os.getloadavg()[0]
    serial = _stages(logs, scratch, None, None, False, "serial")
    # The clips stage as it was before previews were drawn when shown: one stored GIF per clip.
    stored_previews = _stages(logs, scratch, None, None, True, "serial_previews")["clips"]
    run_dir = _untrained_run(scratch / "run", scratch / "clips_serial", "tiny" if quick else "recommended")
    from retrieval.embedding import ModelEmbedder

    serial["embed"] = _timed(lambda: ModelEmbedder(run_dir).embed_clips(scratch / "clips_serial", view="fused"))
    memory = _embed_with_malloc(run_dir, scratch / "clips_serial")
    weight_layout = _weight_layout(run_dir, scratch / "clips_serial")
    batch_size = _batch_size(run_dir, scratch / "clips_serial")
    thread_spin = _thread_spin(run_dir, scratch / "clips_serial")
    ray_start_s = 0.0
    noop = 0.0
    overhead: list[tuple[float, float, float]] = []
    results: dict[int, dict[str, tuple[float, float]]] = {}
    for workers in (2, 1):  # as `--workers N` runs: a runtime of N CPUs
        start = time.perf_counter()
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False, configure_logging=False)
        ray_start_s = max(ray_start_s, time.perf_counter() - start)
        try:
            # Warm the task workers (imports), as any command's first logs do; actors start anew each time.
            _stages(tiny, scratch, None, Execution(workers=workers), False, "warm")
            results[workers] = _stages(logs, scratch, run_dir, Execution(workers=workers), False, f"ray{workers}")
            if workers == 1:
                # Right after the embedding, the first pair's Ray run is much slower than the others: it
                # starts a worker process anew (``docs/research/ray-scale.md``). Warm one again, as the
                # figure is the overhead of a warm worker.
                _stages(tiny, scratch, None, Execution(workers=1), False, "warm")
                for i in range(PAIRS):  # adjacent pairs, alternating which runs first: the load varies over time
                    pair: dict[str, dict[str, tuple[float, float]]] = {}
                    for kind in (("serial", "ray") if i % 2 == 0 else ("ray", "serial")):
                        if kind == "ray":
                            pair[kind] = _stages(tiny, scratch, None, Execution(workers=1), False, "tiny_ray1")
                        else:
                            with _threads(1):  # the one CPU a Ray task gets (Ray sets its threads to it)
                                pair[kind] = _stages(tiny, scratch, None, None, False, "tiny_serial")
                    pair["serial_all_threads"] = _stages(tiny, scratch, None, None, False, "tiny_serial")
                    serial_s, ray_s, all_s = (sum(w for w, _ in pair[k].values())
                                              for k in ("serial", "ray", "serial_all_threads"))
                    overhead.append((serial_s, ray_s, all_s))
                noop = min(_timed(lambda: run_tasks(_noop, list(range(200)), Execution(workers=1),
                                                     items_per_task=1))[0]
                           for _ in range(3))
        finally:
            ray.shutdown()
    ray_1, ray_2 = results[1], results[2]
    load_after = os.getloadavg()[0]

    stages = ("caption", "clips", "embed")
    figures: dict[str, Any] = {
        "logs": n_logs, "log_duration_s": duration_s, "sensors": sensors, "ray_start_s": round(ray_start_s, 2),
        "load_average": [round(load_before, 2), round(load_after, 2)],
    }
    for name, result in (("serial", serial), ("ray_1", ray_1), ("ray_2", ray_2)):
        figures[f"{name}_wall_s"] = {s: round(result[s][0], 2) for s in stages}
        figures[f"{name}_wall_s"]["total"] = round(sum(result[s][0] for s in stages), 2)
    total = {name: figures[f"{name}_wall_s"]["total"] for name in ("serial", "ray_1", "ray_2")}
    figures["speedup_2_vs_1"] = {s: _ratio(ray_1[s][0], ray_2[s][0]) for s in stages} | {
        "total": _ratio(total["ray_1"], total["ray_2"])}
    figures["speedup_2_vs_serial"] = {s: _ratio(serial[s][0], ray_2[s][0]) for s in stages} | {
        "total": _ratio(total["serial"], total["ray_2"])}
    figures["target_1_6_met"] = figures["speedup_2_vs_1"]["total"] >= 1.6
    best_serial, best_ray = min(a for a, _, _ in overhead), min(b for _, b, _ in overhead)
    items = 2 * len(tiny)  # one caption item and one clips item per log
    figures["overhead"] = {"serial_s": round(best_serial, 3), "ray_1_s": round(best_ray, 3),
                           "overhead_fraction": round(float(np.median([b / a for a, b, _ in overhead])) - 1.0, 3),
                           "overhead_fraction_best_of_each": round(best_ray / best_serial - 1.0, 3),
                           "overhead_fraction_vs_all_threads": round(
                               float(np.median([b / c for _, b, c in overhead])) - 1.0, 3),
                           "per_item_ms": round(1000 * (best_ray - best_serial) / items, 1),
                           "empty_task_ms": round(1000 * noop / 200, 2),
                           "runs": [[round(a, 3), round(b, 3), round(c, 3)] for a, b, c in overhead]}
    figures["overhead_target_0_10_met"] = figures["overhead"]["overhead_fraction"] < 0.10
    # The same per-item cost on the benchmark's own logs: two items (caption, clips) per log.
    per_log_s = (serial["caption"][0] + serial["clips"][0]) / n_logs
    figures["overhead"]["fraction_on_benchmark_logs"] = round(2 * (best_ray - best_serial) / items / per_log_s, 4)
    log_s = n_logs * duration_s
    cost = {s: log_s / max(serial[s][1], 1e-9) for s in stages}
    cost["log_to_index"] = log_s / max(sum(serial[s][1] for s in stages), 1e-9)
    cost["clips_stored_previews"] = log_s / max(stored_previews[1], 1e-9)
    cost["log_to_index_stored_previews"] = log_s / max(
        serial["caption"][1] + stored_previews[1] + serial["embed"][1], 1e-9)
    # The baseline of the same run: the serial embedding as it cost in batches of 32 clips.
    batch_32_extra = batch_size["batch_32_cpu_s"] - batch_size[BATCH_NOW]
    cost["log_to_index_batch_32"] = log_s / max(sum(serial[s][1] for s in stages) + batch_32_extra, 1e-9)
    if "cpu_s" in sim:
        cost["simulate"] = sim["log_s"] / max(sim["cpu_s"], 1e-9)
    figures["memory"] = memory
    figures["weight_layout"] = weight_layout
    figures["embed_batch"] = batch_size
    figures["thread_spin"] = thread_spin
    figures["cost"] = {
        "log_s_per_cpu_s": {s: round(v, 2) for s, v in cost.items()},
        f"cpu_hours_for_{HOURS}_h": {s: round(HOURS / v, 1) for s, v in cost.items()},
    }
    shutil.rmtree(scratch, ignore_errors=True)
    return figures
