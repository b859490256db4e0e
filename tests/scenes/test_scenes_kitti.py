"""KITTI tracking import: the camera → ego frame conversion (properties), bad input, the command,
and facts about the real development sequences in ../shared/realdata."""

from __future__ import annotations

import json
import re
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from retrieval.cli import main as cli_main
from scenes.errors import ImportFormatError
from scenes.geometry import SE3, quat_to_rotmat, quat_to_yaw, wrap_angle_rad
from scenes.kitti import (
    DEFAULT_IMAGE_SIZE_PX,
    FRAME_PERIOD_NS,
    KITTI_EPOCH_NS,
    VELODYNE_HEIGHT_M,
    KittiCalibration,
    ego_boxes_to_kitti,
    import_kitti_sequence,
    kitti_boxes_to_ego,
    read_kitti_calibration,
)
from scenes.log import Log
from scenes.validate import validate_log
from tests.realdata import REALDATA

KITTI = REALDATA / "kitti_tracking"
DEV_SEQUENCES = [f"{i:04d}" for i in range(11)]  # 0000–0010 are for development; 0011–0020 are reserved

# Nominal KITTI geometry: Velodyne x fwd / y left / z up → camera x right / y down / z fwd.
NOMINAL_VELO_TO_CAM = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.27]])
CALIB_TEXT = (
    "P0: 700 0 600 0 0 700 170 0 0 0 1 0\n"
    "P2: 700 0 600 45 0 700 170 0.2 0 0 1 0.003\n"
    "R0_rect: 1 0 0 0 1 0 0 0 1\n"
    "Tr_velo_to_cam: " + " ".join(str(v) for v in NOMINAL_VELO_TO_CAM.ravel()) + "\n"
)


def _nominal(rotation_perturbation: np.ndarray | None = None) -> KittiCalibration:
    velo_to_cam = NOMINAL_VELO_TO_CAM.copy()
    if rotation_perturbation is not None:
        velo_to_cam[:, :3] = rotation_perturbation @ velo_to_cam[:, :3]
    p2 = np.array([[700.0, 0, 600, 45], [0, 700, 170, 0.2], [0, 0, 1, 0.003]])
    return KittiCalibration(p2, np.eye(3), velo_to_cam)


def _corners_kitti(bottom: np.ndarray, hwl: np.ndarray, ry: float) -> np.ndarray:
    """(8, 3) box corners in the camera frame, exactly as the KITTI devkit computes them."""
    h, w, length = hwl
    x = np.array([length, length, -length, -length, length, length, -length, -length]) / 2
    y = np.array([0, 0, 0, 0, -h, -h, -h, -h])
    z = np.array([w, -w, -w, w, w, -w, -w, w]) / 2
    rot = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    return (rot @ np.stack([x, y, z])).T + bottom


