"""The fusion's camera weight: what it does to the fused view, its choice on validation, old weights."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from encoders.calibration import CAMERA_WEIGHTS, calibrate_camera_weight
from encoders.inference import evaluate, load_model
from encoders.model import DualEncoder
from encoders.presets import preset
from encoders.train import train
from tests.encoders.synthetic import SyntheticClipDataset, SyntheticSpec

SPEC = SyntheticSpec(frames=6, camera_hw=(24, 32), bev_hw=(24, 12), distractors=1)


def tiny_model(seed: int = 0) -> DualEncoder:
    torch.manual_seed(seed)
    config = preset("tiny").train.model
    item = SyntheticClipDataset(1, "val", SPEC, seed=1)[0]
    bev = dataclasses.replace(config.bev, lidar_channels=int(item["bev_lidar"].shape[1]),
                              map_channels=int(item["bev_map"].shape[1]))
    camera = dataclasses.replace(config.camera, in_channels=int(item["camera"].shape[1]))
    return DualEncoder(dataclasses.replace(config, bev=bev, camera=camera)).eval()


def test_the_camera_weight_sets_how_much_the_camera_view_counts() -> None:
    model = tiny_model()
    fusion, d = model.fusion, model.config.embed_dim
    g = torch.Generator().manual_seed(0)
    camera, bev = torch.randn(4, d, generator=g), torch.randn(4, d, generator=g)
    with_camera = torch.tensor([True, True, False, True])
    equal = fusion(camera, bev, with_camera)
    # 1 (the default, and what weights saved before the weight existed mean): the equal mean.
    mean = (F.normalize(camera, dim=-1) + F.normalize(bev, dim=-1)) / 2
    torch.testing.assert_close(equal[0], (mean + fusion.mlp(mean))[0])
    fusion.set_camera_weight(0.0)  # BEV alone, whatever the camera says
    torch.testing.assert_close(fusion(camera, bev, with_camera), fusion(camera, bev, torch.zeros(4, dtype=torch.bool)))
    fusion.set_camera_weight(0.25)
    quarter = fusion(camera, bev, with_camera)
    torch.testing.assert_close(quarter[2], equal[2])  # a clip without camera is untouched
    assert not torch.allclose(quarter[0], equal[0])
    with pytest.raises(ValueError, match="camera weight must be >= 0"):
        fusion.set_camera_weight(-1.0)


def test_calibration_keeps_the_weight_with_the_best_validation_map() -> None:
    model = tiny_model()
    val = SyntheticClipDataset(12, "val", SPEC, seed=3)
    assert val.camera_flags.any() and not val.camera_flags.all()
    choice = calibrate_camera_weight(model, val, batch_size=5)
    assert list(choice.map_by_weight) == sorted(CAMERA_WEIGHTS) and not choice.reason
    best = max(choice.map_by_weight.values())
    assert choice.map_by_weight[choice.weight] == best
    assert choice.weight == max(w for w, m in choice.map_by_weight.items() if round(m, 6) == round(best, 6))
    assert float(model.fusion.camera_weight) == choice.weight
    # Replaying the fusion over cached views is what embedding the clips with that weight gives.
    assert evaluate(model, val, batch_size=5)["mAP"] == pytest.approx(best, abs=1e-6)
    assert f"camera weight {choice.weight:g} in the fusion, chosen by validation mAP" in choice.describe()


def test_calibration_without_a_camera_clip_or_a_validation_split_leaves_the_weight() -> None:
    model = tiny_model()
    no_camera = SyntheticClipDataset(6, "val", dataclasses.replace(SPEC, camera_fraction=0.0), seed=3)
    choice = calibrate_camera_weight(model, no_camera)
    assert (choice.weight, choice.map_by_weight) == (1.0, {}) and "no camera clip" in choice.describe()
    assert calibrate_camera_weight(model, None).reason == "no validation split"
    assert float(model.fusion.camera_weight) == 1.0


def test_training_saves_the_calibrated_weight_and_weights_without_it_are_refused(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    cfg = dataclasses.replace(preset("tiny").train, batch_size=8, epochs=1)
    data = {"train": SyntheticClipDataset(16, "train", SPEC, seed=1),
            "val": SyntheticClipDataset(8, "val", SPEC, seed=1)}
    lines: list[str] = []
    train("unused", tmp_path / "run", cfg, datasets=data, progress=False, log=lines.append)
    model = load_model(tmp_path / "run")
    weight = float(model.fusion.camera_weight)
    assert weight in CAMERA_WEIGHTS
    assert any(f"camera weight {weight:g} in the fusion, chosen by validation mAP" in line for line in lines)
    assert f"camera weight {weight:g} in the fusion" in (tmp_path / "run" / "model_card.md").read_text()
    # Weights without the fusion's camera weight are another model's.
    state = {k: v for k, v in model.saved_state_dict().items() if k != "fusion.camera_weight"}
    with pytest.raises(ValueError, match=r"missing \['fusion.camera_weight'\]"):
        tiny_model(seed=1).load_saved_state_dict(state)
    # Off, the fusion keeps the equal mean that training used.
    train("unused", tmp_path / "off", dataclasses.replace(cfg, calibrate_camera=False), datasets=data,
          progress=False, log=lambda _m: None)
    assert float(load_model(tmp_path / "off").fusion.camera_weight) == 1.0
    assert "camera weight 1 in the fusion (not calibrated: calibrate_camera is off)" in \
        (tmp_path / "off" / "model_card.md").read_text()
