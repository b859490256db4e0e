"""``scenesearch train`` on a real clips folder (rendered from synthetic logs): run, resume checks, bad input."""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
import torch
from torch.utils.data import DataLoader

from encoders.clips.build import build_clips
from encoders.clips.config import ClipsConfig
from encoders.config import ConfigError
from encoders.dense import DENSE_TASKS
from encoders.inference import collate, embed_clips, embed_texts, frame_tag_figures, load_model, open_split
from encoders.model import DualEncoder
from encoders.presets import preset
from encoders.train import resolve_channels
from retrieval.cli import main
from retrieval.evaluation import evaluate
from retrieval.metrics_tables import metrics_table
from tests.encoders.clip_fixtures import synthetic_captions, synthetic_frame_tags, write_synthetic_log
from tests.retrieval.retrieval_fakes import HashTextEncoder


def make_clips(root: Path, frame_tags: bool) -> Path:
    """Clips of three synthetic logs; with ``frame_tags`` the captions' frame_tags.parquet is beside them,
    so each clip frame carries rule tags."""
    torch.set_num_threads(1)
    logs = [write_synthetic_log(root / "logs", log_id=f"synthetic_{i}", num_frames=24, seed=i) for i in range(3)]
    (root / "captions").mkdir()
    pq.write_table(synthetic_captions(logs, 2, 20), root / "captions" / "captions.parquet")
    if frame_tags:
        pq.write_table(synthetic_frame_tags(logs, 24), root / "captions" / "frame_tags.parquet")
    build_clips(logs, root / "captions", root / "clips", replace(ClipsConfig(), previews=False, frames_per_clip=4))
    return root / "clips"


@pytest.fixture(scope="module")
def clips_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_clips(tmp_path_factory.mktemp("train_cli"), frame_tags=False)


@pytest.fixture(scope="module")
def tagged_clips_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_clips(tmp_path_factory.mktemp("train_cli_dense"), frame_tags=True)


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
    # A run the Python API started has no recipe.yaml: the resume reads the checkpoint's configurations
    # (the tiny preset's batch size, not the recommended one's).
    (out / "recipe.yaml").unlink()
    assert main(["train", str(clips_dir), "--out", str(out), "--resume", "--epochs", "4"]) == 0
    assert len((out / "metrics.jsonl").read_text().splitlines()) == 4
    assert json.loads((out / "config.json").read_text())["batch_size"] == 2

    # A checkpoint that needs more than tensors and plain data to load is refused, naming the file.
    checkpoint = out / "checkpoints" / "last.pt"
    torch.save({**torch.load(checkpoint, weights_only=True), "extra": Path("anything")}, checkpoint)
    capsys.readouterr()
    assert main(["train", str(clips_dir), "--out", str(out), "--resume", "--epochs", "5"]) == 2
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


