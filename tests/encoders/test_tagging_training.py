"""Training alone, loading, whole-log inference, the joint-training hook, new attributes, evaluation."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from encoders.clips.blocks import BlockArray
from encoders.presets import preset
from encoders.tagging.attributes import ATTRIBUTES, FOOTPRINT_M2, TagError
from encoders.tagging.config import TagTrainConfig
from encoders.tagging.evaluate import evaluate_runs, write_report
from encoders.tagging.extend import CAUSES_EGO_BRAKING, add_attributes, ego_brake_cause_targets
from encoders.tagging.inference import EMBEDDING_PREFIXES, load_tagger
from encoders.tagging.targets import open_targets
from encoders.tagging.training import attach_tagging
from tests.encoders.tagging_fixtures import build_tagging_fixture


@pytest.fixture(scope="module")
def fixture(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    torch.manual_seed(0)
    return build_tagging_fixture(tmp_path_factory.mktemp("tagging"), num_frames=8, steps=2)


def test_run_folder_loads_and_tags_whole_logs_chunk_independently(fixture: dict[str, Any]) -> None:
    tagger = load_tagger(fixture["run"])
    assert tagger.names == tuple(a.value for a in ATTRIBUTES)
    folder = Path(fixture["clips"]) / "logs" / "tagged_0"
    lidar = BlockArray(folder / "bev_lidar.blocks")[:]
    bev_map = BlockArray(folder / "bev_map.blocks")[:]
    full = tagger.tag_frames(lidar, bev_map, chunk=64)
    assert full.shape == (8, len(ATTRIBUTES), 80, 40) and np.isfinite(full).all()
    # Chunks with temporal context give the same tensors as one pass.
    np.testing.assert_allclose(tagger.tag_frames(lidar, bev_map, chunk=2), full, atol=1e-5)
    # The stride-2 phases: frames 0, 2, 4, ... form one sequence.
    x = {k: torch.from_numpy(np.array(a[0::2])).float().div(255.0)[None] for k, a in
         (("bev_lidar", lidar), ("bev_map", bev_map))}
    with torch.no_grad():
        direct = tagger.head(tagger.bev.embed_map(x["bev_lidar"], x["bev_map"]))[0].numpy()
    np.testing.assert_allclose(full[0::2], direct, atol=1e-5)


def test_joint_hook_adds_the_head_to_the_optimiser_and_gives_a_loss(fixture: dict[str, Any]) -> None:
    from encoders.bev import BevTower
    from tests.encoders.tagging_fixtures import tiny_bev_config

    class Model(torch.nn.Module):  # what the hook needs of a DualEncoder: .config.bev, .bev_embedding
        def __init__(self) -> None:
            super().__init__()
            self.bev = BevTower(tiny_bev_config(), 16)
            self.config = type("C", (), {"bev": tiny_bev_config()})()

        def bev_embedding(self, batch: dict[str, Any]) -> torch.Tensor:
            return self.bev.embed_map(batch["bev_lidar"], batch["bev_map"])

    model = Model()
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    objective = attach_tagging(fixture["clips"], model, TagTrainConfig(batch_size=2, window_frames=3), optimizer=opt)
    assert objective is not None and len(opt.param_groups) == 2 and objective.optimizer is None
    assert objective.config.bev == tiny_bev_config()  # the run records the tower the tags ride on
    # Joint training learns small densities as presence too, with the presence term at its own weight.
    assert objective.head.config.footprints == {"pedestrian_density": FOOTPRINT_M2["pedestrian_density"]}
    loss = objective.loss(model.bev_embedding)
    loss.backward()
    assert torch.isfinite(loss) and objective.head.attributes.grad is not None
    parts = objective.last_parts
    without = attach_tagging(fixture["clips"], model, TagTrainConfig(batch_size=2, window_frames=3,
                                                                     joint_presence_weight=0.0),
                             optimizer=torch.optim.AdamW(model.parameters(), lr=1e-3))
    assert without is not None
    without.head.load_state_dict(objective.head.state_dict())
    with torch.no_grad():  # the same first batch and head: the losses differ by the weighted presence term
        loss_0 = without.loss(model.bev_embedding)
    weight = TagTrainConfig().joint_presence_weight
    assert weight > 0 and float(loss.detach()) == pytest.approx(float(loss_0) + weight * parts["presence"], rel=1e-5)
    # A state saved before heads recorded their reading resumes with every density regressed.
    state = objective.training_state()
    assert state["footprints"] == objective.head.config.footprints
    del state["footprints"]
    without.load_training_state(state)
    assert without.head.config.footprints == {} and not bool(without.head.presence_mask().any())
    assert attach_tagging(fixture["clips"], model, TagTrainConfig(mode="alone")) is None
    # Without an optimiser the objective trains its head itself.
    own = attach_tagging(fixture["clips"], model, TagTrainConfig(batch_size=2, window_frames=3))
    assert own is not None and own.optimizer is not None
    before = own.head.attributes.detach().clone()
    own.loss(model.bev_embedding).backward()
    own.step(1e-2)
    assert not torch.equal(before, own.head.attributes) and own.head.attributes.grad is None


def test_new_attribute_keeps_old_rows_with_a_frozen_backbone(fixture: dict[str, Any], tmp_path: Path) -> None:
    base = load_tagger(fixture["run"])
    res = add_attributes(fixture["run"], [CAUSES_EGO_BRAKING], ego_brake_cause_targets, tmp_path / "ext",
                         fixture["clips"], fixture["logs"], config=TagTrainConfig(
                             mode="alone", steps=2, batch_size=2, window_frames=3, device="cpu", warmup_steps=1))
    ext = load_tagger(res.run_dir)
    assert ext.names == (*base.names, CAUSES_EGO_BRAKING)
    assert ext.head.config.footprints == base.head.config.footprints  # old rows keep their reading
    torch.testing.assert_close(ext.head.attributes[:-1], base.head.attributes)
    for k, v in base.bev.state_dict().items():
        if k.startswith(EMBEDDING_PREFIXES):  # the part of the tower behind E
            torch.testing.assert_close(ext.bev.state_dict()[k], v)
    t = open_targets(fixture["clips"], "tagged_0", f"bev_attributes_{CAUSES_EGO_BRAKING}")
    assert t.names == (CAUSES_EGO_BRAKING,) and t.present.all()  # the ego brakes for 'lead' in every frame
    with pytest.raises(TagError, match="new and distinct"):
        add_attributes(fixture["run"], ["parked"], ego_brake_cause_targets, tmp_path / "x", fixture["clips"],
                       fixture["logs"])


def test_a_model_built_on_a_regressed_density_keeps_regressing_it(fixture: dict[str, Any], tmp_path: Path) -> None:
    """A row copied from a head saved before presence densities keeps the reading it was trained for."""
    from encoders.tagging.head import TagHead, TagHeadConfig
    from encoders.tagging.training import train_tags

    base = load_tagger(fixture["run"])
    assert "pedestrian_density" in base.head.config.footprints  # trained now: learned as presence
    legacy = TagHead(TagHeadConfig.from_dict({k: v for k, v in base.head.config.to_dict().items()
                                              if k != "footprints"}))
    legacy.load_state_dict(base.head.state_dict())
    base.head = legacy
    train_tags(fixture["clips"], tmp_path / "re", TagTrainConfig(
        mode="alone", steps=1, batch_size=2, window_frames=3, device="cpu", warmup_steps=1), init=base)
    assert load_tagger(tmp_path / "re").head.config.footprints == {}


def test_evaluation_writes_both_tables(fixture: dict[str, Any], tmp_path: Path) -> None:
    result = evaluate_runs(fixture["run"], fixture["clips"])
    json_path, md_path = write_report(tmp_path, result)
    data = json.loads(json_path.read_text())
    assert set(data["inputs"]) == {"none", "both"}
    assert data["by_region"]["parked"]["front"]["metric"] == "F1"
    assert data["by_region"]["vehicle_density"]["full"]["metric"] == "L1"
    assert set(data["by_region"]["parked"]) == {"full", "front", "behind", "around", "intersection", "crosswalk"}
    # Statistics: 'parked' is in front in every training frame, so the constant "yes" is perfect there.
    assert data["inputs"]["none"]["parked"]["metric"] == "F1"
    assert data["statistics_by_region"]["parked"]["front"]["value"] == 1.0
    assert "Table 1" in md_path.read_text() and "| vehicle_density | L1 |" in md_path.read_text()


def test_the_run_against_the_statistics_is_table_2_compared_row_by_row(
        fixture: dict[str, Any], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import encoders.tagging.versus_statistics as versus_statistics
    from encoders.tagging.versus_statistics import beats_statistics, tagging_against_statistics

    lines: list[str] = []
    versus = tagging_against_statistics(fixture["run"], fixture["clips"], say=lines.append)
    assert versus is not None
    rows = evaluate_runs(fixture["run"], fixture["clips"])["inputs"]  # eval-tags' Table 2
    expected = {a: beats_statistics(cell, rows["none"][a]) for a, cell in rows["both"].items()}
    assert versus["above_statistics"] == expected
    assert versus["statistics"]["parked"] == rows["none"]["parked"]["value"]
    defined = [a for a, above in versus["above_statistics"].items() if above is not None]
    assert versus["defined"] == len(defined) > 0
    assert versus["above_statistics_count"] + len(versus["below_statistics"]) == versus["defined"]
    assert versus["test_logs"] >= 1
    assert lines == [f"eval: the tagging head beats the dataset statistics on {versus['above_statistics_count']} "
                     f"of the {versus['defined']} attributes defined on the {versus['test_logs']} test log(s) "
                     f"(skill {versus['skill']['model']:.3f} against {versus['skill']['statistics']:.3f}; below: "
                     f"{', '.join(versus['below_statistics']) or 'none'})"]
    (tmp_path / "plain").mkdir()
    assert tagging_against_statistics(tmp_path / "plain", fixture["clips"]) is None  # trained without tagging

    def no_targets(*args: object, **kwargs: object) -> None:
        raise FileNotFoundError("clips: no test logs with tag targets")

    monkeypatch.setattr(versus_statistics, "evaluate_runs", no_targets)
    lines.clear()
    assert tagging_against_statistics(fixture["run"], fixture["clips"], say=lines.append) is None
    assert lines == ["eval: the tagging head is not scored (clips: no test logs with tag targets)"]


def test_a_joint_run_takes_the_backbone_from_the_dual_encoder(fixture: dict[str, Any], tmp_path: Path) -> None:
    from safetensors.torch import save_file

    from encoders.config import tiny_model_config
    from encoders.model import DualEncoder
    from encoders.train_config import TrainConfig

    config = TrainConfig(model=tiny_model_config(lidar_channels=4, map_channels=6))
    model = DualEncoder(config.model)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    objective = attach_tagging(fixture["clips"], model, TagTrainConfig(batch_size=2, window_frames=3), optimizer=opt)
    assert objective is not None
    objective.loss(model.bev_embedding).backward()
    run = tmp_path / "joint"
    run.mkdir()
    (run / "config.json").write_text(config.to_json())
    save_file({k: v.detach().contiguous() for k, v in model.saved_state_dict().items()}, str(run / "model.safetensors"))
    objective.save(run)
    tagger = load_tagger(run)
    for k, v in model.bev.state_dict().items():
        torch.testing.assert_close(tagger.bev.state_dict()[k], v)
    torch.testing.assert_close(tagger.head.attributes, objective.head.attributes.detach())
    assert not (run / "tag_backbone.safetensors").exists()


def test_scenesearch_training_adds_the_tag_loss_and_writes_the_head(fixture: dict[str, Any], tmp_path: Path) -> None:
    import dataclasses

    from encoders.train import train

    config = dataclasses.replace(preset("tiny").train, epochs=1, batch_size=2, device="cpu")
    lines: list[str] = []
    train(fixture["clips"], tmp_path / "joint", config, log=lines.append, progress=False,
          tagging=TagTrainConfig(batch_size=2, window_frames=3, inputs="lidar"))
    assert any(line.startswith("tagging on") for line in lines)
    tagger = load_tagger(tmp_path / "joint")
    assert tagger.inputs.value == "lidar" and len(tagger.names) == len(ATTRIBUTES)

    # `scenesearch eval` scores the head against the dataset statistics beside the retrieval figures.
    from encoders.tagging.versus_statistics import tagging_against_statistics
    from retrieval.evaluation import evaluate
    from retrieval.metrics_tables import metrics_table
    from tests.retrieval.retrieval_fakes import HashTextEncoder

    metrics = evaluate(tmp_path / "joint", fixture["clips"], split="test", sentence_encoder=HashTextEncoder())
    assert metrics["tagging"] == tagging_against_statistics(tmp_path / "joint", fixture["clips"])
    assert metrics["tagging"]["defined"] > 0
    assert "the tagging head beats the dataset statistics on" in metrics_table(metrics)
    for split in ("all", "val"):  # no thresholds chosen on the logs scored
        assert "tagging" not in evaluate(tmp_path / "joint", fixture["clips"], split=split,
                                         sentence_encoder=HashTextEncoder())
