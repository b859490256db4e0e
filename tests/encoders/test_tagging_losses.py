"""Tagging losses against naive references; task-balanced sampling; target downsampling; config round trips."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from encoders.tagging.ablation import mask_inputs
from encoders.tagging.attributes import FOOTPRINT_M2, OUTPUT_SCALE, TagError
from encoders.tagging.config import TagTrainConfig
from encoders.tagging.head import TagHead, TagHeadConfig
from encoders.tagging.losses import (
    TagLossConfig,
    TaskBalancedSampler,
    downsample_targets,
    hard_negative_bce,
    smooth_l1_scene,
    tag_loss,
)


def naive_hard_negative_bce(logits: torch.Tensor, targets: torch.Tensor, k: int, min_neg: int) -> float:
    rows = []
    for x, t in zip(logits.tolist(), targets.tolist()):
        pos = [i for i, v in enumerate(t) if v >= 0.5]
        neg = sorted((i for i, v in enumerate(t) if v < 0.5), key=lambda i: -x[i])
        keep = neg[: (k * len(pos) if pos else min_neg)]
        sel = pos + keep
        if not sel:
            continue
        bce = [math.log1p(math.exp(-x[i])) if i in pos else math.log1p(math.exp(x[i])) for i in sel]
        rows.append(sum(bce) / len(sel))
    return sum(rows) / len(rows)


def test_hard_negative_bce_matches_the_naive_reference() -> None:
    g = torch.Generator().manual_seed(0)
    logits = torch.randn(6, 40, generator=g)
    targets = (torch.rand(6, 40, generator=g) < 0.08).float()
    targets[2] = 0.0  # a frame without positives keeps min_negatives hardest negatives
    targets[3, :] = 0.0
    targets[3, :39] = 1.0  # fewer negatives than k × positives: all negatives
    for k, m in ((3, 4), (1, 0), (0, 2)):
        got = float(hard_negative_bce(logits, targets, k, m))
        assert got == pytest.approx(naive_hard_negative_bce(logits, targets, k, m), rel=1e-5)


def test_hard_negative_mining_ignores_easy_negatives() -> None:
    logits = torch.tensor([[5.0, -9.0, -9.0, 2.0, -9.0, -9.0, -9.0, -9.0]])
    targets = torch.tensor([[1.0, 0, 0, 0, 0, 0, 0, 0]])
    base = float(hard_negative_bce(logits, targets, k=1))
    logits2 = logits.clone()
    logits2[0, 4] = -20.0  # an easy negative changes: no effect
    assert float(hard_negative_bce(logits2, targets, k=1)) == pytest.approx(base)
    logits3 = logits.clone()
    logits3[0, 3] = 0.0  # the hard negative changes: effect
    assert float(hard_negative_bce(logits3, targets, k=1)) < base


def test_smooth_l1_scene_compares_sums() -> None:
    pred = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    target = torch.tensor([[0.0, 0.0, 1.0], [0.0, 3.0, 0.0]])
    # Same sum in row 0 (0 loss), sums 0 vs 3 in row 1 (|d| = 3/1 ≥ β: 3 − β/2).
    assert float(smooth_l1_scene(pred, target, beta=1.0, norm=1.0)) == pytest.approx((0 + 2.5) / 2)


def test_tag_loss_separates_discrete_and_continuous_terms() -> None:
    v = torch.zeros(1, 2, 2, 4, 4, requires_grad=True)  # (B, T, A, h, w): A = [density, discrete]
    t = torch.zeros(1, 2, 2, 4, 4)
    t[0, :, 0, 1, 1] = 0.5
    t[0, :, 1, 2, 2] = 1.0
    cfg = TagLossConfig(scene_weight=0.0, continuous_weight=1.0, smooth_l1_beta=0.1)
    loss, parts = tag_loss(v, t, torch.tensor([False, True]), torch.ones(2), cfg)
    assert parts["pixel_l1"] == pytest.approx((0.5 - 0.05) / 16)
    assert parts["discrete"] == pytest.approx(math.log(2.0), rel=1e-5)  # logits 0 on 1 pos + 3 negatives
    loss.backward()
    assert v.grad is not None and float(v.grad[0, :, 1].abs().sum()) > 0
    # The scene-sum term applies to densities only.
    cfg2 = TagLossConfig(scene_weight=1.0, continuous_weight=1.0, smooth_l1_beta=0.1, scene_norm=1.0)
    kinds, ones = torch.tensor([False, True]), torch.ones(2)
    _, with_scene = tag_loss(v, t, kinds, ones, cfg2, density=torch.tensor([True, False]))
    _, without = tag_loss(v, t, kinds, ones, cfg2, density=torch.tensor([False, False]))
    assert with_scene["scene_l1"] == pytest.approx(0.5 - 0.05) and without["scene_l1"] == 0.0  # sums 0.5 vs 0


def test_a_density_learned_as_presence_takes_its_own_bce_term_on_any_object_in_the_cell() -> None:
    g = torch.Generator().manual_seed(0)
    v = torch.randn(2, 3, 2, 4, 4, generator=g, requires_grad=True)  # A = [pedestrian-like density, discrete]
    t = torch.zeros(2, 3, 2, 4, 4)
    t[:, :, 0, 1, 2] = 0.04  # a small object covers 4 % of one cell
    t[0, :, 1, 3, 3] = 1.0
    cfg = TagLossConfig(scene_weight=1.0, scene_norm=1.0)
    discrete = torch.tensor([False, True])
    density = torch.tensor([True, False])
    loss, parts = tag_loss(v, t, discrete, torch.ones(2), cfg, density=density, presence=torch.tensor([True, False]))
    # Each row through the hard-negative BCE on its own, the density's on target > 0; no continuous term is left.
    logits = v.detach().transpose(1, 2).reshape(2, 2, 3, 16).transpose(0, 1).reshape(2, 6, 16)  # (A, B*T, P)
    targets = t.transpose(1, 2).reshape(2, 2, 3, 16).transpose(0, 1).reshape(2, 6, 16)
    want_presence = hard_negative_bce(logits[0], (targets[0] > 0).float(), cfg.hard_negatives, cfg.min_negatives)
    want_discrete = hard_negative_bce(logits[1], targets[1], cfg.hard_negatives, cfg.min_negatives)
    assert parts["presence"] == pytest.approx(float(want_presence), rel=1e-6)
    assert parts["discrete"] == pytest.approx(float(want_discrete), rel=1e-6)
    assert parts["pixel_l1"] == 0.0 and parts["scene_l1"] == 0.0
    assert float(loss.detach()) == pytest.approx(float(want_presence + want_discrete), rel=1e-6)
    loss.backward()
    assert v.grad is not None and float(v.grad[:, :, 0].abs().sum()) > 0
    # Its weight is its own: the discrete attributes do not dilute it.
    heavy, _ = tag_loss(v, t, discrete, torch.ones(2), dataclasses.replace(cfg, presence_weight=3.0),
                        density=density, presence=torch.tensor([True, False]))
    assert float(heavy.detach()) == pytest.approx(float(3 * want_presence + want_discrete), rel=1e-6)
    # Nor does their number: with two more discrete rows the presence row's gradient is the same.
    v4 = torch.cat([v.detach(), v.detach()[:, :, 1:].repeat(1, 1, 2, 1, 1)], dim=2).requires_grad_(True)
    t4 = torch.cat([t, t[:, :, 1:].repeat(1, 1, 2, 1, 1)], dim=2)
    more, _ = tag_loss(v4, t4, torch.tensor([False, True, True, True]), torch.ones(4), cfg,
                       density=torch.tensor([True, False, False, False]),
                       presence=torch.tensor([True, False, False, False]))
    more.backward()
    assert v4.grad is not None and torch.allclose(v4.grad[:, :, 0], v.grad[:, :, 0])
    # Without the presence mask the same density is regressed.
    _, regressed = tag_loss(v, t, discrete, torch.ones(2), cfg, density=density)
    assert regressed["pixel_l1"] > 0.0 and regressed["presence"] == 0.0
    with pytest.raises(TagError, match="presence_weight"):
        TagLossConfig(presence_weight=-1.0)


def test_head_config_records_densities_learned_as_presence() -> None:
    head = TagHeadConfig(attributes=("parked", "vehicle_density", "pedestrian_density"), embed_channels=4)
    assert head.footprints == {"pedestrian_density": FOOTPRINT_M2["pedestrian_density"]}
    assert head.footprint_share("pedestrian_density", 4.0) == pytest.approx(FOOTPRINT_M2["pedestrian_density"] / 4)
    assert head.footprint_share("vehicle_density", 4.0) is None
    assert TagHead(head).presence_mask().tolist() == [False, False, True]
    saved = head.to_dict()
    assert TagHeadConfig.from_dict(saved) == head
    # A head saved before presence densities regressed every density: it reads back so.
    legacy = {k: v for k, v in saved.items() if k != "footprints"}
    assert TagHeadConfig.from_dict(legacy).footprints == {}
    with pytest.raises(TagError, match="densities the head has"):
        TagHeadConfig(attributes=("parked", "pedestrian_density"), footprints={"parked": 0.36})
    with pytest.raises(TagError, match="finite and > 0"):
        TagHeadConfig(attributes=("pedestrian_density",), footprints={"pedestrian_density": float("nan")})


def test_task_balanced_sampler_is_uniform_over_attributes() -> None:
    present = np.zeros((1000, 3), bool)
    present[:900, 0] = True  # common
    present[900:905, 1] = True  # rare
    present[:, 2] = False  # never: not drawn
    sampler = TaskBalancedSampler(present, 6000, seed=1)
    attrs, items = sampler.draw()
    counts = np.bincount(attrs, minlength=3)
    assert counts[2] == 0 and abs(counts[0] - counts[1]) < 300
    assert present[items, attrs].all()  # each drawn item has its attribute
    assert list(sampler) == list(TaskBalancedSampler(present, 6000, seed=1))  # seeded
    sampler.set_epoch(1)
    assert list(sampler) != list(TaskBalancedSampler(present, 6000, seed=1))
    with pytest.raises(TagError):
        TaskBalancedSampler(np.zeros((4, 2), bool), 10)


def test_downsample_targets_area_for_densities_max_otherwise() -> None:
    t = torch.zeros(1, 2, 4, 4)
    t[0, 0, 0, 0] = 1.0
    t[0, 1, 0, 0] = 1.0
    out = downsample_targets(t, 2, torch.tensor([True, False]))
    assert out.shape == (1, 2, 2, 2)
    assert float(out[0, 0, 0, 0]) == 0.25 and float(out[0, 1, 0, 0]) == 1.0
    assert torch.equal(out, torch.stack([F.avg_pool2d(t, 2)[0, 0], F.max_pool2d(t, 2)[0, 1]])[None])


def test_mask_inputs_zeroes_the_unused_view() -> None:
    batch = {"bev_lidar": torch.ones(1, 2, 3, 4, 4), "bev_map": torch.ones(1, 2, 5, 4, 4)}
    only_map = mask_inputs(batch, "map")
    assert float(only_map["bev_lidar"].sum()) == 0 and float(only_map["bev_map"].sum()) > 0
    assert float(mask_inputs(batch, "lidar")["bev_map"].sum()) == 0
    none = mask_inputs(batch, "none")
    assert float(none["bev_lidar"].sum() + none["bev_map"].sum()) == 0
    assert mask_inputs(batch, "both") is batch and float(batch["bev_lidar"].sum()) > 0
    with pytest.raises(TagError, match="valid: none, map, lidar, both"):
        mask_inputs(batch, "camera")


def test_configs_round_trip_yaml_and_reject_unknown_keys() -> None:
    cfg = TagTrainConfig(mode="alone", inputs="map", steps=7, loss=TagLossConfig(hard_negatives=2))
    assert TagTrainConfig.from_yaml_text(cfg.to_yaml_text()) == cfg
    head = TagHeadConfig(attributes=("parked", "ego_brake_cause"), embed_channels=8,
                         kinds={"ego_brake_cause": "discrete"})
    assert TagHeadConfig.from_dict(head.to_dict()) == head
    with pytest.raises(ValueError, match="unknown keys"):
        TagTrainConfig.from_dict({"lossy": 1})
    with pytest.raises(ValueError, match="inputs"):
        TagTrainConfig(inputs="radar")
    with pytest.raises(TagError, match="repeats"):
        TagHeadConfig(attributes=("parked", "parked"))


def test_head_config_records_every_output_scale(monkeypatch: pytest.MonkeyPatch) -> None:
    saved = TagHeadConfig(attributes=("parked", "vehicle_speed", "pedestrian_density"), embed_channels=4,
                          scales={"pedestrian_density": 0.05}).to_dict()
    assert saved["scales"] == {"parked": 1.0, "vehicle_speed": 10.0, "pedestrian_density": 0.05}
    # The defaults change later: a saved head keeps the scales it was trained with.
    monkeypatch.setitem(OUTPUT_SCALE, "vehicle_speed", 5.0)
    head = TagHead(TagHeadConfig.from_dict(saved))
    assert head.scale.tolist() == pytest.approx([1.0, 10.0, 0.05])
    # A file written before the scales were recorded reads back with the defaults.
    legacy = {k: v for k, v in saved.items() if k != "scales"}
    assert TagHeadConfig.from_dict(legacy).scales["vehicle_speed"] == 5.0
    with pytest.raises(TagError, match="does not have"):
        TagHeadConfig(attributes=("parked",), scales={"stopped": 2.0})
    with pytest.raises(TagError, match="finite and > 0"):
        TagHeadConfig(attributes=("parked",), scales={"parked": 0.0})
