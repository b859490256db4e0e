"""Every AV2-layout writer round-trips through its reader, and writes are atomic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scenes import av2_io
from scenes.calibration import Calibration, CameraIntrinsics
from scenes.errors import MapFormatError
from scenes.geometry import SE3, yaw_to_quat
from scenes.log import Log
from scenes.map import DrivableArea, LaneSegment, PedestrianCrossing, VectorMap
from scenes.metadata import LogMetadata
from scenes.sensors import LidarSweep
from scenes.tracks import Annotations, EgoTrajectory

T0 = 1_600_000_000_000_000_000


def _annotations(rng: np.random.Generator) -> Annotations:
    n_frames, n_tracks = 6, 4
    ts = np.repeat(T0 + np.arange(n_frames) * 100_000_000, n_tracks)
    ids = np.tile([f"t{k}" for k in range(n_tracks)], n_frames)
    cats = np.tile(["REGULAR_VEHICLE", "PEDESTRIAN", "BUS", "BICYCLIST"], n_frames)
    quat = rng.normal(size=(len(ts), 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    return Annotations(ts, ids, cats, rng.normal(size=(len(ts), 3)) * 20, rng.uniform(0.5, 5, (len(ts), 3)), quat,
                       rng.integers(0, 500, len(ts)))


def _ego(n: int = 31) -> EgoTrajectory:
    ts = T0 - 50_000_000 + np.arange(n) * 20_000_000
    t_s = (ts - ts[0]) * 1e-9
    return EgoTrajectory(ts, yaw_to_quat(0.1 * t_s), np.c_[5 * t_s, 0.5 * t_s, 0.01 * t_s])


def test_annotations_round_trip(tmp_path: Path) -> None:
    ann = _annotations(np.random.default_rng(1))
    shuffled = ann.select(np.random.default_rng(2).permutation(len(ann)))
    path = av2_io.write_annotations(tmp_path, shuffled)
    back = av2_io.read_annotations(path)
    expect = ann.sorted()
    np.testing.assert_array_equal(back.timestamp_ns, expect.timestamp_ns)
    np.testing.assert_array_equal(back.track_id, expect.track_id)
    np.testing.assert_array_equal(back.category, expect.category)
    np.testing.assert_array_equal(back.center_xyz_m, expect.center_xyz_m)
    np.testing.assert_array_equal(back.size_lwh_m, expect.size_lwh_m)
    np.testing.assert_array_equal(back.quat_wxyz, expect.quat_wxyz)
    np.testing.assert_array_equal(back.num_interior_pts, expect.num_interior_pts)


def test_ego_poses_round_trip(tmp_path: Path) -> None:
    ego = _ego()
    back = av2_io.read_ego_poses(av2_io.write_ego_poses(tmp_path, ego))
    np.testing.assert_array_equal(back.timestamps_ns, ego.timestamps_ns)
    np.testing.assert_array_equal(back.quat_wxyz, ego.quat_wxyz)
    np.testing.assert_array_equal(back.translation_m, ego.translation_m)


def test_map_round_trip(tmp_path: Path) -> None:
    left = np.array([[0.0, 1.75, 0.0], [50.0, 1.75, 0.1]])
    right = np.array([[0.0, -1.75, 0.0], [25.0, -1.75, 0.05], [50.0, -1.75, 0.1]])
    vector_map = VectorMap(
        {7: LaneSegment(7, False, "VEHICLE", left, right, "DASHED_WHITE", "SOLID_WHITE", (8,), (6,), None, 9)},
        {3: PedestrianCrossing(3, np.array([[10.0, -2, 0], [10, 2, 0]]), np.array([[13.0, -2, 0], [13, 2, 0]]))},
        {1: DrivableArea(1, np.array([[0.0, -5, 0], [50, -5, 0], [50, 5, 0], [0, 5, 0]]))},
    )
    path = av2_io.write_map(tmp_path, vector_map, "log1", "SIM")
    assert av2_io.find_map_file(tmp_path) == path
    back = av2_io.read_map(path)
    lane = back.lane_segments[7]
    np.testing.assert_array_equal(lane.right_lane_boundary, right)
    assert (lane.successors, lane.predecessors, lane.right_neighbor_id, lane.left_neighbor_id) == ((8,), (6,), 9, None)
    assert lane.left_lane_mark_type == "DASHED_WHITE"
    np.testing.assert_array_equal(back.pedestrian_crossings[3].edge2, vector_map.pedestrian_crossings[3].edge2)
    np.testing.assert_array_equal(back.drivable_areas[1].area_boundary, vector_map.drivable_areas[1].area_boundary)
    np.testing.assert_allclose(lane.centerline(3)[:, 1], 0.0, atol=1e-12)


def test_calibration_round_trip(tmp_path: Path) -> None:
    cam = CameraIntrinsics("ring_front_center", 1700.0, 1690.0, 780.0, 1020.0, 1550, 2048, -0.2, 0.1, -0.01)
    pose = SE3.from_quat(np.array([0.5, -0.5, 0.5, -0.5]), np.array([1.6, 0.0, 1.4]))
    av2_io.write_calibration(tmp_path, Calibration({"ring_front_center": pose, "lidar": SE3.identity()},
                                                   {"ring_front_center": cam}))
    back = av2_io.read_calibration(tmp_path)
    assert back.intrinsics["ring_front_center"] == cam
    np.testing.assert_allclose(back.ego_SE3_sensor["ring_front_center"].matrix, pose.matrix, atol=1e-12)
    np.testing.assert_allclose(back.ego_SE3_sensor["lidar"].matrix, np.eye(4))
    assert av2_io.read_calibration(tmp_path / "nowhere") == Calibration()


def test_lidar_sweep_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    n = 1000
    sweep = LidarSweep(
        T0, (rng.normal(size=(n, 3)) * 30).astype(np.float32), rng.integers(0, 256, n).astype(np.uint8),
        rng.integers(0, 64, n).astype(np.uint8), rng.integers(0, 100_000_000, n).astype(np.int32),
    )
    path = av2_io.write_lidar_sweep(tmp_path, sweep)
    assert path.name == f"{T0}.feather"
    from scenes.sensors import read_lidar_sweep

    back = read_lidar_sweep(path)
    assert back.timestamp_ns == T0
    # AV2 stores coordinates as float16: about 3 significant digits.
    np.testing.assert_allclose(back.xyz_m, sweep.xyz_m, rtol=1e-3, atol=1e-3)
    np.testing.assert_array_equal(back.intensity, sweep.intensity)
    np.testing.assert_array_equal(back.laser_number, sweep.laser_number)
    np.testing.assert_array_equal(back.offset_ns, sweep.offset_ns)
    from scenes.sensors import read_lidar_points

    points = read_lidar_points(path)
    np.testing.assert_array_equal(points, back.xyz_m)
    assert points.dtype == np.float32 and points.T.flags.c_contiguous  # (3, N) rows, as rasters read them


def test_camera_frame_round_trip(tmp_path: Path) -> None:
    yy, xx = np.mgrid[0:48, 0:64]
    image = np.stack([xx * 4, yy * 5, (xx + yy) * 2], axis=-1).astype(np.uint8)
    path = av2_io.write_camera_frame(tmp_path, "ring_front_center", T0, image, jpeg_quality=95)
    from scenes.sensors import read_camera_frame

    back = read_camera_frame(path)
    assert back.shape == image.shape and back.dtype == np.uint8
    assert np.abs(back.astype(int) - image.astype(int)).mean() < 3.0


def test_metadata_round_trip(tmp_path: Path) -> None:
    meta = LogMetadata("log1", "kitti", "KITTI", {"weather": "rain"}, {"dropped_dontcare": 3, "sequence": "0001"})
    av2_io.write_metadata(tmp_path, meta)
    assert av2_io.read_metadata(tmp_path) == meta
    assert av2_io.read_metadata(tmp_path / "nowhere") is None


def test_full_log_round_trip_through_log_open(tmp_path: Path) -> None:
    ann = _annotations(np.random.default_rng(4))
    log_dir = tmp_path / "log1"
    av2_io.write_annotations(log_dir, ann)
    av2_io.write_ego_poses(log_dir, _ego())
    av2_io.write_metadata(log_dir, LogMetadata("log1", "sumo", "SIM"))
    log = Log.open(log_dir)
    assert log.log_id == "log1"
    assert len(log.timestamps_ns) == 6
    assert len(log.tracks()) == 4
    assert log.metadata.source == "sumo"
    assert log.map is None and log.calibration == Calibration()


def test_writes_are_atomic_on_failure(tmp_path: Path) -> None:
    ego = _ego()
    path = av2_io.write_ego_poses(tmp_path, ego)
    before = path.read_bytes()

    class Boom(RuntimeError):
        pass

    def broken(_: Path) -> None:
        raise Boom

    from scenesearch_base.atomic import atomic_write_with

    with pytest.raises(Boom):
        atomic_write_with(path, broken)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temp file left behind


def test_map_files_with_the_same_bytes_share_one_parse(tmp_path: Path) -> None:
    left = np.array([[0.0, 1.75, 0.0], [50.0, 1.75, 0.0]])
    right = np.array([[0.0, -1.75, 0.0], [50.0, -1.75, 0.0]])
    lane = LaneSegment(7, False, "VEHICLE", left, right, "NONE", "NONE", (), (), None, None)
    first = av2_io.write_map(tmp_path / "a", VectorMap({7: lane}), "a")
    second = tmp_path / "b" / "map" / first.name
    second.parent.mkdir(parents=True)
    second.write_bytes(first.read_bytes())
    av2_io.forget_parsed_maps()
    shared = av2_io.read_map(first)
    assert av2_io.read_map(second) is shared
    with pytest.raises(ValueError):  # shared between logs, so nobody may write into it
        shared.lane_segments[7].left_lane_boundary[0, 0] = 1.0
    # Rewritten in place: other bytes, a new parse.
    moved = LaneSegment(7, False, "VEHICLE", left + 1.0, right + 1.0, "NONE", "NONE", (), (), None, None)
    av2_io.write_map(tmp_path / "a", VectorMap({7: moved}), "a")
    np.testing.assert_array_equal(av2_io.read_map(first).lane_segments[7].left_lane_boundary, left + 1.0)


def test_map_points_of_every_json_number_kind(tmp_path: Path) -> None:
    """The fast path takes ints and floats, z optional; bools and strings still get the named error."""
    good = {"lane_segments": {"1": {"id": 1, "is_intersection": False, "lane_type": "VEHICLE",
                                    "left_lane_boundary": [{"x": 0, "y": 1.5}, {"x": 10.0, "y": 1, "z": 2}],
                                    "right_lane_boundary": [{"x": 0, "y": -1, "z": 0.5}, {"x": 10, "y": -1, "z": 0}],
                                    "left_lane_mark_type": "NONE", "right_lane_mark_type": "NONE",
                                    "successors": [], "predecessors": []}}}
    lane = VectorMap.from_json_dict(good).lane_segments[1]
    np.testing.assert_array_equal(lane.left_lane_boundary, [[0, 1.5, 0], [10, 1, 2]])
    bad = dict(good["lane_segments"]["1"], right_lane_boundary=[{"x": 0, "y": True}, {"x": "1", "y": 0}])
    with pytest.raises(MapFormatError, match="right_lane_boundary") as err:
        VectorMap.from_json_dict({"lane_segments": {"1": bad}})
    assert "must be a number" in str(err.value)
