"""From a log to a searchable index: what each stage costs per log and per log-second, with sensors and
track-only, against the cost of merely reading the log's sensor files.

Whole ``scenesearch`` processes, as a user runs them: ``caption`` → ``clips`` (no stored previews) →
``index`` with a trained model, on 1 log and on :data:`LOGS` logs of the same length, with LiDAR and
camera (``sensors``), with the BEV drawn from the boxes (``boxes``: ``--bev-source boxes``, the camera
still rendered) and on the same logs without their sensor and calibration folders (``tracks``: logs
of tracks and map alone, as a tracker's output or a motion dataset gives), :data:`REPEATS` times
(medians). Each process's CPU
time (user + system, children included) is split into a per-log-second cost (the slope between the
two runs: the marginal cost of ingesting more driving) and a per-run cost (the intercept: start-up and
set-up). The headline is the
marginal rate, log-seconds per CPU-second, per stage and from log to index (targets ≥ 25 with
sensors, ≥ 50 track-only).

``index`` runs with the hybrid weight given (``--hybrid-weight``), so that its slope is what each
log-second adds: choosing the weight reads at most :data:`retrieval.hybrid.CHOICE_CLIPS` validation
clips, a cost per index and not per log-second (``make bench``, ``weight_choice``), and where the
smaller run has no validation clip and the larger some, it would fall on the slope alone.
``weight_choice_cpu_s``: what choosing it adds to the larger run, ``index`` run as users run it once
more per repeat. ``marginal_batch_32``: the marginal rate with ``index --batch-size 32`` (each
repeat runs it too), the embedding's batch before :data:`encoders.config.EMBED_BATCH_CLIPS`: the
baseline of the same run.

The baseline, measured in the same run, is what reading the inputs alone costs: every LiDAR sweep,
camera frame and instance mask of the logs read and decoded in one process (``read_floor``), the part
of the sensor path that no rendering or embedding change can remove; ``share_of_floor`` says how many
times that floor the whole ingest costs.

Inputs: the demo's logs, model and ``clips.yaml`` where ``SCENESEARCH_DEMO_DIR`` (default
``demo_out``) holds them; otherwise simulated logs with sensors (``scenesearch simulate``) and a tiny
model trained for two steps on their clips (``--quick``: always this, with shorter logs).
"""

from __future__ import annotations

import os
import shutil
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from benchmarks.processes import measure_process, run_checked

#: Logs of the larger run (the smaller run has one).
LOGS, QUICK_LOGS = 4, 2
#: Length of the simulated logs when the demo's are absent.
SIM_DURATION_S, QUICK_SIM_DURATION_S = 20, 8
STAGES = ("caption", "clips", "index")
#: Runs of each size; the figures are their medians.
REPEATS, QUICK_REPEATS = 3, 1
TARGETS = {"sensors": 25.0, "boxes": 50.0, "tracks": 50.0}
#: What a log of tracks alone lacks.
SENSOR_FOLDERS = ("sensors", "calibration")


def _scenesearch(*args: str | Path) -> list[str]:
    return [sys.executable, "-m", "retrieval.cli", *(str(a) for a in args)]


def _inputs(root: Path, quick: bool) -> tuple[list[Path], Path, Path | None, str]:
    """The logs, a trained run folder, the clips config (None: defaults) and where they come from."""
    demo = Path(os.environ.get("SCENESEARCH_DEMO_DIR", "demo_out"))
    count = QUICK_LOGS if quick else LOGS
    if not quick and (demo / "run").is_dir() and (demo / "clips.yaml").is_file() and (demo / "logs").is_dir():
        logs = sorted(p for p in (demo / "logs").iterdir() if p.is_dir())[:count]
        if len(logs) == count:
            return logs, demo / "run", demo / "clips.yaml", f"the demo's logs and model ({demo})"
    duration = QUICK_SIM_DURATION_S if quick else SIM_DURATION_S
    run_checked(_scenesearch("simulate", "--out", root / "logs", "--logs", str(count), "--duration-s",
                             str(duration), "--seed", "11"))
    logs = sorted(p for p in (root / "logs").iterdir() if p.is_dir())
    run_checked(_scenesearch("caption", *logs, "--out", root / "train_captions"))
    run_checked(_scenesearch("clips", *logs, "--captions", root / "train_captions", "--out", root / "train_clips"))
    run_checked(_scenesearch("train", root / "train_clips", "--out", root / "run", "--preset", "tiny",
                             "--set", "max_steps_per_epoch=2", "--epochs", "1", "--device", "cpu"))
    return logs, root / "run", None, f"simulated logs of {duration} s (seed 11), tiny model trained for 2 steps"


def _tracks_only(logs: list[Path], out: Path) -> list[Path]:
    """Copies of ``logs`` without :data:`SENSOR_FOLDERS` (their other files linked, not copied)."""
    copies = []
    for log_dir in logs:
        copy = out / log_dir.name
        copy.mkdir(parents=True)
        for item in log_dir.iterdir():
            if item.name not in SENSOR_FOLDERS:
                (copy / item.name).symlink_to(item.resolve(), target_is_directory=item.is_dir())
        copies.append(copy)
    return copies


def _log_seconds(logs: list[Path]) -> float:
    from scenes.log import Log

    total = 0.0
    for log_dir in logs:
        ts = Log.open(log_dir).timestamps_ns
        total += float(ts[-1] - ts[0]) / 1e9 if len(ts) > 1 else 0.0
    return total


