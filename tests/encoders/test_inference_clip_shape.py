"""Clips of another shape than a model's training clips are refused before any is embedded, naming the
clips manifest's field, the clips' value and the model's."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
import torch

from encoders.clips.build import build_clips
from encoders.inference import ClipShapeError, check_clips_fit, record_trained_clips
from retrieval.cli import main
from tests.encoders.clip_fixtures import FINE_CLIPS, synthetic_captions, write_synthetic_log


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A tiny run trained on clips of 4 frames, and clips of 6 frames with a smaller camera image."""
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("clip_shape")
    logs = [write_synthetic_log(root / "logs", log_id=f"synthetic_{i}", num_frames=24, seed=i) for i in range(3)]
    (root / "captions").mkdir()
    pq.write_table(synthetic_captions(logs, 2, 20), root / "captions" / "captions.parquet")
    config = replace(FINE_CLIPS, frames_per_clip=4)
    build_clips(logs, root / "captions", root / "trained", config)
    other = replace(config, frames_per_clip=6, camera=replace(config.camera, height_px=48, width_px=80))
    build_clips(logs, root / "captions", root / "other", other)
    run = root / "run"
    assert main(["train", str(root / "trained"), "--out", str(run), "--preset", "tiny", "--batch-size", "2",
                 "--epochs", "1"]) == 0
    record_trained_clips(run, root / "trained")  # the record of the training clips beside the model
    return {"root": root, "run": run, "trained": root / "trained", "other": root / "other"}


def test_the_training_clips_fit_and_embed(data: dict[str, Path]) -> None:
    from retrieval.embedding import ModelEmbedder

    check_clips_fit(data["run"], data["trained"])
    ids, x = ModelEmbedder(data["run"]).embed_clips(data["trained"], view="bev")
    assert len(ids) == x.shape[0] > 0


def test_index_refuses_clips_of_another_shape_before_embedding(data: dict[str, Path],
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    out = data["root"] / "index"
    assert main(["index", str(data["run"]), str(data["other"]), "--out", str(out)]) == 2
    stdout, err = capsys.readouterr()
    assert err == (f"scenesearch index: error: {data['other'] / 'manifest.json'}, field 'frames_per_clip': 6, the "
                   "model was trained on 4; field 'camera.height_px': 48, the model was trained on 96; field "
                   "'camera.width_px': 80, the model was trained on 160 (make the clips as the run's training clips "
                   "were, or train a model on these)\n")
    assert "embedded" not in stdout and not out.exists()


def _manifest_only(data: dict[str, Path], folder: Path, **changes: Any) -> Path:
    manifest = json.loads((data["trained"] / "manifest.json").read_text())
    for name, value in changes.items():
        part, _, key = name.rpartition("__")
        (manifest[part] if part else manifest)[key] = value
    folder.mkdir()
    (folder / "manifest.json").write_text(json.dumps(manifest))
    return folder


def test_a_run_without_the_record_is_held_to_what_its_config_fixes(data: dict[str, Path], tmp_path: Path) -> None:
    """Channel counts and the longest clip of the temporal models come from the run's config.json."""
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(data["run"] / "config.json", run / "config.json")
    check_clips_fit(run, data["other"])  # another frame count and image size: nothing in config.json says no
    clips = _manifest_only(data, tmp_path / "clips", frames_per_clip=40,
                           bev__lidar_channels=["a", "b", "c", "d", "e"])
    with pytest.raises(ClipShapeError) as caught:
        check_clips_fit(run, clips)
    assert str(caught.value) == (
        f"{clips / 'manifest.json'}, field 'frames_per_clip': 40, the model reads at most 32 frames "
        f"({run / 'config.json'}, field 'model.bev.temporal.max_frames'); field 'bev.lidar_channels': 5 channels, the "
        f"model reads 4 ({run / 'config.json'}, field 'model.bev.lidar_channels') (make the clips as the run's "
        "training clips were, or train a model on these)")


def test_an_unreadable_record_is_named(data: dict[str, Path], tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "trained_clips.json").write_text("{not json")
    with pytest.raises(ClipShapeError, match=r"trained_clips\.json: unreadable record of the training clips"):
        check_clips_fit(run, data["trained"])
