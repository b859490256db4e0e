"""Spatio-temporal tagging quality on held-out simulated logs (Segal et al., Tables 1 and 2).

One run, all on this machine's CPU:

1. data: ``scenesearch simulate`` (no sensors: the BEV occupancy is rendered from the boxes),
   captions, clips (split seed chosen so that val and test hold several logs), tag targets
   (junction kinds over each junction's outline and approaches, as the labels' "at a junction");
2. three tagging models trained on the tag loss alone with the same budget, on BEV inputs ``both``,
   ``map`` and ``lidar`` (Table 2), evaluated on the test split against the dataset-statistics row;
3. the tag query "blocked_by & four_way" in front over the test logs: precision of the returned
   spans against the behaviour labels (a span counts when the labels put a blocked vehicle on a
   4-way junction in front in at least one of its frames; frame precision is also reported);
4. a new attribute, ``causes_ego_braking``, added to the trained model (new row of A only, backbone
   frozen; and with the backbone fine-tuned) and compared with a model trained from scratch for it
   alone with the same budget.

``python -m benchmarks.bench_tagging --out DIR`` writes ``DIR/tags.md``, ``DIR/tags.json`` and
``DIR/bench_tagging.json``; ``run(quick)`` returns the figures for ``benchmarks/run.py``.

The figures of past runs and their history: ``docs/research/tagging-benchmark.md``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
WORK = ROOT / "benchmarks" / "_work" / "tagging"


def _cli(*args: str) -> None:
    exe = Path(sys.executable).parent / "scenesearch"
    subprocess.run([str(exe), *args], check=True, stdout=subprocess.DEVNULL)


def make_data(work: Path, logs: int, duration_s: int, seed: int) -> tuple[Path, list[Path]]:
    """Simulated logs, captions, clips and tag targets under ``work`` (reused when present)."""
    from encoders.clips.config import SplitConfig
    from encoders.clips.splits import assign_splits
    from encoders.tagging.targets import add_attribute_targets

    sim, cap, clips = work / "sim", work / "captions", work / "clips"
    if not sim.is_dir():
        _cli("simulate", "--out", str(sim), "--logs", str(logs), "--duration-s", str(duration_s), "--seed",
             str(seed), "--no-sensors")
    log_dirs = sorted(p for p in sim.iterdir() if p.is_dir())
    if not (cap / "captions.parquet").is_file():
        _cli("caption", *map(str, log_dirs), "--out", str(cap))
    if not (clips / "manifest.json").is_file():
        ids = [p.name for p in log_dirs]
        best = max(range(16), key=lambda s: min(
            sum(v.value == k for v in assign_splits(ids, SplitConfig(seed=s)).values()) for k in ("val", "test")))
        _cli("clips", *map(str, log_dirs), "--captions", str(cap), "--out", str(clips),
             "--seed", str(best))
    add_attribute_targets(clips, log_dirs)
    return clips, log_dirs


def frame_truth(clips: Path, log_dirs: list[Path], factor: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per log, (F,) timestamps and (F,) whether the labels put a blocked vehicle on a 4-way junction in front."""
    import pyarrow.parquet as pq
    import torch

    from encoders.clips.layout import FRAMES_FILE, grid_from_manifest, read_manifest, rendered_log_dir
    from encoders.tagging.attributes import Region
    from encoders.tagging.losses import downsample_targets
    from encoders.tagging.scene_tags import coarse_grid, ego_region_mask
    from encoders.tagging.targets import open_targets

    grid = coarse_grid(grid_from_manifest(read_manifest(clips)), factor)
    front = ego_region_mask(grid, Region.FRONT)
    truth: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for d in log_dirs:
        lt = open_targets(clips, d.name)
        cols = [lt.names.index("blocked_by"), lt.names.index("four_way")]
        t = downsample_targets(torch.from_numpy(np.asarray(lt.targets[:, cols], np.float32)), factor,
                               torch.tensor([False, False])).numpy()
        hit = ((t[:, 0] >= 0.5) & (t[:, 1] >= 0.5) & front).any(axis=(1, 2))
        ts = pq.read_table(rendered_log_dir(clips, d.name) / FRAMES_FILE, columns=["timestamp_ns"]).column(0).to_numpy()
        truth[d.name] = (np.asarray(ts), np.asarray(hit, dtype=bool))
    return truth


