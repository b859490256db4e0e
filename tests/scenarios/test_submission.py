"""Scenario-mining submissions: the frames of an answer, the round trip, and what loading refuses."""

from __future__ import annotations

import os
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from scenarios.answer import LogAnswer
from scenarios.submission import (
    SubmissionError,
    evaluation_frames,
    frames_of,
    load_submission,
    write_submission,
)

LOG_ID = "0b86f508-5df9-4a46-bc59-5b9536dbde9f"


def make_answer(log_id: str = LOG_ID, description: str = "car turning left", num_frames: int = 10,
                hz: float = 10.0) -> LogAnswer:
    """3 tracks over ``num_frames`` frames: a car referred from the 3rd frame on, a pedestrian related
    to it while it is, and a cyclist absent at the 5th and 6th frames."""
    t0_ns = 315_971_916_960_141_000
    timestamps_ns = t0_ns + np.round(np.arange(num_frames) * 1e9 / hz).astype(np.int64)
    valid = np.ones((3, num_frames), dtype=bool)
    valid[2, 4:6] = False
    referred = np.zeros((3, num_frames), dtype=np.float32)
    referred[0, 2:] = np.linspace(0.5, 0.9, num_frames - 2)
    related = np.zeros((3, num_frames), dtype=bool)
    related[1, 2:] = True
    time_s = np.arange(num_frames) / hz
    center = np.zeros((3, num_frames, 3))
    center[:, :, 0] = 100.0 + np.array([0.0, 8.0, 20.0])[:, None] + 5.0 * time_s[None, :]
    center[:, :, 1] = np.array([200.0, 203.0, 196.0])[:, None]
    center[~valid] = np.nan
    ego = np.stack([90.0 + 5.0 * time_s, np.full(num_frames, 200.0), np.zeros(num_frames)], axis=1)
    return LogAnswer(
        log_id=log_id, description=description, timestamps_ns=timestamps_ns,
        track_ids=np.array(["car-a", "ped-b", "cyc-c"]), categories=np.array(["car", "pedestrian", "cyclist"]),
        valid=valid, referred=referred, related=related, center_city_xyz_m=center,
        size_lwh_m=np.broadcast_to(np.array([4.5, 1.9, 1.6]), (3, num_frames, 3)).copy(),
        yaw_city_rad=np.zeros((3, num_frames)),
        velocity_city_mps=np.broadcast_to(np.array([5.0, 0.0, 0.0]), (3, num_frames, 3)).copy(),
        ego_city_xyz_m=ego,
    )


def test_frames_are_at_2_hz_from_the_first() -> None:
    answer = make_answer()
    frames = frames_of(answer)
    assert [f["timestamp_ns"] for f in frames] == [int(answer.timestamps_ns[0]), int(answer.timestamps_ns[5])]
    assert len(frames_of(answer, all_timestamps=True)) == 10
    assert len(frames_of(make_answer(num_frames=6, hz=2.0))) == 6
    assert evaluation_frames(np.array([0, 100_000_000, 200_000_000])).tolist() == [0]
    assert evaluation_frames(np.array([7], dtype=np.int64)).tolist() == [0]


def test_frame_fields_labels_and_scores() -> None:
    answer = make_answer()
    first, second = frames_of(answer)
    assert isinstance(first["timestamp_ns"], int)
    assert first["ego_translation_m"] == [90.0, 200.0, 0.0]
    assert first["description"] == "car turning left" and first["seq_id"] == (LOG_ID, "car turning left")
    # Frame 0: nobody referred; frame 5: the car referred, the pedestrian related, the cyclist absent.
    assert first["label"].tolist() == [2, 2, 2] and first["track_id"].tolist() == [0, 1, 2]
    assert second["label"].tolist() == [0, 1] and second["track_id"].tolist() == [0, 1]
    assert second["name"].tolist() == ["REGULAR_VEHICLE", "PEDESTRIAN"]
    assert first["name"][2] == "BICYCLIST"
    assert second["score"][0] == pytest.approx(answer.referred[0, 5])
    # Elsewhere a track's score is its highest referred score in the log (0 if never referred).
    assert first["score"].tolist() == pytest.approx([0.9, 0.0, 0.0])
    assert second["translation_m"].shape == (2, 3) and second["size"].shape == (2, 3)
    assert second["yaw"].shape == (2,) and second["velocity_m_per_s"].shape == (2, 3)
    assert second["translation_m"][0].tolist() == pytest.approx([102.5, 200.0, 0.0])
    for field, dtype in [("track_id", np.int32), ("label", np.int32), ("score", np.float32),
                         ("translation_m", np.float64), ("size", np.float32), ("yaw", np.float32)]:
        assert second[field].dtype == dtype, field


