"""One test per validation error: each builds a bad file and checks that the error names the file,
the row or frame, and the field, on open and in ``scenesearch validate``."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pytest

from retrieval.cli import main as cli_main
from scenes import av2_io, schema
from scenes.calibration import Calibration, CameraIntrinsics
from scenes.errors import LogFormatError, Problem, collect_problems
from scenes.geometry import SE3, yaw_to_quat
from scenes.log import Log
from scenes.map import LaneSegment, VectorMap
from scenes.sensors import LidarSweep, read_lidar_points, read_lidar_sweep
from scenes.tracks import Annotations, EgoTrajectory
from scenes.validate import validate_log

T0 = 1_600_000_000_000_000_000
ANN = av2_io.ANNOTATIONS_FILENAME
POSES = av2_io.POSES_FILENAME


def _write_log(log_dir: Path, categories: tuple[str, ...] = ("REGULAR_VEHICLE", "PEDESTRIAN", "BUS")) -> Path:
    """A valid log: 5 frames × len(categories) tracks, poses at 20 Hz, a LiDAR sweep, a map, a camera."""
    n_frames, n_tracks = 5, len(categories)
    ts = np.repeat(T0 + np.arange(n_frames) * 100_000_000, n_tracks)
    ids = np.tile([f"track{k}" for k in range(n_tracks)], n_frames)
    cats = np.tile(list(categories), n_frames)
    centers = np.tile(np.arange(n_tracks)[:, None] * [5.0, 1.0, 0.0] + [10.0, 0.0, 0.8], (n_frames, 1))
    av2_io.write_annotations(
        log_dir, Annotations.from_yaw(ts, ids, cats, centers, np.tile([4.0, 2.0, 1.5], (len(ts), 1)), np.zeros(len(ts)))
    )
    pose_ts = T0 + np.arange(0, 9) * 50_000_000
    t_s = (pose_ts - T0) * 1e-9
    av2_io.write_ego_poses(log_dir, EgoTrajectory(pose_ts, yaw_to_quat(0.05 * t_s), np.c_[8 * t_s, 0 * t_s, 0 * t_s]))
    rng = np.random.default_rng(0)
    av2_io.write_lidar_sweep(log_dir, LidarSweep(T0, rng.normal(size=(50, 3)).astype(np.float32),
                                                 np.zeros(50, np.uint8), np.arange(50, dtype=np.uint8) % 64,
                                                 np.zeros(50, np.int32)))
    lane = LaneSegment(1, False, "VEHICLE", np.array([[0.0, 1.75, 0], [40, 1.75, 0]]),
                       np.array([[0.0, -1.75, 0], [40, -1.75, 0]]))
    av2_io.write_map(log_dir, VectorMap({1: lane}), log_dir.name)
    cam = CameraIntrinsics("front", 500.0, 500.0, 32.0, 24.0, 64, 48)
    av2_io.write_calibration(log_dir, Calibration({"front": SE3.identity()}, {"front": cam}))
    av2_io.write_camera_frame(log_dir, "front", T0, np.zeros((48, 64, 3), np.uint8))
    return log_dir


@pytest.fixture
def log_dir(tmp_path: Path) -> Path:
    return _write_log(tmp_path / "log1")


def _edit(path: Path, change: Callable[[pa.Table], pa.Table]) -> None:
    feather.write_feather(change(feather.read_table(path)), path)


def _set(table: pa.Table, name: str, values: object, type_: pa.DataType | None = None) -> pa.Table:
    index = table.column_names.index(name)
    return table.set_column(index, name, pa.array(values, type_) if type_ is not None else values)


def _open_problems(log_dir: Path) -> list[Problem]:
    with pytest.raises(LogFormatError) as info:
        Log.open(log_dir)
    report = validate_log(log_dir)
    assert not report.ok
    assert [str(p) for p in report.problems] == [str(p) for p in info.value.problems]
    return info.value.problems


def _only(problems: list[Problem]) -> Problem:
    assert len(problems) == 1, problems
    return problems[0]


def test_valid_log_opens_and_validates(log_dir: Path) -> None:
    Log.open(log_dir)
    report = validate_log(log_dir)
    assert report.ok, report.problems
    assert report.warnings == []
    assert report.facts == {"frames": 5, "tracks": 3, "duration_s": 0.4, "lidar_sweeps": 1, "cameras": 1,
                            "camera_frames": 1, "has_map": True}


def test_missing_annotations_is_a_clear_error(log_dir: Path) -> None:
    (log_dir / ANN).unlink()
    problem = _only(_open_problems(log_dir))
    assert problem.path == log_dir / ANN
    assert "no annotations" in problem.message


def test_missing_poses_file(log_dir: Path) -> None:
    (log_dir / POSES).unlink()
    problem = _only(_open_problems(log_dir))
    assert problem.path == log_dir / POSES and "missing" in problem.message


def test_missing_log_folder(tmp_path: Path) -> None:
    with pytest.raises(LogFormatError, match="does not exist"):
        Log.open(tmp_path / "nope")
    assert "does not exist" in str(_only(validate_log(tmp_path / "nope").problems))


def test_wrong_column_name(log_dir: Path) -> None:
    _edit(log_dir / ANN, lambda t: t.rename_columns(["x_m" if c == "tx_m" else c for c in t.column_names]))
    problem = _only(_open_problems(log_dir))
    assert (problem.path.name, problem.field, problem.message) == (ANN, "tx_m", "missing column")


def test_wrong_column_dtype(log_dir: Path) -> None:
    _edit(log_dir / ANN, lambda t: _set(t, "ty_m", [str(v) for v in t.column("ty_m").to_pylist()], pa.string()))
    problem = _only(_open_problems(log_dir))
    assert (problem.path.name, problem.field) == (ANN, "ty_m")
    assert "wrong type" in problem.message


def _put(row: int, value: object) -> Callable[[np.ndarray], np.ndarray]:
    def change(values: np.ndarray) -> np.ndarray:
        values[row] = value
        return values

    return change


def _shift_from(row: int, offset: float) -> Callable[[np.ndarray], np.ndarray]:
    def change(values: np.ndarray) -> np.ndarray:
        values[row:] += offset
        return values

    return change


def _copy_row(src: int, dst: int) -> Callable[[np.ndarray], np.ndarray]:
    def change(values: np.ndarray) -> np.ndarray:
        values[dst] = values[src]
        return values

    return change


@pytest.mark.parametrize(
    ("filename", "column", "change", "row", "field", "message"),
    [
        pytest.param(ANN, "ty_m", _put(7, np.nan), 7, "ty_m", "NaN", id="nan-names-row-and-field"),
        pytest.param(POSES, "qz", _put(3, np.inf), 3, "qz", "NaN or inf", id="inf-in-poses"),
        pytest.param(POSES, "timestamp_ns", _copy_row(3, 4), 4, "timestamp_ns", "appears twice (rows 3 and 4)",
                     id="pose-timestamp-repeated"),
        # rows 3 and 4 share a timestamp
        pytest.param(ANN, "track_uuid", _copy_row(3, 4), 4, "track_uuid", "twice", id="track-twice-in-one-frame"),
        pytest.param(ANN, "qw", _put(2, 1.5), 2, "qw..qz", "norm 1.5", id="quaternion-far-from-unit-norm"),
        pytest.param(POSES, "tx_m", _shift_from(5, 30.0), 5, "tx_m,ty_m,tz_m", "jumps", id="pose-jump-30m-in-50ms"),
        pytest.param(ANN, "width_m", _put(9, 0.0), 9, "width_m", "positive", id="non-positive-box-size"),
    ],
)
def test_one_bad_value_names_file_row_and_field(
    log_dir: Path, filename: str, column: str, change: Callable[[np.ndarray], np.ndarray], row: int, field: str,
    message: str,
) -> None:
    def edit(t: pa.Table) -> pa.Table:
        return _set(t, column, change(t.column(column).to_numpy(zero_copy_only=False).copy()), t.column(column).type)

    _edit(log_dir / filename, edit)
    problem = _only(_open_problems(log_dir))
    assert (problem.path.name, problem.row, problem.field) == (filename, row, field)
    assert message in problem.message


def test_rows_in_any_order_are_read_in_time_order(log_dir: Path) -> None:
    """Annotations and poses whose rows are not in time order open, sorted; a pose jump still names
    the row as it is in the file."""
    before = Log.open(log_dir)
    reverse = lambda t: t.take(pa.array(np.arange(t.num_rows)[::-1]))  # noqa: E731
    _edit(log_dir / ANN, reverse)
    _edit(log_dir / POSES, reverse)
    after = Log.open(log_dir)
    np.testing.assert_array_equal(after.annotations.timestamp_ns, before.annotations.timestamp_ns)
    np.testing.assert_array_equal(after.annotations.track_id, before.annotations.track_id)
    np.testing.assert_array_equal(after.ego.timestamps_ns, before.ego.timestamps_ns)
    np.testing.assert_array_equal(after.ego.translation_m, before.ego.translation_m)
    assert validate_log(log_dir).ok

    def jump(t: pa.Table) -> pa.Table:  # reversed file: file row 2 is the 7th pose in time
        tx = t.column("tx_m").to_numpy().copy()
        tx[:3] += 30.0
        return _set(t, "tx_m", tx, pa.float64())

    _edit(log_dir / POSES, jump)
    problem = _only(_open_problems(log_dir))
    assert (problem.path.name, problem.row, problem.field) == (POSES, 2, "tx_m,ty_m,tz_m")


def test_empty_table(log_dir: Path) -> None:
    _edit(log_dir / ANN, lambda t: t.slice(0, 0))
    problem = _only(_open_problems(log_dir))
    assert problem.path.name == ANN and "no rows" in problem.message


def test_truncated_feather_file(log_dir: Path) -> None:
    data = (log_dir / POSES).read_bytes()
    (log_dir / POSES).write_bytes(data[: len(data) // 2])
    problem = _only(_open_problems(log_dir))
    assert problem.path.name == POSES and "unreadable" in problem.message


def test_annotations_outside_the_pose_stream(log_dir: Path) -> None:
    _edit(log_dir / POSES, lambda t: t.slice(0, 2))
    problem = _only(_open_problems(log_dir))
    assert (problem.path.name, problem.field) == (ANN, "timestamp_ns") and "no ego pose" in problem.message


def test_unknown_category_is_mapped_to_other_and_counted(tmp_path: Path) -> None:
    log_dir = _write_log(tmp_path / "log2", ("REGULAR_VEHICLE", "SPACESHIP", "SPACESHIP"))
    log = Log.open(log_dir)
    assert log.unknown_categories == {"SPACESHIP": 10}
    assert {t.category.value for t in log.tracks().values()} == {"car", "other"}
    report = validate_log(log_dir)
    assert report.ok
    assert report.warnings == ["unknown categories mapped to 'other': SPACESHIP=10"]


def test_every_problem_is_reported_not_just_the_first(log_dir: Path) -> None:
    _edit(log_dir / ANN, lambda t: t.drop_columns(["qx", "tz_m"]))
    (log_dir / POSES).unlink()
    problems = _open_problems(log_dir)
    assert {(p.path.name, p.field) for p in problems} == {(ANN, "qx"), (ANN, "tz_m"), (POSES, None)}


# ---- parts that Log.open reads lazily: checked by validate_log and by their readers


def _sweep_path(log_dir: Path) -> Path:
    return log_dir / av2_io.LIDAR_DIR / f"{T0}.feather"


def test_lidar_sweep_wrong_dtype(log_dir: Path) -> None:
    _edit(_sweep_path(log_dir), lambda t: _set(t, "laser_number", ["a"] * t.num_rows, pa.string()))
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.field) == (_sweep_path(log_dir), "laser_number")
    with pytest.raises(LogFormatError, match="laser_number"):
        read_lidar_sweep(_sweep_path(log_dir))
    # The points alone leave the other columns unread: the same points as the sweep's before the edit.
    assert read_lidar_points(_sweep_path(log_dir)).shape == (50, 3)


def test_lidar_sweep_missing_column_and_nan(log_dir: Path) -> None:
    _edit(_sweep_path(log_dir), lambda t: t.drop_columns(["y"]))
    assert _only(validate_log(log_dir).problems).field == "y"
    with pytest.raises(LogFormatError) as info:
        read_lidar_points(_sweep_path(log_dir))
    assert [(p.field, p.message) for p in info.value.problems] == [("y", "missing column")]

    def with_nan(t: pa.Table) -> pa.Table:
        z = np.zeros(t.num_rows, np.float16)
        z[11] = np.nan
        t = t.append_column("y", pa.array(np.zeros(t.num_rows, np.float16), pa.float16()))
        return t.set_column(t.column_names.index("z"), "z", pa.array(z, pa.float16()))

    _edit(_sweep_path(log_dir), with_nan)
    problem = _only(validate_log(log_dir).problems)
    assert (problem.row, problem.field) == (11, "z")
    with pytest.raises(LogFormatError, match="row 11"):
        read_lidar_sweep(_sweep_path(log_dir))
    with pytest.raises(LogFormatError, match="row 11"):
        read_lidar_points(_sweep_path(log_dir))


def test_lidar_sweep_reader_and_validate_name_every_bad_coordinate_column(log_dir: Path) -> None:
    def with_bad_values(t: pa.Table) -> pa.Table:
        for name, row, value in (("x", 3, np.nan), ("z", 1, np.inf)):
            values = t.column(name).to_numpy().copy()
            values[row] = value
            t = _set(t, name, values, pa.float16())
        return t

    _edit(_sweep_path(log_dir), with_bad_values)
    with pytest.raises(LogFormatError) as info:
        read_lidar_sweep(_sweep_path(log_dir))
    expected = [(_sweep_path(log_dir), 3, "x"), (_sweep_path(log_dir), 1, "z")]
    assert [(p.path, p.row, p.field) for p in info.value.problems] == expected
    assert validate_log(log_dir).problems == info.value.problems


def test_lidar_sweep_missing_file_is_named_like_the_other_tables(log_dir: Path) -> None:
    path = log_dir / av2_io.LIDAR_DIR / "123.feather"
    with pytest.raises(LogFormatError) as info:
        Log.open(log_dir).lidar_sweep(123)
    assert [(p.path, p.message) for p in info.value.problems] == [(path, "file is missing")]


def test_lidar_sweep_truncated(log_dir: Path) -> None:
    path = _sweep_path(log_dir)
    path.write_bytes(path.read_bytes()[:100])
    problem = _only(validate_log(log_dir).problems)
    assert problem.path == path and "unreadable" in problem.message


def test_map_json_unparseable(log_dir: Path) -> None:
    map_path = av2_io.find_map_file(log_dir)
    assert map_path is not None
    map_path.write_text('{"lane_segments": {')
    problem = _only(validate_log(log_dir).problems)
    assert problem.path == map_path and "map JSON" in problem.message


def _lane(data: dict) -> dict:
    return data["lane_segments"]["1"]


@pytest.mark.parametrize(
    ("change", "field", "row", "message"),
    [
        pytest.param(lambda d: [], None, None, "got a list", id="map-is-a-list"),
        pytest.param(lambda d: {**d, "lane_segments": list(d["lane_segments"].values())}, "lane_segments", None,
                     "must be an object keyed by id, got a list", id="lane-segments-is-a-list"),
        pytest.param(lambda d: {**d, "drivable_areas": 3}, "drivable_areas", None, "got a number",
                     id="section-is-a-number"),
        pytest.param(lambda d: {**d, "lane_segments": {"1": "lane"}}, "lane_segments[1]", None,
                     "must be an object, got a string", id="element-is-a-string"),
        pytest.param(lambda d: _lane(d).pop("right_lane_boundary") and d, "lane_segments[1].right_lane_boundary",
                     None, "missing key", id="element-missing-key"),
        pytest.param(lambda d: _lane(d).pop("id") and d, "lane_segments[1].id", None, "missing key",
                     id="element-missing-id"),
        pytest.param(lambda d: _lane(d).update(id=[1]) or d, "lane_segments[1].id", None, "integer id",
                     id="id-is-a-list"),
        pytest.param(lambda d: _lane(d).update(left_lane_boundary={"x": 1}) or d,
                     "lane_segments[1].left_lane_boundary", None, "list of {x, y, z} points", id="polyline-is-dict"),
        pytest.param(lambda d: _lane(d).update(left_lane_boundary=[]) or d, "lane_segments[1].left_lane_boundary",
                     None, "no points", id="polyline-empty"),
        pytest.param(lambda d: _lane(d)["left_lane_boundary"][1].pop("y") and d,
                     "lane_segments[1].left_lane_boundary", 1, "point has no 'y'", id="point-missing-y"),
        pytest.param(lambda d: _lane(d)["right_lane_boundary"][0].update(x="far") or d,
                     "lane_segments[1].right_lane_boundary", 0, "must be a number, got a string",
                     id="coordinate-is-a-string"),
        pytest.param(lambda d: _lane(d).update(successors=7) or d, "lane_segments[1].successors", None,
                     "list of ids", id="successors-not-a-list"),
        pytest.param(lambda d: _lane(d).update(successors=[2, None]) or d, "lane_segments[1].successors[1]", None,
                     "integer id", id="successor-is-null"),
    ],
)
def test_bad_map_shape_names_file_and_key(
    log_dir: Path, change: Callable[[dict], object], field: str | None, row: int | None, message: str
) -> None:
    """Each bad shape is one problem naming the map file and the key, in validate and in the reader that
    captioning and clips use (no traceback)."""
    map_path = av2_io.find_map_file(log_dir)
    assert map_path is not None
    map_path.write_text(json.dumps(change(json.loads(map_path.read_text()))))
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.field, problem.row) == (map_path, field, row)
    assert message in problem.message
    with pytest.raises(LogFormatError) as info:
        _ = Log.open(log_dir).map
    assert info.value.problems == [problem]


def test_every_bad_map_element_is_reported(log_dir: Path) -> None:
    map_path = av2_io.find_map_file(log_dir)
    assert map_path is not None
    data = json.loads(map_path.read_text())
    data["lane_segments"]["2"] = {**_lane(data), "id": 2, "lane_type": None}
    del data["lane_segments"]["2"]["is_intersection"]
    del _lane(data)["left_lane_boundary"]
    data["pedestrian_crossings"] = {"5": {"id": 5, "edge1": [{"x": 0, "y": 0}], "edge2": 4}}
    map_path.write_text(json.dumps(data))
    fields = [p.field for p in validate_log(log_dir).problems]
    assert fields == ["lane_segments[1].left_lane_boundary", "lane_segments[2].is_intersection",
                      "pedestrian_crossings[5].edge2"]


def test_map_boolean_written_as_a_string_is_refused(log_dir: Path) -> None:
    map_path = av2_io.find_map_file(log_dir)
    assert map_path is not None
    data = json.loads(map_path.read_text())
    _lane(data)["is_intersection"] = "false"  # truthy as a string: it would read as an intersection
    map_path.write_text(json.dumps(data))
    problem = _only(validate_log(log_dir).problems)
    assert problem.field == "lane_segments[1].is_intersection" and "must be true or false" in problem.message


def test_map_not_utf8(log_dir: Path) -> None:
    map_path = av2_io.find_map_file(log_dir)
    assert map_path is not None
    map_path.write_bytes(b"\xff\xfe{")
    problem = _only(validate_log(log_dir).problems)
    assert problem.path == map_path and "unreadable map JSON" in problem.message


def _edit_map(log_dir: Path, change: Callable[[dict], None]) -> Path:
    """Change the log's map JSON in place; its path."""
    map_path = av2_io.find_map_file(log_dir)
    assert map_path is not None
    data = json.loads(map_path.read_text())
    change(data)
    map_path.write_text(json.dumps(data))
    return map_path