def _corners_av2(center: np.ndarray, lwh: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """(8, 3) corners of an AV2 cuboid (x length, y width, z height) in its parent frame."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    return (quat_to_rotmat(quat) @ (signs * lwh / 2).T).T + center


def _sorted_rows(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(np.round(a, 6).T[::-1])]


small = st.floats(-0.05, 0.05, allow_nan=False)
box = st.tuples(
    st.floats(-30, 30, allow_nan=False), st.floats(-1, 3, allow_nan=False), st.floats(2, 80, allow_nan=False),
    st.floats(0.5, 4, allow_nan=False), st.floats(0.4, 3, allow_nan=False), st.floats(0.3, 15, allow_nan=False),
    st.floats(-np.pi, np.pi, allow_nan=False),
)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(box, st.tuples(small, small, small))
def test_camera_box_to_ego_and_back(values: tuple[float, ...], tilt: tuple[float, float, float]) -> None:
    x, y, z, h, w, length, ry = values
    perturb = SE3.from_quat(np.array([1.0, *tilt]), np.zeros(3)).rotation
    calib = _nominal(perturb)
    bottom = np.array([[x, y, z]])
    center, quat = kitti_boxes_to_ego(bottom, np.array([h]), np.array([ry]), calib.ego_SE3_cam)
    # The same physical box: the devkit's corners mapped to ego equal the AV2 cuboid's corners.
    expect = calib.ego_SE3_cam.transform_points(_corners_kitti(bottom[0], np.array([h, w, length]), ry))
    got = _corners_av2(center[0], np.array([length, w, h]), quat[0])
    np.testing.assert_allclose(_sorted_rows(got), _sorted_rows(expect), atol=1e-6)
    # And back.
    bottom_back, ry_back = ego_boxes_to_kitti(center, np.array([h]), quat, calib.ego_SE3_cam)
    np.testing.assert_allclose(bottom_back, bottom, atol=1e-9)
    assert float(wrap_angle_rad(ry_back[0] - ry)) == pytest.approx(0.0, abs=1e-9)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(box)
def test_nominal_calibration_gives_the_textbook_relation(values: tuple[float, ...]) -> None:
    x, y, z, h, _, _, ry = values
    calib = _nominal()
    center, quat = kitti_boxes_to_ego(np.array([[x, y, z]]), np.array([h]), np.array([ry]), calib.ego_SE3_cam)
    # yaw_lidar = −ry − π/2; forward = camera z (less the 0.27 m offset), left = −camera x, up = −camera y.
    assert float(wrap_angle_rad(quat_to_yaw(quat)[0] - (-ry - np.pi / 2))) == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(center[0], [z + 0.27, -x, VELODYNE_HEIGHT_M - y - 0.08 + h / 2], atol=1e-9)


def test_heading_directions() -> None:
    calib = _nominal()
    # ry = −π/2: the object faces the camera's forward axis, i.e. ego +x; ry = 0 faces right (ego −y).
    _, quat = kitti_boxes_to_ego(np.zeros((2, 3)), np.ones(2), np.array([-np.pi / 2, 0.0]), calib.ego_SE3_cam)
    np.testing.assert_allclose(quat_to_yaw(quat), [0.0, -np.pi / 2], atol=1e-12)


# ---- bad input (synthetic files)

LABEL_OK = (
    "0 -1 DontCare -1 -1 -10 1 2 3 4 -1000 -1000 -1000 -10 -1 -1 -1\n"
    "0 0 Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 2.0 1.7 20.0 -1.57\n"
    "0 1 Pedestrian 0 0 -1.5 10 20 30 40 1.8 0.6 0.8 -3.0 1.7 15.0 0.0\n"
    "1 0 Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 2.0 1.7 19.0 -1.57\n"
    "1 2 Zeppelin 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 8.0 1.7 30.0 0.0\n"
    "2 -1 DontCare -1 -1 -10 1 2 3 4 -1000 -1000 -1000 -10 -1 -1 -1\n"
)


def _pose_lines(n: int, step_m: float = 1.0) -> str:
    return "".join(f"1 0 0 0 0 1 0 0 0 0 1 {i * step_m}\n" for i in range(n))


def _inputs(tmp_path: Path, labels: str = LABEL_OK, poses: str | None = None, seq: str = "0042") -> dict[str, Path]:
    paths = {"labels": tmp_path / "label_02" / f"{seq}.txt", "poses": tmp_path / "poses" / f"{seq}.txt",
             "calib": tmp_path / "calib" / f"{seq}.txt"}
    for p in paths.values():
        p.parent.mkdir(parents=True, exist_ok=True)
    paths["labels"].write_text(labels)
    paths["poses"].write_text(_pose_lines(3) if poses is None else poses)
    paths["calib"].write_text(CALIB_TEXT)
    return paths


def _import(paths: dict[str, Path], out: Path, overwrite: bool = False) -> Path:
    return import_kitti_sequence(paths["labels"], paths["poses"], paths["calib"], out, overwrite=overwrite).log_dir


def test_synthetic_import_counts_and_maps(tmp_path: Path) -> None:
    paths = _inputs(tmp_path)
    report = import_kitti_sequence(paths["labels"], paths["poses"], paths["calib"], tmp_path / "out")
    assert report.log_dir == tmp_path / "out" / "kitti_0042"
    assert (report.frames, report.rows, report.tracks, report.dropped_dontcare) == (3, 4, 3, 2)
    assert report.unknown_types == {"Zeppelin": 1}
    assert "skipped 2 DontCare rows" in report.summary() and "Zeppelin=1" in report.summary()
    log = Log.open(report.log_dir)
    assert log.metadata.source == "kitti"
    assert log.metadata.extra["dropped_dontcare"] == 2
    assert log.metadata.extra["sequence"] == "0042"
    assert log.metadata.extra["frames"] == 3
    assert log.metadata.extra["kitti_type_counts"] == {"Car": 2, "Pedestrian": 1, "Zeppelin": 1}
    assert sorted(set(log.annotations.category)) == ["PEDESTRIAN", "REGULAR_VEHICLE", "WHEELED_DEVICE"]
    tracks = log.tracks()
    assert tracks["2"].category.value == "other"
    np.testing.assert_array_equal(log.timestamps_ns, KITTI_EPOCH_NS + np.array([0, 1]) * FRAME_PERIOD_NS)
    # The camera moves 1 m forward per frame (+z); the parked car at z=20 → 19 in the camera stays put.
    np.testing.assert_allclose(np.ptp(tracks["0"].center_city_xyz_m, axis=0), 0.0, atol=1e-9)
    np.testing.assert_allclose(log.ego.translation_m[:, 0], [0.0, 1.0, 2.0], atol=1e-9)
    calibration = log.calibration
    assert calibration.intrinsics["image_02"].width_px == DEFAULT_IMAGE_SIZE_PX[0]
    # P2 = K·[I | t]: camera 2 sits at −t in the reference camera, about 6 cm to its left (+y in ego).
    t = np.linalg.solve(np.array([[700.0, 0, 600], [0, 700, 170], [0, 0, 1]]), np.array([45, 0.2, 0.003]))
    ref = _nominal().ego_SE3_cam.translation
    np.testing.assert_allclose(calibration.ego_SE3_sensor["image_02"].translation - ref, [-t[2], t[0], t[1]],
                               atol=1e-12)
    assert validate_log(report.log_dir).ok


@pytest.mark.parametrize(
    ("labels", "line", "field", "message"),
    [
        ("0 0 Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 2.0 1.7 20.0\n", 1, None, "expected 17 columns"),
        (LABEL_OK + "3 0 Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 2.0 1.7 20.0 -1.57 0.9 extra\n", 7, None, "got 19"),
        ("0 0 Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 two 1.7 20.0 -1.57\n", 1, "x", "not a number"),
        ("0 0 Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 2.0 nan 20.0 -1.57\n", 1, "y", "NaN"),
        ("zero 0 Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 2.0 1.7 20.0 -1.57\n", 1, "frame", "not an integer"),
        ("0 0 Car 0 0 -1.5 10 20 30 40 1.5 0 4.0 2.0 1.7 20.0 -1.57\n", 1, "w", "must be positive"),
        (LABEL_OK[: LABEL_OK.rindex("2 -1")] + "1 0 Van 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 2.0 1.7 20.0 -1.57\n", 6,
         "track_id", "twice in frame 1 (first on line 4)"),
        (LABEL_OK + "1 5 Van 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 2.0 1.7 20.0 -1.57\n", 7, "frame", "not in order"),
        ("0 -1 DontCare -1 -1 -10 1 2 3 4 -1000 -1000 -1000 -10 -1 -1 -1\n", None, None, "no annotations"),
        ("", None, None, "no rows"),
    ],
    ids=["too-few-columns", "too-many-columns", "not-a-number", "nan", "bad-frame", "zero-width", "duplicate-track",
         "frames-out-of-order", "dontcare-only", "empty"],
)
def test_bad_label_files_name_the_line(
    tmp_path: Path, labels: str, line: int | None, field: str | None, message: str
) -> None:
    paths = _inputs(tmp_path, labels=labels)
    with pytest.raises(ImportFormatError) as info:
        _import(paths, tmp_path / "out")
    err = info.value
    assert err.path == paths["labels"]
    assert (err.line, err.field) == (line, field)
    assert message in str(err)
    if line is not None:
        assert f", line {line}" in str(err)
    assert not (tmp_path / "out" / "kitti_0042").exists()  # nothing half-written


def test_poses_shorter_than_labels(tmp_path: Path) -> None:
    paths = _inputs(tmp_path, poses=_pose_lines(1))
    with pytest.raises(ImportFormatError, match="pose file has 1 frames") as info:
        _import(paths, tmp_path / "out")
    assert info.value.path == paths["poses"]
    assert not (tmp_path / "out" / "kitti_0042").exists()


@pytest.mark.parametrize(
    ("poses", "line", "message"),
    [
        (_pose_lines(1) + "1 0 0 0 0 1 0 0 0 0 1\n" + _pose_lines(1), 2, "expected 12 numbers"),
        (_pose_lines(2) + "2 0 0 0 0 1 0 0 0 0 1 0\n", 3, "not orthonormal"),
        (_pose_lines(2) + "1 0 0 0 0 1 0 0 0 0 1 x\n", 3, "not a number"),
    ],
)
def test_bad_pose_files_name_the_line(tmp_path: Path, poses: str, line: int, message: str) -> None:
    paths = _inputs(tmp_path, poses=poses)
    with pytest.raises(ImportFormatError, match=message) as info:
        _import(paths, tmp_path / "out")
    assert (info.value.path, info.value.line) == (paths["poses"], line)


def test_bad_calibration(tmp_path: Path) -> None:
    paths = _inputs(tmp_path)
    paths["calib"].write_text(CALIB_TEXT.replace("R0_rect: 1 0 0 0 1 0 0 0 1\n", ""))
    with pytest.raises(ImportFormatError, match="missing calibration entry") as info:
        read_kitti_calibration(paths["calib"])
    assert info.value.field == "R0_rect or R_rect"
    paths["calib"].write_text(CALIB_TEXT.replace("P2: 700 0 600 45", "P2: 700 0 600"))
    with pytest.raises(ImportFormatError, match="expected 12 numbers, got 11") as info:
        read_kitti_calibration(paths["calib"])
    assert (info.value.line, info.value.field) == (2, "P2")


_TR = "Tr_velo_to_cam: " + " ".join(str(v) for v in NOMINAL_VELO_TO_CAM.ravel())


@pytest.mark.parametrize(
    ("old", "new", "line", "field", "message"),
    [
        pytest.param("R0_rect: 1 0 0 0 1 0 0 0 1", "R0_rect: 0 0 0 0 0 0 0 0 0", 3, "R0_rect",
                     "matrix is not a proper rotation", id="rectification-all-zeros"),
        pytest.param("R0_rect: 1 0 0 0 1 0 0 0 1", "R_rect: 1 0 0 0 1 0 0 0 -1", 3, "R_rect",
                     "det = -1", id="rectification-reflection"),
        pytest.param("R0_rect: 1 0 0 0 1 0 0 0 1", "R0_rect: 2 0 0 0 2 0 0 0 2", 3, "R0_rect",
                     "not a proper rotation", id="rectification-scaled"),
        pytest.param(_TR, "Tr_velo_cam: " + " ".join(["0"] * 12), 4, "Tr_velo_cam",
                     "rotation part is not a proper rotation", id="velo-to-cam-all-zeros"),
        pytest.param(_TR, "Tr_velo_to_cam: 0 -1 0 0 0 0 -1 -0.08 1 0 0.2 -0.27", 4, "Tr_velo_to_cam",
                     "rotation part is not a proper rotation", id="velo-to-cam-sheared"),
        pytest.param("P2: 700 0 600 45 0 700", "P2: 0 0 600 45 0 700", 2, "P2", "fx (P2[0,0]) must be positive",
                     id="focal-length-zero"),
        pytest.param("P2: 700 0 600 45 0 700", "P2: 700 0 600 45 0 -700", 2, "P2", "fy (P2[1,1]) must be positive",
                     id="focal-length-negative"),
        pytest.param("P2: 700 0 600 45 0 700", "P2: nan 0 600 45 0 700", 2, "value 1", "NaN",
                     id="focal-length-nan"),
    ],
)
def test_calibration_values_must_describe_a_rig(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], old: str, new: str, line: int, field: str, message: str
) -> None:
    """A calibration that parses but is not a camera rig is refused, naming file, line and entry,
    before anything is imported (an all-zero rectification once put every box at one point)."""
    paths = _inputs(tmp_path)
    assert old in CALIB_TEXT
    paths["calib"].write_text(CALIB_TEXT.replace(old, new))
    with pytest.raises(ImportFormatError, match=re.escape(message)) as info:
        read_kitti_calibration(paths["calib"])
    assert (info.value.path, info.value.line, info.value.field) == (paths["calib"], line, field)
    argv = ["import", "kitti", "--labels", str(paths["labels"]), "--poses", str(paths["poses"]),
            "--calib", str(paths["calib"]), "--out", str(tmp_path / "out")]
    assert cli_main(argv) == 2
    assert f"{paths['calib']}, line {line}, field '{field}'" in capsys.readouterr().err
    assert not (tmp_path / "out" / "kitti_0042").exists()


def test_files_of_different_sequences_are_refused(tmp_path: Path) -> None:
    paths = _inputs(tmp_path)
    other = paths["calib"].with_name("0043.txt")
    paths["calib"].rename(other)
    with pytest.raises(ImportFormatError, match="belongs to sequence 0043, but the labels are sequence 0042"):
        import_kitti_sequence(paths["labels"], paths["poses"], other, tmp_path / "out")


def test_missing_input_file(tmp_path: Path) -> None:
    paths = _inputs(tmp_path)
    paths["poses"].unlink()
    with pytest.raises(FileNotFoundError, match="poses"):
        _import(paths, tmp_path / "out")


def test_existing_output_needs_overwrite(tmp_path: Path) -> None:
    paths = _inputs(tmp_path)
    log_dir = _import(paths, tmp_path / "out")
    with pytest.raises(FileExistsError):
        _import(paths, tmp_path / "out")
    paths["poses"].write_text(_pose_lines(3, step_m=2.0))
    assert _import(paths, tmp_path / "out", overwrite=True) == log_dir
    np.testing.assert_allclose(Log.open(log_dir).ego.translation_m[-1, 0], 4.0)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["kitti_0042"]  # no temp folders left


def test_import_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    paths = _inputs(tmp_path)
    argv = ["import", "kitti", "--labels", str(paths["labels"]), "--poses", str(paths["poses"]),
            "--calib", str(paths["calib"]), "--out", str(tmp_path / "out")]
    assert cli_main(argv) == 0
    assert "kitti_0042: 3 frames, 3 tracks, 4 boxes; skipped 2 DontCare rows" in capsys.readouterr().out
    assert cli_main(argv) == 2  # exists, no --overwrite: one-line error
    assert "already exists" in capsys.readouterr().err
    assert cli_main([*argv, "--overwrite"]) == 0
    capsys.readouterr()
    bad = _inputs(tmp_path / "bad", labels="0 0 Car 1 2 3\n")
    assert cli_main(["import", "kitti", "--labels", str(bad["labels"]), "--poses", str(bad["poses"]),
                     "--calib", str(bad["calib"]), "--out", str(tmp_path / "out2")]) == 2
    err = capsys.readouterr().err
    assert f"{bad['labels']}, line 1: expected 17 columns" in err
    with pytest.raises(SystemExit):
        cli_main([*argv, "--detections", "d.txt"])  # --labels and --detections exclude each other


def test_import_command_detections_hook(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    calls: list[tuple[object, ...]] = []
    fake = types.ModuleType("scenes.tracking")

    def import_kitti_detections(*args: object, overwrite: bool = False) -> str:
        calls.append((*args, overwrite))
        return "tracked"

    fake.import_kitti_detections = import_kitti_detections  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "scenes.tracking", fake)
    argv = ["import", "kitti", "--detections", "a.txt", "b.txt", "--poses", "p.txt", "--calib", "c.txt",
            "--out", str(tmp_path)]
    assert cli_main(argv) == 0
    assert calls == [([Path("a.txt"), Path("b.txt")], Path("p.txt"), Path("c.txt"), tmp_path, False)]
    assert capsys.readouterr().out.strip() == "tracked"


# ---- real KITTI sequences marked for development


def _require_kitti() -> None:
    if not (KITTI / "label_02" / "0001.txt").is_file():
        pytest.skip(f"real KITTI tracking data not found at {KITTI} (the shared realdata folder is absent)")


def _real_paths(seq: str) -> tuple[Path, Path, Path]:
    return KITTI / "label_02" / f"{seq}.txt", KITTI / "poses_orbslam3" / f"{seq}.txt", KITTI / "calib" / f"{seq}.txt"


@pytest.fixture(scope="module")
def kitti_0001(tmp_path_factory: pytest.TempPathFactory) -> Log:
    _require_kitti()
    out = tmp_path_factory.mktemp("kitti")
    report = import_kitti_sequence(*_real_paths("0001"), out)
    return Log.open(report.log_dir)


def test_real_0001_frames_and_counts(kitti_0001: Log) -> None:
    labels, poses, _ = _real_paths("0001")
    lines = [line.split() for line in labels.read_text().splitlines() if line.strip()]
    label_frames = {int(t[0]) for t in lines}
    assert kitti_0001.log_id == "kitti_0001"
    extra = kitti_0001.metadata.extra
    assert extra["frames"] == len(label_frames) == max(label_frames) + 1 == 447
    assert extra["label_frames"] == 447
    assert extra["dropped_dontcare"] == sum(t[2] == "DontCare" for t in lines) == 1241
    assert len(kitti_0001.annotations) == len(lines) - 1241
    assert extra["unknown_types"] == {}
    assert len(kitti_0001.ego) == len(poses.read_text().splitlines()) == 447
    np.testing.assert_array_equal(np.diff(kitti_0001.ego.timestamps_ns), FRAME_PERIOD_NS)
    # Frames that hold only DontCare boxes have no annotation rows; every other frame is on the grid.
    boxed = {int(t[0]) for t in lines if t[2] != "DontCare"}
    np.testing.assert_array_equal(kitti_0001.timestamps_ns, KITTI_EPOCH_NS + np.array(sorted(boxed)) * FRAME_PERIOD_NS)
    assert validate_log(kitti_0001.log_dir).ok


def test_real_0001_ego_moves_forward(kitti_0001: Log) -> None:
    ego = kitti_0001.ego
    np.testing.assert_allclose(ego.city_SE3_ego(0).matrix, np.eye(4), atol=1e-6)
    ego0_SE3_ego10 = ego.city_SE3_ego(0).inverse().compose(ego.city_SE3_ego(10))
    x, y, z = ego0_SE3_ego10.translation
    assert x > 5.0 and abs(y) < 0.5 and abs(z) < 0.5  # about 11 m/s straight ahead
    speed = ego.speed_mps()
    assert 9.0 < speed[:50].mean() < 14.0


def test_real_0001_parked_cars_stay_put_in_the_city_frame(kitti_0001: Log) -> None:
    cars = [t for t in kitti_0001.tracks().values() if t.category.value == "car" and len(t) >= 20]
    spread = np.array([
        np.linalg.norm(t.center_city_xyz_m[:, :2] - np.median(t.center_city_xyz_m[:, :2], axis=0), axis=1).max()
        for t in cars
    ])
    passed_m = np.array([np.linalg.norm(t.center_ego_xyz_m[-1, :2] - t.center_ego_xyz_m[0, :2]) for t in cars])
    parked = spread < 1.0
    # The ego drives past parked cars (20–50 m of relative motion, through a 90° turn); converted
    # to the city frame they stay within a metre, headings within a few degrees.
    assert parked.sum() >= 45
    assert (passed_m[parked] > 15.0).all()
    heading_change = np.array([np.ptp(np.unwrap(t.yaw_city_rad)) for t in cars])[parked]
    assert np.degrees(np.median(heading_change)) < 3.0
    turn = np.unwrap(kitti_0001.ego.yaw_rad)
    assert np.degrees(abs(turn[-1] - turn[0])) > 60


def test_real_0001_boxes_sit_on_the_road_with_kitti_yaw(kitti_0001: Log) -> None:
    ann = kitti_0001.annotations
    bottom_z = ann.center_xyz_m[:, 2] - ann.size_lwh_m[:, 2] / 2
    assert abs(np.median(bottom_z)) < 0.5  # the ego origin is on the road
    labels, _, calib_path = _real_paths("0001")
    calib = read_kitti_calibration(calib_path)
    row = next(line.split() for line in labels.read_text().splitlines() if line.split()[2] == "Car")
    ry = float(row[16])
    _, quat = kitti_boxes_to_ego(np.array([[float(v) for v in row[13:16]]]), np.array([float(row[10])]),
                                 np.array([ry]), calib.ego_SE3_cam)
    assert float(wrap_angle_rad(quat_to_yaw(quat)[0] + ry + np.pi / 2)) == pytest.approx(0.0, abs=np.radians(2))


@pytest.mark.parametrize("seq", DEV_SEQUENCES)
def test_real_development_sequences_import_and_validate(seq: str, tmp_path: Path) -> None:
    _require_kitti()
    labels, poses, calib = _real_paths(seq)
    report = import_kitti_sequence(labels, poses, calib, tmp_path)
    lines = [line.split() for line in labels.read_text().splitlines() if line.strip()]
    assert report.frames == len(poses.read_text().splitlines())
    assert report.frames >= max(int(t[0]) for t in lines) + 1
    assert report.dropped_dontcare == sum(t[2] == "DontCare" for t in lines)
    validation = validate_log(report.log_dir)
    assert validation.ok, validation.problems
    meta = json.loads((report.log_dir / "log_metadata.json").read_text())
    assert meta["extra"]["sequence"] == seq
