"""Evaluation of scene tags (Segal et al., Tables 1 and 2).

For every frame of the held-out logs (the clips folder's ``test`` split), each attribute is pooled
over each region, for the model's tag tensors and for the ground truth alike (at E's resolution:
targets area-pooled for densities, max-pooled otherwise; map regions from the rendered map). Metrics
per attribute × region:

- continuous: **L1** between pooled prediction and pooled truth, averaged over frames (densities in
  m² covered, ``vehicle_speed`` in m/s), after a calibration ``max(0, a · pred + b)`` fitted per
  attribute × region on the ``val`` split (:func:`calibrate_l1`; ``raw_value`` is the L1 without it);
- discrete: **F1** over frames of "the attribute occurs in the region" (truth: any positive cell;
  prediction: pooled probability ≥ a threshold chosen per attribute × region on the ``val`` split —
  on a few training logs where no validation frame is positive, 0.5 without either; 0, "always
  present", is a candidate, as it is the statistics row's answer).

The **dataset-statistics** baseline (inputs ``none``) predicts, per attribute × region, a constant
from the training split: the median pooled value (continuous, the L1-optimal constant) or
"present" when the attribute occurs there in at least one training frame (discrete; F1 of always
answering yes, the best a constant can do, else 0).

Table 2's value per attribute is the mean of Table 1's metric over the regions.

The truth of a log is the simulator's behaviour labels where it has them and the captioning rules'
own-behaviour tags otherwise (:mod:`encoders.tagging.targets`); ``meta.target_sources`` and the
report say which, per log.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from encoders.clips.blocks import FrameArray
from encoders.clips.layout import (
    BEV_LIDAR_FILE,
    BEV_MAP_FILE,
    TARGETS_STEM,
    grid_from_manifest,
    load_rendered_array,
    read_manifest,
    rendered_log_dir,
)
from encoders.tagging.attributes import AttributeKind, Region, attribute_kind, is_density
from encoders.tagging.data import split_logs
from encoders.tagging.inference import Tagger
from encoders.tagging.losses import downsample_targets
from encoders.tagging.scene_tags import (
    coarse_grid,
    downsample_max,
    pool_values,
    reduction_of,
    region_masks,
    values_of,
)
from encoders.tagging.targets import has_targets, open_targets, targets_source
from scenesearch_base.atomic import atomic_write_text
from scenesearch_base.folders import FolderKind, claim_folder, mark_folder

Pooled = dict[str, dict[str, NDArray[np.float32]]]


def log_has_map(bev_map: FrameArray) -> bool:
    """Whether a rendered log has map layers (a log rendered without a map has all-zero layers)."""
    return bool(np.asarray(bev_map[:: max(1, bev_map.shape[0] // 8)]).any())


def pooled_truth_and_pred(
    clips_dir: Path, log_id: str, tagger: Tagger | None, factor: int, names: tuple[str, ...] | None = None,
    stem: str = TARGETS_STEM,
) -> tuple[Pooled, Pooled | None]:
    """Per-frame pooled truth (and model prediction) of one rendered log.

    Returns:
        ``truth[attr][region]`` (F,) and ``pred`` of the same layout (None without ``tagger``).
    """
    manifest = read_manifest(clips_dir)
    grid = coarse_grid(grid_from_manifest(manifest), factor)
    folder = rendered_log_dir(clips_dir, log_id)
    bev_map = load_rendered_array(folder, BEV_MAP_FILE)
    lt = open_targets(clips_dir, log_id, stem)
    attrs = names or lt.names
    cols = [lt.names.index(a) for a in attrs]
    tg = torch.from_numpy(np.asarray(lt.targets[:, cols], dtype=np.float32))  # (F, A, H, W)
    area = torch.tensor([is_density(a) for a in attrs])
    small = downsample_targets(tg, factor, area).numpy()  # (F, A, h, w)
    map_small = downsample_max(np.asarray(bev_map, dtype=np.float32), factor) if log_has_map(bev_map) else None
    masks = region_masks(grid, map_small, manifest["bev"]["map_channels"])
    cell = grid.resolution_m**2
    v = None
    if tagger is not None:
        lidar = load_rendered_array(folder, BEV_LIDAR_FILE)
        v = tagger.tag_frames(lidar, bev_map, attributes=[tagger.names.index(a) for a in attrs])
    truth: Pooled = {}
    pred: Pooled = {}
    for i, a in enumerate(attrs):
        kind = attribute_kind(a) if tagger is None else tagger.head.config.kind(a)
        red = reduction_of([a])
        t = small[:, i] if kind == AttributeKind.CONTINUOUS else (small[:, i] >= 0.5).astype(np.float32)
        truth[a] = {r.value: pool_values(t, m, red, cell) for r, m in masks.items()}
        if tagger is not None and v is not None:
            x = values_of(v[:, i], a, kind, tagger.head.config.footprint_share(a, cell))
            pred[a] = {r.value: pool_values(x, m, red, cell) for r, m in masks.items()}
    return truth, (pred if v is not None else None)


def _concat(parts: list[Pooled]) -> Pooled:
    lists: dict[str, dict[str, list[NDArray[np.float32]]]] = {}
    for p in parts:
        for a, regions in p.items():
            for r, x in regions.items():
                lists.setdefault(a, {}).setdefault(r, []).append(x)
    return {a: {r: np.concatenate(xs) for r, xs in regions.items()} for a, regions in lists.items()}


def region_f1(pred: NDArray[np.bool_], truth: NDArray[np.bool_]) -> float | None:
    """F1 of a region's frames; ``None`` (undefined) when no test frame is positive there: every
    answer then scores 0, so the cell would only dilute the mean over regions."""
    return round(f1_score(pred, truth), 4) if truth.any() else None


def f1_score(pred: NDArray[np.bool_], truth: NDArray[np.bool_]) -> float:
    tp = float((pred & truth).sum())
    fp = float((pred & ~truth).sum())
    fn = float((~pred & truth).sum())
    return 0.0 if tp == 0 else 2 * tp / (2 * tp + fp + fn)


def best_threshold(prob: NDArray[np.floating], truth: NDArray[np.bool_], allow_always: bool = False) -> float:
    """The threshold with the best F1 on ``prob`` (0.5 when nothing is positive).

    The candidates are the midpoints between consecutive distinct scores, so every split of the
    frames by score is tried, whatever the scale of the probabilities: hard-negative mining leaves
    pooled probabilities uncalibrated, and a model can rank frames well with all its scores inside
    one step of a fixed grid (the tagging benchmark's map-only four-way junctions:
    ``docs/research/tagging.md``). Ties keep the lower threshold.

    ``allow_always`` adds 0, "present in every frame" — the constant answer of the
    dataset-statistics row — as the last candidate, so a tag whose scores do not separate the
    frames falls back to it rather than to a worse threshold (ties keep the real threshold).
    """
    truth = np.asarray(truth, dtype=bool)
    if not truth.any():
        return 0.5
    scores = np.asarray(prob, dtype=np.float64)
    order = np.argsort(-scores, kind="stable")
    s, t = scores[order], truth[order]  # (N,) descending
    last = np.flatnonzero(np.r_[s[1:] != s[:-1], True])  # (K,) last index of each distinct score
    f1 = 2 * np.cumsum(t)[last] / (last + 1 + t.sum())  # (K,) 2 TP / (2 TP + FP + FN) above each cut
    cuts = (s[last] + np.r_[s[last[:-1] + 1], s[-1]]) / 2  # (K,) midway to the next lower score; last: s[-1]
    # With "always" a candidate, calling every frame positive is its job (and generalises to frames
    # scoring below the lowest one seen), so the real thresholds are the splits that leave some out.
    real = f1[:-1] if allow_always else f1
    if real.size == 0 or (allow_always and f1[-1] > real.max()):
        return 0.0
    best = int(np.flatnonzero(real == real.max())[-1])  # the lowest threshold among ties
    return float(cuts[best])


def held_out_threshold(
    held: Iterable[tuple[str, NDArray[np.floating] | None, NDArray[np.bool_] | None]], allow_always: bool = False,
) -> tuple[float, str]:
    """The F1 threshold from the first held-out source with a positive frame, and its name.

    Args:
        held: ``(name, prob, truth)`` in order of preference (e.g. validation, then training logs);
            a source with ``None`` values is skipped. Consumed lazily: a generator computes later
            sources only when the earlier ones have no positive frame.
        allow_always: see :func:`best_threshold`.

    Returns:
        ``(threshold, name)``; ``(0.5, "default")`` when no source has a positive frame.
    """
    for name, prob, truth in held:
        if prob is not None and truth is not None and truth.any():
            return best_threshold(prob, truth, allow_always), name
    return 0.5, "default"


#: Candidate scales of the validation calibration of continuous tags (0: a constant).
CALIBRATION_SCALES = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0)


def calibrate_l1(pred: NDArray[np.floating], truth: NDArray[np.floating]) -> tuple[float, float]:
    """``(scale, offset)`` of the calibration ``max(0, scale · pred + offset)`` with the lowest L1 on
    ``(pred, truth)``: for each candidate scale the L1-optimal offset is the median residual.

    Pooled continuous tags sum many cells, so a small bias per cell becomes a large one per region;
    the validation split measures it. Scale 0 is the constant median, so a calibrated tag is never
    worse on validation than the best constant.
    """
    best = (float("inf"), 1.0, 0.0)
    for scale in CALIBRATION_SCALES:
        offset = float(np.median(truth - scale * pred))
        l1 = float(np.abs(np.maximum(0.0, scale * pred + offset) - truth).mean())
        if l1 < best[0] - 1e-9:
            best = (l1, scale, offset)
    return best[1], best[2]


@dataclass
class SplitPooled:
    """Pooled values of the logs of a split."""

    truth: Pooled = field(default_factory=dict)
    pred: Pooled | None = None
    logs: list[str] = field(default_factory=list)


def pool_split(clips_dir: Path, split: str, tagger: Tagger | None, factor: int,
               names: tuple[str, ...] | None = None, progress: Callable[[str], None] | None = None,
               stem: str = TARGETS_STEM, max_logs: int | None = None) -> SplitPooled:
    logs = [lid for lid in split_logs(read_manifest(clips_dir), split) if has_targets(clips_dir, lid, stem)]
    logs = logs[:max_logs] if max_logs is not None else logs
    truths, preds = [], []
    for lid in logs:
        t, p = pooled_truth_and_pred(clips_dir, lid, tagger, factor, names, stem)
        truths.append(t)
        if p is not None:
            preds.append(p)
        if progress:
            progress(f"{split} {lid}: pooled")
    return SplitPooled(_concat(truths) if truths else {}, _concat(preds) if preds else None, logs)


def _pooled(split: SplitPooled | None, a: str, r: str) -> tuple[NDArray[np.float32] | None, NDArray[np.bool_] | None]:
    """A split's pooled prediction and truth (present or not) of attribute ``a`` in region ``r``, if any."""
    if split is None or split.pred is None or a not in split.pred or r not in split.pred[a]:
        return None, None
    return split.pred[a][r], split.truth[a][r] > 0


