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

Last measured (2026-12-04, 2 CPU cores, 33.8 min; 60 simulated logs × 30 s, split 35 / 13 / 12 logs, 3600 test
frames; the default tower for tags, ``tagging_bev_config``: widths (8, 16, 32, 64), two dilated
context blocks — a receptive field of about 80 m — D_e = 64, r = 2; 2000 steps × 4 windows of 5
frames, about 390 s per model; pedestrian density learned as presence (``FOOTPRINT_M2`` in
:mod:`encoders.tagging.attributes`, a loss term of its own); F1 thresholds and L1 calibrations from the 13
validation logs; F1 is undefined, and left out of the means, in a region without a positive test
frame). Table 2, mean over the six regions (L1 lower is better, F1 higher):

=====================  ======  =======  =======  =======  =======
attribute              metric  none     map      lidar    both
=====================  ======  =======  =======  =======  =======
vehicle_density        L1 m²   10.46    9.86     1.28     1.38
pedestrian_density     L1 m²   0.219    0.230    0.090    0.079
vehicle_speed          L1 m/s  3.52     3.59     2.71     2.52
parked                 F1      0.242    0.202    0.760    0.998
stopped                F1      0.261    0.270    0.431    0.502
braking                F1      0.195    0.195    0.291    0.322
keeping_lane           F1      0.550    0.549    0.744    0.775
left_turn              F1      0.312    0.327    0.592    0.747
right_turn             F1      0.085    0.132    0.224    0.317
left_lane_change       F1      0.027    0.022    0.045    0.046
right_lane_change      F1      0.040    0.037    0.098    0.083
blocked_by             F1      0.118    0.059    0.136    0.190
braking_for            F1      0.083    0.078    0.128    0.187
three_way              F1      0.892    0.907    0.896    0.895
four_way               F1      0.300    0.622    0.390    0.356
skill (mean)                   0.207    0.226    0.429    0.481
=====================  ======  =======  =======  =======  =======

``both`` beats the statistics on all 15 attributes, and LiDAR + map is best overall (skill 0.481 vs
LiDAR 0.429, map 0.226). F1 thresholds are now the midpoints between the validation scores that split
them best (``best_threshold``), not a fixed grid; the models are the same as in the run before (same
seeds, same training), so the changes are the thresholds': the map alone on four-way junctions 0.302 →
0.622 (statistics 0.300; it ranks the test frames by them with AUC 0.76, but its mean probability is
0.186 on positive frames and 0.184 on the others), LiDAR alone 0.308 → 0.390, three-way 0.896 → 0.907
(map); where a model has no signal the finer threshold can do worse than "always" on the test logs (map
alone: ``blocked_by`` 0.118 → 0.059, parked 0.242 → 0.202). The map-only regression after commit 7f83740
(four-way 0.874 there, 0.378 one commit later at 1b37f87, which only added street furniture and standing
people and changed no target but pedestrian density) was mostly this: the 1b37f87 model still ranks the
test frames by four-way junction with AUC 0.88 (0.90 at 7f83740), but its pooled probabilities average
0.23 on positive frames and 0.21 on the others (0.63 and 0.13 at 7f83740), which no grid step separated;
with the midpoints the two score 0.715 and 0.892 (13 validation logs), and the rest of the gap, like
this run's lower AUC, is a weaker ranking. Not this: LiDAR + map on four-way junctions, 0.805 on
2026-11-21, 0.356 here; that model does not rank the test frames by junction kind (AUC 0.56 over the
whole grid, 0.75 on the junction cells). Found on 2026-12-04 (one data set simulated at 13106bc and
shared by every run, 2000 steps, 13 validation logs, midpoint thresholds): 13106bc, cdd7c2a and 2841a03
train bit-identical models (four-way 0.693, every figure equal), this commit 0.384 (seed 1: 0.369), and
this commit with pedestrian density regressed as before (no ``FOOTPRINT_M2``) 0.693 again, every figure
equal to 2841a03's: the change is 734d44f, pedestrian density learned as presence. Since then the
junction rows barely learn in the budget: four-way pooled probability 0.221 on positive test frames
against 0.211 elsewhere (AUC 0.66), three-way 0.206 against 0.206 (AUC 0.46; its F1 0.895 is the
statistics' 0.892); with the density regressed 0.402 against 0.207 (AUC 0.88), three-way AUC 0.93.
Nothing simpler brings them back, all at seed 0 on the same data: no pedestrian loss at all
(``presence_weight=0``) four-way 0.467; the vehicle rows at their former shares of the continuous term
(``continuous_weight`` 2/3, ``scene_weight`` 0.075) 0.436; presence plus a count term (the presence
probabilities' sum against the occupied cells) 0.395; presence plus the former regression on a row of
its own 0.484 (three-way F1 0.877). Nor is the former loss reliably better: at training seed 1 it scores
four-way 0.466 (three-way 0.867, blocked_by 0.476). Whether the junction rows take off within 2000 steps
depends on the run: regressed 0.693 and 0.466 (seeds 0, 1), as presence 0.384, 0.369 and 0.404 (seeds 0,
1, 2; skill 0.504, 0.495, 0.511): presence costs four-way junctions on average and has not taken off at
any seed. The trade at seed 0: presence brings pedestrian density L1 0.222 → 0.073, vehicle density 2.03
→ 1.40, right turn 0.267 → 0.384 and skill 0.491 → 0.504, and costs four-way 0.693 → 0.384 and the lane
changes (left 0.205 → 0.064, right 0.239 → 0.112). 37b7268, whose tag training is 13106bc's code, scored
0.756 on logs simulated on another machine: such data move four-way by about 0.06; the street
furniture's 0.1 (0.451 without it at this commit) is of that order. Against 2026-11-21 also: pedestrian
density 0.211 → 0.079, left turn 0.656 → 0.747, right turn 0.222 → 0.317; ``blocked_by`` 0.344 → 0.190,
``braking_for`` 0.242 → 0.187, left lane change 0.165 → 0.046. The query "blocked_by & four_way" in
front (threshold 0.0195, best frame F1 on the validation logs) returns 8 spans over the 12 test logs, 2
confirmed by the labels (span precision 25%, frame precision 5%; the test logs hold 17 such frames, 41%
of them found); on 2026-11-21 it returned 1 span, confirmed. ``causes_ego_braking`` (F1 in front, 87
positive test frames in the full scene): added to the trained model with a frozen backbone 0.098, with
the backbone fine-tuned 0.201, trained from scratch 0.260 (1000 steps each).
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
