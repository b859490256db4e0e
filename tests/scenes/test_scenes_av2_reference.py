"""The readers against av2-api, the reference readers of the AV2 layout, on the development logs.

Both read the same files: ego poses, cuboids (in the ego and, composed with the ego pose, the city
frame), sensor extrinsics and intrinsics, and every map element. av2-api is a test dependency,
installed without its own dependencies (``make install`` does it); the tests skip without it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from scenes import av2_io
from scenes.geometry import quat_to_rotmat
from scenes.log import Log
from tests.scenes.av2_fixtures import DEV_LOGS, VARIANTS, require, rewritten_log

pytest.importorskip("av2", reason="av2-api is not installed (make install adds it: pip install --no-deps av2==0.3.6)")
try:  # the reference readers; av2 comes without its dependencies, so name the one that is missing
    from av2.geometry.camera.pinhole_camera import PinholeCamera
    from av2.map.map_api import ArgoverseStaticMap
    from av2.structures.cuboid import CuboidList
    from av2.utils.io import read_city_SE3_ego, read_ego_SE3_sensor, read_feather
except ModuleNotFoundError as exc:
    pytest.skip(f"av2-api is installed but its readers need '{exc.name}', which is not (make install adds it)",
                allow_module_level=True)

ATOL = 1e-9


@pytest.fixture(scope="module", params=sorted(DEV_LOGS))
def log_dir(request: pytest.FixtureRequest) -> Path:
    return require(DEV_LOGS[request.param])


def test_ego_poses(log_dir: Path) -> None:
    reference = read_city_SE3_ego(log_dir)
    ego = av2_io.read_ego_poses(log_dir / av2_io.POSES_FILENAME)
    assert ego.timestamps_ns.tolist() == sorted(int(ts) for ts in reference)
    rotation = np.stack([reference[ts].rotation for ts in ego.timestamps_ns])
    translation = np.stack([reference[ts].translation for ts in ego.timestamps_ns])
    np.testing.assert_allclose(ego.rotation, rotation, atol=ATOL)
    np.testing.assert_allclose(ego.translation_m, translation, atol=ATOL)


def _reference_cuboids(log_dir: Path) -> dict[str, Any]:
    """Every cuboid av2-api reads, in file order, with the track id of its row (a cuboid has none)."""
    path = log_dir / av2_io.ANNOTATIONS_FILENAME
    cuboids = CuboidList.from_feather(path).cuboids
    poses = read_city_SE3_ego(log_dir)
    return {
        "timestamp_ns": np.array([c.timestamp_ns for c in cuboids], dtype=np.int64),
        "track_id": read_feather(path)["track_uuid"].to_numpy().astype(str),
        "category": np.array([c.category for c in cuboids], dtype=str),
        "size_lwh_m": np.array([[c.length_m, c.width_m, c.height_m] for c in cuboids]),
        "rotation": np.stack([c.dst_SE3_object.rotation for c in cuboids]),
        "center_xyz_m": np.stack([c.dst_SE3_object.translation for c in cuboids]),
        "center_city_xyz_m": np.stack([poses[c.timestamp_ns].compose(c.dst_SE3_object).translation for c in cuboids]),
    }


def _check_cuboids(log_dir: Path, reference_dir: Path | None = None) -> None:
    """Our annotations of ``log_dir`` are av2-api's cuboids of it, row for row (matched by timestamp and
    track), and our city-frame centres are av2-api's pose ∘ cuboid."""
    ref = _reference_cuboids(log_dir)
    log = Log.open(log_dir)
    ann = log.annotations
    assert len(ann) == ref["timestamp_ns"].shape[0]
    order = np.lexsort((ref["track_id"], ref["timestamp_ns"]))  # our rows are in (timestamp, track id) order
    np.testing.assert_array_equal(ann.timestamp_ns, ref["timestamp_ns"][order])
    np.testing.assert_array_equal(ann.track_id, ref["track_id"][order])
    np.testing.assert_array_equal(ann.category, ref["category"][order])
    np.testing.assert_allclose(ann.size_lwh_m, ref["size_lwh_m"][order], atol=ATOL)
    np.testing.assert_allclose(ann.center_xyz_m, ref["center_xyz_m"][order], atol=ATOL)
    np.testing.assert_allclose(quat_to_rotmat(ann.quat_wxyz), ref["rotation"][order], atol=ATOL)
    # City frame: every non-ego row of the reference against the track views.
    tracks = log.tracks()
    ours = {(str(tid), int(ts)): xyz
            for tid, t in tracks.items() for ts, xyz in zip(t.timestamps_ns, t.center_city_xyz_m)}
    keep = ref["category"] != "EGO_VEHICLE"
    assert len(ours) == int(keep.sum())
    for i in np.flatnonzero(keep)[::17]:
        np.testing.assert_allclose(ours[(ref["track_id"][i], int(ref["timestamp_ns"][i]))],
                                   ref["center_city_xyz_m"][i], atol=1e-6)