def test_map_nan_coordinate(log_dir: Path) -> None:
    map_path = _edit_map(log_dir, lambda d: _lane(d)["left_lane_boundary"][1].update(y=float("nan")))
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.row, problem.field) == (map_path, 1, "lane_segments[1].left_lane_boundary")


def test_a_map_element_id_given_twice_is_refused(log_dir: Path) -> None:
    map_path = av2_io.find_map_file(log_dir)
    assert map_path is not None
    text = map_path.read_text()
    lanes_at = text.index('"lane_segments": {') + len('"lane_segments": {')
    lane = json.dumps(json.loads(text)["lane_segments"]["1"])
    map_path.write_text(text[:lanes_at] + f'"1": {lane}, ' + text[lanes_at:])  # the lane "1" twice
    problem = _only(validate_log(log_dir).problems)
    assert problem.path == map_path and "key '1' appears twice in one object" in problem.message


@pytest.mark.parametrize("side", ["left_lane_boundary", "right_lane_boundary"])
def test_map_point_thousands_of_km_away_is_refused(log_dir: Path, side: str) -> None:
    # 9,000 km away, inside the bound on city coordinates; named by its own polyline and row
    map_path = _edit_map(log_dir, lambda d: _lane(d)[side][1].update(x=9.0e6))
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.row, problem.field) == (map_path, 1, f"lane_segments[1].{side}")
    assert "km from every ego pose" in problem.message
    with pytest.raises(LogFormatError, match="lane_segments"):
        _ = Log.open(log_dir).map


