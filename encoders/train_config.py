"""Configuration of a training run: :class:`TrainConfig`, the model (:mod:`encoders.config`) and how it trains.

Reading and writing go through :mod:`scenesearch_base.config` (``TrainConfig.from_yaml(path)``, ``to_yaml(path)``):
unknown keys are an error that lists them all, with their dotted path. A run folder keeps its config as
``config.json`` (:meth:`TrainConfig.to_json`, :meth:`TrainConfig.from_json`), which holds every key: a
run's config that lacks one was written by an older version and is refused. Complete recipes are files
selected by name (:mod:`encoders.presets`).
"""

from __future__ import annotations

import dataclasses
import json
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any, ClassVar

from encoders.config import ConfigError, DualEncoderConfig, EncodersConfig, check_device_name, ordered_names
from scenesearch_base.config import check_at_least, check_fraction


class HardNegative(StrEnum):
    """Edits of a clip's steps whose captions train as extra negatives of the clip (:mod:`encoders.negatives`)."""

    REVERSE = "reverse"  #: the steps in reverse order


def hard_negative_kinds(names: Sequence[str], where: str) -> tuple[HardNegative, ...]:
    """``names`` as :class:`HardNegative` edits in the enum's order, without repeats (resume compares them)."""
    return tuple(HardNegative(k) for k in ordered_names(names, where, [k.value for k in HardNegative]))