def test_cuboids(log_dir: Path) -> None:
    _check_cuboids(log_dir)


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_cuboids_in_any_row_order(tmp_path: Path, variant: str) -> None:
    """Files av2-api reads whatever their row order (shuffled, grouped by track, ``EGO_VEHICLE`` rows
    appended) read the same with both."""
    source = require(DEV_LOGS["7fab2350"])
    _check_cuboids(rewritten_log(source, tmp_path / source.name, VARIANTS[variant]))


def test_calibration() -> None:
    log_dir = require(DEV_LOGS["7fab2350"])  # the development log with calibration files
    calibration = av2_io.read_calibration(log_dir)
    reference = read_ego_SE3_sensor(log_dir)
    assert sorted(calibration.ego_SE3_sensor) == sorted(reference)
    for name, pose in reference.items():
        np.testing.assert_allclose(calibration.ego_SE3_sensor[name].rotation, pose.rotation, atol=ATOL)
        np.testing.assert_allclose(calibration.ego_SE3_sensor[name].translation, pose.translation, atol=ATOL)
    assert calibration.camera_names()
    for name in calibration.camera_names():
        camera = PinholeCamera.from_feather(log_dir, name)
        ours = calibration.intrinsics[name]
        np.testing.assert_allclose(ours.K, camera.intrinsics.K, atol=ATOL)
        assert (ours.width_px, ours.height_px) == (camera.width_px, camera.height_px)


def _lane_view(lane: Any, reference: bool) -> tuple[Any, ...]:
    left = lane.left_lane_boundary.xyz if reference else lane.left_lane_boundary
    right = lane.right_lane_boundary.xyz if reference else lane.right_lane_boundary
    lane_type = lane.lane_type.value if reference else lane.lane_type
    marks = (lane.left_mark_type.value, lane.right_mark_type.value) if reference else (
        lane.left_lane_mark_type, lane.right_lane_mark_type)
    return (np.round(left, 9).tolist(), np.round(right, 9).tolist(), lane_type, marks, bool(lane.is_intersection),
            sorted(lane.successors), sorted(lane.predecessors), lane.left_neighbor_id, lane.right_neighbor_id)


def test_map_elements(log_dir: Path) -> None:
    map_path = av2_io.find_map_file(log_dir)
    assert map_path is not None
    ours = av2_io.read_map(map_path)
    reference = ArgoverseStaticMap.from_json(map_path)
    assert sorted(ours.lane_segments) == sorted(reference.vector_lane_segments)
    for lane_id, lane in reference.vector_lane_segments.items():
        assert _lane_view(ours.lane_segments[lane_id], False) == _lane_view(lane, True), lane_id
    assert sorted(ours.pedestrian_crossings) == sorted(reference.vector_pedestrian_crossings)
    for crossing_id, crossing in reference.vector_pedestrian_crossings.items():
        np.testing.assert_allclose(ours.pedestrian_crossings[crossing_id].edge1, crossing.edge1.xyz, atol=ATOL)
        np.testing.assert_allclose(ours.pedestrian_crossings[crossing_id].edge2, crossing.edge2.xyz, atol=ATOL)
    assert sorted(ours.drivable_areas) == sorted(reference.vector_drivable_areas)
    for area_id, area in reference.vector_drivable_areas.items():
        # av2-api closes the polygon by repeating its first vertex; ours keeps the file's vertices.
        np.testing.assert_array_equal(area.xyz[-1], area.xyz[0])
        np.testing.assert_allclose(ours.drivable_areas[area_id].area_boundary, area.xyz[:-1], atol=ATOL)
    assert len(ours.lane_segments) > 50 and ours.pedestrian_crossings and ours.drivable_areas
