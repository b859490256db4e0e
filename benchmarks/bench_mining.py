"""Scenario mining (RefAV's task) on simulated logs, scored by av2's official evaluator, and its speed.

Quality, on the development set of :mod:`benchmarks.mining_data` (ground truth from the reference's
plain loops over true boxes, the simulator's behaviour labels and the map), for each split apart
(:data:`benchmarks.mining_data.SPLITS`: the later held-out descriptions, the held-out half, the
development half): mean HOTA-Temporal, HOTA-Track, timestamp and log balanced accuracy
(:func:`retrieval.commands.eval_mining.score_submission`), overall and per family, for

- ``system``: each description compiled (:func:`scenarios.compiler.compile_description`) and
  answered on each log's cached features, with ground-truth tracks (``gt_tracks``), with the
  tracker's output on noisy detections at 10 Hz (``tracker_10hz``) and those tracked logs at 2 Hz
  (``tracker_2hz``);
- ``intended_program``: the program each description means (the one the ground truth answers) run by
  the vectorised evaluation on ground-truth tracks, which separates a wrong parse (the compiled
  program scores low, the intended one high) from a definition that differs from the simulator's
  labels (both low);
- ``baseline_clip_search``: clip search used as mining. The ground-truth logs are captioned
  (``scenesearch caption``) and indexed (``index --captions``: :class:`retrieval.captions_search.CaptionSearch`);
  for each log, the description ranks every caption window of that log and the top
  :data:`BASELINE_K` are returned; each returned window marks its track over the window as referred
  (score: the cosine similarity mapped to [0, 1]).

A description whose ground truth refers to no object within :data:`EVALUATION_RANGE_M` of the ego at
any evaluation frame scores 0 for every method; it is listed (``unscored_…``) and left out of the
means. Each description is scored by its own call of the evaluator (the figures are per description
either way, and one call over many descriptions costs quadratically).

Per description, ``reference_agreement_iou`` is the intersection over union of the (object, frame)
cells its meant program selects by the vectorised evaluation and by the reference on ground-truth
tracks: 1 where the definitions read alike, lower where the predicates' sources differ (captioning
rules and map rasters against the simulator's labels and outlines).

Every description whose system HOTA-Temporal on ground-truth tracks (or with the tracker) is below
:data:`LOW_HOTA` is listed with the program it compiled to, the one it means, the words left unused
and the likely cause: ``parse`` (the meant program scores well, the compiled one not), ``definition``
(the meant program scores low too), ``tracker`` (well on ground-truth tracks, low on tracked logs).

Speed (:mod:`benchmarks.mining_speed`): one description over 1,000 busy logs, against the reference's
per-object loop; and the feature cache's size as a share of the logs' ``annotations.feather`` bytes,
and the cost of building it per log-second.
"""

from __future__ import annotations

import dataclasses
import shutil
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.mining_data import FAMILIES, SPLITS, WORK, Description, MiningData, build_data
from benchmarks.mining_reference import reference_selection
from benchmarks.mining_reference_log import load_reference_log
from benchmarks.mining_speed import speed
from scenarios.answer import LogAnswer
from scenarios.features import LogFeatures

#: Caption windows returned per log by the clip-search baseline.
BASELINE_K = 5
#: Below this HOTA-Temporal a description is listed with its program and the likely cause.
LOW_HOTA = 0.5
#: The feature cache's target size, as a share of the logs' annotation bytes.
TARGET_CACHE_SHARE = 0.10
FIGURES = ("hota_temporal", "hota_track", "timestamp_balanced_accuracy", "log_balanced_accuracy")
#: Objects farther than this from the ego are left out of the evaluation (av2's official range).
EVALUATION_RANGE_M = 50


# ---------------------------------------------------------------------------------- answers


def on_timestamps(answer: LogAnswer, timestamps_ns: np.ndarray) -> LogAnswer:
    """``answer`` laid on another frame grid (T,): frames it lacks hold no object, frames off the grid go."""
    t = np.asarray(timestamps_ns, dtype=np.int64)
    pos = np.searchsorted(answer.timestamps_ns, t)
    pos_clipped = np.minimum(pos, max(len(answer.timestamps_ns) - 1, 0))
    found = (pos < len(answer.timestamps_ns)) & (answer.timestamps_ns[pos_clipped] == t) if len(
        answer.timestamps_ns) else np.zeros(len(t), bool)
    k = len(answer.track_ids)

    def lay(values: np.ndarray, fill: float | bool) -> np.ndarray:
        out = np.full((k, len(t), *values.shape[2:]), fill, dtype=values.dtype)
        out[:, found] = values[:, pos_clipped[found]]
        return out

    ego = np.zeros((len(t), 3))
    if found.any():
        ego[found] = answer.ego_city_xyz_m[pos_clipped[found]]
        # Frames the answer lacks: the nearest known ego position (the evaluator's range filter reads it).
        known = np.flatnonzero(found)
        nearest = known[np.clip(np.searchsorted(known, np.arange(len(t))), 0, len(known) - 1)]
        ego[~found] = ego[nearest[~found]]
    return dataclasses.replace(
        answer, timestamps_ns=t, valid=lay(answer.valid, False), referred=lay(answer.referred, 0.0),
        related=lay(answer.related, False), center_city_xyz_m=lay(answer.center_city_xyz_m, np.nan),
        size_lwh_m=lay(answer.size_lwh_m, 0.0), yaw_city_rad=lay(answer.yaw_city_rad, 0.0),
        velocity_city_mps=lay(answer.velocity_city_mps, 0.0), ego_city_xyz_m=ego)