def test_map_of_another_place_is_refused(log_dir: Path, tmp_path: Path) -> None:
    """Another log's map (here: the same lane 5 km away) covers none of this log's poses."""

    def shift(data: dict) -> None:
        for side in ("left_lane_boundary", "right_lane_boundary"):
            for point in _lane(data)[side]:
                point["x"] += 5000.0

    map_path = _edit_map(log_dir, shift)
    problem = _only(validate_log(log_dir).problems)
    assert problem.path == map_path and "the map is not this log's: only 0 of 9 ego poses" in problem.message
    with pytest.raises(LogFormatError, match="not this log's"):
        _ = Log.open(log_dir).map


def test_lidar_sweep_named_outside_the_log_is_refused(log_dir: Path) -> None:
    sweep = _sweep_path(log_dir)
    odd = sweep.with_name("1.feather")
    odd.write_bytes(sweep.read_bytes())
    problem = _only(_open_problems(log_dir))
    assert (problem.path, problem.field) == (odd, "timestamp_ns (file name)")
    assert "outside the ego poses" in problem.message


def test_a_camera_without_extrinsics_is_a_warning(log_dir: Path) -> None:
    extrinsics = log_dir / av2_io.EXTRINSICS_PATH
    _edit(extrinsics, lambda t: t.filter(pa.array([name != "front" for name in t.column("sensor_name").to_pylist()])))
    report = validate_log(log_dir)
    assert report.ok and any("camera 'front' has 1 frames but no row in calibration/egovehicle_SE3_sensor.feather"
                             in w for w in report.warnings)


