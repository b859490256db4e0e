"""Tracking metrics: CLEAR-MOT, IDF1 and HOTA against hand-computed values, with KITTI's ignore rules.

The hand-made case (4 frames, identity ego, so the city frame is the ego frame; max_distance_m = 2,
so similarity s = 1 − d / 4 and a CLEAR/IDF1 match needs d ≤ 2 m):

    ground truth (car)                 predictions (car)
    A  frames 0–3 at (10, 0)           1  frames 0–1 on A (s = 1)
    B  frames 0–3 at (10, 10)          2  frames 2–3 at (10, 1.1): on A with d = 1.1, s = 0.725
    V  frames 0–1 at (10, −10), Van    3  frames 0–2 on B (s = 1); B is missed at frame 3
    C  frame 3 at (20, −20), truncated 4  frame 0 on V
                                       5  frame 1 at (30, 30), image box inside a DontCare region
                                       6  frame 2 at (−20, 5), tall image box, no region: a false positive
                                       7  frame 3 at (40, 40), image box 10 px tall

KITTI rules: V (Van) and C (truncated) are distractors: 4 matches V and is dropped, V's miss at
frame 1 and C's at frame 3 are no misses (3 ignored ground-truth rows). 5 is dropped (in a
DontCare region), 7 is dropped (≤ 25 px). Left: GT = A×4 + B×4 = 8; predictions 1×2, 2×2, 3×3, 6×1.

CLEAR-MOT: frames 0, 1: A–1, B–3. Frame 2: A–2 (A was last matched to 1: one ID switch), B–3, and 6
is a false positive. Frame 3: A–2, B missed. TP 7, FN 1, FP 1, IDSW 1:
    MOTA = 1 − (1 + 1 + 1) / 8 = 0.625;   MOTP = (5 × 0 + 2 × 1.1) / 7 = 0.3143 m.
IDF1: frames each pair matches: A–1 2, A–2 2, B–3 3; best one-to-one: A–1 (or A–2) + B–3 = 5 = IDTP;
IDFN = 8 − 5 = 3, IDFP = 8 − 5 = 3:  IDF1 = 10 / (10 + 3 + 3) = 0.625.
HOTA: pairs only ever overlap their own object, so each pair's per-frame soft match is 1 and the
matching per frame is the obvious one. Pair A–2 (s = 0.725) counts for α ≤ 0.70 (14 of the 19 α),
not for α ≥ 0.75 (5 of them).
    α ≤ 0.70: TP 7, FN 1, FP 1 → DetA = 7/9. Per pair TPA / (|gt track| + |pred track| − TPA):
              A–1 2/(4+2−2) = 0.5, A–2 0.5, B–3 3/(4+3−3) = 0.75 → AssA = (2·0.5 + 2·0.5 + 3·0.75)/7 = 4.25/7.
              HOTA_α = sqrt(7/9 · 4.25/7) = 0.687184;  LocA_α = (5 + 2 · 0.725)/7 = 0.921429.
    α ≥ 0.75: TP 5, FN 3, FP 3 → DetA = 5/11; AssA = (2·0.5 + 3·0.75)/5 = 0.65;
              HOTA_α = sqrt(5/11 · 0.65) = 0.543557;  LocA_α = 1.
    HOTA = (14 · 0.687184 + 5 · 0.543557)/19 = 0.6494;  DetA = (14 · 7/9 + 5 · 5/11)/19 = 0.6927;
    AssA = (14 · 4.25/7 + 5 · 0.65)/19 = 0.6184;        LocA = (14 · 0.921429 + 5)/19 = 0.9421.

Without the rules (every box counts): GT 11, TP 8 (4 matches V), FN 3 (B at 3, V at 1, C at 3),
FP 3 (5, 6, 7), IDSW 1: MOTA = 1 − 7/11 = 0.3636; IDTP = 2 + 3 + 1 = 6 of 11 and 11 rows:
IDF1 = 12 / 22 = 0.5455.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from retrieval.cli import main
from scenes.calibration import CameraIntrinsics
from scenes.categories import Category
from scenes.geometry import SE3
from scenes.kitti import (
    KITTI_EPOCH_NS,
    ego_trajectory_from_kitti,
    import_kitti_sequence,
    kitti_boxes_to_ego,
    read_kitti_calibration,
    read_kitti_labels,
    read_kitti_poses,
    write_kitti_log,
)
from scenes.metadata import LogMetadata
from scenes.tracking.evaluate import IgnoreRules, evaluate_tracking, similarity, tracking_counts
from scenes.tracking.kitti_protocol import kitti_ignore_rules, project_boxes_px
from scenes.tracking.log_evaluation import Protocol, evaluate_log_pair
from scenes.tracks import Annotations, EgoTrajectory

PERIOD_NS = 100_000_000
CAR = "REGULAR_VEHICLE"
TALL = (500.0, 100.0, 600.0, 200.0)
REGION = (0.0, 0.0, 400.0, 375.0)  # the DontCare region of frame 1

#: (frame, track, x, y) of the ground truth; V and C are the distractors.
GT_ROWS = [(f, "A", 10.0, 0.0) for f in range(4)] + [(f, "B", 10.0, 10.0) for f in range(4)] + [
    (0, "V", 10.0, -10.0), (1, "V", 10.0, -10.0), (3, "C", 20.0, -20.0)]
GT_DISTRACTOR = [False] * 8 + [True] * 3
#: (frame, track, x, y, image box) of the predictions.
PRED_ROWS = [
    (0, "1", 10.0, 0.0, TALL), (1, "1", 10.0, 0.0, (100.0, 100.0, 200.0, 200.0)),  # matched, so kept in the region
    (2, "2", 10.0, 1.1, TALL), (3, "2", 10.0, 1.1, TALL),
    (0, "3", 10.0, 10.0, TALL), (1, "3", 10.0, 10.0, TALL), (2, "3", 10.0, 10.0, TALL),
    (0, "4", 10.0, -10.0, TALL),
    (1, "5", 30.0, 30.0, (100.0, 100.0, 200.0, 200.0)),
    (2, "6", -20.0, 5.0, (700.0, 100.0, 800.0, 200.0)),
    (3, "7", 40.0, 40.0, (700.0, 150.0, 720.0, 160.0)),
]

KITTI_FIGURES = {"MOTA": 0.625, "MOTP": 0.3143, "IDF1": 0.625, "HOTA": 0.6494, "DetA": 0.6927, "AssA": 0.6184,
                 "LocA": 0.9421, "IDSW": 1, "TP": 7, "FP": 1, "FN": 1, "GT": 8, "ignored_GT": 3,
                 "ignored_pred_distractor": 1, "ignored_pred_region": 1, "ignored_pred_small": 1}
PLAIN_FIGURES = {"MOTA": 0.3636, "IDF1": 0.5455, "IDSW": 1, "TP": 8, "FP": 3, "FN": 3, "GT": 11, "ignored_GT": 0,
                 "ignored_pred": 0}


def _annotations(rows: list[tuple[Any, ...]]) -> Annotations:
    n = len(rows)
    return Annotations.from_yaw(
        timestamp_ns=np.array([r[0] * PERIOD_NS for r in rows]), track_id=[r[1] for r in rows], category=[CAR] * n,
        center_xyz_m=np.array([(r[2], r[3], 0.75) for r in rows]), size_lwh_m=np.tile([4.0, 1.8, 1.5], (n, 1)),
        yaw_rad=np.zeros(n))


def _static_ego(frames: int = 4) -> EgoTrajectory:
    return EgoTrajectory.from_xy_yaw(np.arange(frames) * PERIOD_NS, np.zeros((frames, 2)), np.zeros(frames))


def _hand_case() -> tuple[Annotations, Annotations, IgnoreRules]:
    rules = IgnoreRules(
        gt_distractor=np.array(GT_DISTRACTOR), pred_box_px=np.array([r[4] for r in PRED_ROWS]),
        region_timestamp_ns=np.array([1 * PERIOD_NS]), region_box_px=np.array([REGION]))
    return _annotations(PRED_ROWS), _annotations(GT_ROWS), rules


def _assert_figures(got: dict[str, Any], expected: dict[str, Any]) -> None:
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, abs=1e-4), key


def test_hand_case_with_dontcare_and_van_matches_the_official_definitions() -> None:
    pred, gt, rules = _hand_case()
    ego = _static_ego()
    _assert_figures(evaluate_tracking(pred, ego, gt, ego, ignore=rules)["car"], KITTI_FIGURES)
    _assert_figures(evaluate_tracking(pred, ego, gt, ego)["car"], PLAIN_FIGURES)


def test_ignore_rules_are_strict_at_their_thresholds() -> None:
    """A box exactly half inside a region, or exactly 25 px tall, is not dropped for it (more than
    half / at most 25 px are the rules)."""
    gt = _annotations([(0, "A", 10.0, 0.0)])
    pred = _annotations([(0, "1", 30.0, 0.0), (0, "2", 40.0, 0.0), (0, "3", 50.0, 0.0)])
    boxes = np.array([(0.0, 0.0, 100.0, 100.0), (500.0, 0.0, 600.0, 25.0), (500.0, 0.0, 600.0, 25.5)])
    rules = IgnoreRules(np.array([False]), boxes, np.array([0]), np.array([(50.0, 0.0, 300.0, 100.0)]))
    m = evaluate_tracking(pred, _static_ego(1), gt, _static_ego(1), ignore=rules)["car"]
    assert (m["ignored_pred_region"], m["ignored_pred_small"], m["FP"]) == (0, 1, 2)


def test_similarity_puts_the_match_threshold_at_max_distance() -> None:
    assert similarity(np.array([0.0, 2.0, 4.0, 9.0]), 2.0).tolist() == [1.0, 0.5, 0.0, 0.0]


def test_counts_pool_over_logs_as_one_split() -> None:
    pred, gt, rules = _hand_case()
    ego = _static_ego()
    one = tracking_counts(pred, ego, gt, ego, ignore=rules)[Category.CAR]
    both = (one + one).figures()
    # Twice the same log: every count doubles, every ratio stays.
    assert both["TP"] == 2 * KITTI_FIGURES["TP"] and both["GT"] == 2 * KITTI_FIGURES["GT"]
    for key in ("MOTA", "IDF1", "HOTA", "DetA", "AssA", "LocA"):
        assert both[key] == pytest.approx(KITTI_FIGURES[key], abs=1e-4)


def test_plain_counts_agree_with_motmetrics_on_random_scenes() -> None:
    """CLEAR-MOT and IDF1 without ignore rules are the standard ones: motmetrics, with the same
    distance threshold, gives the same numbers on scenes with misses, switches and false alarms."""
    mm = pytest.importorskip("motmetrics")
    for seed in range(5):
        rng = np.random.default_rng(seed)
        frames, objects = 30, 6
        start = rng.uniform(-60, 60, size=(objects, 2))
        while np.linalg.norm(start[:, None] - start[None], axis=2)[np.triu_indices(objects, 1)].min() < 10:
            start = rng.uniform(-60, 60, size=(objects, 2))  # far apart: one sensible assignment per frame
        gt_rows, pred_rows = [], []
        track = {o: f"p{o}" for o in range(objects)}
        for f in range(frames):
            for o in range(objects):
                xy = start[o] + 0.5 * f
                gt_rows.append((f, f"g{o}", *xy))
                if rng.random() < 0.15:
                    continue
                if rng.random() < 0.05:
                    track[o] = f"p{o}-{f}"
                pred_rows.append((f, track[o], *(xy + rng.normal(0, 0.8, 2))))
            pred_rows += [(f, f"fp{f}-{k}", *rng.uniform(-80, 80, 2)) for k in range(rng.poisson(0.5))]
        gt, pred = _annotations(gt_rows), _annotations(pred_rows)
        ego = _static_ego(frames)
        ours = evaluate_tracking(pred, ego, gt, ego, max_distance_m=2.0)["car"]
        acc = mm.MOTAccumulator(auto_id=True)
        number: dict[str, int] = {}  # motmetrics wants numeric ids
        for f in range(frames):
            g = [r for r in gt_rows if r[0] == f]
            p = [r for r in pred_rows if r[0] == f]
            g_xy, p_xy = np.array([r[2:] for r in g]), np.array([r[2:] for r in p]).reshape(-1, 2)
            d = np.linalg.norm(g_xy[:, None] - p_xy[None], axis=2)
            d[d > 2.0] = np.nan
            acc.update([number.setdefault(r[1], len(number)) for r in g],
                       [number.setdefault(r[1], len(number)) for r in p], d)
        ref = mm.metrics.create().compute(acc, metrics=["mota", "idf1", "num_switches", "num_false_positives",
                                                         "num_misses", "motp"]).iloc[0]
        assert ours["MOTA"] == pytest.approx(ref["mota"], abs=1e-4)
        assert ours["IDF1"] == pytest.approx(ref["idf1"], abs=1e-4)
        assert (ours["IDSW"], ours["FP"], ours["FN"]) == (ref["num_switches"], ref["num_false_positives"],
                                                          ref["num_misses"])
        assert ours["MOTP"] == pytest.approx(ref["motp"], abs=1e-4)


def test_projection_of_a_box_ahead_is_the_pinhole_one() -> None:
    # Camera at the ego origin looking along ego x (cam z = ego x, cam x = −ego y, cam y = −ego z).
    ego_SE3_cam = SE3(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.zeros(3))
    cam = CameraIntrinsics("image_02", 700.0, 700.0, 600.0, 180.0, 1242, 375)
    boxes = Annotations.from_yaw(np.zeros(3, np.int64), ["a", "b", "c"], [CAR] * 3,
                                 np.array([(20.0, 0.0, 0.75), (-20.0, 0.0, 0.75), (1.0, 0.0, 0.75)]),
                                 np.tile([4.0, 2.0, 1.5], (3, 1)), np.zeros(3))
    px = project_boxes_px(boxes, ego_SE3_cam, cam)
    # Box a: nearest face at 18 m, 2 m wide, from the ground (v = cy) up 1.5 m.
    assert px[0] == pytest.approx([600 - 700 / 18, 180 - 700 * 1.5 / 18, 600 + 700 / 18, 180], abs=1e-6)
    assert (px[1] == 0).all()  # behind the camera
    # Box c reaches behind the camera: cut at the near plane, it spans the image to the borders.
    assert px[2] == pytest.approx([0, 0, 1241, 180], abs=1e-6)


# The same hand case as a KITTI sequence: label file, calibration, poses, imported as the CLI does.
P2 = "721.5377 0 609.5593 44.85728 0 721.5377 172.854 0.2163791 0 0 1 0.002745884"
CALIB = f"P0: {P2}\nP1: {P2}\nP2: {P2}\nP3: {P2}\nR_rect 1 0 0 0 1 0 0 0 1\n" \
        "Tr_velo_cam 0 -1 0 0 0 0 -1 0 1 0 0 0\nTr_imu_velo 1 0 0 0 0 1 0 0 0 0 1 0\n"
# Camera frame: x right, y down (the road 1.73 m below), z forward; ego (x, y) = (z, −x) here.
KITTI_GT = [  # frame, id, type, truncated, occluded, x, z
    *[(f, 0, "Car", 0, 0, 0.0, 10.0) for f in range(4)], *[(f, 1, "Car", 0, 1, -10.0, 10.0) for f in range(4)],
    (0, 2, "Van", 0, 0, 10.0, 10.0), (1, 2, "Van", 0, 0, 10.0, 10.0), (3, 3, "Car", 1, 0, 20.0, 20.0)]
KITTI_PRED = [  # frame, track, x, z — the predictions of the hand case, placed in the camera frame
    (0, "1", 0.0, 10.0), (1, "1", 0.0, 10.0), (2, "2", -1.1, 10.0), (3, "2", -1.1, 10.0),
    (0, "3", -10.0, 10.0), (1, "3", -10.0, 10.0), (2, "3", -10.0, 10.0), (0, "4", 10.0, 10.0),
    (1, "5", -12.0, 25.0),  # projects inside the DontCare region [0, 400] × [0, 375] of frame 1
    (2, "6", 12.0, 25.0),  # 43 px tall, no region: a false positive
    (3, "7", 0.0, 70.0)]  # 15 px tall


def _kitti_sequence(root: Path) -> tuple[Path, Path]:
    """Write the hand case as KITTI files and logs; returns (predicted log, ground-truth log)."""
    for sub in ("label_02", "calib", "poses"):
        (root / sub).mkdir(parents=True)
    lines = [f"{f} {i} {t} {tr} {oc} 0 500 150 600 250 1.5 1.8 4.0 {x} 1.73 {z} 0"
             for f, i, t, tr, oc, x, z in KITTI_GT]
    lines.insert(2, "1 -1 DontCare -1 -1 -10 0 0 400 375 -1000 -1000 -1000 -10 -1 -1 -1")
    lines.sort(key=lambda line: int(line.split()[0]))
    (root / "label_02" / "0000.txt").write_text("\n".join(lines) + "\n")
    (root / "calib" / "0000.txt").write_text(CALIB)
    (root / "poses" / "0000.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 4)
    gt = import_kitti_sequence(root / "label_02" / "0000.txt", root / "poses" / "0000.txt",
                               root / "calib" / "0000.txt", root / "gt").log_dir
    calibration = read_kitti_calibration(root / "calib" / "0000.txt")
    n = len(KITTI_PRED)
    center, quat = kitti_boxes_to_ego(np.array([(x, 1.73, z) for _, _, x, z in KITTI_PRED]), np.full(n, 1.5),
                                      np.zeros(n), calibration.ego_SE3_cam)
    pred = Annotations(np.array([KITTI_EPOCH_NS + f * PERIOD_NS for f, *_ in KITTI_PRED]),
                       np.array([t for _, t, _, _ in KITTI_PRED]), np.array([CAR] * n), center,
                       np.tile([4.0, 1.8, 1.5], (n, 1)), quat, np.full(n, -1))
    ego = ego_trajectory_from_kitti(read_kitti_poses(root / "poses" / "0000.txt"), calibration.ego_SE3_cam)
    pred_dir = write_kitti_log(root / "pred", pred.sorted(), ego, calibration,
                               LogMetadata(log_id="kitti_0000", source="kitti-tracker", city_name="KITTI"))
    return pred_dir, gt


def test_kitti_sequence_of_the_hand_case_gives_the_hand_figures(tmp_path: Path) -> None:
    pred_dir, gt_dir = _kitti_sequence(tmp_path)
    labels = read_kitti_labels(tmp_path / "label_02" / "0000.txt")
    assert labels.dontcare_frame.tolist() == [1] and labels.dontcare_box_px.tolist() == [list(REGION)]
    result = evaluate_log_pair(pred_dir, gt_dir)  # auto: the ground truth was imported from KITTI labels
    assert result.protocol is Protocol.KITTI and result.labels_path == tmp_path / "label_02" / "0000.txt"
    _assert_figures(result.figures()["car"], KITTI_FIGURES)
    plain = evaluate_log_pair(pred_dir, gt_dir, Protocol.PLAIN)
    _assert_figures(plain.figures()["car"], PLAIN_FIGURES)


def test_kitti_rules_refuse_another_sequences_label_file(tmp_path: Path) -> None:
    from scenes.errors import ImportFormatError
    from scenes.log import Log

    pred_dir, gt_dir = _kitti_sequence(tmp_path)
    other = tmp_path / "other.txt"
    other.write_text("0 0 Car 0 0 0 500 150 600 250 1.5 1.8 4.0 0 1.73 10 0\n")
    gt, pred = Log.open(gt_dir), Log.open(pred_dir)
    with pytest.raises(ImportFormatError, match=r"other\.txt.*frame 0, track 1"):
        kitti_ignore_rules(gt.annotations, read_kitti_labels(other), other, pred.annotations, gt.calibration)


def test_cli_scores_a_folder_of_logs_and_reports_what_it_skipped(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    pred_dir, gt_dir = _kitti_sequence(tmp_path)
    (tmp_path / "pred" / "kitti_9999").mkdir()  # a prediction without ground truth
    out = tmp_path / "metrics.json"
    assert main(["eval-tracking", str(tmp_path / "pred"), str(tmp_path / "gt"), "--out", str(out)]) == 0
    metrics = json.loads(out.read_text())
    _assert_figures(metrics["combined"]["car"], KITTI_FIGURES)
    assert metrics["logs"]["kitti_0000"]["protocol"] == "kitti"
    assert "kitti_9999" in metrics["skipped"]
    assert "skipped kitti_9999" in capsys.readouterr().err
    # One pair: the file holds the categories, as before.
    assert main(["eval-tracking", str(pred_dir), str(gt_dir), "--out", str(out), "--protocol", "plain"]) == 0
    _assert_figures(json.loads(out.read_text())["car"], PLAIN_FIGURES)


def test_cli_refuses_kitti_rules_without_the_label_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pred_dir, gt_dir = _kitti_sequence(tmp_path)
    (tmp_path / "label_02" / "0000.txt").unlink()
    out = tmp_path / "metrics.json"
    out.write_text("previous")
    assert main(["eval-tracking", str(pred_dir), str(gt_dir), "--out", str(out)]) == 2
    assert "--kitti-labels" in capsys.readouterr().err
    # A folder in which every pair fails leaves the previous output as it was.
    assert main(["eval-tracking", str(tmp_path / "pred"), str(tmp_path / "gt"), "--out", str(out)]) == 2
    assert out.read_text() == "previous"