def metrics_by_region(test: SplitPooled, val: SplitPooled | None,
                      fallback: SplitPooled | None = None) -> dict[str, dict[str, dict[str, Any]]]:
    """Table 1 of a model: ``{attr: {region: {"metric", "value", ...}}}``.

    F1 thresholds and L1 calibrations come from ``val``; a discrete tag with no positive frame in
    ``val`` for a region takes its threshold from ``fallback`` (training logs) instead, 0.5 when
    neither has one. ``threshold_from`` records which.
    """
    out: dict[str, dict[str, dict[str, Any]]] = {}
    assert test.pred is not None
    for a, regions in test.truth.items():
        out[a] = {}
        for r, truth in regions.items():
            pred = test.pred[a][r]
            if attribute_kind(a) == AttributeKind.CONTINUOUS:
                scale, offset = 1.0, 0.0
                val_pred = _pooled(val, a, r)[0]
                if val_pred is not None:
                    assert val is not None
                    scale, offset = calibrate_l1(val_pred, val.truth[a][r])
                calibrated = np.maximum(0.0, scale * pred + offset)
                out[a][r] = {"metric": "L1", "value": round(float(np.abs(calibrated - truth).mean()), 4),
                             "raw_value": round(float(np.abs(pred - truth).mean()), 4),
                             "calibration": {"scale": scale, "offset": round(offset, 4)}}
                continue
            thr, source = held_out_threshold([(name, *_pooled(split, a, r)) for name, split in
                                              (("val", val), ("train", fallback))], allow_always=True)
            out[a][r] = {"metric": "F1", "value": region_f1(pred >= thr, truth > 0), "threshold": thr,
                         "threshold_from": source, "positives": int((truth > 0).sum()),
                         "frames": int(truth.shape[0])}
    return out