def test_camera_frames_of_another_size_than_the_intrinsics_are_refused(log_dir: Path) -> None:
    cam = CameraIntrinsics("front", 500.0, 500.0, 64.0, 48.0, 128, 96)  # the frames are 64 × 48
    av2_io.write_calibration(log_dir, Calibration({"front": SE3.identity()}, {"front": cam}))
    problem = _only(validate_log(log_dir).problems)
    assert problem.path == log_dir / "sensors" / "cameras" / "front" / f"{T0}.jpg"
    assert problem.message == "the image is 64×48 px, the camera's intrinsics say 128×96 px"


def test_ego_quaternions_written_scalar_last_are_refused(log_dir: Path) -> None:
    """(x, y, z, w) in the (qw, qx, qy, qz) columns: still unit quaternions, but the car lies on its side."""
    def scalar_last(t: pa.Table) -> pa.Table:
        w, x, y, z = (t.column(c) for c in ("qw", "qx", "qy", "qz"))
        for name, values in zip(("qw", "qx", "qy", "qz"), (x, y, z, w)):
            t = t.set_column(t.column_names.index(name), name, values)
        return t

    pose_ts = T0 + np.arange(0, 9) * 50_000_000
    t_s = (pose_ts - T0) * 1e-9  # heading north-east: a yaw-only quaternion far from the identity
    av2_io.write_ego_poses(log_dir, EgoTrajectory(pose_ts, yaw_to_quat(1.2 + 0.05 * t_s), np.c_[8 * t_s, 0 * t_s,
                                                                                              0 * t_s]))
    assert validate_log(log_dir).ok
    _edit(log_dir / POSES, scalar_last)
    problem = _only(_open_problems(log_dir))
    assert (problem.path, problem.field, problem.row) == (log_dir / POSES, "qw,qx,qy,qz", 0)
    assert "are the quaternions in (qw, qx, qy, qz) order?" in problem.message


