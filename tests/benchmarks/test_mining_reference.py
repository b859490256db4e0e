"""The mining benchmark's reference loops and the vectorised evaluation agree on a log built by hand.

The log: the ego standing at the origin facing +x; a car driving along +x with a cyclist riding 3 m to
its right at the same pace; a pedestrian standing 15 m ahead of the car's start; a second car
following the first 10 m behind; and a walker crossing the first car's path. Both evaluations read
the same boxes from disk; a disagreement in the benchmark then means one of them changed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchmarks.mining_reference import reference_answer, reference_selection
from benchmarks.mining_reference_log import load_reference_log
from scenarios.evaluate import evaluate
from scenarios.features import build_features
from scenarios.syntax import parse_program
from scenes import av2_io
from scenes.log import Log
from scenes.tracks import Annotations, EgoTrajectory

FRAMES = 30
PERIOD_NS = 100_000_000
T0_NS = 1_000_000_000_000


def _write_log(root: Path) -> Path:
    t = np.arange(FRAMES) * 0.1
    rows: list[tuple[int, str, str, float, float, float, tuple[float, float, float]]] = []
    for f in range(FRAMES):
        ts = T0_NS + f * PERIOD_NS
        car_x = 10.0 + 5.0 * t[f]
        rows.append((ts, "car-a", "REGULAR_VEHICLE", car_x, 0.0, 0.0, (4.5, 1.9, 1.6)))
        rows.append((ts, "bike-b", "BICYCLIST", car_x, -3.0, 0.0, (1.8, 0.6, 1.7)))
        rows.append((ts, "ped-c", "PEDESTRIAN", 25.0, 6.0, 0.0, (0.6, 0.6, 1.7)))
        rows.append((ts, "car-d", "REGULAR_VEHICLE", car_x - 10.0, 0.0, 0.0, (4.5, 1.9, 1.6)))
        # Walks across +y → −y, 6 m ahead of the first car's centre, crossing its heading line mid-log.
        rows.append((ts, "ped-e", "PEDESTRIAN", car_x + 6.0, 3.0 - 4.0 * t[f], -np.pi / 2, (0.6, 0.6, 1.7)))
    n = len(rows)
    annotations = Annotations.from_yaw(
        np.array([r[0] for r in rows], dtype=np.int64), [r[1] for r in rows], [r[2] for r in rows],
        np.array([[r[3], r[4], 0.8] for r in rows]), np.array([r[6] for r in rows]),
        np.array([r[5] for r in rows]))
    assert n == 5 * FRAMES
    log_dir = root / "hand-built-log"
    log_dir.mkdir()
    av2_io.write_annotations(log_dir, annotations.sorted())
    timestamps = T0_NS + np.arange(FRAMES, dtype=np.int64) * PERIOD_NS
    av2_io.write_ego_poses(log_dir, EgoTrajectory.from_xy_yaw(timestamps, np.zeros((FRAMES, 2)), np.zeros(FRAMES)))
    return log_dir


PROGRAMS = [
    "direction(vehicle, cyclist, side=right, lateral_m=2)",
    "reverse(direction(vehicle, cyclist, side=right, lateral_m=2))",
    "direction(car, pedestrian, side=front, within_m=12)",
    "near(cyclist, vehicle, within_m=2)",
    "near(pedestrian, car, within_m=30, beyond_m=8)",  # a least distance
    "reverse(direction(car, pedestrian, side=front, within_m=1000, beyond_m=5))",
    "following(vehicle, vehicle)",
    "reverse(following(vehicle, vehicle))",
    "crossed_by(car, pedestrian)",
    "not(direction(vehicle, cyclist, side=right, lateral_m=2))",
    "direction(vehicle, pedestrian, side=front, min_count=2)",
    "for_at_least(direction(car, pedestrian, side=front, within_m=12), seconds=1)",
    "reverse(direction(ego, vehicle, side=front))",
    "reverse(direction(ego, vehicle, side=front, nearest=1))",
    "near(vehicle, any, within_m=30, nearest=1, min_count=1)",
    "reverse(near(car, pedestrian, within_m=30, nearest=1))",
    "or(cyclist, moving(pedestrian))",
    # The standing pedestrian comes within 8 m of the first car at 1.3 s; the second car has a pedestrian
    # 12 m ahead from 2.3 s.
    "before(near(pedestrian, car, within_m=8), direction(car, pedestrian, side=front, within_m=12), within_s=1.5)",
    "after(direction(car, pedestrian, side=front, within_m=12), near(pedestrian, car, within_m=8), within_s=1.5)",
    # The crossing pedestrian is on the first car's left, in front of it, then on its right: a chain of three
    # steps, each soon after the one before, written nested either way.
    "then(then(reverse(direction(car, pedestrian, side=left)), reverse(direction(car, pedestrian, side=front, "
    "lateral_m=1)), within_s=0.5), reverse(direction(car, pedestrian, side=right)), within_s=0.3)",
    "then(reverse(direction(car, pedestrian, side=left)), then(reverse(direction(car, pedestrian, side=front, "
    "lateral_m=1)), reverse(direction(car, pedestrian, side=right)), within_s=0.3), within_s=0.5)",
    # The chain begins where its last step does, with an event of another object after it.
    "before(then(then(reverse(direction(car, pedestrian, side=left)), reverse(direction(car, pedestrian, "
    "side=front, lateral_m=1)), within_s=0.5), reverse(direction(car, pedestrian, side=right)), within_s=0.3), "
    "near(pedestrian, car, within_m=8), within_s=3)",
    "after(near(pedestrian, car, within_m=8), then(reverse(direction(car, pedestrian, side=left)), "
    "then(reverse(direction(car, pedestrian, side=front, lateral_m=1)), reverse(direction(car, pedestrian, "
    "side=right)), within_s=0.3), within_s=0.5), within_s=3)",
]


@pytest.fixture(scope="module")
def hand_built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _write_log(tmp_path_factory.mktemp("mining"))


@pytest.mark.parametrize("text", PROGRAMS)
def test_reference_and_vectorised_evaluation_agree(hand_built: Path, text: str) -> None:
    features = build_features(Log.open(hand_built))
    reference = load_reference_log(hand_built)
    assert list(reference.track_ids) == features.track_ids.tolist()
    program = parse_program(text)
    theirs = np.asarray(reference_selection(program, reference)[0], dtype=bool)
    ours = evaluate(program, features).selection.mask & features.valid
    assert theirs.any(), f"{text}: selects nothing on the hand-built log (the test would prove little)"
    disagree = np.argwhere(theirs != ours)
    assert disagree.size == 0, (f"{text}: reference and vectorised evaluation differ at (object, frame) "
                                f"{[(features.track_ids[o], f) for o, f in disagree[:5]]}")


def test_the_reference_sees_the_cyclist_on_the_cars_right_only(hand_built: Path) -> None:
    reference = load_reference_log(hand_built)
    selected, related = reference_selection(parse_program("direction(vehicle, cyclist, side=right, lateral_m=2)"),
                                            reference)
    rows = {track: i for i, track in enumerate(reference.track_ids)}
    assert all(selected[rows["car-a"]]) and not any(selected[rows["car-d"]])
    assert all(related[rows["bike-b"]])
    answer = reference_answer(parse_program("cyclist"), reference, "cyclist")
    assert answer.referred[rows["bike-b"]].min() == 1.0 and answer.referred.sum() == FRAMES