def _features(log_dirs: Sequence[Path], cache_dir: Path) -> tuple[list[LogFeatures], float]:
    """Each log's features through the cache (built now into an empty ``cache_dir``), and the seconds taken."""
    from scenarios.cache import cached_features

    if cache_dir.exists():
        shutil.rmtree(cache_dir)
    cache_dir.mkdir(parents=True)
    start = time.perf_counter()
    out = [cached_features(d, cache_dir)[0] for d in log_dirs]
    return out, time.perf_counter() - start


def _system_answers(programs: dict[str, Any], features: Sequence[LogFeatures],
                    grids: dict[str, np.ndarray]) -> tuple[list[LogAnswer], dict[str, str]]:
    """Every program's answer on every log, laid on the ground truth's frames; errors by description."""
    from scenarios.evaluate import answer

    answers, errors = [], {}
    for description, program in programs.items():
        if program is None:
            continue
        for x in features:
            try:
                result, _ = answer(program, x, description)
            except ValueError as exc:
                errors[description] = str(exc)
                break
            answers.append(on_timestamps(result, grids[x.log_id]))
    return answers, errors


def _baseline_answers(data: MiningData, items: Sequence[Description], features: Sequence[LogFeatures]
                      ) -> list[LogAnswer]:
    """Clip search used as mining: each log's top :data:`BASELINE_K` caption windows, their tracks marked."""
    from retrieval.captions_search import CaptionSearch
    from retrieval.logs_search import caption_logs
    from scenarios.evaluate import answer
    from scenarios.program import Objects

    table, _ = caption_logs(data.log_dirs)
    search = CaptionSearch.build(table, data.root / "baseline_caption_index")
    answers = []
    for x in features:
        empty, _ = answer(Objects("any"), x)  # every object's positions, nothing referred
        row_of = {str(t): i for i, t in enumerate(x.track_ids.tolist())}
        for item in items:
            referred = np.zeros(empty.referred.shape, np.float32)
            for hit in search.search(item.text, k=BASELINE_K, filters={"log_id": x.log_id}):
                row = row_of.get(hit.track_id)
                if row is None:
                    continue
                inside = (x.timestamps_ns >= hit.start_ns) & (x.timestamps_ns <= hit.end_ns) & x.valid[row]
                referred[row] = np.maximum(referred[row], np.where(inside, (hit.score + 1.0) / 2.0, 0.0))
            answers.append(dataclasses.replace(empty, description=item.text, referred=referred,
                                               related=np.zeros_like(empty.related)))
    return answers


def _score(answers: list[LogAnswer], labels: dict[Any, Any], texts: set[str]) -> dict[str, dict[str, float]]:
    """av2's four figures of each description, one evaluator call per description.

    av2's evaluator (through trackeval) scores every sequence against every description of a call, so
    one call per description costs the same figures linearly instead of quadratically. Its
    confusion-matrix plots are not drawn (pictures, not figures), and its progress bars are not shown.
    """
    import contextlib
    import io
    from unittest import mock

    from retrieval.commands.eval_mining import _av2_evaluate, align_predictions, score_submission
    from scenarios.submission import build_submission

    _av2_evaluate()  # imported once, its notices muted
    predictions = build_submission([a for a in answers if a.description in texts])
    out = {}
    for text in sorted(texts):
        gt = {k: v for k, v in labels.items() if k[1] == text}
        pred = {k: v for k, v in predictions.items() if k[1] == text}
        aligned, _ = align_predictions(pred, gt, Path("predictions"))
        with mock.patch("av2.evaluation.scenario_mining.eval._plot_confusion_matrix"), \
                contextlib.redirect_stderr(io.StringIO()):
            metrics = score_submission(aligned, gt, EVALUATION_RANGE_M, None)
        out[text] = {f: float(metrics[f]) for f in FIGURES}
    return out