def test_missing_map_is_a_warning(log_dir: Path) -> None:
    for p in (log_dir / "map").iterdir():
        p.unlink()
    report = validate_log(log_dir)
    assert report.ok and report.facts["has_map"] is False
    assert any("no map" in w for w in report.warnings)


def test_calibration_bad_quaternion_and_nan(log_dir: Path) -> None:
    path = log_dir / av2_io.EXTRINSICS_PATH
    _edit(path, lambda t: _set(t, "qw", [3.0], pa.float64()))
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.row, problem.field) == (path, 0, "qw..qz")
    _edit(path, lambda t: _set(t, "tx_m", [float("nan")], pa.float64()))
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.row, problem.field) == (path, 0, "tx_m")


def test_intrinsics_missing_column(log_dir: Path) -> None:
    path = log_dir / av2_io.INTRINSICS_PATH
    _edit(path, lambda t: t.drop_columns(["fy_px"]))
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.field) == (path, "fy_px")


@pytest.mark.parametrize(
    ("column", "value", "message"),
    [
        pytest.param("fx_px", float("nan"), "NaN or inf", id="fx-nan"),
        pytest.param("fy_px", float("inf"), "NaN or inf", id="fy-inf"),
        pytest.param("cx_px", float("nan"), "NaN or inf", id="cx-nan"),
        pytest.param("fx_px", 0.0, "focal length must be positive", id="fx-zero"),
        pytest.param("fy_px", -500.0, "focal length must be positive", id="fy-negative"),
        pytest.param("width_px", 0, "image size must be positive", id="width-zero"),
        pytest.param("k1", float("nan"), "NaN or inf", id="distortion-nan"),
    ],
)
def test_intrinsics_values_must_make_sense(log_dir: Path, column: str, value: float, message: str) -> None:
    path = log_dir / av2_io.INTRINSICS_PATH
    _edit(path, lambda t: _set(t, column, [value], t.column(column).type))
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.row, problem.field) == (path, 0, column)
    assert message in problem.message
    with pytest.raises(LogFormatError, match=column):
        av2_io.read_calibration(log_dir)


def test_every_calibration_problem_of_both_files_is_reported(log_dir: Path) -> None:
    _edit(log_dir / av2_io.EXTRINSICS_PATH, lambda t: _set(t, "qw", [0.0], pa.float64()))
    _edit(log_dir / av2_io.EXTRINSICS_PATH, lambda t: _set(t, "qz", [0.0], pa.float64()))
    _edit(log_dir / av2_io.INTRINSICS_PATH, lambda t: _set(t, "fx_px", [float("nan")], pa.float64()))
    _edit(log_dir / av2_io.INTRINSICS_PATH, lambda t: _set(t, "height_px", [0], t.column("height_px").type))
    with pytest.raises(LogFormatError) as info:
        av2_io.read_calibration(log_dir)
    assert [(p.path.name, p.field) for p in info.value.problems] == [
        ("egovehicle_SE3_sensor.feather", "qw..qz"), ("intrinsics.feather", "fx_px"),
        ("intrinsics.feather", "height_px")]
    assert validate_log(log_dir).problems == info.value.problems


