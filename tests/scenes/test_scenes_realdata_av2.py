"""Real Argoverse 2 logs marked for development in ../shared/realdata open, validate, and show what
their README says happens in them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from scenes import av2_io
from scenes.categories import Category
from scenes.errors import LogFormatError
from scenes.log import Log
from scenes.validate import validate_log
from tests.realdata import REALDATA
from tests.scenes.av2_fixtures import rewritten_log

LOG_7FAB = REALDATA / "av2" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
LOG_ADCF = REALDATA / "av2" / "adcf7d18-0510-35b0-a2fa-b4cea13a6d76"


def _require(path: Path) -> Path:
    if not path.is_dir():
        pytest.skip(f"real AV2 data not found at {path} (the shared realdata folder is absent)")
    return path


@pytest.fixture(scope="module")
def log_7fab() -> Log:
    return Log.open(_require(LOG_7FAB))


@pytest.fixture(scope="module")
def log_adcf() -> Log:
    return Log.open(_require(LOG_ADCF))


def _speed_and_time(log: Log) -> tuple[np.ndarray, np.ndarray]:
    ego = log.ego_at_frames()
    return ego.speed_mps(), (log.timestamps_ns - log.timestamps_ns[0]) * 1e-9


@pytest.mark.parametrize("path", [LOG_7FAB, LOG_ADCF], ids=["7fab2350", "adcf7d18"])
def test_development_logs_validate(path: Path) -> None:
    report = validate_log(_require(path))
    assert report.ok, report.problems
    assert report.facts["frames"] == 156
    assert report.facts["duration_s"] == pytest.approx(15.5, abs=0.05)
    assert report.facts["has_map"] is True
    assert not any("unknown categories" in w for w in report.warnings)


def test_7fab_frames_and_sensors(log_7fab: Log) -> None:
    assert len(log_7fab.timestamps_ns) == 156
    np.testing.assert_allclose(np.diff(log_7fab.timestamps_ns) * 1e-9, 0.1, atol=0.002)
    # Ego poses come at about 200 Hz.
    rate_hz = (len(log_7fab.ego) - 1) / ((log_7fab.ego.timestamps_ns[-1] - log_7fab.ego.timestamps_ns[0]) * 1e-9)
    assert 150 < rate_hz < 250
    assert log_7fab.metadata.city_name == "PIT"
    assert "ring_front_center" in log_7fab.calibration.camera_names()
    front = log_7fab.calibration.ego_SE3_sensor["ring_front_center"].translation
    assert 1.0 < front[0] < 2.5 and abs(front[1]) < 0.2 and 1.0 < front[2] < 2.0  # ahead of the rear axle, up
    vector_map = log_7fab.map
    assert vector_map is not None and len(vector_map.lane_segments) > 50


def test_7fab_ego_brakes_to_a_stop_then_moves_again(log_7fab: Log) -> None:
    speed, t = _speed_and_time(log_7fab)
    assert 9.5 < speed[:5].mean() < 12.0  # about 11 m/s at the start
    stopped = np.flatnonzero(speed < 0.3)
    assert stopped.size > 0
    assert 5.0 < t[stopped[0]] < 13.0
    assert speed[stopped[-1]:].max() > 3.0  # pulls off again
    assert (np.diff(speed[: stopped[0] - 15]) < 0.2).all()  # braking: speed never rises much before the stop
    ego = log_7fab.ego_at_frames()
    turn_deg = np.degrees(np.unwrap(ego.yaw_rad)[-1] - ego.yaw_rad[0])
    assert abs(turn_deg) > 30  # pulls off through a turn


def test_adcf_ego_stands_then_accelerates(log_adcf: Log) -> None:
    speed, t = _speed_and_time(log_adcf)
    standing = t < 4.5
    assert (speed[standing] < 0.3).all()
    moving_from = t[np.flatnonzero(speed > 0.3)[0]]
    assert 4.5 < moving_from < 6.0
    assert speed[t > 8.0].min() > 2.0
    ego = log_adcf.ego_at_frames()
    assert abs(np.degrees(ego.yaw_rad[-1] - ego.yaw_rad[0])) < 5  # straight on


def test_adcf_has_many_pedestrians_and_a_bus(log_adcf: Log) -> None:
    tracks = log_adcf.tracks()
    categories = [t.category for t in tracks.values()]
    assert categories.count(Category.PEDESTRIAN) >= 20
    assert Category.BUS in categories


def test_7fab_lidar_sweeps(log_7fab: Log) -> None:
    stamps = log_7fab.lidar_timestamps_ns
    assert len(stamps) == 2
    assert (stamps[1] - stamps[0]) * 1e-9 == pytest.approx(0.1, abs=0.005)
    sweep = log_7fab.lidar_sweep(int(stamps[0]))
    assert 95_000 < len(sweep) < 105_000
    assert (int(sweep.laser_number.min()), int(sweep.laser_number.max())) == (0, 63)
    assert np.isfinite(sweep.xyz_m).all()
    xyz = sweep.xyz_m.astype(np.float64)
    ring = (np.linalg.norm(xyz[:, :2], axis=1) > 5) & (np.linalg.norm(xyz[:, :2], axis=1) < 20)
    assert -1.0 < np.percentile(xyz[ring, 2], 10) < 0.5  # ego frame: the road is near z = 0


def test_7fab_parked_cars_are_still_in_the_city_frame(log_7fab: Log) -> None:
    dense = log_7fab.dense_tracks()
    tracks = log_7fab.tracks()
    # dense and per-track views agree on real data
    for k in range(0, len(dense.track_ids), 7):
        track = tracks[str(dense.track_ids[k])]
        np.testing.assert_allclose(dense.center_city_xyz_m[k, dense.valid[k]], track.center_city_xyz_m, atol=1e-9)
    long_cars = [t for t in tracks.values() if t.raw_category == "REGULAR_VEHICLE" and len(t) > 100]
    spread = [np.linalg.norm(t.center_city_xyz_m[:, :2] - np.median(t.center_city_xyz_m[:, :2], 0), axis=1).max()
              for t in long_cars]
    # The ego travels ~70 m and turns; parked cars still stay put within a metre in the city frame.
    assert sum(s < 1.0 for s in spread) >= 15


def test_7fab_with_an_8_s_gap_in_its_poses_is_refused(tmp_path: Path) -> None:
    """Poses dropped from 3 s to 11 s: the annotation frames inside would be given interpolated poses."""
    source = _require(LOG_7FAB)

    def drop(table: pa.Table) -> pa.Table:
        ts = table.column("timestamp_ns").to_numpy()
        return table.filter(pa.array((ts < ts[0] + 3_000_000_000) | (ts > ts[0] + 11_000_000_000)))

    log_dir = rewritten_log(source, tmp_path / source.name, drop, av2_io.POSES_FILENAME)
    with pytest.raises(LogFormatError) as info:
        Log.open(log_dir)
    [problem] = info.value.problems
    assert (problem.path.name, problem.field) == (av2_io.POSES_FILENAME, "timestamp_ns")
    assert "s apart, more than the limit of 1 s" in problem.message
    assert validate_log(log_dir).problems == [problem]
    assert len(Log.open(log_dir, max_pose_gap_s=10.0).tracks()) == 114


def test_7fab_cut_to_one_frame_reports_one_frame(tmp_path: Path) -> None:
    """Its two sweeps lie 11.6 s after the first frame: they are counted as sweeps, not as frames."""
    source = _require(LOG_7FAB)

    def first_frame(table: pa.Table) -> pa.Table:
        ts = table.column("timestamp_ns").to_numpy()
        return table.filter(pa.array(ts == ts.min()))

    report = validate_log(rewritten_log(source, tmp_path / source.name, first_frame))
    assert report.ok, report.problems
    assert (report.facts["frames"], report.facts["duration_s"], report.facts["lidar_sweeps"]) == (1, 0.0, 2)


@pytest.mark.parametrize("log_path", [LOG_7FAB, LOG_ADCF], ids=["7fab2350", "adcf7d18"])
def test_development_logs_hold_within_the_plausibility_bounds(log_path: Path) -> None:
    report = validate_log(_require(log_path))
    assert report.ok, report.problems