def span_precision(clips: Path, log_dirs: list[Path], spans: list[Any], factor: int) -> dict[str, float]:
    """Spans confirmed by the labels: a blocked vehicle's footprint on a 4-way junction in front."""
    truth = frame_truth(clips, log_dirs, factor)
    ok_spans, ok_frames, frames = 0, 0, 0
    for s in spans:
        ts, hit = truth[s.log_id]
        sel = (ts >= s.start_ns) & (ts <= s.end_ns)
        ok_spans += int(hit[sel].any())
        ok_frames += int(hit[sel].sum())
        frames += int(sel.sum())
    positives = int(sum(h.sum() for _, h in truth.values()))
    found = 0
    for lid, (ts, h) in truth.items():
        covered = np.zeros_like(h)
        for s in spans:
            if s.log_id == lid:
                covered |= (ts >= s.start_ns) & (ts <= s.end_ns)
        found += int((h & covered).sum())
    return {"spans": len(spans), "span_precision": round(ok_spans / len(spans), 3) if spans else float("nan"),
            "frame_precision": round(ok_frames / frames, 3) if frames else float("nan"),
            "frame_recall": round(found / positives, 3) if positives else float("nan"),
            "positive_frames_in_logs": positives}


def run(quick: bool = False, out: Path | None = None, steps: int | None = None,
        work: Path | None = None) -> dict[str, Any]:
    import dataclasses

    import torch

    from encoders.clips.layout import read_manifest
    from encoders.tagging.config import TagTrainConfig
    from encoders.tagging.data import split_logs
    from encoders.tagging.evaluate import best_threshold, evaluate_runs, metrics_by_region, pool_split, write_report
    from encoders.tagging.extend import CAUSES_EGO_BRAKING, add_attributes, ego_brake_cause_targets
    from encoders.tagging.inference import load_tagger
    from encoders.tagging.targets import open_targets
    from encoders.tagging.training import train_tags
    from encoders.tagging.versus_statistics import beats_statistics
    from retrieval.tagging import TagSearch

    torch.set_num_threads(2)
    work = work or (WORK / ("quick" if quick else "full"))
    out = out or work / "report"
    n_steps = steps or (20 if quick else 2000)
    t0 = time.perf_counter()
    clips, log_dirs = make_data(work, 6 if quick else 60, 10 if quick else 30, 5)
    data_s = time.perf_counter() - t0
    # The default tower for tags (``tagging_bev_config``): four stages and two dilated context blocks,
    # a receptive field of about 80 m — a junction's arms (3-way vs 4-way) from the far end of its
    # approach, and a queue's leader.
    config = TagTrainConfig(mode="alone", steps=n_steps, batch_size=4, window_frames=5, device="cpu", seed=0)
    runs: dict[str, Path] = {}
    train_s: dict[str, float] = {}
    for inputs in ("both", "map", "lidar"):
        rd = work / f"run_{inputs}"
        if not (rd / "tagging.json").is_file():
            res = train_tags(clips, rd, dataclasses.replace(config, inputs=inputs))
            train_s[inputs] = round(res.seconds, 1)
        runs[inputs] = rd
    result = evaluate_runs(runs["both"], clips, {"map": runs["map"], "lidar": runs["lidar"]})
    write_report(out, result)
    rows = result["inputs"]
    beats = {a: beats_statistics(m, rows["none"][a]) for a, m in rows["both"].items()}

    # The query of the issue, over the test logs.
    test_ids = set(split_logs(read_manifest(clips), "test"))
    test_dirs = [d for d in log_dirs if d.name in test_ids]
    search = TagSearch(runs["both"], clips_dir=clips)
    # The span threshold is chosen on the validation logs (best frame F1 against the labels).
    val_ids = set(split_logs(read_manifest(clips), "val"))
    val_dirs = [d for d in log_dirs if d.name in val_ids]
    truth = frame_truth(clips, val_dirs, search.tagger.downsample)
    series = {d.name: search.series(d, "blocked_by & four_way", "front")[1] for d in val_dirs}
    pred_all = np.concatenate([series[d.name] for d in val_dirs])
    true_all = np.concatenate([truth[d.name][1] for d in val_dirs])
    threshold = best_threshold(pred_all, true_all)
    q0 = time.perf_counter()
    spans = search.find(test_dirs, "blocked_by & four_way", "front", threshold=threshold, min_duration_s=0.5)
    query_s = time.perf_counter() - q0
    precision = span_precision(clips, test_dirs, spans, search.tagger.downsample)
    precision["threshold_from_val"] = threshold

    # A new attribute: added to the trained model vs trained from scratch, same budget.
    stem = f"bev_attributes_{CAUSES_EGO_BRAKING}"
    ext_dir, ft_dir, scratch_dir = work / "run_extended", work / "run_extended_ft", work / "run_scratch_new"
    for rd, finetune in ((ext_dir, False), (ft_dir, True)):
        if not (rd / "tagging.json").is_file():
            add_attributes(runs["both"], [CAUSES_EGO_BRAKING], ego_brake_cause_targets, rd, clips, log_dirs,
                           finetune_backbone=finetune, config=dataclasses.replace(config, steps=max(10, n_steps // 2)))
    if not (scratch_dir / "tagging.json").is_file():
        train_tags(clips, scratch_dir, dataclasses.replace(config, steps=max(10, n_steps // 2)),
                   targets=lambda lid: open_targets(clips, lid, stem))
    new_attr: dict[str, Any] = {}
    for key, rd in (("added_frozen_backbone", ext_dir), ("added_finetuned_backbone", ft_dir),
                    ("from_scratch", scratch_dir)):
        tagger = load_tagger(rd)
        names = (CAUSES_EGO_BRAKING,)
        test = pool_split(clips, "test", tagger, tagger.downsample, names, stem=stem)
        val = pool_split(clips, "val", tagger, tagger.downsample, names, stem=stem)
        table = metrics_by_region(test, val)[CAUSES_EGO_BRAKING]
        new_attr[key] = {r: m["value"] for r, m in table.items()}
    new_attr["positives_test_frames_full"] = metrics_by_region(test, val)[CAUSES_EGO_BRAKING]["full"]["positives"]

    figures = {
        "table2": {k: {a: m["value"] for a, m in row.items()} for k, row in rows.items()},
        "skill": result["skill"],
        "both_beats_statistics": beats,
        "both_beats_statistics_all": all(b is not False for b in beats.values()),
        "both_beats_map_and_lidar_overall": result["skill"]["both"] > max(result["skill"]["map"],
                                                                          result["skill"]["lidar"]),
        "query_blocked_by_and_four_way_front": {**precision, "seconds": round(query_s, 2),
                                                "top": [s.to_dict() for s in spans[:5]]},
        "new_attribute_causes_ego_braking_F1": new_attr,
        "train_s": train_s, "steps": n_steps, "data_s": round(data_s, 1),
        "test_logs": result["meta"]["test_logs"], "frames_test": result["meta"]["frames"],
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_tagging.json").write_text(json.dumps(figures, indent=2))
    return figures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, help="report folder (default benchmarks/_work/tagging/<size>/report)")
    parser.add_argument("--work", type=Path, help="data and runs folder (reused when present)")
    parser.add_argument("--steps", type=int, help="training steps per model")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    figures = run(args.quick, args.out, args.steps, args.work)
    print(json.dumps(figures, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