def test_check_rotations_refuses_zeros_scale_and_reflection() -> None:
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    bad = {"zeros": np.zeros((3, 3)), "scaled": 1.1 * turn, "reflection": np.diag([1.0, 1.0, -1.0]),
           "shear": turn + np.array([[0.0, 0.01, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])}
    for name, matrix in bad.items():
        problems = schema.check_rotations(Path("calib"), np.stack([turn, turn, matrix]), "R")
        assert [(p.row, p.field) for p in problems] == [(2, "R")], name
        assert "not a proper rotation" in problems[0].message
    rounded = np.round(turn @ np.array([[0.9999239, 0.0098378, -0.0074450], [-0.0098698, 0.9999421, -0.0042785],
                                        [0.0074025, 0.0043516, 0.9999631]]), 7)  # printed to 7 digits, as KITTI
    assert schema.check_rotations(Path("calib"), rounded[None], "R") == []


def test_camera_frame_not_a_jpeg(log_dir: Path) -> None:
    path = log_dir / av2_io.CAMERAS_DIR / "front" / f"{T0 + 100_000_000}.jpg"
    path.write_bytes(b"")
    problem = _only(validate_log(log_dir).problems)
    assert problem.path == path and "JPEG" in problem.message


def test_a_truncated_camera_frame_is_refused_by_validate_and_the_reader(log_dir: Path) -> None:
    path = log_dir / av2_io.CAMERAS_DIR / "front" / f"{T0}.jpg"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 3])
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.message) == (path, "truncated JPEG (no end-of-image marker)")
    with pytest.raises(LogFormatError, match="truncated JPEG"):
        Log.open(log_dir).camera_frame("front", T0)


def test_unreadable_metadata(log_dir: Path) -> None:
    (log_dir / "log_metadata.json").write_text("[1, 2]")
    problem = _only(validate_log(log_dir).problems)
    assert problem.path.name == "log_metadata.json"


# ---- implausible values, ambiguous files and vague causes: refused by the readers, named by validate


def test_two_map_archives_are_refused_naming_both(log_dir: Path) -> None:
    """An extra (empty) archive beside the map: which one is the log's map is ambiguous, so neither is used."""
    real = av2_io.find_map_file(log_dir)
    assert real is not None
    extra = real.parent / "log_map_archive_extra____PIT_city_1.json"
    extra.write_text(json.dumps({"lane_segments": {}, "pedestrian_crossings": {}, "drivable_areas": {}}))
    with pytest.raises(LogFormatError) as info:
        av2_io.find_map_file(log_dir)
    problem = _only(info.value.problems)
    assert problem.path == real.parent and real.name in problem.message and extra.name in problem.message
    with pytest.raises(LogFormatError):
        _ = Log.open(log_dir).map
    report = validate_log(log_dir)
    assert report.problems == [problem] and not any("no map" in w for w in report.warnings)


def _drop_poses_between(t_from_ns: int, t_to_ns: int) -> Callable[[pa.Table], pa.Table]:
    def change(t: pa.Table) -> pa.Table:
        ts = t.column("timestamp_ns").to_numpy()
        return t.filter(pa.array((ts <= t_from_ns) | (ts >= t_to_ns)))

    return change


def test_gap_in_ego_poses_is_refused_not_interpolated(log_dir: Path) -> None:
    """Poses at 20 Hz with the 5 poses from 50 to 250 ms dropped: annotation frames at 100 and
    200 ms would get poses made up across a 300 ms gap."""
    _edit(log_dir / POSES, _drop_poses_between(T0, T0 + 300_000_000))
    with pytest.raises(LogFormatError) as info:
        Log.open(log_dir, max_pose_gap_s=0.25)
    problem = _only(info.value.problems)
    assert (problem.path.name, problem.field, problem.row) == (POSES, "timestamp_ns", 1)
    for text in (f"ego poses at {T0} (row 0) and {T0 + 300_000_000} (row 1)", "0.300 s apart",
                 "limit of 0.25 s", f"annotation timestamp {T0 + 100_000_000}", "max_pose_gap_s"):
        assert text in problem.message
    assert validate_log(log_dir, max_pose_gap_s=0.25).problems == [problem]
    assert Log.open(log_dir).annotations is not None  # the documented default (1 s) allows 300 ms
    assert validate_log(log_dir).ok


def test_default_pose_gap_limit_refuses_a_long_gap(tmp_path: Path) -> None:
    log_dir = _write_log(tmp_path / "log")
    """Two poses 2 s apart around frames every 400 ms: refused at the default limit, accepted when raised."""
    _edit(log_dir / POSES, lambda t: _set(t.slice(0, 2), "timestamp_ns", [T0, T0 + 2_000_000_000], pa.int64()))
    _edit(log_dir / ANN, lambda t: _set(t, "timestamp_ns", np.repeat(T0 + np.arange(5) * 400_000_000, 3), pa.int64()))
    problem = _only(_open_problems(log_dir))
    assert problem.path.name == POSES and f"limit of {schema.DEFAULT_MAX_POSE_GAP_S:g} s" in problem.message
    assert Log.open(log_dir, max_pose_gap_s=2.5).annotations is not None


def test_annotation_on_a_pose_timestamp_is_not_interpolated(log_dir: Path) -> None:
    """Annotations exactly at pose timestamps (KITTI, WOMD) need no interpolation: sparse poses pass."""
    _edit(log_dir / POSES, lambda t: t.take(pa.array([0, 2, 4, 6, 8])))  # every 100 ms, on the frames
    assert Log.open(log_dir, max_pose_gap_s=0.01).annotations is not None


@pytest.mark.parametrize(
    ("filename", "column", "row", "value", "message"),
    [
        pytest.param(POSES, "tx_m", 2, 1e12, "city-frame coordinate 1e+12 m is beyond the bound of ±1e+07 m",
                     id="pose-far-from-the-city-origin"),
        pytest.param(ANN, "ty_m", 4, 1e12, "ego-frame coordinate 1e+12 m is beyond the bound of ±1000 m",
                     id="box-centre-far-from-the-ego"),
        pytest.param(ANN, "tz_m", 6, -1500.0, "ego-frame coordinate -1500 m", id="box-centre-below-the-ego"),
        pytest.param(ANN, "length_m", 8, 1e9, "box size 1e+09 m exceeds the bound of 60 m", id="box-1e9-m-long"),
    ],
)
def test_implausible_values_name_file_row_field_value_and_bound(
    log_dir: Path, filename: str, column: str, row: int, value: float, message: str
) -> None:
    def edit(t: pa.Table) -> pa.Table:
        values = t.column(column).to_numpy().copy()
        values[row] = value
        return _set(t, column, values, t.column(column).type)

    _edit(log_dir / filename, edit)
    problem = _only(_open_problems(log_dir))
    assert (problem.path.name, problem.row, problem.field) == (filename, row, column)
    assert message in problem.message


