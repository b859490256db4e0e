"""The speed part of the scenario-mining benchmark (:mod:`benchmarks.bench_mining`).

Measured as ratios in the same run (wall seconds, and the process's CPU seconds, which a
machine shared with other jobs disturbs less):

- one description over :data:`SCALE_LOGS` logs of :data:`SCALE_DURATION_S` s with about
  :data:`SCALE_OBJECTS` objects a frame (the simulated logs' features, trimmed, their objects
  replicated with shifted track ids, each copy 1 km from the others; files in the feature cache
  format), each log's features read from its cache file and answered (quick: fewer logs, scaled);
- the same description by the reference's per-object Python loop on a subset of those logs (its
  inputs already in memory), against the vectorised evaluation on the same logs (decoding their
  cache files included).
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from benchmarks.mining_data import MiningData
from benchmarks.mining_reference import reference_selection
from benchmarks.mining_reference_log import load_reference_log, replicate
from scenarios.features import LogFeatures

#: The speed test: logs, their length, objects a frame.
SCALE_LOGS, QUICK_SCALE_LOGS = 1000, 100
SCALE_DURATION_S = 15.0
SCALE_OBJECTS = 100
#: Logs of the speed test that the reference loop answers.
REFERENCE_LOGS, QUICK_REFERENCE_LOGS = 3, 1
#: The description of the speed test.
SPEED_DESCRIPTION = "vehicle with a pedestrian within 15 m in front of it"
#: Targets: seconds for 1,000 logs, and the speed-up over the reference's loop.
TARGET_SCALE_S, TARGET_SPEEDUP = 30.0, 100.0


def _trim(x: LogFeatures, frames: int) -> LogFeatures:
    fields = {}
    for field in dataclasses.fields(x):
        value = getattr(x, field.name)
        if isinstance(value, np.ndarray) and value.ndim >= 2 and value.shape[1] == x.num_frames \
                and field.name != "size_lwh_m":
            value = value[:, :frames]
        fields[field.name] = value
    fields["timestamps_ns"] = x.timestamps_ns[:frames]
    return LogFeatures(**fields)


def replicate_features(x: LogFeatures, copies: int, offset_m: float) -> LogFeatures:
    """``x`` with its objects (not the ego) repeated ``copies`` times, copy c shifted by ``c·offset_m`` along x
    and its track ids suffixed ``#c`` (as :func:`benchmarks.mining_reference.replicate` does)."""
    objects = np.arange(x.num_objects - 1)
    order = np.concatenate([np.tile(objects, copies), [x.ego_index]])
    copy = np.concatenate([np.repeat(np.arange(copies), len(objects)), [0]])
    fields = {}
    for field in dataclasses.fields(x):
        value = getattr(x, field.name)
        if isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == x.num_objects \
                and field.name != "timestamps_ns":
            value = value[order]
        fields[field.name] = value
    fields["track_ids"] = np.asarray([f"{t}#{c}" if c else str(t) for t, c in zip(x.track_ids[order], copy)])
    xy = x.xy_m[order].copy()
    xy[..., 0] += (copy * offset_m)[:, None].astype(np.float32)
    fields["xy_m"] = xy
    return LogFeatures(**fields)


def speed(data: MiningData, features: Sequence[LogFeatures], quick: bool) -> dict[str, Any]:
    """The figures above, on ``data``'s logs and their ground-truth ``features``."""
    from scenarios.cache import decode, encode
    from scenarios.compiler import compile_description
    from scenarios.evaluate import answer

    program = compile_description(SPEED_DESCRIPTION).program
    work = data.root / "speed"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir()
    per_frame = [float(x.valid[:-1].sum(axis=0).mean()) for x in features]
    copies = [max(1, math.ceil(SCALE_OBJECTS / max(p, 1.0))) for p in per_frame]
    frames = [min(x.num_frames, 1 + round(SCALE_DURATION_S / float(np.median(np.diff(x.time_s))))) for x in features]
    busy = [replicate_features(_trim(x, f), c, 1000.0) for x, f, c in zip(features, frames, copies)]
    sources = []
    for i, x in enumerate(busy):
        path = work / f"source_{i}.npz"
        path.write_bytes(encode(x, "speed"))
        sources.append(path)
    n = QUICK_SCALE_LOGS if quick else SCALE_LOGS
    files = []
    for i in range(n):
        path = work / f"log_{i:04d}.npz"
        shutil.copyfile(sources[i % len(sources)], path)
        files.append(path)
    start, cpu_start = time.perf_counter(), time.process_time()
    referred = 0
    for path in files:
        x, _ = decode(path.read_bytes())
        result, _ = answer(program, x, SPEED_DESCRIPTION)
        referred += int(result.referred_mask.sum())
    scale_s, scale_cpu_s = time.perf_counter() - start, time.process_time() - cpu_start
    shutil.rmtree(work)

    # The reference loop and the vectorised evaluation on the same busy logs (untrimmed).
    subset = REFERENCE_LOGS if not quick else QUICK_REFERENCE_LOGS
    ref_s = sys_s = ref_cpu_s = sys_cpu_s = 0.0
    both = either = 0
    for log_dir, x, c in list(zip(data.log_dirs, features, copies))[:subset]:
        ref_log = replicate(load_reference_log(log_dir), c, 1000.0)
        busy_x = replicate_features(x, c, 1000.0)
        start, cpu_start = time.perf_counter(), time.process_time()
        ref_sel, _ = reference_selection(program, ref_log)
        ref_s, ref_cpu_s = ref_s + time.perf_counter() - start, ref_cpu_s + time.process_time() - cpu_start
        data_bytes = encode(busy_x, "speed")
        start, cpu_start = time.perf_counter(), time.process_time()
        decoded, _ = decode(data_bytes)
        result, _ = answer(program, decoded, SPEED_DESCRIPTION)
        sys_s, sys_cpu_s = sys_s + time.perf_counter() - start, sys_cpu_s + time.process_time() - cpu_start
        ref_mask = np.asarray(ref_sel, dtype=bool)
        both += int((ref_mask & result.referred_mask).sum())
        either += int((ref_mask | result.referred_mask).sum())
    busy_per_frame = [float(x.valid[:-1].sum(axis=0).mean()) for x in busy]
    return {
        "description": SPEED_DESCRIPTION, "logs_timed": n, "log_duration_s": SCALE_DURATION_S,
        "objects_per_frame": round(float(np.mean(busy_per_frame)), 1),
        "seconds_timed": round(scale_s, 3), "seconds_per_1000_logs": round(scale_s * SCALE_LOGS / n, 2),
        "cpu_seconds_per_1000_logs": round(scale_cpu_s * SCALE_LOGS / n, 2),
        "target_seconds_per_1000_logs": TARGET_SCALE_S,
        "meets_scale_target": scale_s * SCALE_LOGS / n <= TARGET_SCALE_S,
        "referred_cells": referred,
        "reference_loop_logs": subset, "reference_loop_seconds_per_log": round(ref_s / subset, 3),
        "vectorised_seconds_per_log": round(sys_s / subset, 4),
        "reference_agreement_iou": round(both / either, 4) if either else 1.0,
        "speedup_vs_reference_loop": round(ref_s / max(sys_s, 1e-9), 1),
        "cpu_speedup_vs_reference_loop": round(ref_cpu_s / max(sys_cpu_s, 1e-9), 1), "target_speedup": TARGET_SPEEDUP,
        "meets_speedup_target": ref_s / max(sys_s, 1e-9) >= TARGET_SPEEDUP,
    }
