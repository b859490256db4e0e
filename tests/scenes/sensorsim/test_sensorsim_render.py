"""Rendering a whole log: files in the AV2 layout, readable like a real log; bad objects refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.feather as feather
import pytest

from retrieval.cli import main as cli_main
from scenes import av2_io
from scenes.errors import LogFormatError
from scenes.log import Log
from scenes.metadata import MAP_WITHHELD_KEY, METADATA_FILENAME, LogMetadata
from scenes.sensorsim.config import LIDAR_SENSOR_NAME, SensorConfig
from scenes.sensorsim.errors import BadObjectError
from scenes.sensorsim.instance_masks import instance_mask_dir, read_instance_mask
from scenes.sensorsim.render import check_objects, render_log_sensors
from scenes.sensorsim.synthetic import write_synthetic_log
from scenes.tracks import Annotations, EgoTrajectory, dense_tracks
from tests.realdata import REALDATA

AV2_SWEEP_DIR = REALDATA / "av2" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede" / "sensors" / "lidar"


@pytest.fixture(scope="module")
def rendered_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    small = SensorConfig.from_yaml_text(
        "lidar: {beams: 16, azimuth_steps: 256}\ncamera: {width_px: 160, height_px: 90}\n"
        "world: {raster_resolution_m: 0.25, margin_m: 60.0}\n"
    )
    log_dir = write_synthetic_log(tmp_path_factory.mktemp("logs") / "crossroad", num_frames=8, num_objects=12,
                                  time_of_day="dusk", weather="rain")
    report = render_log_sensors(log_dir, small, progress=False)
    assert report.frames == 8 and report.sweeps_written == 8 and report.camera_frames_written == 8
    return log_dir


def test_log_reads_sweeps_and_frames_at_10_hz(rendered_log: Path) -> None:
    log = Log.open(rendered_log)
    assert np.array_equal(log.lidar_timestamps_ns, log.timestamps_ns)
    assert np.all(np.diff(log.lidar_timestamps_ns) == 100_000_000)
    assert log.camera_names() == ["ring_front_center"]
    assert np.array_equal(log.camera_timestamps_ns("ring_front_center"), log.timestamps_ns)
    sweep = log.lidar_sweep(int(log.timestamps_ns[3]))
    assert len(sweep) > 1000 and sweep.laser_number.max() < 16
    image = log.camera_frame("ring_front_center", int(log.timestamps_ns[3]))
    assert image.shape == (90, 160, 3)
    calib = log.calibration
    assert set(calib.ego_SE3_sensor) >= {LIDAR_SENSOR_NAME, "ring_front_center"}
    assert calib.intrinsics["ring_front_center"].width_px == 160
    assert calib.ego_SE3_sensor[LIDAR_SENSOR_NAME].translation[2] == pytest.approx(1.9)


def test_sweep_columns_match_a_real_av2_sweep(rendered_log: Path) -> None:
    if not AV2_SWEEP_DIR.is_dir():
        pytest.skip(f"real AV2 sweeps not found at {AV2_SWEEP_DIR}")
    real = feather.read_table(sorted(AV2_SWEEP_DIR.glob("*.feather"))[0]).schema
    ours = feather.read_table(sorted((rendered_log / av2_io.LIDAR_DIR).glob("*.feather"))[0]).schema
    assert [(f.name, f.type) for f in ours] == [(f.name, f.type) for f in real]


def test_instance_masks_index_the_log_tracks(rendered_log: Path) -> None:
    log = Log.open(rendered_log)
    dense = log.dense_tracks()
    calib = log.calibration
    cam_SE3_ego = calib.ego_SE3_sensor["ring_front_center"].inverse()
    intr = calib.intrinsics["ring_front_center"]
    checked = 0
    for frame, ts in enumerate(log.timestamps_ns):
        mask, track_ids = read_instance_mask(rendered_log, "ring_front_center", int(ts))
        assert track_ids == [str(t) for t in dense.track_ids]
        assert mask.shape == (90, 160) and mask.dtype == np.uint16
        # Every visible object is a track present in this frame.
        present = {int(k) + 1 for k in np.flatnonzero(dense.valid[:, frame])}
        assert set(np.unique(mask).tolist()) - {0} <= present
        # Box centres in view project onto their own mask, unless a nearer box covers them.
        centers = dense.center_ego_xyz_m[:, frame]
        ok_rows = np.flatnonzero(dense.valid[:, frame])
        cam = cam_SE3_ego.transform_points(centers[ok_rows])
        uv, ok = intr.project(cam)
        # Objects at least 3 pixels wide (a far pedestrian may fall between pixel centres).
        size_px = intr.fx_px * dense.size_lwh_m[ok_rows, frame, :2].min(axis=1) / np.maximum(cam[:, 2], 1e-3)
        for k, (u, v), inside, px in zip(ok_rows, uv, ok, size_px):
            if not inside or px < 3:
                continue
            value = int(mask[int(v), int(u)])
            if value != 0 and value != k + 1:
                # occluded: the other object must be nearer to the camera
                other = centers[value - 1]
                assert np.linalg.norm(other[:2]) < np.linalg.norm(centers[k, :2])
                continue
            assert value == k + 1
            checked += 1
    assert checked >= 5
    assert len(list(instance_mask_dir(rendered_log, "ring_front_center").glob("*.png"))) == 8


def test_render_is_deterministic(rendered_log: Path, tmp_path: Path) -> None:
    small = SensorConfig.from_yaml_text(
        "lidar: {beams: 16, azimuth_steps: 256}\ncamera: {width_px: 160, height_px: 90}\n"
        "world: {raster_resolution_m: 0.25, margin_m: 60.0}\nrender_camera: false\n"
    )
    again = write_synthetic_log(tmp_path / "crossroad", num_frames=8, num_objects=12, time_of_day="dusk",
                                weather="rain")
    render_log_sensors(again, small, progress=False)
    for name in ("1000000000000.feather", "1000300000000.feather"):
        a = (rendered_log / av2_io.LIDAR_DIR / name).read_bytes()
        b = (again / av2_io.LIDAR_DIR / name).read_bytes()
        assert a == b


def _one_box_log(tmp_path: Path, center: tuple[float, float, float], size: tuple[float, float, float]) -> Path:
    log_dir = tmp_path / "box"
    ts = np.array([0, 100_000_000, 200_000_000], dtype=np.int64)
    ann = Annotations.from_yaw(ts, ["obj-7"] * 3, ["REGULAR_VEHICLE"] * 3, np.tile(center, (3, 1)),
                               np.tile(size, (3, 1)), np.zeros(3))
    av2_io.write_annotations(log_dir, ann)
    av2_io.write_ego_poses(log_dir, EgoTrajectory.from_xy_yaw(ts, np.zeros((3, 2)), np.zeros(3)))
    return log_dir


def test_object_holding_the_sensor_is_refused_before_writing(tmp_path: Path) -> None:
    log_dir = _one_box_log(tmp_path, (1.4, 0.0, 1.0), (5.0, 2.0, 2.0))
    with pytest.raises(BadObjectError, match=r"track 'obj-7', frame 0 .*holds the sensor") as info:
        render_log_sensors(log_dir, progress=False)
    assert info.value.track_id == "obj-7" and info.value.frame == 0
    assert not (log_dir / "sensors").exists() and not (log_dir / "calibration").exists()


def test_non_positive_size_names_the_track(tmp_path: Path) -> None:
    ts = np.array([0, 100_000_000], dtype=np.int64)
    ann = Annotations.from_yaw(ts, ["ok", "flat"], ["BUS", "BUS"], np.array([[10.0, 0, 1], [20.0, 0, 1]]),
                               np.array([[4.0, 2, 2], [4.0, 0.0, 2]]), np.zeros(2))
    dense = dense_tracks(ann, EgoTrajectory.from_xy_yaw(ts, np.zeros((2, 2)), np.zeros(2)))
    with pytest.raises(BadObjectError, match=r"track 'flat', frame 1 .*field 'width_m'"):
        check_objects(dense, SensorConfig(), tmp_path / "annotations.feather")
    # On disk, the log reader refuses such a box first, naming the file and field.
    log_dir = _one_box_log(tmp_path, (10.0, 0.0, 1.0), (4.0, 2.0, -1.0))
    with pytest.raises(LogFormatError, match="height_m"):
        render_log_sensors(log_dir, progress=False)


def test_log_without_map_or_objects_in_view(tmp_path: Path) -> None:
    log_dir = _one_box_log(tmp_path, (-30.0, 0.0, 1.0), (4.0, 2.0, 2.0))  # behind the ego
    config = SensorConfig.from_yaml_text("lidar: {beams: 8, azimuth_steps: 64}\ncamera: {width_px: 64, height_px: 36}\n"
                                         "world: {margin_m: 20.0, raster_resolution_m: 0.5}\n")
    report = render_log_sensors(log_dir, config, progress=False)
    assert report.empty_camera_frames == 3
    mask, _ = read_instance_mask(log_dir, "ring_front_center", 0)
    assert not mask.any()


def test_a_simulated_log_whose_map_was_withheld_is_not_rendered_on_bare_ground(tmp_path: Path) -> None:
    log_dir = _one_box_log(tmp_path, (10.0, 0.0, 1.0), (4.0, 2.0, 2.0))
    av2_io.write_metadata(log_dir, LogMetadata("box", source="sumo", extra={MAP_WITHHELD_KEY: True}))
    with pytest.raises(LogFormatError, match=rf"{METADATA_FILENAME}.*extra.{MAP_WITHHELD_KEY}.*simulate the log again"):
        render_log_sensors(log_dir, progress=False)
    assert not (log_dir / "sensors").exists() and not (log_dir / "calibration").exists()


def test_cli_renders_and_reports_skipped_logs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = write_synthetic_log(tmp_path / "good", num_frames=3, num_objects=4)
    bad = _one_box_log(tmp_path / "b", (1.4, 0.0, 1.0), (5.0, 2.0, 2.0))
    status = cli_main(["render-sensors", str(good), str(bad), "--beams", "8", "--azimuth-steps", "64", "--width",
                       "64", "--height", "36", "--quiet", "--seed", "3"])
    assert status == 1
    out = capsys.readouterr()
    assert "good: 3 frames" in out.out
    assert "skipped" in out.err and "obj-7" in out.err
    assert Log.open(good).calibration.intrinsics["ring_front_center"].width_px == 64