def test_poses_shifted_far_away_are_refused(log_dir: Path) -> None:
    """Every pose moved by 1e12 m: no jump between poses, but far beyond any city frame."""
    _edit(log_dir / POSES, lambda t: _set(t, "ty_m", t.column("ty_m").to_numpy() + 1e12, pa.float64()))
    problem = _only(_open_problems(log_dir))
    assert (problem.path.name, problem.row, problem.field) == (POSES, 0, "ty_m")


def test_map_point_far_away_is_refused_by_the_reader(log_dir: Path) -> None:
    map_path = av2_io.find_map_file(log_dir)
    assert map_path is not None
    data = json.loads(map_path.read_text())
    data["lane_segments"]["1"]["right_lane_boundary"][1]["y"] = 1e12
    map_path.write_text(json.dumps(data))
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.row, problem.field) == (map_path, 1, "lane_segments[1].right_lane_boundary")
    assert "y = 1e+12 m is beyond the bound of ±1e+07 m" in problem.message
    with pytest.raises(LogFormatError) as info:
        _ = Log.open(log_dir).map
    assert info.value.problems == [problem]


@pytest.mark.parametrize("path", [av2_io.EXTRINSICS_PATH, av2_io.INTRINSICS_PATH], ids=["extrinsics", "intrinsics"])
def test_calibration_sensor_named_twice_is_refused(log_dir: Path, path: Path) -> None:
    """A second row for the same sensor (with another pose) would silently win by row order."""
    def duplicate(t: pa.Table) -> pa.Table:
        extra = t.slice(0, 1)
        return pa.concat_tables([t, _set(extra, "cx_px" if "cx_px" in t.column_names else "tx_m", [1.0],
                                         pa.float64())])

    _edit(log_dir / path, duplicate)
    problem = _only(validate_log(log_dir).problems)
    assert (problem.path, problem.row, problem.field) == (log_dir / path, 1, "sensor_name")
    assert "'front' appears on rows 0, 1" in problem.message
    with pytest.raises(LogFormatError, match="sensor_name"):
        av2_io.read_calibration(log_dir)


def test_facts_count_annotated_frames_only(log_dir: Path) -> None:
    """A log cut to one annotated frame keeps its sweeps; those neither add frames nor stretch the duration."""
    av2_io.write_lidar_sweep(log_dir, LidarSweep(T0 + 400_000_000, np.ones((5, 3), np.float32), np.zeros(5, np.uint8),
                                                 np.zeros(5, np.uint8), np.zeros(5, np.int32)))
    _edit(log_dir / ANN, lambda t: t.filter(pa.compute.equal(t.column("timestamp_ns"), T0 + 200_000_000)))
    facts = validate_log(log_dir).facts
    assert (facts["frames"], facts["duration_s"], facts["lidar_sweeps"]) == (1, 0.0, 2)


def test_symbolic_link_loop_is_named_as_such(log_dir: Path) -> None:
    (log_dir / ANN).unlink()
    (log_dir / ANN).symlink_to(log_dir / ANN)
    problem = _only(_open_problems(log_dir))
    assert problem.path == log_dir / ANN
    assert problem.message == f"symbolic-link loop: {log_dir / ANN} never resolves to a file"
    (log_dir / POSES).unlink()
    (log_dir / POSES).symlink_to(log_dir / "nowhere.feather")
    assert any("broken symbolic link" in p.message and p.path == log_dir / POSES for p in _open_problems(log_dir))


def test_symbolic_link_loop_as_the_log_folder(tmp_path: Path) -> None:
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    assert "symbolic-link loop" in str(_only(validate_log(tmp_path / "loop").problems))
    with pytest.raises(LogFormatError, match="symbolic-link loop"):
        Log.open(tmp_path / "loop")


