"""``scenesearch train`` on a real clips folder (rendered from synthetic logs): run, resume checks, bad input."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import torch

from encoders.clips.build import build_clips
from encoders.clips.config import ClipsConfig
from encoders.clips.testing import synthetic_captions, write_synthetic_log
from encoders.inference import embed_clips, embed_texts, load_model
from retrieval.cli import main


@pytest.fixture(scope="module")
def clips_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("train_cli")
    logs = [write_synthetic_log(root / "logs", log_id=f"synthetic_{i}", num_frames=24, seed=i) for i in range(3)]
    (root / "captions").mkdir()
    pq.write_table(synthetic_captions(logs, 2, 20), root / "captions" / "captions.parquet")
    build_clips(logs, root / "captions", root / "clips", replace(ClipsConfig(), previews=False, frames_per_clip=4))
    return root / "clips"


def test_train_resume_and_bad_input(clips_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    base = ["train", str(clips_dir), "--out", str(out), "--preset", "tiny", "--batch-size", "2"]
    assert main([*base, "--epochs", "1"]) == 0
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert len(rows) == 1 and "R@1" in rows[0]["val"]
    config = json.loads((out / "config.json").read_text())
    assert config["model"]["bev"]["lidar_channels"] > 0

    model = load_model(out)
    ids, vectors = embed_clips(model, clips_dir, split="test", view="bev")
    assert len(ids) == vectors.shape[0] > 0 and vectors.shape[1] == config["model"]["embed_dim"]
    assert embed_texts(model, ["a car follows behind"]).shape == (1, config["model"]["embed_dim"])

    # Extending the epochs is allowed; another learning rate is not, unless forced.
    assert main([*base, "--epochs", "2", "--lr", "0.5", "--resume"]) == 2
    assert "lr: 0.001 -> 0.5" in capsys.readouterr().err
    assert main([*base, "--epochs", "2", "--resume"]) == 0
    assert len((out / "metrics.jsonl").read_text().splitlines()) == 2
    # Without --config or --preset, --resume continues with the run's own config.json.
    assert main(["train", str(clips_dir), "--out", str(out), "--resume", "--epochs", "3"]) == 0
    assert len((out / "metrics.jsonl").read_text().splitlines()) == 3

    # A checkpoint that needs more than tensors and plain data to load is refused, naming the file.
    checkpoint = out / "checkpoints" / "last.pt"
    torch.save({**torch.load(checkpoint, weights_only=True), "extra": Path("anything")}, checkpoint)
    capsys.readouterr()
    assert main(["train", str(clips_dir), "--out", str(out), "--resume", "--epochs", "4"]) == 2
    err = capsys.readouterr().err
    assert f"{checkpoint}: not a checkpoint that loads as plain tensors" in err and "Traceback" not in err


def test_bad_config_and_missing_split(clips_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "train.yaml"
    bad.write_text("epochs: 1\nlearning_rate: 0.1\nmodel:\n  bev:\n    depth: 3\n")
    assert main(["train", str(clips_dir), "--out", str(tmp_path / "a"), "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "learning_rate" in err and "model.bev.depth" in err and str(bad) in err

    broken = tmp_path / "broken.yaml"
    broken.write_text("epochs: [1\n")
    assert main(["train", str(clips_dir), "--out", str(tmp_path / "c"), "--config", str(broken)]) == 2
    err = capsys.readouterr().err
    assert f"{broken}: not valid YAML (line 2, column 1)" in err and not (tmp_path / "c").exists()

    empty = tmp_path / "empty_clips"
    empty.mkdir()
    for name in ("manifest.json",):
        (empty / name).write_text((clips_dir / name).read_text())
    table = pq.read_table(clips_dir / "clips.parquet")
    not_train = table.column("split").to_numpy(zero_copy_only=False) != "train"
    pq.write_table(table.filter(not_train), empty / "clips.parquet")
    assert main(["train", str(empty), "--out", str(tmp_path / "b"), "--preset", "tiny"]) == 2
    assert "'train' split" in capsys.readouterr().err
