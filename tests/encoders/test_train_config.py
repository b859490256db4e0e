"""TrainConfig: YAML and run-folder JSON round trips, unknown keys listed with their path, values checked."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

import common.config
from encoders.config import BevConfig, ConfigError, FusionConfig, TrainConfig


@pytest.mark.parametrize("preset", ["default", "tiny"])
def test_yaml_round_trip(preset: str, tmp_path: Path) -> None:
    config = TrainConfig.preset(preset)
    config.to_yaml(tmp_path / "train.yaml")
    again = TrainConfig.from_yaml(tmp_path / "train.yaml")
    assert again == config == TrainConfig.from_yaml_text(config.to_yaml_text())
    assert isinstance(again.model.camera.widths, tuple)


def test_run_config_json_round_trips(tmp_path: Path) -> None:
    config = dataclasses.replace(TrainConfig.preset("tiny"), lr=1e-6)  # JSON writes 1e-06, which YAML 1.1 reads as text
    (tmp_path / "config.json").write_text(config.to_json())
    assert TrainConfig.from_json(tmp_path / "config.json") == config


@pytest.mark.parametrize(
    ("text", "message"),
    [('{"epochs": "three"}', r"config\.json: key 'epochs': expected an integer"),
     ("{", r"config\.json: cannot read config")],
)
def test_a_bad_run_config_json_names_the_file(tmp_path: Path, text: str, message: str) -> None:
    (tmp_path / "config.json").write_text(text)
    with pytest.raises(ConfigError, match=message):
        TrainConfig.from_json(tmp_path / "config.json")


def test_errors_are_the_common_config_error() -> None:
    assert issubclass(ConfigError, common.config.ConfigError)
    with pytest.raises(common.config.ConfigError, match="train.yaml: unknown keys epochz"):
        TrainConfig.from_yaml_text("epochz: 3", source="train.yaml")


def test_partial_yaml_keeps_defaults() -> None:
    config = TrainConfig.from_yaml_text("epochs: 3\nmodel:\n  bev:\n    embed_channels: 32\n")
    assert config.epochs == 3 and config.model.bev.embed_channels == 32
    assert config.model.bev.downsample == BevConfig().downsample and config.lr == TrainConfig().lr


def test_unknown_keys_are_listed_with_their_path() -> None:
    text = "epochz: 3\nmodel:\n  camera:\n    widht: 4\n  bev:\n    temporal:\n      layerz: 1\n"
    with pytest.raises(ConfigError) as info:
        TrainConfig.from_yaml_text(text)
    message = str(info.value)
    for key in ("epochz", "model.camera.widht", "model.bev.temporal.layerz"):
        assert key in message


@pytest.mark.parametrize(
    ("text", "field"),
    [("loss: hinge", "loss"), ("positives: words", "positives"), ("batch_size: 0", "batch_size"),
     ("device: tpu", "device"), ("model:\n  bev:\n    downsample: 3", "downsample"),
     ("model:\n  text:\n    kind: lstm", "kind"), ("model:\n  bev:\n    ego_features: 7", "ego_features"),
     ("model:\n  dense_tasks: [lane, speed]", "dense_tasks.*speed"), ("model:\n  dense_tasks: []", "dense_tasks")],
)
def test_bad_values(text: str, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        TrainConfig.from_yaml_text(text)


def test_modality_dropout_keeps_one_view() -> None:
    with pytest.raises(ConfigError, match="drop_camera_p"):
        FusionConfig(drop_camera_p=0.7, drop_bev_p=0.5)
    with pytest.raises(ConfigError, match="category_drop_p"):
        FusionConfig(object_category=True, category_drop_p=1.5)


def test_defaults_of_the_universal_embedding() -> None:
    bev = TrainConfig().model.bev
    assert (bev.embed_channels, bev.downsample) == (64, 2)
    assert dataclasses.asdict(TrainConfig())["model"]["logit_scale_max"] == pytest.approx(4.60517, abs=1e-5)


def test_a_run_written_before_newer_keys_loads_and_resumes_as_it_was(tmp_path: Path) -> None:
    from encoders.checkpoints import check_resume_config

    old = TrainConfig().to_dict()
    del old["view_weight"], old["time_reversal"], old["model"]["bev"]["track_range"], old["model"]["dense_tasks"]
    del old["model"]["text"]["whole_text"]
    path = tmp_path / "config.json"
    path.write_text(json.dumps(old))
    config = TrainConfig.from_json(path)
    assert config.view_weight == 0.0 and config.time_reversal == 0.0 and config.model.bev.track_range is False
    # The whole text was encoded in one piece before its sentences made it up.
    assert config.model.text.whole_text == "text" and TrainConfig().model.text.whole_text == "sentences"
    # Dense heads from before the action and context tasks predict the first four.
    assert config.model.dense_tasks == ("lane", "motion", "host_motion", "host_direction")
    assert TrainConfig().model.dense_tasks[4:] == ("action", "context")
    check_resume_config(config, old, done_epochs=1)  # the checkpoint's dict lacks the same keys
    changed = dataclasses.replace(config.model, bev=dataclasses.replace(config.model.bev, track_range=True))
    with pytest.raises(ConfigError, match="track_range"):
        check_resume_config(dataclasses.replace(config, model=changed), old, done_epochs=1)
    with pytest.raises(ConfigError, match=r"run/checkpoints/last.pt: config.*bogus"):
        check_resume_config(config, {**old, "bogus": 1}, done_epochs=1, source="run/checkpoints/last.pt")
    with pytest.raises(ConfigError, match="time_reversal"):
        TrainConfig(time_reversal=1.5)


def test_a_tagging_checkpoint_written_before_the_presence_weights_resumes() -> None:
    from types import SimpleNamespace

    from encoders.checkpoints import check_resume_tagging
    from encoders.tagging.config import TagTrainConfig

    new = SimpleNamespace(config=TagTrainConfig())
    old = TagTrainConfig().to_dict()
    del old["joint_presence_weight"], old["loss"]["presence_weight"]
    check_resume_tagging(new, old)  # type: ignore[arg-type]  # what the keys weigh has no row in an older head
    with pytest.raises(ConfigError, match="tagging.joint_weight"):
        check_resume_tagging(new, {**old, "joint_weight": 2.0})  # type: ignore[arg-type]