def test_pose_timestamps_in_int32_seconds_name_the_unit(log_dir: Path) -> None:
    _edit(log_dir / POSES, lambda t: _set(t, "timestamp_ns", (t.column("timestamp_ns").to_numpy() // 10**9)
                                          .astype(np.int32), pa.int32()))
    problem = _only(_open_problems(log_dir))
    assert (problem.path.name, problem.row, problem.field) == (POSES, None, "timestamp_ns")
    assert "int64 nanoseconds" in problem.message and "int32" in problem.message


@pytest.mark.parametrize(("filename", "divisor"), [(POSES, 10**9), (POSES, 10**6), (ANN, 10**3)],
                         ids=["pose-seconds", "pose-milliseconds", "annotation-microseconds"])
def test_int64_timestamps_in_another_unit_name_the_unit(log_dir: Path, filename: str, divisor: int) -> None:
    """Milliseconds and microseconds look like a MHz stream, and are named as not nanoseconds; seconds
    of a 0.4 s log collapse to one value, and the repeat names the unit it must hold."""
    _edit(log_dir / filename, lambda t: _set(t, "timestamp_ns", t.column("timestamp_ns").to_numpy() // divisor,
                                             pa.int64()))
    problems = _open_problems(log_dir)
    unit = [p for p in problems if p.path.name == filename]
    assert len(unit) == 1 and unit[0].field == "timestamp_ns"
    assert "int64 nanoseconds" in unit[0].message
    assert ("appears twice" if divisor == 10**9 else "not nanoseconds") in unit[0].message


def test_timestamps_starting_near_zero_are_nanoseconds(tmp_path: Path) -> None:
    """WOMD logs start at 0 ns: the unit check looks at the steps, not at the epoch."""
    log_dir = _write_log(tmp_path / "log")
    for name in (ANN, POSES):
        _edit(log_dir / name, lambda t: _set(t, "timestamp_ns", t.column("timestamp_ns").to_numpy() - T0, pa.int64()))
    (log_dir / av2_io.LIDAR_DIR / f"{T0}.feather").rename(log_dir / av2_io.LIDAR_DIR / "0.feather")
    cam = log_dir / av2_io.CAMERAS_DIR / "front"
    (cam / f"{T0}.jpg").rename(cam / "0.jpg")
    assert validate_log(log_dir).ok


# ---- the command


def test_validate_command_exit_status_and_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = _write_log(tmp_path / "good")
    bad = _write_log(tmp_path / "bad")
    _edit(bad / ANN, lambda t: t.drop_columns(["qy"]))
    assert cli_main(["validate", str(good)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"OK {good} (frames=5, tracks=3")
    assert cli_main(["validate", str(good), str(bad)]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("OK ")
    assert lines[1] == f"FAIL {bad}: 1 problem(s)"
    assert lines[2] == f"  {bad / ANN}, field 'qy': missing column"
    assert lines[3] == "1 of 2 logs OK"
    assert cli_main(["validate", "--json", str(good), str(bad)]) == 1
    reports = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["ok"] for r in reports] == [True, False]
    assert reports[1]["problems"] == [{"path": str(bad / ANN), "row": None, "field": "qy", "message": "missing column"}]
    assert reports[0]["facts"]["lidar_sweeps"] == 1


def test_validate_command_checks_every_log_after_bad_ones(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A bad map, bad intrinsics, an unreadable log: each log fails alone and the ones after are checked."""
    bad_map = _write_log(tmp_path / "bad_map")
    map_path = av2_io.find_map_file(bad_map)
    assert map_path is not None
    map_path.write_text("[]")
    bad_calib = _write_log(tmp_path / "bad_calib")
    _edit(bad_calib / av2_io.INTRINSICS_PATH, lambda t: _set(t, "fx_px", [float("nan")], pa.float64()))
    unreadable = _write_log(tmp_path / "unreadable")
    good = _write_log(tmp_path / "good")
    real_validate = validate_log

    def validate_or_fail(log_dir: Path | str, *args: float) -> object:
        if Path(log_dir) == unreadable:
            raise PermissionError(13, "Permission denied", str(unreadable / "sensors"))
        return real_validate(log_dir, *args)

    monkeypatch.setattr("retrieval.commands.validate.validate_log", validate_or_fail)
    assert cli_main(["validate", str(bad_map), str(bad_calib), str(unreadable), str(good)]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines == [
        f"FAIL {bad_map}: 1 problem(s)",
        f"  {map_path}: map JSON must be an object with 'lane_segments', 'pedestrian_crossings' and "
        "'drivable_areas', got a list",
        f"FAIL {bad_calib}: 1 problem(s)",
        f"  {bad_calib / av2_io.INTRINSICS_PATH}, row 0, field 'fx_px': NaN or inf value",
        f"FAIL {unreadable}: 1 problem(s)",
        f"  {unreadable / 'sensors'}: cannot read: Permission denied",
        *[line for line in lines if line.startswith(f"OK {good} ")],
        "1 of 4 logs OK",
    ]
    assert lines[-2].startswith(f"OK {good} ")


def test_validate_command_exit_status_when_nothing_is_ok(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """0: every log OK; 1: some OK, some failed (listed); 2: none OK."""
    bad = _write_log(tmp_path / "bad")
    _edit(bad / ANN, lambda t: t.drop_columns(["qy"]))
    assert cli_main(["validate", str(bad)]) == 2
    assert cli_main(["validate", str(bad), str(tmp_path / "missing")]) == 2
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == "0 of 2 logs OK"


def test_validate_command_reports_a_log_named_twice(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The same folder twice (also through a link), or two folders with one log id: checked once, each
    repeat fails as a duplicate naming the first."""
    good = _write_log(tmp_path / "log1")
    link = tmp_path / "link"
    link.symlink_to(good, target_is_directory=True)
    same_id = _write_log(tmp_path / "elsewhere" / "log1")
    assert cli_main(["validate", str(good), f"{good}/", str(link), str(same_id)]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"OK {good} ")
    assert lines[1:] == [
        f"FAIL {good}: 1 problem(s)",
        f"  {good}: duplicated log in the batch: the same log folder as {good}",
        f"FAIL {link}: 1 problem(s)",
        f"  {link}: duplicated log in the batch: the same log folder as {good}",
        f"FAIL {same_id}: 1 problem(s)",
        f"  {same_id}: duplicated log in the batch: the same log id as {good}",
        "1 of 4 logs OK",
    ]


def test_validate_command_max_pose_gap(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log_dir = _write_log(tmp_path / "log")
    _edit(log_dir / POSES, _drop_poses_between(T0, T0 + 300_000_000))
    assert cli_main(["validate", str(log_dir)]) == 0
    assert cli_main(["validate", "--max-pose-gap-s", "0.2", str(log_dir)]) == 2
    out = capsys.readouterr().out
    assert f"{log_dir / POSES}, row 1, field 'timestamp_ns': ego poses at" in out and "limit of 0.2 s" in out
    assert cli_main(["validate", "--max-pose-gap-s", "0", str(log_dir)]) == 2
    assert "--max-pose-gap-s must be > 0" in capsys.readouterr().err


def test_collect_problems_keeps_going_after_a_bad_file(tmp_path: Path) -> None:
    problems: list[Problem] = []
    assert collect_problems(problems, av2_io.read_ego_poses, tmp_path / POSES) is None
    assert collect_problems(problems, lambda: 7) == 7
    assert [(p.path, p.message) for p in problems] == [(tmp_path / POSES, "file is missing")]