def statistics_by_region(train: SplitPooled, test: SplitPooled) -> dict[str, dict[str, dict[str, Any]]]:
    """Table 1 of the dataset-statistics baseline (constants from the training split)."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for a, regions in test.truth.items():
        out[a] = {}
        for r, truth in regions.items():
            tr = train.truth.get(a, {}).get(r, np.zeros(1, np.float32))
            if attribute_kind(a) == AttributeKind.CONTINUOUS:
                const = float(np.median(tr))
                out[a][r] = {"metric": "L1", "value": round(float(np.abs(const - truth).mean()), 4)}
            else:
                yes = bool((tr > 0).any())
                pred = np.full(truth.shape, yes)
                out[a][r] = {"metric": "F1", "value": region_f1(pred, truth > 0),
                             "positives": int((truth > 0).sum()), "frames": int(truth.shape[0])}
    return out


def table2_row(by_region: dict[str, dict[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """Mean over regions of each attribute's Table 1 metric (regions where F1 is undefined left out;
    ``None`` when it is undefined everywhere)."""
    row: dict[str, dict[str, Any]] = {}
    for a, regions in by_region.items():
        vals = [m["value"] for m in regions.values() if m["value"] is not None]
        metric = next(iter(regions.values()))["metric"] if regions else "F1"
        row[a] = {"metric": metric, "value": round(float(np.mean(vals)), 4) if vals else None}
    return row


def skill(row: dict[str, dict[str, Any]], statistics: dict[str, dict[str, Any]]) -> float:
    """One number per Table 2 row: mean over attributes of F1 (discrete) or 1 − L1 / L1_statistics clipped to
    [−1, 1] (continuous; 0 = as good as the dataset statistics)."""
    vals = []
    for a, m in row.items():
        if m["value"] is None:
            continue
        if m["metric"] == "F1":
            vals.append(m["value"])
        else:
            base = statistics.get(a, {}).get("value", 0.0)
            vals.append(float(np.clip(1.0 - m["value"] / base, -1.0, 1.0)) if base > 0 else 0.0)
    return round(float(np.mean(vals)), 4) if vals else float("nan")


def cell_text(value: float | None) -> str:
    """A Table 1 / 2 value as printed: three decimals, ``n/a`` where undefined."""
    return "n/a" if value is None else f"{value:.3f}"


def markdown_tables(by_region: dict[str, dict[str, dict[str, Any]]], inputs: dict[str, dict[str, dict[str, Any]]],
                    skills: dict[str, float]) -> str:
    """Tables 1 and 2 as Markdown."""
    regions = [r.value for r in Region if any(r.value in v for v in by_region.values())]
    lines = ["## Table 1: scene tags per attribute and region (test split)", "",
             "| attribute | metric | " + " | ".join(regions) + " |",
             "|---|---|" + "---|" * len(regions)]
    for a, regs in by_region.items():
        metric = next(iter(regs.values()))["metric"] if regs else ""
        cells = [cell_text(regs[r]["value"]) if r in regs else "–" for r in regions]
        lines.append(f"| {a} | {metric} | " + " | ".join(cells) + " |")
    rows = [k for k in ("none", "map", "lidar", "both") if k in inputs]
    lines += ["", "L1: lower is better (densities in m² covered, speed in m/s); F1: higher is better; "
              "n/a: no positive test frame in that region (F1 undefined, left out of the means).", "",
              "## Table 2: inputs (mean over regions; none = dataset statistics)", "",
              "| attribute | metric | " + " | ".join(rows) + " |", "|---|---|" + "---|" * len(rows)]
    attrs = list(next(iter(inputs.values())).keys()) if inputs else []
    for a in attrs:
        metric = inputs[rows[0]][a]["metric"]
        cells = [cell_text(inputs[k][a]["value"]) if a in inputs[k] else "–" for k in rows]
        lines.append(f"| {a} | {metric} | " + " | ".join(cells) + " |")
    lines.append("| **skill** (mean of F1 and 1 − L1/L1_none clipped to ±1) | | " + " | ".join(
        f"{skills.get(k, float('nan')):.3f}" for k in rows) + " |")
    return "\n".join(lines) + "\n"


def evaluate_runs(
    run_dir: Path | str,
    clips_dir: Path | str,
    input_runs: Mapping[str, Path | str] | None = None,
    split: str = "test",
    device: str = "cpu",
    progress: Callable[[str], None] | None = None,
    max_val_logs: int | None = None,
    max_train_logs: int | None = 4,
) -> dict[str, Any]:
    """Tables 1 and 2 for a run (and the runs of the input ablation) on a clips folder's held-out logs.

    Args:
        run_dir: the full model (its ``inputs`` names its Table 2 row, normally ``both``).
        clips_dir: a clips folder whose logs have tag targets.
        input_runs: more Table 2 rows: ``{"map": RUN, "lidar": RUN}``.
        split: the held-out split.
        max_val_logs: validation logs used to choose the F1 thresholds and calibrations (None: all).
        max_train_logs: training logs used for thresholds where no validation frame is positive.

    Returns:
        ``{"by_region": ..., "inputs": ..., "skill": {row: x}, "meta": {...}}`` (the layout of ``tags.json``).
    """
    from encoders.tagging.inference import load_tagger

    clips = Path(clips_dir)
    say = progress or (lambda _line: None)
    main = load_tagger(run_dir, device)
    names = tuple(n for n in main.names if has_attribute_targets(clips, n))
    factor = main.downsample
    train = pool_split(clips, "train", None, factor, names)
    test_truth = pool_split(clips, split, None, factor, names)
    if not test_truth.logs:
        raise FileNotFoundError(f"{clips}: no {split} logs with tag targets")
    runs: dict[str, Tagger] = {main.inputs.value: main}
    for key, rd in (input_runs or {}).items():
        runs[key] = load_tagger(rd, device)
    tables: dict[str, dict[str, dict[str, dict[str, Any]]]] = {}
    for key, tagger in runs.items():
        t0 = time.perf_counter()
        test = pool_split(clips, split, tagger, tagger.downsample, names)
        val = pool_split(clips, "val", tagger, tagger.downsample, names, max_logs=max_val_logs)
        held_train = pool_split(clips, "train", tagger, tagger.downsample, names, max_logs=max_train_logs)
        tables[key] = metrics_by_region(test, val if val.logs else None, held_train if held_train.logs else None)
        say(f"inputs={key}: evaluated {len(test.logs)} {split} + {len(val.logs)} val + {len(held_train.logs)} "
            f"train logs in {time.perf_counter() - t0:.1f} s")
    stats = statistics_by_region(train, test_truth)
    inputs = {"none": table2_row(stats), **{k: table2_row(v) for k, v in tables.items()}}
    skills = {k: skill(row, inputs["none"]) for k, row in inputs.items()}
    return {
        "by_region": tables[main.inputs.value],
        "inputs": {k: inputs[k] for k in ("none", "map", "lidar", "both") if k in inputs},
        "skill": skills,
        "statistics_by_region": stats,
        "meta": {"split": split, "test_logs": test_truth.logs, "train_logs": train.logs,
                 "target_sources": {lid: targets_source(clips, lid) for lid in [*test_truth.logs, *train.logs]},
                 "frames": int(next(iter(next(iter(test_truth.truth.values())).values())).shape[0]),
                 "runs": {k: str(Path(rd)) for k, rd in {main.inputs.value: run_dir, **(input_runs or {})}.items()}},
    }


def has_attribute_targets(clips_dir: Path, name: str) -> bool:
    """Whether the clips folder's targets include ``name`` (checked on its first log with targets)."""
    for lid in split_logs(read_manifest(clips_dir), None):
        if has_targets(clips_dir, lid):
            return name in open_targets(clips_dir, lid).names
    return False


