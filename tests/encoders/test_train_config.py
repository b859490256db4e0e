"""TrainConfig: YAML and run-folder JSON round trips, unknown keys listed with their path, values checked."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest
import yaml

import scenesearch_base.config
from encoders.config import (
    BevConfig,
    CameraConfig,
    ConfigError,
    DualEncoderConfig,
    FusionConfig,
    TemporalConfig,
    TextConfig,
)
from encoders.presets import PRESETS_DIR, preset, preset_names, read_recipe
from encoders.tagging.config import TagTrainConfig
from encoders.train_config import HardNegative, TrainConfig


@pytest.mark.parametrize("name", preset_names())
def test_every_preset_is_a_complete_recipe_that_round_trips(name: str, tmp_path: Path) -> None:
    recipe = preset(name)
    config = recipe.train
    config.to_yaml(tmp_path / "train.yaml")
    again = TrainConfig.from_yaml(tmp_path / "train.yaml")
    assert again == config == TrainConfig.from_yaml_text(config.to_yaml_text())
    assert isinstance(again.model.camera.widths, tuple)
    recipe.to_yaml(tmp_path / "recipe.yaml")
    assert read_recipe(tmp_path / "recipe.yaml") == recipe
    # Complete: every key of the config is written in the preset's file, nothing left to code defaults.
    written = yaml.safe_load((PRESETS_DIR / f"{name}.yaml").read_text())
    assert set(written) - {"tagging"} == set(config.to_dict())


def test_presets_are_the_two_recipes() -> None:
    assert preset_names() == ["recommended", "tiny"]
    recommended = preset("recommended").train
    assert recommended.model.time_slots == 4 and recommended.hard_negatives == (HardNegative.REVERSE,)
    assert recommended.order_weight == 0.3 and recommended.dense_weight == 5.0 and recommended.camera_apart
    with pytest.raises(ConfigError, match="unknown preset 'default'"):
        preset("default")


def test_run_config_json_round_trips(tmp_path: Path) -> None:
    config = dataclasses.replace(preset("tiny").train, lr=1e-6)  # JSON writes 1e-06, which YAML 1.1 reads as text
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
    assert issubclass(ConfigError, scenesearch_base.config.ConfigError)
    with pytest.raises(scenesearch_base.config.ConfigError, match="train.yaml: unknown keys epochz"):
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
    [("epochs: 0", "epochs"), ("hard_negatives: [mirror]", "hard_negatives"), ("batch_size: 0", "batch_size"),
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


def test_a_run_that_lacks_a_key_or_holds_a_removed_one_is_refused(tmp_path: Path) -> None:
    from encoders.checkpoints import check_resume_config

    config = TrainConfig()
    written = config.to_dict()
    check_resume_config(config, written, done_epochs=1)
    path = tmp_path / "config.json"
    lacking = json.loads(json.dumps(written))
    del lacking["view_weight"], lacking["model"]["text"]["whole_text"]
    path.write_text(json.dumps(lacking))
    with pytest.raises(ConfigError, match=r"config.json: written by an older version \(it lacks "
                                          r"model.text.whole_text, view_weight\): train the model again"):
        TrainConfig.from_json(path)
    with pytest.raises(ConfigError, match="run/checkpoints/last.pt: config: written by an older version"):
        check_resume_config(config, lacking, done_epochs=1, source="run/checkpoints/last.pt")
    for removed in ("time_reversal", "loss", "positives", "tag_weight"):
        path.write_text(json.dumps({**written, removed: 0.0}))
        with pytest.raises(ConfigError, match=f"unknown keys {removed}"):
            TrainConfig.from_json(path)
    path.write_text(json.dumps({**written, "model": {**written["model"], "bev": {**written["model"]["bev"],
                                                                                  "track_range": False}}}))
    with pytest.raises(ConfigError, match="unknown keys model.bev.track_range"):
        TrainConfig.from_json(path)
    changed = dataclasses.replace(config.model, bev=dataclasses.replace(config.model.bev, track_velocity=True))
    with pytest.raises(ConfigError, match="track_velocity"):
        check_resume_config(dataclasses.replace(config, model=changed), written, done_epochs=1)
    with pytest.raises(ConfigError, match=r"run/checkpoints/last.pt: config.*bogus"):
        check_resume_config(config, {**written, "bogus": 1}, done_epochs=1, source="run/checkpoints/last.pt")


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


# --- upper bounds -----------------------------------------------------------------------------------

#: Where each bounded config sits in a TrainConfig file (its keys are named from the top).
BOUNDED_PLACES: dict[type[scenesearch_base.config.YamlConfig], str] = {
    TrainConfig: "", DualEncoderConfig: "model.", TextConfig: "model.text.", CameraConfig: "model.camera.",
    TemporalConfig: "model.camera.temporal.", BevConfig: "model.bev.", FusionConfig: "model.fusion."}
#: Other values a field needs at its bound (heads divide the width; time slots go with the slots text tower).
AT_BOUND_COMPANIONS: dict[str, dict[str, object]] = {
    "model.camera.temporal.heads": {"model.camera.temporal.width": 256},
    "model.time_slots": {"model.text.kind": "slots", "model.slot_dim": 16, "model.embed_dim": 8192}}
BOUNDED_KEYS = [(f"{prefix}{key}", bound) for cls, prefix in BOUNDED_PLACES.items()
                for key, bound in cls.upper_bounds.items()]


def nested(values: dict[str, object]) -> dict[str, object]:
    """``{"a.b": 1}`` → ``{"a": {"b": 1}}``."""
    data: dict[str, object] = {}
    for dotted, value in values.items():
        *parents, last = dotted.split(".")
        node = data
        for part in parents:
            node = node.setdefault(part, {})  # type: ignore[assignment]
        node[last] = value
    return data


def refused(key: str, bound: float) -> str:
    """The pattern of the error that refuses ``key`` above ``bound``."""
    return rf"key '{re.escape(key)}': \S+ is above its upper bound {re.escape(f'{bound:g}')}$"


def _value(path: str, number: float) -> object:
    return [number] if path.endswith("widths") else number  # widths: each stage's bound


def test_every_bounded_config_has_a_place_and_a_documented_bound() -> None:
    for cls in BOUNDED_PLACES:
        assert cls.upper_bounds and "Upper bounds:" in (cls.__doc__ or "")
        assert set(cls.upper_bounds) <= {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    assert "Upper bounds:" in (TagTrainConfig.__doc__ or "")


@pytest.mark.parametrize(("path", "bound"), BOUNDED_KEYS, ids=[path for path, _ in BOUNDED_KEYS])
def test_a_size_above_its_bound_is_refused_naming_the_key(path: str, bound: float) -> None:
    with pytest.raises(ConfigError, match=r"^train\.yaml: " + refused(path, bound)):
        TrainConfig.from_dict(nested({path: _value(path, bound + 1)}), source="train.yaml")


@pytest.mark.parametrize(("path", "bound"), BOUNDED_KEYS, ids=[path for path, _ in BOUNDED_KEYS])
def test_a_size_at_its_bound_is_accepted(path: str, bound: float) -> None:
    config = TrainConfig.from_dict(nested({path: _value(path, bound), **AT_BOUND_COMPANIONS.get(path, {})}))
    value: object = config
    for part in path.split("."):
        value = getattr(value, part)
    assert value == ((bound,) if path.endswith("widths") else bound)


def test_the_bound_message_names_the_file_key_and_bound() -> None:
    with pytest.raises(ConfigError) as info:
        TrainConfig.from_yaml_text("epochs: 1000000000\n", source="train.yaml")
    assert str(info.value) == "train.yaml: key 'epochs': 1000000000 is above its upper bound 10000"
    with pytest.raises(ConfigError, match="key 'batch_size': 5000 is above its upper bound 4096"):
        TrainConfig(batch_size=5000)  # built in code, too


@pytest.mark.parametrize(("key", "bound"), list(TagTrainConfig.upper_bounds.items()))
def test_tag_training_sizes_are_bounded(key: str, bound: float) -> None:
    with pytest.raises(ConfigError, match=r"^tagging\.json: " + refused(key, bound)):
        TagTrainConfig.from_dict({key: bound + 1}, source="tagging.json")
    assert getattr(TagTrainConfig.from_dict({key: bound}), key) == bound