def _ingest(logs: list[Path], run: Path, clips_config: Path | None, mode: str, out: Path,
            env: dict[str, str], choose_weight: bool = False) -> dict[str, float]:
    """CPU seconds of each stage for ``logs`` (one run of each; ``out`` is removed after); with
    ``choose_weight`` also ``index_choosing`` (``index`` choosing the hybrid weight, as by default)."""
    from encoders.clips.config import ClipsConfig

    extra = ["--bev-source", "boxes"] if mode == "boxes" else []
    config: list[str] = []
    if clips_config is not None:  # the demo's settings without stored previews (a demo made before kept them)
        out.mkdir(parents=True, exist_ok=True)
        replace(ClipsConfig.from_yaml(clips_config), previews=False).to_yaml(out / "clips.yaml")
        config = ["--config", str(out / "clips.yaml")]
    commands = {
        "caption": _scenesearch("caption", *logs, "--out", out / "captions"),
        "clips": _scenesearch("clips", *logs, "--captions", out / "captions", "--out", out / "clips",
                              *config, *extra),
        "index": _scenesearch("index", run, out / "clips", "--out", out / "index", "--hybrid-weight", "0.5"),
    }
    # The baseline of the same run: the embedding in batches of 32 clips, as before EMBED_BATCH_CLIPS.
    commands["index_batch_32"] = _scenesearch("index", run, out / "clips", "--out", out / "index_32",
                                              "--hybrid-weight", "0.5", "--batch-size", "32")
    if choose_weight:
        commands["index_choosing"] = _scenesearch("index", run, out / "clips", "--out", out / "index_choosing")
    try:
        return {stage: measure_process(argv, env)[1] for stage, argv in commands.items()}
    finally:
        shutil.rmtree(out, ignore_errors=True)


def read_floor(logs: list[Path], clips_config: Path | None) -> float:
    """CPU seconds of reading and decoding every LiDAR sweep of ``logs``, and every frame and instance
    mask of the camera the clips render."""
    from encoders.clips.config import ClipsConfig
    from scenes.log import Log
    from scenes.sensorsim.instance_masks import read_instance_mask

    camera = (ClipsConfig.from_yaml(clips_config) if clips_config is not None else ClipsConfig()).camera.camera_name
    start = time.process_time()
    for log_dir in logs:
        log = Log.open(log_dir)
        for ts in log.lidar_timestamps_ns:
            log.lidar_sweep(int(ts))
        if camera in log.camera_names():
            for ts in log.camera_timestamps_ns(camera):
                log.camera_frame(camera, int(ts))
                read_instance_mask(log.log_dir, camera, int(ts))
    return time.process_time() - start


def run(quick: bool = False) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="bench_ingest_") as tmp:
        root = Path(tmp)
        env = {**{k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"},
               "XDG_CACHE_HOME": str(root / "cache")}
        logs, run_dir, clips_config, source = _inputs(root, quick)
        small, large = logs[:1], logs
        seconds = {"small": _log_seconds(small), "large": _log_seconds(large)}
        repeats = QUICK_REPEATS if quick else REPEATS
        results: dict[str, Any] = {"inputs": source, "repeats": repeats,
                                   "logs": {"small": len(small), "large": len(large)},
                                   "log_seconds": {k: round(v, 1) for k, v in seconds.items()}}
        marginal_s = seconds["large"] - seconds["small"]
        tracks = _tracks_only(large, root / "tracks_logs")
        for mode in ("sensors", "boxes", "tracks"):
            runs: dict[str, list[dict[str, float]]] = {"small": [], "large": []}
            sizes = (("small", tracks[:1]), ("large", tracks)) if mode == "tracks" else (("small", small),
                                                                                         ("large", large))
            for _ in range(repeats):  # the sizes interleaved, so that the load of the moment falls on both
                for size, chosen in sizes:
                    runs[size].append(_ingest(chosen, run_dir, clips_config, mode, root / f"{mode}_{size}", env,
                                              choose_weight=size == "large"))
            cpu = {size: {s: statistics.median(r[s] for r in rs) for s in STAGES} for size, rs in runs.items()}
            per_log_s = {s: (cpu["large"][s] - cpu["small"][s]) / marginal_s for s in STAGES}
            per_run = {s: cpu["small"][s] - per_log_s[s] * seconds["small"] for s in STAGES}
            total = sum(per_log_s.values())
            index_32 = {size: statistics.median(r["index_batch_32"] for r in rs) for size, rs in runs.items()}
            total_32 = total - per_log_s["index"] + (index_32["large"] - index_32["small"]) / marginal_s
            results[mode] = {
                "cpu_s": {size: {s: round(v, 2) for s, v in c.items()} for size, c in cpu.items()},
                "cpu_s_per_log_second": {s: round(v, 4) for s, v in per_log_s.items()},
                "cpu_s_per_run": {s: round(v, 2) for s, v in per_run.items()},
                "log_seconds_per_cpu_second": {s: round(1 / v, 1) if v > 0 else None for s, v in per_log_s.items()},
                "marginal_log_seconds_per_cpu_second": round(1 / total, 2) if total > 0 else None,
                "marginal_batch_32": round(1 / total_32, 2) if total_32 > 0 else None,
                "target": TARGETS[mode],
                "target_met": bool(total > 0 and 1 / total >= TARGETS[mode]),
                "weight_choice_cpu_s": round(statistics.median(r["index_choosing"] for r in runs["large"])
                                             - cpu["large"]["index"], 2),
            }
        floor = read_floor(large, clips_config) / seconds["large"]
        sensors_total = sum(results["sensors"]["cpu_s_per_log_second"].values())
        results["read_floor"] = {"cpu_s_per_log_second": round(floor, 4),
                                 "log_seconds_per_cpu_second": round(1 / floor, 1) if floor > 0 else None,
                                 "share_of_floor": round(sensors_total / floor, 1) if floor > 0 else None}
    return results


if __name__ == "__main__":
    import json

    print(json.dumps(run(quick="--quick" in sys.argv), indent=2))
