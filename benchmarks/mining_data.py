"""Development data of the scenario-mining benchmark: simulated logs, descriptions and their ground truth.

``python -m benchmarks.mining_data [--out DIR] [--quick]`` (or :func:`build_data`) writes into ``DIR``
(default ``benchmarks/_work/mining``)::

    logs/<log_id>/            simulated logs (AV2 layout, no sensors) with detections.parquet
    tracked_10hz/<log_id>/    the same logs, annotations from ``scenesearch track`` on noisy detections
    tracked_2hz/<log_id>/     those tracked logs at every 5th ground-truth timestamp (2 Hz)
    descriptions.json         every description: text, family, split, the program it means
    gt_development.pkl        ground truth of the development descriptions (AV2 scenario-mining format)
    gt_held_out.pkl           ground truth of the held-out descriptions
    gt_held_out_2.pkl         ground truth of the later held-out descriptions (:data:`LATER_HELD_OUT`)
    gt_held_out_3.pkl         ground truth of the third later set (:data:`THIRD_HELD_OUT`)
    gt_held_out_4.pkl         ground truth of the fourth (:data:`FOURTH_HELD_OUT`)
    manifest.json             what the folder was built from (a folder that matches is reused)

The logs come from simulator seeds no other benchmark uses (:data:`SEEDS`). Each description is
written as people write them (RefAV's style and everyday phrasing) together with the program it
means (:data:`DESCRIPTIONS`); the ground truth is that program answered by the reference
(:mod:`benchmarks.mining_reference`: plain loops over true boxes, the simulator's behaviour labels
and the map), never by :mod:`scenarios`' vectorised evaluation, and never from the compiler's
reading of the text. Referred objects carry label 0 at the 2-Hz evaluation timestamps, related
objects 1, the others 2 (:func:`scenarios.submission.write_submission`).

A description's split is fixed by a seeded hash of its text (:func:`split_of`): within each family,
half are development descriptions, the rest held out; nothing is tuned on the held-out half.

Tracked logs keep the ground truth's log ids, so predictions made on them are scored against the
same ground truth; av2's evaluator matches objects by position, not by track id.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.mining_reference import reference_answer
from benchmarks.mining_reference_log import load_reference_log
from scenarios.syntax import parse_program
from scenes import av2_io
from scenes.log import Log
from scenes.tracks import Annotations
from scenesearch_base.atomic import atomic_write_text

#: Simulator seeds of the development logs (no other benchmark simulates these).
SEEDS = (61, 62)
#: Logs per seed and their length (quick: fewer logs, same length).
LOGS_PER_SEED, QUICK_LOGS_PER_SEED, DURATION_S = 5, 2, 20
#: Salt of the split hash; changing it changes every split.
SPLIT_SALT = "scenesearch-mining-split-1"
#: Ground-truth timestamps kept in the 2-Hz logs: every this many.
SUBSAMPLE = 5
WORK = Path(__file__).resolve().parent / "_work" / "mining"
#: Bump when the data or its ground truth changes meaning; a folder of another version is rebuilt.
DATA_VERSION = 3

FAMILIES = ("category", "behaviour", "map", "ego", "relation", "composition", "temporal")

#: (description, family, the program it means).
DESCRIPTIONS: tuple[tuple[str, str, str], ...] = (
    ("vehicle", "category", "vehicle"),
    ("pedestrians", "category", "pedestrian"),
    ("buses", "category", "bus"),
    ("motorcyclist", "category", "motorcycle"),
    ("bicyclists", "category", "cyclist"),
    ("box truck", "category", "box_truck"),
    ("stopped vehicle", "behaviour", "stopped(vehicle)"),
    ("parked car", "behaviour", "parked(car)"),
    ("moving pedestrian", "behaviour", "moving(pedestrian)"),
    ("vehicle braking", "behaviour", "braking(vehicle)"),
    ("accelerating vehicle", "behaviour", "accelerating(vehicle)"),
    ("vehicle turning left", "behaviour", "turning(vehicle, direction=left)"),
    ("car making a right turn", "behaviour", "turning(car, direction=right)"),
    ("vehicle changing lanes", "behaviour", "changing_lanes(vehicle)"),
    ("ego vehicle braking", "behaviour", "braking(ego)"),
    ("bus that is moving", "behaviour", "moving(bus)"),
    ("vehicle changing lanes to the left", "behaviour", "changing_lanes(vehicle, direction=left)"),
    ("vehicle at an intersection", "map", "at_intersection(vehicle)"),
    ("pedestrian on a crosswalk", "map", "on_crosswalk(pedestrian)"),
    ("vehicle near an intersection", "map", "near_intersection(vehicle)"),
    ("stopped vehicle at an intersection", "map", "at_intersection(stopped(vehicle))"),
    ("bicyclist at the intersection", "map", "at_intersection(cyclist)"),
    ("vehicle in the same lane as us", "ego", "ego_lane(vehicle, lane=host)"),
    ("vehicle in the lane to our left", "ego", "ego_lane(vehicle, lane=left)"),
    ("car in the right lane", "ego", "ego_lane(car, lane=right)"),
    ("oncoming vehicle", "ego", "ego_lane(vehicle, lane=oncoming)"),
    ("vehicle in front of the ego vehicle", "ego", "reverse(direction(ego, vehicle, side=front))"),
    ("vehicle behind the ego vehicle", "ego", "reverse(direction(ego, vehicle, side=behind))"),
    ("vehicle approaching the ego vehicle", "ego", "approaching_ego(vehicle)"),
    ("pedestrian ahead of us within 20 meters", "ego", "reverse(direction(ego, pedestrian, side=front, within_m=20))"),
    ("vehicle with a pedestrian within 15 m in front of it", "relation",
     "direction(vehicle, pedestrian, side=front, within_m=15)"),
    ("bicyclist directly to the right of a vehicle", "relation",
     "reverse(direction(vehicle, cyclist, side=right, lateral_m=2))"),
    ("vehicle with another vehicle on its left within 5 meters", "relation",
     "direction(vehicle, vehicle, side=left, within_m=5)"),
    ("pedestrian near a bus", "relation", "near(pedestrian, bus)"),
    ("vehicle following another vehicle", "relation", "following(vehicle, vehicle)"),
    ("vehicle tailgating another vehicle", "relation", "following(vehicle, vehicle, within_m=10)"),
    ("vehicle in the same lane as a bus", "relation", "same_lane(vehicle, bus)"),
    ("pedestrian crossing in front of a vehicle", "relation", "reverse(crossed_by(vehicle, pedestrian))"),
    ("vehicle being crossed by a pedestrian", "relation", "crossed_by(vehicle, pedestrian)"),
    ("vehicle between two other vehicles", "relation", "between(vehicle, vehicle, vehicle)"),
    ("vehicle with multiple pedestrians nearby", "relation", "near(vehicle, pedestrian, min_count=2)"),
    ("vehicle in front of a bus", "relation", "reverse(direction(bus, vehicle, side=front))"),
    ("vehicle being followed by another vehicle", "relation", "reverse(following(vehicle, vehicle))"),
    ("moving vehicle not at an intersection", "composition", "not(at_intersection(moving(vehicle)))"),
    ("pedestrians or bicyclists", "composition", "or(pedestrian, cyclist)"),
    ("parked or stopped vehicle", "composition", "or(parked(vehicle), stopped(vehicle))"),
    ("vehicle that is not moving", "composition", "not(moving(vehicle))"),
    ("turning vehicle with a pedestrian nearby", "composition", "near(turning(vehicle), pedestrian)"),
    ("braking vehicle in front of the ego vehicle", "composition",
     "reverse(direction(ego, braking(vehicle), side=front))"),
    ("vehicle stopped for at least 3 seconds", "temporal", "for_at_least(stopped(vehicle), seconds=3)"),
    ("vehicle that brakes and then stops within 4 seconds", "temporal",
     "then(braking(vehicle), stopped(vehicle), within_s=4)"),
    ("pedestrian walking while the ego vehicle is stopped", "temporal", "while(moving(pedestrian), stopped(ego))"),
    ("vehicle braking for at least 1 second", "temporal", "for_at_least(braking(vehicle), seconds=1)"),
    ("vehicle turning left while a pedestrian is on a crosswalk", "temporal",
     "while(turning(vehicle, direction=left), on_crosswalk(pedestrian))"),
    ("stopped vehicle that starts moving", "temporal", "then(stopped(vehicle), moving(vehicle), within_s=4)"),
    ("vehicle moving for at least 5 seconds", "temporal", "for_at_least(moving(vehicle), seconds=5)"),
)

#: (description, family, the program it means), written after the held-out half of :data:`DESCRIPTIONS`
#: had been read to find parse errors, before the compiler changed again: all held out (split
#: ``held_out_2``), so that the compiler is measured on descriptions it was never corrected on.
LATER_HELD_OUT: tuple[tuple[str, str, str], ...] = (
    ("cars", "category", "car"),
    ("braking bus", "behaviour", "braking(bus)"),
    ("vehicle changing lanes to the right", "behaviour", "changing_lanes(vehicle, direction=right)"),
    ("ego vehicle accelerating", "behaviour", "accelerating(ego)"),
    ("car turning right at an intersection", "map", "at_intersection(turning(car, direction=right))"),
    ("braking vehicle at an intersection", "map", "at_intersection(braking(vehicle))"),
    ("stopped vehicle on a crosswalk", "map", "on_crosswalk(stopped(vehicle))"),
    ("bus in the lane to our right", "ego", "ego_lane(bus, lane=right)"),
    ("car approaching us", "ego", "approaching_ego(car)"),
    ("pedestrian in front of the ego vehicle within 30 m", "ego",
     "reverse(direction(ego, pedestrian, side=front, within_m=30))"),
    ("car with a bicyclist near it", "relation", "near(car, cyclist)"),
    ("bus following a vehicle", "relation", "following(bus, vehicle)"),
    ("vehicle with a pedestrian on its right within 10 m", "relation",
     "direction(vehicle, pedestrian, side=right, within_m=10)"),
    ("car in the same lane as another car", "relation", "same_lane(car, car)"),
    ("buses and motorcycles", "composition", "or(bus, motorcycle)"),
    ("pedestrian who is not moving", "composition", "not(moving(pedestrian))"),
    ("moving vehicle near a pedestrian", "composition", "near(moving(vehicle), pedestrian)"),
    ("pedestrian on a crosswalk while the ego vehicle is stopped", "temporal",
     "while(on_crosswalk(pedestrian), stopped(ego))"),
    ("car that stops and then starts moving again within 5 seconds", "temporal",
     "then(stopped(car), moving(car), within_s=5)"),
    ("bus stopped for at least 2 seconds", "temporal", "for_at_least(stopped(bus), seconds=2)"),
)
#: (description, family, the program it means), written after :data:`LATER_HELD_OUT` had been measured and
#: before the definitions it found wanting (crosswalks, the lanes beside the ego, braking) were looked at:
#: all held out (split ``held_out_3``), to measure those definitions on descriptions they were not fixed on.
THIRD_HELD_OUT: tuple[tuple[str, str, str], ...] = (
    ("trucks", "category", "truck"),
    ("truck that is braking", "behaviour", "braking(truck)"),
    ("car turning left", "behaviour", "turning(car, direction=left)"),
    ("accelerating car", "behaviour", "accelerating(car)"),
    ("car stopped on a crosswalk", "map", "on_crosswalk(stopped(car))"),
    ("pedestrian at an intersection", "map", "at_intersection(pedestrian)"),
    ("vehicle turning left at an intersection", "map", "at_intersection(turning(vehicle, direction=left))"),
    ("truck in the lane to our left", "ego", "ego_lane(truck, lane=left)"),
    ("car in the lane to the right of us", "ego", "ego_lane(car, lane=right)"),
    ("bus approaching the ego vehicle", "ego", "approaching_ego(bus)"),
    ("vehicle behind us within 20 meters", "ego", "reverse(direction(ego, vehicle, side=behind, within_m=20))"),
    ("pedestrian near a car", "relation", "near(pedestrian, car)"),
    ("car following a bus", "relation", "following(car, bus)"),
    ("truck with a car on its left", "relation", "direction(truck, car, side=left)"),
    ("cyclist in the same lane as a car", "relation", "same_lane(cyclist, car)"),
    ("car that is not stopped", "composition", "not(stopped(car))"),
    ("braking car near a pedestrian", "composition", "near(braking(car), pedestrian)"),
    ("trucks and cars", "composition", "or(truck, car)"),
    ("car stopped for at least 4 seconds", "temporal", "for_at_least(stopped(car), seconds=4)"),
    ("pedestrian moving while the ego vehicle is braking", "temporal", "while(moving(pedestrian), braking(ego))"),
    ("bus that brakes and then stops within 5 seconds", "temporal", "then(braking(bus), stopped(bus), within_s=5)"),
)
#: (description, family, the program it means), written after :data:`THIRD_HELD_OUT` had been measured and
#: read, before the compiler and the definitions were measured again: all held out (split ``held_out_4``).
FOURTH_HELD_OUT: tuple[tuple[str, str, str], ...] = (
    ("motorcycles", "category", "motorcycle"),
    ("all vehicles", "category", "vehicle"),
    ("bus turning right", "behaviour", "turning(bus, direction=right)"),
    ("parked truck", "behaviour", "parked(truck)"),
    ("car changing lanes to the left", "behaviour", "changing_lanes(car, direction=left)"),
    ("truck at an intersection", "map", "at_intersection(truck)"),
    ("bicyclist on a crosswalk", "map", "on_crosswalk(cyclist)"),
    ("stopped car at an intersection", "map", "at_intersection(stopped(car))"),
    ("car in our lane", "ego", "ego_lane(car, lane=host)"),
    ("oncoming truck", "ego", "ego_lane(truck, lane=oncoming)"),
    ("car behind the ego vehicle", "ego", "reverse(direction(ego, car, side=behind))"),
    ("pedestrian approaching us", "ego", "approaching_ego(pedestrian)"),
    ("bus near a pedestrian", "relation", "near(bus, pedestrian)"),
    ("car following a truck", "relation", "following(car, truck)"),
    ("car with a pedestrian in front of it within 10 m", "relation",
     "direction(car, pedestrian, side=front, within_m=10)"),
    ("cars or buses", "composition", "or(car, bus)"),
    ("truck that is not moving", "composition", "not(moving(truck))"),
    ("bus moving for at least 4 seconds", "temporal", "for_at_least(moving(bus), seconds=4)"),
    ("car braking while the ego vehicle is stopped", "temporal", "while(braking(car), stopped(ego))"),
    ("car that brakes and then stops within 3 seconds", "temporal", "then(braking(car), stopped(car), within_s=3)"),
)
#: The splits, the last measured first.
SPLITS = ("held_out_4", "held_out_3", "held_out_2", "held_out", "development")


def _rank_key(description: str) -> bytes:
    return hashlib.sha256(f"{SPLIT_SALT}/{description}".encode()).digest()


def split_of(description: str) -> str:
    """``development`` or ``held_out``: within its family, descriptions ordered by a seeded hash of their
    text alternate held-out, development, held-out, …, so every family has both halves."""
    family = next(f for text, f, _ in DESCRIPTIONS if text == description)
    ranked = sorted((text for text, f, _ in DESCRIPTIONS if f == family), key=_rank_key)
    return "held_out" if ranked.index(description) % 2 == 0 else "development"


@dataclass(frozen=True)
class Description:
    """One benchmark description."""

    text: str
    family: str
    program: str
    split: str


def descriptions() -> list[Description]:
    """Every description with its family, the program it means and its split."""
    return [*(Description(text, family, program, split_of(text)) for text, family, program in DESCRIPTIONS),
            *(Description(text, family, program, "held_out_2") for text, family, program in LATER_HELD_OUT),
            *(Description(text, family, program, "held_out_3") for text, family, program in THIRD_HELD_OUT),
            *(Description(text, family, program, "held_out_4") for text, family, program in FOURTH_HELD_OUT)]


@dataclass(frozen=True)
class MiningData:
    """A built development set (see the module docstring for the layout).

    Attributes:
        root: the folder.
        log_dirs: the simulated logs (ground-truth tracks).
        tracked_10hz, tracked_2hz: the tracked logs, in the same order (a log the tracker confirmed
            nothing in is missing).
        descriptions: every description.
        gt: split → ground-truth pickle.
        seconds: stage → wall seconds of building it (empty when reused).
    """

    root: Path
    log_dirs: list[Path]
    tracked_10hz: list[Path]
    tracked_2hz: list[Path]
    descriptions: list[Description]
    gt: dict[str, Path]
    seconds: dict[str, float]


def _simulate(out: Path, seed: int, logs: int, cache: Path) -> list[Path]:
    from retrieval.cli import main

    argv = ["simulate", "--out", str(out), "--logs", str(logs), "--duration-s", str(DURATION_S), "--seed", str(seed),
            "--no-sensors", "--emit-detections", "--cache-dir", str(cache), "--overwrite"]
    if main(argv) != 0:
        raise RuntimeError(f"simulate failed: scenesearch {' '.join(argv)}")
    return sorted(p for p in out.iterdir() if p.is_dir() and not p.name.startswith("."))


def subsample_log(log_dir: Path, timestamps_ns: np.ndarray, out_root: Path) -> Path:
    """A copy of ``log_dir`` under ``out_root`` whose annotations keep only ``timestamps_ns`` (the 2-Hz grid)."""
    target = out_root / log_dir.name
    if target.exists():
        shutil.rmtree(target)
    shutil.copytree(log_dir, target, ignore=shutil.ignore_patterns(av2_io.ANNOTATIONS_FILENAME, ".*"))
    annotations: Annotations = av2_io.read_annotations(log_dir / av2_io.ANNOTATIONS_FILENAME)
    av2_io.write_annotations(target, annotations.select(np.isin(annotations.timestamp_ns, timestamps_ns)))
    Log.open(target)
    return target


def _manifest(quick: bool) -> dict[str, object]:
    return {"version": DATA_VERSION, "seeds": list(SEEDS), "logs_per_seed": QUICK_LOGS_PER_SEED if quick else
            LOGS_PER_SEED, "duration_s": DURATION_S,
            "descriptions": [list(d) for d in (*DESCRIPTIONS, *LATER_HELD_OUT, *THIRD_HELD_OUT, *FOURTH_HELD_OUT)],
            "split_salt": SPLIT_SALT}


def build_data(root: Path | None = None, quick: bool = False, rebuild: bool = False) -> MiningData:
    """Build (or reuse) the development set in ``root`` (see the module docstring)."""
    from scenarios.submission import write_submission
    from scenes.tracking.log_tracking import track_log

    root = Path(root or (WORK / ("quick" if quick else "full")))
    manifest = _manifest(quick)
    items = descriptions()
    seconds: dict[str, float] = {}
    manifest_path = root / "manifest.json"
    reuse = not rebuild and manifest_path.is_file() and json.loads(manifest_path.read_text()).get("built") == manifest
    if not reuse:
        if root.exists():
            shutil.rmtree(root)
        root.mkdir(parents=True)
        start = time.perf_counter()
        log_dirs: list[Path] = []
        for seed in SEEDS:
            sim = root / f"sim_{seed}"
            log_dirs += _simulate(sim, seed, int(str(manifest["logs_per_seed"])), root / "network_cache")
        (root / "logs").mkdir()
        for log_dir in log_dirs:
            log_dir.rename(root / "logs" / log_dir.name)
        for seed in SEEDS:
            shutil.rmtree(root / f"sim_{seed}")
        seconds["simulate"] = time.perf_counter() - start

        start = time.perf_counter()
        for log_dir in sorted((root / "logs").iterdir()):
            try:
                tracked = track_log(log_dir, log_dir / "detections.parquet", root / "tracked_10hz").log_dir
            except ValueError as exc:  # nothing confirmed: the log has no tracked copies
                print(f"{log_dir.name}: not tracked ({exc})", file=sys.stderr)
                continue
            gt_timestamps = Log.open(log_dir).timestamps_ns[::SUBSAMPLE]
            subsample_log(tracked, gt_timestamps, root / "tracked_2hz")
        seconds["track"] = time.perf_counter() - start

        start = time.perf_counter()
        refs = [load_reference_log(d) for d in sorted((root / "logs").iterdir())]
        for split in SPLITS:
            answers = [reference_answer(parse_program(d.program), ref, d.text)
                       for d in items if d.split == split for ref in refs]
            write_submission(answers, root / f"gt_{split}.pkl")
        seconds["ground_truth"] = time.perf_counter() - start
        atomic_write_text(root / "descriptions.json", json.dumps(
            [{"description": d.text, "family": d.family, "program": d.program, "split": d.split} for d in items],
            indent=2))
        atomic_write_text(manifest_path, json.dumps({"built": manifest, "seconds": seconds}, indent=2))
    logs = sorted(p for p in (root / "logs").iterdir() if p.is_dir())
    tracked_10 = [root / "tracked_10hz" / p.name for p in logs if (root / "tracked_10hz" / p.name).is_dir()]
    tracked_2 = [root / "tracked_2hz" / p.name for p in logs if (root / "tracked_2hz" / p.name).is_dir()]
    return MiningData(root, logs, tracked_10, tracked_2, items,
                      {s: root / f"gt_{s}.pkl" for s in SPLITS}, seconds)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help=f"folder to build into (default {WORK}/full or quick)")
    parser.add_argument("--quick", action="store_true", help="fewer logs")
    parser.add_argument("--rebuild", action="store_true", help="build again even when the folder matches")
    args = parser.parse_args(argv)
    data = build_data(args.out, args.quick, args.rebuild)
    counts = {s: sum(d.split == s for d in data.descriptions) for s in SPLITS}
    print(f"{data.root}: {len(data.log_dirs)} logs, {len(data.tracked_10hz)} tracked; descriptions {counts}; "
          f"built in {data.seconds or 'reused'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