def referred_in_range(labels: dict[Any, Any]) -> dict[str, int]:
    """Description → referred objects of the ground truth within :data:`EVALUATION_RANGE_M` of the ego, over
    all evaluation frames (a description with none there is scored 0 by every method, so it is left out)."""
    counts: dict[str, int] = defaultdict(int)
    for (_, text), frames in labels.items():
        for frame in frames:
            referred = frame["label"] == 0
            ego = np.asarray(frame["ego_translation_m"][:2])
            near = np.linalg.norm(frame["translation_m"][:, :2] - ego, axis=1) <= EVALUATION_RANGE_M
            counts[text] += int((referred & near).sum())
    return counts


def _summary(figures: dict[str, dict[str, float]], items: Sequence[Description]) -> dict[str, Any]:
    """The four figures averaged over the descriptions (as av2 averages them), overall and per family."""
    def mean(rows: list[dict[str, float]]) -> dict[str, float]:
        return {f: round(float(np.mean([r[f] for r in rows])), 4) for f in FIGURES}

    scored = [i for i in items if i.text in figures]
    families = {family: mean([figures[i.text] for i in scored if i.family == family])
                for family in FAMILIES if any(i.family == family for i in scored)}
    return {**mean([figures[i.text] for i in scored]), "by_family": families}


# ---------------------------------------------------------------------------------- the benchmark


def _diagnose(compiled_text: str | None, meant_text: str, hota: dict[str, float], agreement: float) -> str:
    """The likely causes of a low HOTA-Temporal (see the module docstring), most telling first."""
    if compiled_text is None:
        return "parse: the description does not compile"
    causes = []
    if compiled_text != meant_text and hota["intended_program"] > hota["gt_tracks"]:
        causes.append(f"parse: the compiled program scores {hota['gt_tracks']:.2f} on ground-truth tracks, the "
                      f"meant one {hota['intended_program']:.2f}")
    if hota["intended_program"] < LOW_HOTA:
        causes.append(f"definition: the meant program scores {hota['intended_program']:.2f} on ground-truth tracks; "
                      f"the vectorised evaluation and the reference agree on {agreement:.0%} of the cells either "
                      "selects")
    if hota["gt_tracks"] >= LOW_HOTA > min(hota["tracker_10hz"], hota["tracker_2hz"]):
        causes.append(f"tracker: {hota['gt_tracks']:.2f} on ground-truth tracks, {hota['tracker_10hz']:.2f} / "
                      f"{hota['tracker_2hz']:.2f} on tracked logs at 10 / 2 Hz")
    return "; ".join(causes) or "parse"


def agreement(items: Sequence[Description], log_dirs: Sequence[Path], features: Sequence[LogFeatures]
              ) -> dict[str, float]:
    """Description → intersection over union of the (object, frame) cells its meant program selects by
    the vectorised evaluation and by the reference, on ground-truth tracks (every frame)."""
    from scenarios.evaluate import evaluate
    from scenarios.syntax import parse_program

    refs = [load_reference_log(d) for d in log_dirs]
    out = {}
    for item in items:
        program = parse_program(item.program)
        both = either = 0
        for ref, x in zip(refs, features):
            ours = evaluate(program, x).selection.mask & x.valid
            theirs = np.asarray(reference_selection(program, ref)[0], dtype=bool)
            both += int((ours & theirs).sum())
            either += int((ours | theirs).sum())
        out[item.text] = round(both / either, 4) if either else 1.0
    return out