def test_round_trip(tmp_path: Path) -> None:
    answers = [make_answer(), make_answer(description="pedestrian crossing")]
    written = write_submission(answers, tmp_path / "pred.pkl")
    loaded = load_submission(tmp_path / "pred.pkl", require_score=True)
    assert list(loaded) == [(LOG_ID, "car turning left"), (LOG_ID, "pedestrian crossing")]
    for key, frames in written.items():
        for a, b in zip(frames, loaded[key], strict=True):
            assert a.keys() == b.keys()
            for field in a:
                np.testing.assert_array_equal(a[field], b[field])
    with pytest.raises(ValueError, match="given twice"):
        write_submission([make_answer(), make_answer()], tmp_path / "twice.pkl")
    assert not (tmp_path / "twice.pkl").exists()


def test_numpy_2_and_numpy_1_pickles_load(tmp_path: Path) -> None:
    """Arrays pickled at protocol 5 (numpy's _frombuffer) and 2 (numpy.core paths, _codecs) load too."""
    written = write_submission([make_answer()], tmp_path / "a.pkl")
    for protocol in (2, 5):
        (tmp_path / "b.pkl").write_bytes(pickle.dumps(written, protocol=protocol))
        assert load_submission(tmp_path / "b.pkl").keys() == written.keys()


class Payload:
    """A class a pickle refers to by name: loading must never construct it."""


@pytest.mark.parametrize(("payload", "global_name"), [(os.system, "posix.system"),
                                                      (Payload(), "test_submission.Payload")])
def test_a_non_numpy_global_is_refused(tmp_path: Path, payload: Any, global_name: str) -> None:
    submission = {(LOG_ID, "x"): [{"timestamp_ns": 1, "extra": payload}]}
    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps(submission, protocol=4))
    with pytest.raises(SubmissionError, match=rf"evil\.pkl: refuses the global .*{global_name.split('.')[-1]}"):
        load_submission(path)


def test_garbage_is_refused_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "cut.pkl"
    path.write_bytes(pickle.dumps({"a": np.zeros(3)}, protocol=4)[:-10])
    with pytest.raises(SubmissionError, match=r"cut\.pkl: not a readable pickle"):
        load_submission(path)


def _break(frame: dict[str, Any], field: str, how: str) -> None:
    if how == "missing":
        del frame[field]
    elif how == "short":
        frame[field] = frame[field][:-1]
    elif how == "nan":
        frame[field] = frame[field].astype(np.float64)
        frame[field].flat[0] = np.nan
    elif how == "five":
        frame[field] = frame[field].copy()
        frame[field][0] = 5


@pytest.mark.parametrize(("field", "how", "message"), [
    ("translation_m", "missing", "missing"),
    ("score", "missing", "missing"),
    ("size", "short", r"shape \(1, 3\), expected \(2, 3\)"),
    ("yaw", "nan", "nan at object 0 is not finite"),
    ("label", "five", "5 at object 0 is not 0"),
])
def test_malformed_frames_are_refused_naming_key_frame_field(tmp_path: Path, field: str, how: str,
                                                              message: str) -> None:
    written = write_submission([make_answer()], tmp_path / "pred.pkl")
    key = (LOG_ID, "car turning left")
    _break(written[key][1], field, how)
    path = tmp_path / "bad.pkl"
    path.write_bytes(pickle.dumps(written, protocol=4))
    expected = rf"bad\.pkl: key \('{LOG_ID}', 'car turning left'\), frame 1, field '{field}': {message}"
    with pytest.raises(SubmissionError, match=expected):
        load_submission(path, require_score=True)


@pytest.mark.parametrize(("submission", "message"), [
    ([1, 2], "holds a list"),
    ({"log-description": []}, "key 'log-description': not a"),
    ({(LOG_ID, "x"): []}, "not a non-empty list of frames"),
])
def test_malformed_containers_are_refused(tmp_path: Path, submission: Any, message: str) -> None:
    path = tmp_path / "bad.pkl"
    path.write_bytes(pickle.dumps(submission, protocol=4))
    with pytest.raises(SubmissionError, match=message):
        load_submission(path)


def test_ego_translation_as_an_array_and_reversed_timestamps_are_refused(tmp_path: Path) -> None:
    written = write_submission([make_answer()], tmp_path / "pred.pkl")
    frames = written[(LOG_ID, "car turning left")]
    frames[0]["ego_translation_m"] = np.array(frames[0]["ego_translation_m"])
    (tmp_path / "a.pkl").write_bytes(pickle.dumps(written))
    with pytest.raises(SubmissionError, match="frame 0, field 'ego_translation_m'"):
        load_submission(tmp_path / "a.pkl")
    frames[0]["ego_translation_m"] = [0.0, 0.0, 0.0]
    frames.reverse()
    (tmp_path / "b.pkl").write_bytes(pickle.dumps(written))
    with pytest.raises(SubmissionError, match="frame 1, field 'timestamp_ns'"):
        load_submission(tmp_path / "b.pkl")