def test_dense_weight_trains_frame_tag_heads_and_eval_reports_them(
        tagged_clips_dir: Path, clips_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    settings = ["dense_weight=1", "model.dense_streams=[track]", "model.bev.track_velocity=true",
                "model.bev.track_rates=true", "model.camera.ego_features=6", "model.camera.mask_scale=true",
                "camera_apart=true", "model.camera.object_crop=true", "model.fusion.object_category=true"]
    args = ["--preset", "tiny", "--batch-size", "4", "--epochs", "2", *(f"--set={s}" for s in settings)]
    assert main(["train", str(tagged_clips_dir), "--out", str(out), *args]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["dense_weight"] == 1.0 and config["model"]["dense_streams"] == ["track"]
    assert config["model"]["bev"]["track_velocity"] is True and config["model"]["bev"]["track_rates"] is True
    assert config["model"]["camera"]["ego_features"] == 6 and config["model"]["camera"]["mask_scale"] is True
    assert config["camera_apart"] is True and config["model"]["camera"]["object_crop"] is True
    assert config["model"]["fusion"]["object_category"] is True

    metrics = evaluate(out, tagged_clips_dir, split="all", sentence_encoder=HashTextEncoder())
    dense = metrics["frame_tags"]
    assert set(dense["streams"]) == {"track"} and set(dense["streams"]["track"]) == set(DENSE_TASKS)
    # Every synthetic ego frame cruises straight: the most frequent tag is always right.
    assert dense["majority"]["host_motion"] == dense["majority"]["host_direction"] == 1.0
    assert dense["frames"]["lane"] == dense["frames"]["motion"] > 0
    assert all(0.0 <= v <= 1.0 for v in dense["streams"]["track"].values())
    assert "frame tags from the track stream: lane" in metrics_table(metrics)

    # Clips without frame tags cannot train dense heads; the error says what is missing.
    capsys.readouterr()
    assert main(["train", str(clips_dir), "--out", str(tmp_path / "untagged"), *args]) == 2
    err = capsys.readouterr().err
    assert "dense_weight needs the clip frames' rule tags" in err and "frame_tags.parquet" in err
    assert not (tmp_path / "untagged" / "model.safetensors").exists()


def test_frame_tag_figures_of_perfect_heads(tagged_clips_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    dataset = open_split(tagged_clips_dir, None)
    tiny = resolve_channels(preset("tiny").train, dataset[0]).model
    model = DualEncoder(replace(tiny, dense_streams=("track",)))
    targets = iter(torch.as_tensor(b["frame_targets"]) for b in DataLoader(dataset, batch_size=32, collate_fn=collate))

    def perfect(frames: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        target = next(targets)  # (B, T, K): one-hot logits of each task's tag
        parts = [torch.nn.functional.one_hot(target[..., k].clamp(min=0), len(c)).float()
                 for k, c in enumerate(DENSE_TASKS.values())]
        return {"track": torch.cat(parts, dim=-1)}

    monkeypatch.setattr(model, "dense_logits", perfect)
    figures = frame_tag_figures(model, dataset)
    assert figures["streams"]["track"] == dict.fromkeys(DENSE_TASKS, 1.0)
    assert figures["first_last_motion"]["track"] == [1.0, 1.0]
    # Lead, parked and follower in every frame: two of three in a lane other than the left.
    assert figures["majority"]["motion"] == pytest.approx(1 / 3)
    assert frame_tag_figures(DualEncoder(tiny), dataset) == {}


def test_recipe_settings_reach_the_configs(tmp_path: Path) -> None:
    from encoders.tagging.config import TagTrainConfig
    from retrieval.commands import train as train_command

    parser = argparse.ArgumentParser()
    train_command.configure(parser)
    base = ["clips", "--out", str(tmp_path / "run")]

    def recipe(*argv: str) -> Any:
        return train_command.build_recipe(parser.parse_args([*base, *argv]))

    default = recipe()
    assert default.name == "recommended" and default.train == preset("recommended").train
    both = recipe("--set", "model.dense_streams=[camera, track]", "--set", "dense_weight=1").train
    assert both.model.dense_streams == ("camera", "track") and both.dense_weight == 1.0
    with pytest.raises(ConfigError, match="lidar"):
        recipe("--set", "model.dense_streams=[lidar]")
    with pytest.raises(ConfigError, match="order_weight > 0 needs 'reverse'"):
        recipe("--set", "hard_negatives=[]")
    assert recipe("--set", "partial_weight=0.25").train.partial_weight == 0.25
    assert recipe("--set", "tagging.joint_presence_weight=2").tagging == TagTrainConfig(joint_presence_weight=2.0)
    with pytest.raises(ConfigError, match="joint_presence_weight"):
        recipe("--set", "tagging.joint_presence_weight=-1")
    with pytest.raises(ConfigError, match="unknown key 'model.widht'"):
        recipe("--set", "model.widht=3")
    with pytest.raises(ConfigError, match="write KEY=VALUE"):
        recipe("--set", "epochs")
    tiny = recipe("--preset", "tiny", "--epochs", "2", "--lr", "0.01").train
    assert tiny.epochs == 2 and tiny.lr == 0.01 and tiny.model.embed_dim == 32
    with pytest.raises(SystemExit):
        parser.parse_args([*base, "--time-slots", "4"])  # architecture lives in the recipe, not in flags