def run(quick: bool) -> dict[str, Any]:
    from scenarios.compiler import DescriptionError, compile_description
    from scenarios.program import to_text
    from scenarios.submission import load_submission
    from scenarios.syntax import parse_program

    total_start = time.perf_counter()
    data = build_data(WORK / ("quick" if quick else "full"), quick)
    items = data.descriptions
    compiled: dict[str, Any] = {}
    compile_notes: dict[str, dict[str, Any]] = {}
    for item in items:
        try:
            c = compile_description(item.text)
            compiled[item.text] = c.program
            compile_notes[item.text] = {"program": c.text, "unused": list(c.unused)}
        except DescriptionError as exc:
            compiled[item.text] = None
            compile_notes[item.text] = {"program": None, "error": str(exc)}
    meant = {i.text: parse_program(i.program) for i in items}
    meant_text = {i.text: to_text(meant[i.text]) for i in items}
    differs = {t for t in meant if compile_notes[t]["program"] != meant_text[t]}

    seconds: dict[str, float] = {}
    gt_features, build_s = _features(data.log_dirs, data.root / "features" / "gt_tracks")
    grids = {x.log_id: x.timestamps_ns for x in gt_features}
    log_seconds = float(sum(x.time_s[-1] + float(np.median(np.diff(x.time_s))) for x in gt_features))
    cache_bytes = sum(p.stat().st_size for p in (data.root / "features" / "gt_tracks").glob("*.features"))
    annotation_bytes = sum((d / "annotations.feather").stat().st_size for d in data.log_dirs)
    conditions: dict[str, list[LogAnswer]] = {}
    errors: dict[str, dict[str, str]] = {}
    start = time.perf_counter()
    conditions["gt_tracks"], errors["gt_tracks"] = _system_answers(compiled, gt_features, grids)
    seconds["answer_gt_tracks"] = time.perf_counter() - start
    conditions["intended_program"], errors["intended_program"] = _system_answers(
        {t: p for t, p in meant.items() if t in differs}, gt_features, grids)
    for name, dirs in (("tracker_10hz", data.tracked_10hz), ("tracker_2hz", data.tracked_2hz)):
        feats, _ = _features(dirs, data.root / "features" / name)
        conditions[name], errors[name] = _system_answers(compiled, feats, grids)
    start = time.perf_counter()
    conditions["baseline_clip_search"] = _baseline_answers(data, items, gt_features)
    seconds["baseline"] = time.perf_counter() - start
    start = time.perf_counter()
    agree = agreement(items, data.log_dirs, gt_features)
    seconds["reference_agreement"] = time.perf_counter() - start

    quality: dict[str, Any] = {}
    figures: dict[str, dict[str, dict[str, float]]] = defaultdict(dict)  # description → condition → figures
    unscored: dict[str, list[str]] = {}
    start = time.perf_counter()
    for split in SPLITS:
        labels = load_submission(data.gt[split])
        in_range = referred_in_range(labels)
        in_split = [i for i in items if i.split == split]
        unscored[split] = [i.text for i in in_split if in_range.get(i.text, 0) == 0]
        scored = [i for i in in_split if i.text not in unscored[split]]
        texts = {i.text for i in scored}
        quality[split] = {"descriptions_scored": len(scored)}
        for name, answers in conditions.items():
            chosen = texts & differs if name == "intended_program" else texts
            for text, values in _score(answers, labels, chosen).items():
                figures[text][name] = values
            if name == "intended_program":  # the same program as compiled: the same figures
                for text in texts - differs:
                    figures[text][name] = figures[text]["gt_tracks"]
            quality[split][name] = _summary({t: figures[t][name] for t in texts}, scored)
    seconds["evaluate"] = time.perf_counter() - start

    per_description = {}
    low = []
    for item in items:
        if item.text not in figures:
            continue
        hota = {name: round(values["hota_temporal"], 4) for name, values in figures[item.text].items()}
        per_description[item.text] = {"split": item.split, "family": item.family, "hota_temporal": hota,
                                      "reference_agreement_iou": agree[item.text]}
        if min(hota["gt_tracks"], hota["tracker_10hz"], hota["tracker_2hz"]) < LOW_HOTA:
            low.append({"description": item.text, "split": item.split, "family": item.family,
                        "compiled": compile_notes[item.text]["program"],
                        "unused_words": compile_notes[item.text].get("unused", []),
                        "meant": meant_text[item.text], "hota_temporal": hota,
                        "reference_agreement_iou": agree[item.text],
                        "cause": _diagnose(compile_notes[item.text]["program"], meant_text[item.text], hota,
                                           agree[item.text])})
    speed_start = time.perf_counter()
    speed_figures = speed(data, gt_features, quick)
    seconds["speed"] = time.perf_counter() - speed_start
    seconds["total"] = time.perf_counter() - total_start
    return {
        "logs": len(data.log_dirs), "tracked_logs": len(data.tracked_10hz), "log_seconds": round(log_seconds, 1),
        "descriptions": {s: sum(i.split == s for i in items) for s in SPLITS},
        "unscored_no_referred_object_in_range": unscored,
        "baseline_k": BASELINE_K, "quality": quality, "per_description": per_description,
        "low_hota_temporal": low,
        "compile_errors": {t: n["error"] for t, n in compile_notes.items() if n["program"] is None},
        "evaluation_errors": {k: v for k, v in errors.items() if v},
        "parse_differs_from_meant": {t: {"compiled": compile_notes[t]["program"], "meant": meant_text[t]}
                                     for t in sorted(differs)},
        "cache": {"bytes": cache_bytes, "annotation_bytes": annotation_bytes,
                  "share_of_annotations": round(cache_bytes / max(annotation_bytes, 1), 4),
                  "target_share": TARGET_CACHE_SHARE,
                  "meets_share_target": cache_bytes / max(annotation_bytes, 1) <= TARGET_CACHE_SHARE,
                  "build_seconds": round(build_s, 3),
                  "build_ms_per_log_second": round(1000 * build_s / log_seconds, 2)},
        "speed": speed_figures, "seconds": {k: round(v, 2) for k, v in seconds.items()},
    }
