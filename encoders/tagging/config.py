"""Configuration of tag training (:class:`TagTrainConfig`), kept by every run folder that answers tag queries.

Training reads it to train; loading a tagging model (:mod:`encoders.tagging.inference`) reads it back
from ``tagging.json`` for the BEV tower, the inputs and the frame spacing the model was trained with.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

from encoders.config import BevConfig, ConfigError, EncodersConfig, check_device_name
from encoders.tagging.ablation import parse_inputs
from encoders.tagging.losses import TagLossConfig
from scenesearch_base.config import check_at_least, check_positive

MODES = ("joint", "alone")


def tagging_bev_config() -> BevConfig:
    """The BEV tower trained for tags alone (the one ``benchmarks/bench_tagging.py`` measures).

    Four stages (strides 2–16) then two dilated context blocks: a receptive field of about 80 m.
    A junction's kind (3-way or 4-way) is only visible with all its arms in view, also from the far
    end of an approach lane; with four plain stages (about 15 m) ``four_way`` stayed at the
    statistics, with the context blocks it rose well above them. D_e = 64: with 32 channels shared by
    the 15 attributes, pedestrian density (a sparse, small signal) stayed behind the statistics. The
    figures: ``docs/research/tagging.md``.
    """
    return BevConfig(widths=(8, 16, 32, 64), embed_channels=64, downsample=2, context_blocks=2)


@dataclass(frozen=True)
class TagTrainConfig(EncodersConfig):
    """Tag training.

    Attributes:
        mode: ``joint`` (with the contrastive loss, in ``scenesearch train``) or ``alone``.
        inputs: BEV inputs the model sees: ``none``, ``map``, ``lidar`` or ``both``.
        bev: the BEV tower trained ``alone`` (joint runs use the dual encoder's).
        loss: the tagging loss.
        joint_weight: weight of the tag loss added to the contrastive loss in joint training.
        joint_presence_weight: in joint training, the weight of the presence term (densities learned as
            presence) in place of ``loss.presence_weight``. Beside the contrastive losses the shared tower
            learns presence only with a stronger pull and a wider first stage; alone, weight 1 does best
            (``docs/research/tagging.md``).
        window_frames: T frames per training window.
        frame_stride: frames between the window's frames (the same spacing is used at query time).
        batch_size: windows per step.
        steps: optimiser steps (``alone``).
        lr: peak AdamW learning rate (``alone``), linear warm-up then cosine decay.
        warmup_steps: warm-up steps.
        weight_decay: AdamW weight decay.
        seed: seeds torch, numpy and the sampler.
        device: ``auto``, ``cpu`` or ``cuda[:i]``.
        log_every: steps between lines of ``tag_metrics.jsonl``.

    Upper bounds: ``window_frames`` 256, ``frame_stride`` 100, ``batch_size`` 4096, ``steps`` 500000.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"window_frames": 256, "frame_stride": 100, "batch_size": 4096,
                                                   "steps": 500_000}

    mode: str = "joint"
    inputs: str = "both"
    bev: BevConfig = field(default_factory=tagging_bev_config)
    loss: TagLossConfig = field(default_factory=TagLossConfig)
    joint_weight: float = 1.0
    joint_presence_weight: float = 5.0
    window_frames: int = 5
    frame_stride: int = 2
    batch_size: int = 8
    steps: int = 400
    lr: float = 3e-3
    warmup_steps: int = 20
    weight_decay: float = 1e-4
    seed: int = 0
    device: str = "auto"
    log_every: int = 20

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.mode not in MODES:
            raise ConfigError(f"TagTrainConfig.mode must be one of {MODES}, got {self.mode!r}")
        parse_inputs(self.inputs)
        check_at_least("TagTrainConfig", 1, error=ConfigError, window_frames=self.window_frames,
                       frame_stride=self.frame_stride, batch_size=self.batch_size, steps=self.steps,
                       log_every=self.log_every)
        check_positive("TagTrainConfig", error=ConfigError, lr=self.lr)
        check_at_least("TagTrainConfig", 0, error=ConfigError, weight_decay=self.weight_decay,
                       joint_weight=self.joint_weight, joint_presence_weight=self.joint_presence_weight,
                       warmup_steps=self.warmup_steps)
        check_device_name(self.device, "TagTrainConfig.device")
