"""Tracker behaviour on hand-made detections with known answers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scenes.errors import ImportFormatError
from scenes.geometry import wrap_angle_rad
from scenes.tracking import Detections, TrackerConfig, kalman, track_detections
from scenes.tracking.config import Association
from scenes.tracking.detections import read_detections_table, write_detections_table
from scenes.tracking.evaluate import evaluate_tracking
from scenes.tracks import Annotations, EgoTrajectory

PERIOD_NS = 100_000_000


def _ego(frames: int, speed_mps: float = 0.0) -> EgoTrajectory:
    ts = np.arange(frames, dtype=np.int64) * PERIOD_NS
    xy = np.stack([np.arange(frames) * speed_mps * 0.1, np.zeros(frames)], axis=1)
    return EgoTrajectory.from_xy_yaw(ts, xy, np.zeros(frames))


def _detections(rows: list[tuple[int, str, float, float, float, float]]) -> Detections:
    """rows: (frame, category, score, x_m, y_m, yaw_rad) in the ego frame; car-sized boxes."""
    a = np.array([(f, s, x, y, yaw) for f, _, s, x, y, yaw in rows], dtype=np.float64)
    sizes = {"car": (4.5, 1.9, 1.6), "pedestrian": (0.6, 0.6, 1.7)}
    return Detections(
        timestamp_ns=a[:, 0].astype(np.int64) * PERIOD_NS,
        category=np.array([c for _, c, *_ in rows], dtype=np.str_),
        score=a[:, 1],
        center_xyz_m=np.stack([a[:, 2], a[:, 3], np.full(len(rows), 0.8)], axis=1),
        size_lwh_m=np.array([sizes[c] for _, c, *_ in rows]),
        yaw_rad=a[:, 4],
        source_line=np.arange(1, len(rows) + 1),
    )


def _tracks_by_id(ann: Annotations) -> dict[str, np.ndarray]:
    """Track id → (n, 3) rows of (frame, x, y)."""
    out = {}
    for tid in ann.track_ids:
        m = ann.track_id == tid
        out[tid] = np.column_stack([ann.timestamp_ns[m] // PERIOD_NS, ann.center_xyz_m[m, :2]])
    return out


def test_crossing_objects_keep_their_identities() -> None:
    # Two cars cross in an X: A goes from (10, -6) to (10, +6) heading left, B from (4, 0) to (16, 0)
    # heading forward; they pass the same point at frame 20, 1 m apart in time-shifted paths.
    rows = []
    for f in range(41):
        rows.append((f, "car", 0.9, 10.0, -6.0 + 0.3 * f, np.pi / 2))
        rows.append((f, "car", 0.9, 4.0 + 0.3 * f, 0.2, 0.0))
    ann = track_detections(_detections(rows), _ego(41), TrackerConfig(min_hits=3))
    tracks = _tracks_by_id(ann)
    assert len(tracks) == 2
    for rows_of_track in tracks.values():
        assert rows_of_track.shape[0] == 41
        # Each identity stays on one straight line: either x constant (A) or y constant (B).
        x_span = np.ptp(rows_of_track[:, 1])
        y_span = np.ptp(rows_of_track[:, 2])
        assert min(x_span, y_span) < 0.3


def test_a_missed_frame_is_bridged_and_a_false_positive_dropped() -> None:
    rows = [(f, "car", 0.9, 15.0 + 0.5 * f, 3.5, 0.0) for f in range(30) if f != 12]
    rows.append((7, "car", 0.9, -8.0, -9.0, 0.0))  # one-frame ghost
    ego = _ego(30)
    ann = track_detections(_detections(rows), ego, TrackerConfig(min_hits=3, max_age=2),
                           frame_timestamps_ns=ego.timestamps_ns)
    tracks = _tracks_by_id(ann)
    assert len(tracks) == 1, "the ghost must not become a track and the gap must not split the car"
    (car,) = tracks.values()
    assert car.shape[0] == 30
    # The missed frame is filled by interpolation between its neighbours.
    filled = car[car[:, 0] == 12][0]
    np.testing.assert_allclose(filled[1:], [15.0 + 0.5 * 12, 3.5], atol=0.05)
    unfilled = track_detections(_detections(rows), ego, TrackerConfig(fill_gaps=False),
                                frame_timestamps_ns=ego.timestamps_ns)
    assert 12 not in _tracks_by_id(unfilled)[unfilled.track_ids[0]][:, 0]


def test_a_long_gap_starts_a_new_track() -> None:
    rows = [(f, "car", 0.9, 15.0 + 0.5 * f, 3.5, 0.0) for f in range(30) if not 10 <= f < 16]
    ego = _ego(30)
    # Frames with no detection at all exist only if the log says so: pass its frame grid.
    ann = track_detections(_detections(rows), ego, TrackerConfig(min_hits=3, max_age=2),
                           frame_timestamps_ns=ego.timestamps_ns)
    assert len(ann.track_ids) == 2


def test_ego_motion_is_removed() -> None:
    # A parked car seen from an ego driving at 10 m/s: x_ego shrinks by 1 m per frame, but in the city
    # frame it stands still, so the filter's velocity must stay near zero and the track whole.
    rows = [(f, "car", 0.9, 40.0 - 1.0 * f, -3.0, 0.0) for f in range(30) if f % 7 != 3]
    ann = track_detections(_detections(rows), _ego(30, speed_mps=10.0), TrackerConfig())
    assert len(ann.track_ids) == 1


def test_score_threshold_and_categories_are_respected() -> None:
    rows = [(f, "car", 0.2, 10.0, 0.0, 0.0) for f in range(10)]
    rows += [(f, "pedestrian", 0.9, 10.0, 0.3, 0.0) for f in range(10)]
    ann = track_detections(_detections(rows), _ego(10), TrackerConfig(score_threshold=0.5))
    assert set(ann.category.tolist()) == {"PEDESTRIAN"}


def test_yaw_flip_is_absorbed() -> None:
    rows = [(f, "car", 0.9, 10.0 + 0.8 * f, 0.0, np.pi if f % 3 == 1 else 0.0) for f in range(20)]
    ann = track_detections(_detections(rows), _ego(20), TrackerConfig())
    assert len(ann.track_ids) == 1
    assert np.abs(wrap_angle_rad(ann.yaw_rad)).max() < 0.5


def test_bev_iou_association_tracks_too() -> None:
    rows = [(f, "car", 0.9, 10.0 + 0.5 * f, 0.0, 0.0) for f in range(15)]
    ann = track_detections(_detections(rows), _ego(15), TrackerConfig(association=Association.BEV_IOU))
    assert len(ann.track_ids) == 1 and len(ann) == 15


def test_kalman_recovers_constant_velocity() -> None:
    cfg = TrackerConfig()
    states, cov = kalman.initial_states(np.array([[0.0, 0, 0, 0, 4, 2, 1.5]]), cfg)
    for step in range(1, 30):
        states, cov = kalman.predict(states, cov, 0.1, cfg)
        meas = np.array([[0.1 * 7.0 * step, 0.1 * -2.0 * step, 0, 0, 4, 2, 1.5]])
        states, cov = kalman.update(states, cov, meas, cfg)
    np.testing.assert_allclose(states[0, 7:9], [7.0, -2.0], atol=0.2)


def test_detection_timestamps_without_poses_are_an_error() -> None:
    rows = [(f, "car", 0.9, 10.0, 0.0, 0.0) for f in range(5)] + [(50, "car", 0.9, 10.0, 0.0, 0.0)]
    with pytest.raises(ImportFormatError, match="line 6.*timestamp_ns"):
        track_detections(_detections(rows), _ego(5), source="dets.parquet")


@pytest.mark.parametrize(
    ("column", "value", "field"),
    [("score", 1.5, "score"), ("length_m", 0.0, "length_m"), ("tx_m", float("nan"), "tx_m")],
)
def test_bad_detection_rows_name_the_line(tmp_path: Path, column: str, value: float, field: str) -> None:
    import pyarrow.parquet as pq

    path = tmp_path / "dets.parquet"
    write_detections_table(path, _detections([(f, "car", 0.9, 10.0, 0.0, 0.0) for f in range(4)]))
    table = pq.read_table(path)
    values = table.column(column).to_pylist()
    values[2] = value
    table = table.set_column(table.column_names.index(column), column, [values])
    pq.write_table(table, path)
    with pytest.raises(ImportFormatError, match=f"line 3.*{field}"):
        read_detections_table(path)


def test_detections_table_round_trip(tmp_path: Path) -> None:
    dets = _detections([(f, "car", 0.9, 10.0 + f, -1.0, 0.1) for f in range(4)])
    write_detections_table(tmp_path / "d.parquet", dets)
    back = read_detections_table(tmp_path / "d.parquet")
    np.testing.assert_array_equal(back.timestamp_ns, dets.timestamp_ns)
    np.testing.assert_allclose(back.center_xyz_m, dets.center_xyz_m)
    assert back.category.tolist() == ["car"] * 4


def test_config_yaml_round_trip_and_unknown_keys(tmp_path: Path) -> None:
    cfg = TrackerConfig(association=Association.BEV_IOU, min_hits=2, score_threshold=0.7)
    cfg.to_yaml(tmp_path / "t.yaml")
    assert TrackerConfig.from_yaml(tmp_path / "t.yaml") == cfg
    (tmp_path / "bad.yaml").write_text("min_hit: 3\n")
    with pytest.raises(ValueError, match="bad.yaml: unknown keys min_hit"):
        TrackerConfig.from_yaml(tmp_path / "bad.yaml")
    with pytest.raises(ValueError, match="score_threshold"):
        TrackerConfig(score_threshold=2.0)


def test_evaluation_counts_switches_and_misses() -> None:
    ego = _ego(10)
    gt_rows = [(f, "car", 1.0, 10.0 + f, 0.0, 0.0) for f in range(10)]
    gt_det = _detections(gt_rows)
    gt = Annotations.from_yaw(gt_det.timestamp_ns, ["a"] * 10, ["REGULAR_VEHICLE"] * 10, gt_det.center_xyz_m,
                              gt_det.size_lwh_m, gt_det.yaw_rad)
    # Prediction: right for frames 0–4 as "p1", then the id switches to "p2", and frame 9 is missed.
    ids = ["p1"] * 5 + ["p2"] * 4
    keep = np.arange(9)
    pred = Annotations.from_yaw(gt.timestamp_ns[keep], ids, ["REGULAR_VEHICLE"] * 9, gt.center_xyz_m[keep] + 0.3,
                                gt.size_lwh_m[keep], gt.yaw_rad[keep])
    m = evaluate_tracking(pred, ego, gt, ego)["car"]
    assert m["GT"] == 10 and m["FN"] == 1 and m["IDSW"] == 1 and m["FP"] == 0
    assert m["MOTA"] == pytest.approx(1 - (1 + 1) / 10)
    assert m["MOTP"] == pytest.approx(0.3 * np.sqrt(2), abs=1e-4)


def test_heading_turns_to_follow_motion() -> None:
    # A detector that reports every box of a car driving along +x backwards (yaw π): once the track
    # is confirmed and moving, its heading must follow the velocity.
    rows = [(f, "car", 0.9, 10.0 + 1.0 * f, 0.0, np.pi) for f in range(20)]
    ann = track_detections(_detections(rows), _ego(20), TrackerConfig(heading_min_speed_mps=2.0))
    late = ann.timestamp_ns >= 10 * PERIOD_NS
    assert np.abs(wrap_angle_rad(ann.yaw_rad[late])).max() < 0.3
    # A parked car keeps whatever heading it was detected with: there is no motion to say otherwise.
    parked = [(f, "car", 0.9, 10.0, 0.0, np.pi) for f in range(20)]
    ann = track_detections(_detections(parked), _ego(20), TrackerConfig())
    assert np.abs(np.abs(wrap_angle_rad(ann.yaw_rad)) - np.pi).max() < 0.3