def sources_line(result: dict[str, Any]) -> str:
    """Where the evaluated logs' targets come from: the simulator's labels or the captioning rules."""
    sources = result.get("meta", {}).get("target_sources") or {}
    test = [sources.get(lid, "labels") for lid in result.get("meta", {}).get("test_logs", [])]
    if not test:
        return ""
    counts = {s: test.count(s) for s in dict.fromkeys(test)}
    said = ", ".join(f"{n} from the {'simulator' if s == 'labels' else 'captioning'} {s}" for s, n in counts.items())
    return f"\nTruth of the {len(test)} test log(s): {said}.\n"


#: The folder ``scenesearch eval-tags`` writes (:mod:`scenesearch_base.folders`).
TAG_REPORT_FOLDER = FolderKind("tag report", signature="tags.json", entries=("tags.json", "tags.md"))


def write_report(out_dir: Path | str, result: dict[str, Any], inputs: Sequence[Path | str] = ()) -> tuple[Path, Path]:
    """``DIR/tags.json`` and ``DIR/tags.md`` (atomic), in a new, empty or tag report folder that is none
    of ``inputs`` (:mod:`scenesearch_base.folders`)."""
    out = Path(out_dir)
    claim_folder(out, TAG_REPORT_FOLDER, inputs)
    mark_folder(out, TAG_REPORT_FOLDER, TAG_REPORT_FOLDER.entries)
    md = markdown_tables(result["by_region"], result["inputs"], result["skill"]) + sources_line(result)
    atomic_write_text(out / "tags.json", json.dumps(result, indent=2))
    atomic_write_text(out / "tags.md", "# Spatio-temporal tagging\n\n" + md)
    return out / "tags.json", out / "tags.md"
