"""Own-behaviour rules against the simulator's behaviour labels: F1 per attribute, clean and with tracker noise.

The rules (``captioning.behavior``) see only the tracks in the city frame and the map; the labels
(``behavior_labels.feather``) come from the simulator's own state. Thresholds were chosen on the
simulated seeds of :data:`TUNED_SEEDS`; the figures that count are on :data:`REPORT_SEEDS`, which
the tuning never saw (both sets are measured here, in the same run). Per frame, over the object
frames that carry a label row and a computed tag; objects renamed by a tracker's id switch have no
label rows and are left out.

Also measured: the share of labelled ``braking`` frames in runs of one or two frames (the
simulator's speed dithering: a step of 0.1–0.2 m/s between two 0.1 s frames already reads as
braking at 1 m/s²), which caps the recall any rule on positions can reach; and how often the
junction kind the map gives (``captioning.map_context``) equals the simulator's (``junctions.feather``).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from captioning.agreement import BehaviorCounts, behavior_counts, label_grid
from captioning.behavior import LABELS
from captioning.config import CaptioningConfig
from captioning.map_context import JUNCTION_KINDS, lookup, rasterize_map
from captioning.pipeline import caption_log
from scenes.behavior import BehaviorLabel, read_behavior_labels, read_junctions
from scenes.log import Log

TUNED_SEEDS = (1, 2)
REPORT_SEEDS = (5, 6, 7)
#: label → (clean target, noisy target); None: no target.
TARGETS: dict[str, tuple[float | None, float | None]] = {
    BehaviorLabel.PARKED: (0.85, 0.7),
    BehaviorLabel.STOPPED: (0.85, 0.7),
    BehaviorLabel.BRAKING: (0.85, 0.7),
    BehaviorLabel.LEFT_TURN: (0.85, 0.7),
    BehaviorLabel.RIGHT_TURN: (0.85, 0.7),
    BehaviorLabel.LEFT_LANE_CHANGE: (0.7, None),
    BehaviorLabel.RIGHT_LANE_CHANGE: (0.7, None),
    BehaviorLabel.BLOCKED_BY: (0.7, None),
    BehaviorLabel.BRAKING_FOR: (0.7, None),
}


def _simulate(out: Path, seed: int, logs: int, duration_s: int, noisy: bool, cache: Path) -> list[Path]:
    from retrieval.cli import main

    argv = ["simulate", "--out", str(out), "--logs", str(logs), "--duration-s", str(duration_s), "--seed", str(seed),
            "--no-sensors", "--cache-dir", str(cache)] + (["--tracker-noise"] if noisy else [])
    if main(argv) != 0:
        raise RuntimeError(f"simulate failed: {argv}")
    return sorted(p for p in out.iterdir() if p.is_dir())


def _short_braking(labels_and_grids: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Share of labelled braking frames in runs of at most two frames."""
    i = LABELS.index(BehaviorLabel.BRAKING)
    short = total = 0
    for truth, _ in labels_and_grids:
        for row in truth[..., i]:
            edges = np.flatnonzero(np.diff(np.r_[0, row.astype(np.int8), 0]))
            lengths = edges[1::2] - edges[::2]
            short += int(lengths[lengths <= 2].sum())
            total += int(lengths.sum())
    return round(short / total, 3) if total else float("nan")


def _junction_agreement(log_dirs: list[Path], config: CaptioningConfig) -> tuple[int, int]:
    """(junctions whose map-derived kind equals the simulator's, junctions looked at)."""
    same = seen = 0
    for log_dir in log_dirs:
        log = Log.open(log_dir)
        table = read_junctions(log_dir)
        if table is None or log.map is None:
            continue
        dense = log.dense_tracks()
        raster = rasterize_map(log.map, dense.center_city_xyz_m[..., :2][dense.valid], config.map)
        if raster is None:
            continue
        for row in table.to_pylist():
            found = lookup(raster, np.array([[row["center_x_m"], row["center_y_m"]]]))
            if found.junction[0] < 0:
                continue  # outside the area the log's tracks cover
            code = int(raster.junction_kind[found.junction[0]])
            seen += 1
            same += int(code >= 0 and JUNCTION_KINDS[code].value == row["kind"])
    return same, seen


def _measure(log_dirs: list[Path], config: CaptioningConfig) -> tuple[BehaviorCounts, float]:
    total = BehaviorCounts()
    grids = []
    for log_dir in log_dirs:
        labels = read_behavior_labels(log_dir)
        if labels is None:
            continue
        result = caption_log(Log.open(log_dir), config)
        total = total + behavior_counts(result, labels)
        grids.append(label_grid(labels, result.timestamps_ns, result.track_ids))
    return total, _short_braking(grids)


def run(quick: bool) -> dict:
    config = CaptioningConfig()
    logs, duration_s = (2, 30) if quick else (4, 40)
    report_seeds = REPORT_SEEDS[:1] if quick else REPORT_SEEDS
    tuned_seeds = TUNED_SEEDS[:1] if quick else TUNED_SEEDS
    out: dict = {"logs_per_seed": logs, "duration_s": duration_s, "report_seeds": list(report_seeds),
                 "tuned_seeds": list(tuned_seeds)}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for name, seeds in (("report", report_seeds), ("tuned", tuned_seeds)):
            for noisy in (False, True):
                dirs: list[Path] = []
                for seed in seeds:
                    sub = root / f"{name}_{seed}_{'noisy' if noisy else 'clean'}"
                    dirs += _simulate(sub, seed, logs, duration_s, noisy, root / "cache")
                counts, short = _measure(dirs, config)
                key = f"{name}_{'noisy' if noisy else 'clean'}"
                out[key] = counts.to_dict()
                out[f"{key}_braking_short_label_share"] = short
                if name == "report" and not noisy:
                    same, seen = _junction_agreement(dirs, config)
                    out["junction_kind_agreement"] = {"same": same, "junctions": seen}
    met: dict[str, dict[str, bool | None]] = {}
    for label, (clean, noisy_target) in TARGETS.items():
        met[label.value] = {
            "clean": None if clean is None else bool(out["report_clean"][label.value]["f1"] >= clean),
            "noisy": None if noisy_target is None else bool(out["report_noisy"][label.value]["f1"] >= noisy_target),
        }
    out["targets"] = {k.value: {"clean": v[0], "noisy": v[1]} for k, v in TARGETS.items()}
    out["targets_met_on_report_seeds"] = met
    return out


if __name__ == "__main__":
    import json
    import sys

    print(json.dumps(run(quick="--quick" in sys.argv), indent=2))
