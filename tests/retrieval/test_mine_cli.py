"""``scenesearch mine`` on the development logs: a submission that loads, what each description reads as,
and the exit status of every case."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from retrieval.cli import main
from scenarios.submission import load_submission
from tests.scenes.av2_fixtures import DEV_LOGS, require


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    root = tmp_path_factory.mktemp("mine_logs")
    found = []
    for key in ("7fab2350", "adcf7d18"):
        source = require(DEV_LOGS[key])
        (root / source.name).symlink_to(source, target_is_directory=True)
        found.append(root / source.name)
    return found


def test_mine_writes_a_submission_at_2_hz(logs: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "pred.pkl"
    assert main(["mine", *map(str, logs), "--description", "vehicle with a pedestrian to its right",
                 "--description", "stopped(vehicle)", "--out", str(out), "--cache", str(tmp_path / "cache")]) == 0
    said = capsys.readouterr().out
    assert "program: direction(vehicle, pedestrian, side=right)" in said and "reads:" in said
    submission = load_submission(out, require_score=True)
    assert len(submission) == 4
    frames = submission[(logs[0].name, "vehicle with a pedestrian to its right")]
    stamps = np.asarray([f["timestamp_ns"] for f in frames])
    assert np.allclose(np.diff(stamps), 5e8, rtol=0.05)  # every fifth 10 Hz timestamp
    assert any((f["label"] == 0).any() for f in frames) and any((f["label"] == 1).any() for f in frames)
    assert main(["mine", *map(str, logs), "--description", "stopped(vehicle)", "--out", str(out), "--cache",
                 str(tmp_path / "cache")]) == 0
    assert "(2 from the feature cache)" in capsys.readouterr().out


def test_mine_refuses_a_description_that_names_nothing(logs: list[Path], tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "pred.pkl"
    assert main(["mine", str(logs[0]), "--description", "purple elephants", "--out", str(out)]) == 2
    assert "words not understood: purple, elephants" in capsys.readouterr().err and not out.exists()


def test_mine_skips_an_unreadable_log_and_notes_what_a_log_cannot_answer(
        logs: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mapless = tmp_path / "mapless" / logs[1].name
    mapless.mkdir(parents=True)
    for entry in logs[1].resolve().iterdir():
        if entry.name != "map":
            (mapless / entry.name).symlink_to(entry, target_is_directory=entry.is_dir())
    empty = tmp_path / "not_a_log"
    empty.mkdir()
    out = tmp_path / "pred.pkl"
    assert main(["mine", str(mapless), str(empty), "--description", "vehicle at an intersection", "--out",
                 str(out)]) == 1
    said = capsys.readouterr().out
    assert f"skipped log {empty}" in said
    assert "'at_intersection' needs a map, and the log has none: no answer there (not 'false')" in said
    assert main(["mine", str(empty), "--description", "vehicle", "--out", str(out)]) == 2
    shutil.rmtree(tmp_path / "mapless")
