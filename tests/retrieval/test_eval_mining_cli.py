"""``scenesearch eval-mining``: av2's scenario-mining evaluator behind the CLI, on submissions the tests write."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from retrieval.cli import main
from scenarios.answer import LogAnswer
from scenarios.submission import write_submission

pytest.importorskip("trackeval", reason="trackeval is not installed (make install adds it)")

AV2_LOG = "0b86f508-5df9-4a46-bc59-5b9536dbde9f"
SIM_LOG = "sim_0001"  # not 36 characters: the command hands it to av2 under a stand-in id


def make_answer(log_id: str, description: str, refer: bool = True, num_frames: int = 30) -> LogAnswer:
    """3 tracks at 10 Hz: a car referred (when ``refer``) from frame 10 on, a pedestrian related to it, a cyclist."""
    timestamps_ns = 315_971_916_960_141_000 + np.arange(num_frames, dtype=np.int64) * 100_000_000
    valid = np.ones((3, num_frames), dtype=bool)
    referred = np.zeros((3, num_frames), dtype=np.float32)
    related = np.zeros((3, num_frames), dtype=bool)
    if refer:
        referred[0, 10:] = 0.8
        related[1, 10:] = True
    time_s = np.arange(num_frames) / 10.0
    center = np.zeros((3, num_frames, 3))
    center[:, :, 0] = np.array([110.0, 118.0, 125.0])[:, None] + 5.0 * time_s[None, :]
    center[:, :, 1] = np.array([200.0, 204.0, 195.0])[:, None]
    return LogAnswer(
        log_id=log_id, description=description, timestamps_ns=timestamps_ns,
        track_ids=np.array(["a", "b", "c"]), categories=np.array(["car", "pedestrian", "cyclist"]),
        valid=valid, referred=referred, related=related, center_city_xyz_m=center,
        size_lwh_m=np.full((3, num_frames, 3), 2.0), yaw_city_rad=np.zeros((3, num_frames)),
        velocity_city_mps=np.zeros((3, num_frames, 3)),
        ego_city_xyz_m=np.stack([100.0 + 5.0 * time_s, np.full(num_frames, 200.0), np.zeros(num_frames)], axis=1),
    )


@pytest.fixture
def gt_path(tmp_path: Path) -> Path:
    answers = [make_answer(AV2_LOG, "car with a pedestrian to its left"), make_answer(SIM_LOG, "car ahead")]
    write_submission(answers, tmp_path / "gt.pkl")
    return tmp_path / "gt.pkl"


# With a Ray runtime in this process: the evaluator's workers must not be forks of it (they would hang).
@pytest.mark.usefixtures("ray_local")
def test_a_perfect_prediction_scores_the_maximum_and_an_empty_one_less(
        tmp_path: Path, gt_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The prediction holds every 10 Hz frame; the command picks the ground truth's 2 Hz ones.
    answers = [make_answer(AV2_LOG, "car with a pedestrian to its left"), make_answer(SIM_LOG, "car ahead")]
    write_submission(answers, tmp_path / "pred.pkl", all_timestamps=True)
    assert main(["eval-mining", str(tmp_path / "pred.pkl"), str(gt_path), "--out", str(tmp_path / "m.json")]) == 0
    printed = capsys.readouterr().out
    assert "HOTA-Temporal" in printed and "Log balanced accuracy" in printed
    perfect = json.loads((tmp_path / "m.json").read_text())
    for figure in ("hota_temporal", "hota_track", "timestamp_balanced_accuracy", "log_balanced_accuracy"):
        assert perfect[figure] == pytest.approx(1.0), figure
    assert set(perfect["by_description"]) == {"car with a pedestrian to its left", "car ahead"}
    assert perfect["by_description"]["car ahead"]["hota_temporal"] == pytest.approx(1.0)

    # Nothing referred in one log, the other log missing from the prediction.
    write_submission([make_answer(AV2_LOG, "car with a pedestrian to its left", refer=False)], tmp_path / "empty.pkl")
    assert main(["eval-mining", str(tmp_path / "empty.pkl"), str(gt_path), "--out", str(tmp_path / "e.json")]) == 0
    assert "1 ground-truth (log_id, description) pairs have no prediction" in capsys.readouterr().err
    empty = json.loads((tmp_path / "e.json").read_text())
    assert empty["hota_temporal"] < perfect["hota_temporal"]
    assert empty["hota_track"] < perfect["hota_track"]
    assert empty["timestamp_balanced_accuracy"] < 1.0


def test_a_malformed_prediction_is_refused_before_scoring(
        tmp_path: Path, gt_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with gt_path.open("rb") as file:
        submission = pickle.load(file)
    submission[(SIM_LOG, "car ahead")][2]["label"] = np.array([0, 5, 2], dtype=np.int32)
    (tmp_path / "bad.pkl").write_bytes(pickle.dumps(submission, protocol=4))
    assert main(["eval-mining", str(tmp_path / "bad.pkl"), str(gt_path)]) == 2
    err = capsys.readouterr().err
    assert "bad.pkl: key ('sim_0001', 'car ahead'), frame 2, field 'label': 5 at object 1" in err
    assert "Traceback" not in err


def test_a_prediction_without_scores_or_a_ground_truth_timestamp_is_refused(
        tmp_path: Path, gt_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The ground truth itself has scores; without them it is no prediction.
    with gt_path.open("rb") as file:
        submission = pickle.load(file)
    del submission[(AV2_LOG, "car with a pedestrian to its left")][0]["score"]
    (tmp_path / "noscore.pkl").write_bytes(pickle.dumps(submission, protocol=4))
    assert main(["eval-mining", str(tmp_path / "noscore.pkl"), str(gt_path)]) == 2
    assert "frame 0, field 'score': missing" in capsys.readouterr().err

    write_submission([make_answer(SIM_LOG, "car ahead", num_frames=12)], tmp_path / "short.pkl")
    assert main(["eval-mining", str(tmp_path / "short.pkl"), str(gt_path)]) == 2
    assert "key ('sim_0001', 'car ahead'): no frame at the ground truth's frame 3" in capsys.readouterr().err


def test_a_dataset_dir_without_map_rasters_is_refused(
        tmp_path: Path, gt_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    (logs / AV2_LOG / "map").mkdir(parents=True)
    assert main(["eval-mining", str(gt_path), str(gt_path), "--dataset-dir", str(logs)]) == 2
    assert f"{logs / AV2_LOG / 'city_SE3_egovehicle.feather'} not found" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["missing", "a_file", "without_the_log"])
def test_a_dataset_dir_that_is_not_the_logs_folder_names_the_path_tried(
        kind: str, tmp_path: Path, gt_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    if kind == "a_file":
        logs.write_text("not a folder")
    elif kind == "without_the_log":
        logs.mkdir()
    assert main(["eval-mining", str(gt_path), str(gt_path), "--dataset-dir", str(logs)]) == 2
    err = capsys.readouterr().err
    expected = {"missing": f"--dataset-dir {logs}: does not exist", "a_file": f"--dataset-dir {logs}: is not a folder",
                "without_the_log": f"no folder {logs / AV2_LOG} for the log '{AV2_LOG}'"}[kind]
    assert expected in err and "Traceback" not in err


def test_a_truncated_map_raster_in_the_dataset_dir_is_named(
        tmp_path: Path, gt_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import numpy as np

    log = tmp_path / "logs" / AV2_LOG
    (log / "map").mkdir(parents=True)
    (log / "city_SE3_egovehicle.feather").write_bytes(b"")
    (log / "map" / "log_map_archive_x.json").write_text("{}")
    (log / "map" / "x___img_Sim2_city.json").write_text("{}")
    raster = log / "map" / "x_ground_height_surface____PIT.npy"
    np.save(raster, np.zeros((785, 880), np.float32))
    raster.write_bytes(raster.read_bytes()[:10_000])  # truncated
    assert main(["eval-mining", str(gt_path), str(gt_path), "--dataset-dir", str(tmp_path / "logs")]) == 2
    err = capsys.readouterr().err
    assert f"{raster}: not a readable map raster" in err and "Traceback" not in err