@dataclass(frozen=True)
class TrainConfig(EncodersConfig):
    """A training run.

    Attributes:
        model: the model.
        epochs: passes over the training split.
        batch_size: clips per step.
        lr: peak learning rate of AdamW.
        weight_decay: AdamW weight decay (not applied to biases, norms, embeddings and the logit scale).
        warmup_steps: linear warm-up steps, then cosine decay to 0 at the last step.
        grad_clip: clip the global gradient norm to this (0 disables).
        seed: seeds python, numpy, torch, the data order, the augmentation and the data-loader workers.
        num_workers: data-loader worker processes.
        device: ``auto`` (CUDA when available, else CPU), ``cpu`` or ``cuda[:i]``.
        amp: bf16 autocast on CUDA (ignored on CPU).
        augment: train on seeded caption paraphrases instead of the canonical caption.
        eval_every: run validation every this many epochs (and always after the last).
        max_steps_per_epoch: cap steps per epoch (0 = the whole split); for smoke runs.
        eval_batch_size: clips per forward pass in validation and embedding.
        shuffle_frames: train on clips whose frames are shuffled in time (the bag-of-frames baseline).
        hard_negatives: edits of each clip's steps (``reverse``) whose captions
            join the batch as extra negatives on the clip → text side (empty: in-batch negatives only).
        order_weight: weight of :func:`encoders.loss.order_loss` (a clip against its steps reversed; needs ``reverse``).
        view_weight: weight of the contrastive losses of each view alone (the camera view over the
            clips with camera, the BEV view over all), added to the fused view's loss (0: fused only):
            through the fused view alone, where BEV carries most of the signal, the camera tower barely learns.
        camera_share: when fewer of the training clips than this share have a camera view, every step's batch
            holds this share of camera clips, drawn again as often as needed (:class:`encoders.sampler.EpochSampler`;
            0: one permutation): logs without sensors thin the camera clips out, and its loss needs several a batch.
        dense_weight: weight of the dense loss: each clip frame's rule tags (``model.dense_tasks``) predicted
            from the frame tokens of the streams in ``model.dense_streams`` (:mod:`encoders.dense`); needs a
            clip table with frame tags.
        calibrate_camera: after the last epoch, weigh the camera view in the fusion by the weight with
            the best validation mAP (:mod:`encoders.calibration`); off, the fusion keeps the equal
            mean that training used.
        camera_apart: the camera tower learns beside the shared space, not in it: its own view loss
            against captions whose vectors it does not move, and its dense heads; the fused view reads
            its vectors without their gradient. Otherwise what the camera explains of a caption is asked
            less of the BEV tower and the text tower bends towards what the camera sees, which costs
            clips without a camera (needs ``view_weight`` > 0: the camera's one contrastive loss).
        partial_weight: weight of :func:`encoders.loss.partial_query_loss`: the halves of the clips'
            captions (the object's sentence, the ego's) as queries of their own beside the whole captions
            (:mod:`encoders.partial_queries`; 0: none). People type one half ("a stopped car in the ego
            lane"); a model that only ever read whole captions finds the clips of a half much worse.
        partial_object_share: share of a step's clips whose object sentence trains as a query.
        partial_host_share: share of a step's clips whose ego sentence trains as a query (the clips of a log
            at one time share it, so a few carry it).

    Upper bounds: ``epochs`` 10000, ``batch_size`` and ``eval_batch_size`` 4096, ``num_workers`` 256,
    ``max_steps_per_epoch`` 500000.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"epochs": 10_000, "batch_size": 4096, "eval_batch_size": 4096,
                                                   "num_workers": 256, "max_steps_per_epoch": 500_000}

    model: DualEncoderConfig = field(default_factory=DualEncoderConfig)
    epochs: int = 10
    batch_size: int = 32
    lr: float = 1e-3
    weight_decay: float = 0.05
    warmup_steps: int = 50
    grad_clip: float = 1.0
    seed: int = 0
    num_workers: int = 0
    device: str = "auto"
    amp: bool = True
    augment: bool = True
    eval_every: int = 1
    max_steps_per_epoch: int = 0
    eval_batch_size: int = 32
    shuffle_frames: bool = False
    hard_negatives: tuple[HardNegative, ...] = ()
    order_weight: float = 0.0
    view_weight: float = 1.0
    camera_share: float = 0.0
    dense_weight: float = 0.0
    calibrate_camera: bool = True
    camera_apart: bool = False
    partial_weight: float = 0.0
    partial_object_share: float = 1.0
    partial_host_share: float = 0.25

    def __post_init__(self) -> None:
        super().__post_init__()
        kinds = hard_negative_kinds(self.hard_negatives, "TrainConfig.hard_negatives")
        object.__setattr__(self, "hard_negatives", kinds)
        check_at_least("TrainConfig", 1, error=ConfigError, epochs=self.epochs, batch_size=self.batch_size,
                       eval_every=self.eval_every, eval_batch_size=self.eval_batch_size)
        check_at_least("TrainConfig", 0, error=ConfigError, lr=self.lr, weight_decay=self.weight_decay,
                       warmup_steps=self.warmup_steps, grad_clip=self.grad_clip, num_workers=self.num_workers,
                       view_weight=self.view_weight, dense_weight=self.dense_weight, order_weight=self.order_weight,
                       partial_weight=self.partial_weight)
        if self.order_weight > 0 and HardNegative.REVERSE not in self.hard_negatives:
            raise ConfigError("TrainConfig.order_weight > 0 needs 'reverse' among hard_negatives")
        if self.camera_apart and self.view_weight <= 0:
            raise ConfigError("TrainConfig.camera_apart needs view_weight > 0: the camera view's own loss is then "
                              "all that trains it contrastively")
        if self.dense_weight > 0 and not self.model.dense_streams:
            raise ConfigError("TrainConfig.dense_weight > 0 needs dense heads: set model.dense_streams")
        check_fraction("TrainConfig", error=ConfigError, camera_share=self.camera_share,
                       partial_object_share=self.partial_object_share, partial_host_share=self.partial_host_share)
        check_at_least("TrainConfig", 0, error=ConfigError, max_steps_per_epoch=self.max_steps_per_epoch)
        check_device_name(self.device, "TrainConfig.device")

    def to_json(self) -> str:
        """The ``config.json`` of a run folder (sorted keys, so that two runs' files diff cleanly)."""
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, path: Path | str) -> TrainConfig:
        """The config of a run folder's ``config.json``; :class:`ConfigError` names the file and key."""
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ConfigError(f"{path}: cannot read config ({exc})") from None
        return cls.from_run_dict(data, source=str(path))

    @classmethod
    def from_run_dict(cls, data: Any, source: str = "<dict>") -> TrainConfig:
        """A config that a run wrote (its ``config.json``, its checkpoint's), which holds every key.

        Raises:
            ConfigError: a key is missing (an older version wrote the run: train it again), unknown, or
                holds a bad value; the message names ``source`` and the keys.
        """
        config = cls.from_dict(data, source=source)
        missing = _missing_keys(cls, data)
        if missing:
            raise ConfigError(f"{source}: written by an older version (it lacks {', '.join(missing)}): "
                              "train the model again")
        return config


def _missing_keys(cls: type, data: Mapping[str, Any], prefix: str = "") -> list[str]:
    """The dotted keys of the nested config dataclass ``cls`` that ``data`` lacks."""
    hints = typing.get_type_hints(cls)
    missing = []
    for f in dataclasses.fields(cls):
        value = data.get(f.name)
        if f.name not in data:
            missing.append(f"{prefix}{f.name}")
        elif isinstance(value, Mapping) and dataclasses.is_dataclass(hints[f.name]):
            missing += _missing_keys(hints[f.name], value, f"{prefix}{f.name}.")
    return missing
