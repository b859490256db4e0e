"""Training the attribute head (and the BEV backbone) on tag targets, and writing the tagging run files.

Two ways to train, chosen by :attr:`TagTrainConfig.mode`:

- ``joint`` (default): with the contrastive loss, inside ``scenesearch train``. The training loop
  creates a :class:`TaggingObjective` beside the :class:`~encoders.model.DualEncoder`, adds its
  parameters (A and b) to the optimiser, adds ``weight × objective.loss(model)`` to every step's
  loss (the objective draws its own task-balanced batch of tag windows and calls
  ``model.bev_embedding``), and calls ``objective.save(run_dir)`` with the weights. Its checkpoints
  hold :meth:`TaggingObjective.training_state` (head and its reading, optimiser, windows drawn), so a resumed run
  draws the same windows and takes the same steps as one that never stopped.
- ``alone``: :func:`train_tags` trains a :class:`~encoders.bev.BevTower` and the head on the tag
  loss only (``scenesearch eval-tags --train`` and the benchmarks use it for the input ablation).

:func:`save_tagging` writes the files of a run folder that answers tag queries (``tagging.json``,
``tag_head.safetensors`` and, ``alone``, ``tag_backbone.safetensors``); :mod:`encoders.tagging.inference`
loads them.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import save_file
from torch import nn

from encoders.bev import BevTower
from encoders.clips.layout import read_manifest
from encoders.config import BevConfig
from encoders.inference import resolve_device
from encoders.run_folder import claim_run_dir
from encoders.tagging.ablation import mask_inputs
from encoders.tagging.attributes import FOOTPRINT_M2, TagError, is_density
from encoders.tagging.config import TagTrainConfig
from encoders.tagging.data import TagWindowDataset, TargetSource, collate_windows
from encoders.tagging.head import TagHead, TagHeadConfig
from encoders.tagging.inference import BACKBONE_FILE, HEAD_FILE, TAGGING_FILE, Tagger
from encoders.tagging.losses import TaskBalancedSampler, downsample_targets, tag_loss
from scenesearch_base.atomic import atomic_path, atomic_write_text

METRICS_FILE = "tag_metrics.jsonl"


def _area_mask(names: tuple[str, ...], device: torch.device) -> torch.Tensor:
    return torch.tensor([is_density(a) for a in names], device=device)


def window_loss(
    embed: Callable[[dict[str, Any]], torch.Tensor], head: TagHead, batch: dict[str, Any], config: TagTrainConfig,
    device: torch.device,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Tag loss of a batch of windows: ``embed(batch)`` → E (B, T, D_e, h, w), V = head(E), targets pooled to (h, w)."""
    batch = mask_inputs({k: (v.to(device) if isinstance(v, torch.Tensor) else v) for k, v in batch.items()},
                        config.inputs)
    e = embed(batch)  # (B, T, D_e, h, w)
    v = head(e)  # (B, T, A, h, w)
    tg = batch["targets"]  # (B, T, A, H, W)
    b, t, a, hh, _ = tg.shape
    r = hh // v.shape[-2]
    small = downsample_targets(tg.flatten(0, 1), r, _area_mask(head.names, device))  # (B*T, A, h, w)
    small = small.reshape(b, t, a, *small.shape[-2:])
    return tag_loss(v, small, head.discrete_mask(), head.scale, config.loss,
                    density=_area_mask(head.names, device), presence=head.presence_mask())


#: Batches of one task-balanced draw of :class:`TaggingObjective` (the draw is seeded by its number).
BATCHES_PER_DRAW = 64


class TaggingObjective(nn.Module):
    """The tagging term of joint training: owns the head and draws task-balanced windows.

    >>> objective = attach_tagging(clips_dir, model, TagTrainConfig())    # None without tag targets
    >>> loss = contrastive + objective.weight * objective.loss(model.bev_embedding)
    >>> loss.backward(); opt.step(); objective.step(lr)

    The n-th batch drawn is a pure function of (seed, n): draw ``n // BATCHES_PER_DRAW`` of the
    :class:`TaskBalancedSampler`, batch ``n % BATCHES_PER_DRAW`` of it. Drawing touches no global
    random state (training re-seeds torch every step, and must see the same stream whether or not
    a run was resumed between two batches). With ``shard`` (rank, processes) of data-parallel
    training, the n-th batch of each process is its rank-th part of the n-th batch one process would
    draw with ``processes`` times the batch size, and the mean of their losses is that batch's loss.
    """

    def __init__(self, clips_dir: Path | str, config: TagTrainConfig, embed_channels: int,
                 targets: TargetSource | None = None, head_config: TagHeadConfig | None = None,
                 shard: tuple[int, int] = (0, 1)) -> None:
        super().__init__()
        self.clips_dir = Path(clips_dir)
        self.config = config
        self.dataset = TagWindowDataset(self.clips_dir, "train", config.window_frames, config.frame_stride, targets)
        # Densities small against a cell are learned as presence here too, with the presence term at
        # ``joint_presence_weight`` (see TagTrainConfig): at the weight that suits tags alone the row
        # stayed below the reading threshold beside the contrastive losses.
        self._window_config = dataclasses.replace(
            config, loss=dataclasses.replace(config.loss, presence_weight=config.joint_presence_weight))
        hc = head_config or TagHeadConfig(attributes=self.dataset.names, embed_channels=embed_channels)
        if hc.attributes != self.dataset.names:
            raise TagError(f"head attributes {list(hc.attributes)} differ from the targets' {list(self.dataset.names)}")
        self.head = TagHead(hc)
        self.weight = config.joint_weight
        self.shard = shard
        self.batches_drawn = 0
        self._it: Iterator[dict[str, Any]] | None = None
        self.last_parts: dict[str, float] = {}
        self.optimizer: torch.optim.Optimizer | None = None

    def _batches(self) -> Iterator[dict[str, Any]]:
        """Batches from the ``batches_drawn``-th on."""
        size = self.config.batch_size
        rank, processes = self.shard
        whole = size * processes  # windows of a step over all processes
        sampler = TaskBalancedSampler(self.dataset.present, BATCHES_PER_DRAW * whole, self.config.seed)
        while True:
            draw, first = divmod(self.batches_drawn, BATCHES_PER_DRAW)
            sampler.set_epoch(draw)
            items = sampler.draw()[1]  # (BATCHES_PER_DRAW * whole,)
            for b in range(first, BATCHES_PER_DRAW):
                start = b * whole + rank * size
                batch = collate_windows([self.dataset[int(i)] for i in items[start : start + size]])
                self.batches_drawn += 1
                yield batch

    def loss(self, embed: Callable[[dict[str, Any]], torch.Tensor]) -> torch.Tensor:
        """The tag loss of the next task-balanced batch; ``embed`` is e.g. ``model.bev_embedding``."""
        if self._it is None:
            self._it = self._batches()
        device = self.head.attributes.device
        loss, self.last_parts = window_loss(embed, self.head, next(self._it), self._window_config, device)
        return loss

    def step(self, lr: float) -> None:
        """Step the objective's own optimiser (when it has one) at ``lr`` and clear the head's gradients."""
        if self.optimizer is None:
            return
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)

    def training_state(self) -> dict[str, Any]:
        """What a checkpoint keeps to resume exactly: tensors and plain data only (loads with ``weights_only``).

        ``{"attributes": [names], "footprints": {density learned as presence: m²}, "head": head state dict,
        "optimizer": own optimiser state or None, "batches_drawn": int}``; the learning rate is not state:
        :meth:`step` receives it from the training loop's schedule.
        """
        return {
            "attributes": list(self.head.names),
            "footprints": dict(self.head.config.footprints or {}),
            "head": {k: v.detach().cpu().clone() for k, v in self.head.state_dict().items()},
            "optimizer": self.optimizer.state_dict() if self.optimizer is not None else None,
            "batches_drawn": self.batches_drawn,
        }

    def load_training_state(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`training_state` returned; the next batch is the one after the last drawn."""
        saved = list(state.get("attributes") or [])
        if saved != list(self.head.names):
            raise TagError(f"the saved tagging head has attributes {saved}, the clips' tag targets "
                           f"{list(self.head.names)}")
        self.head.load_state_dict(state["head"])
        # Each row goes on being trained for the reading it was trained for; states saved before heads
        # recorded it regressed every density.
        footprints = {str(a): float(v) for a, v in (state.get("footprints") or {}).items()}
        self.head.config = dataclasses.replace(self.head.config, footprints=footprints)
        if (state["optimizer"] is None) != (self.optimizer is None):
            raise TagError("the saved tagging state and this objective differ in who steps the head "
                           "(its own optimiser or the training loop's)")
        if self.optimizer is not None:
            self.optimizer.load_state_dict(state["optimizer"])
        self.batches_drawn = int(state["batches_drawn"])
        self._it = None

    def save(self, run_dir: Path | str, backbone: nn.Module | None = None) -> None:
        save_tagging(run_dir, self.head, self.config, read_manifest(self.clips_dir), backbone,
                     extra={"clips_dir": str(self.clips_dir.resolve())})


def save_tagging(run_dir: Path | str, head: TagHead, config: TagTrainConfig, manifest: dict[str, Any],
                 backbone: nn.Module | None = None, extra: dict[str, Any] | None = None) -> None:
    """Write ``tagging.json``, ``tag_head.safetensors`` and (alone) ``tag_backbone.safetensors`` atomically."""
    run = Path(run_dir)
    run.mkdir(parents=True, exist_ok=True)
    with atomic_path(run / HEAD_FILE) as tmp:
        save_file({k: v.detach().cpu().contiguous() for k, v in head.state_dict().items()}, str(tmp))
    if backbone is not None:
        with atomic_path(run / BACKBONE_FILE) as tmp:
            save_file({k: v.detach().cpu().contiguous() for k, v in backbone.state_dict().items()}, str(tmp))
    meta = {
        "format_version": 1,
        "config": config.to_dict(),
        "head": head.config.to_dict(),
        "grid": manifest["bev"],
        "clips_config": manifest.get("config", {}),
        "backbone": BACKBONE_FILE if backbone is not None else "model.safetensors",
        **(extra or {}),
    }
    atomic_write_text(run / TAGGING_FILE, json.dumps(meta, indent=2))


def _lr_at(step: int, config: TagTrainConfig) -> float:
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    frac = (step - config.warmup_steps) / max(1, config.steps - config.warmup_steps)
    return config.lr * 0.5 * (1.0 + math.cos(math.pi * min(1.0, frac)))


@dataclass
class TagTrainResult:
    """What :func:`train_tags` did."""

    run_dir: Path
    steps: int
    final_loss: float
    seconds: float
    windows_per_s: float


def train_tags(
    clips_dir: Path | str,
    run_dir: Path | str,
    config: TagTrainConfig,
    targets: TargetSource | None = None,
    init: Tagger | None = None,
    train_backbone: bool = True,
    progress: Callable[[str], None] | None = None,
) -> TagTrainResult:
    """Train a BEV tower and the attribute head on the tag loss alone (``mode: alone``).

    Args:
        clips_dir: a clips folder whose logs have tag targets.
        run_dir: output folder.
        config: options.
        targets: where targets come from (default ``bev_attributes.blocks`` of each log).
        init: start from this model's backbone (and its head rows for attributes of the same name).
        train_backbone: train the backbone too (else only A and b).
    """
    say = progress or (lambda _line: None)
    torch.manual_seed(config.seed)
    np.random.seed(config.seed)
    device = resolve_device(config.device)
    manifest = read_manifest(clips_dir)
    if init is None:
        # The tower's input channels follow the clips folder.
        config = dataclasses.replace(config, bev=dataclasses.replace(
            config.bev, lidar_channels=len(manifest["bev"]["lidar_channels"]),
            map_channels=len(manifest["bev"]["map_channels"])))
    else:
        # A model built on another keeps its tower, inputs and frame spacing.
        config = dataclasses.replace(config, bev=init.bev_config, inputs=init.config.inputs,
                                     frame_stride=init.config.frame_stride)
    ds = TagWindowDataset(clips_dir, "train", config.window_frames, config.frame_stride, targets)
    bev = BevTower(config.bev, 32) if init is None else init.bev
    footprints = None
    if init is not None:
        # A row copied from the model built on keeps the reading it was trained for (presence or regression).
        base = init.head.config.footprints or {}
        footprints = {a: FOOTPRINT_M2[a] for a in ds.names if a in FOOTPRINT_M2 and a not in init.head.names}
        footprints.update({a: f for a, f in base.items() if a in ds.names})
    head = TagHead(TagHeadConfig(attributes=ds.names, embed_channels=config.bev.embed_channels, footprints=footprints))
    if init is not None:
        with torch.no_grad():
            for i, name in enumerate(ds.names):
                if name in init.head.names:
                    j = init.head.index(name)
                    head.attributes[i] = init.head.attributes[j]
                    head.bias[i] = init.head.bias[j]
    bev.to(device)
    head.to(device)
    bev.train(train_backbone)
    bev.requires_grad_(train_backbone)
    params = [p for p in [*bev.parameters(), *head.parameters()] if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=config.lr, weight_decay=config.weight_decay)
    sampler = TaskBalancedSampler(ds.present, config.steps * config.batch_size, config.seed)
    loader = torch.utils.data.DataLoader(ds, batch_size=config.batch_size, sampler=sampler,
                                         collate_fn=collate_windows)
    run = Path(run_dir)
    claim_run_dir(run, clips_dir)
    lines: list[str] = []
    start = time.perf_counter()
    loss_avg = float("nan")
    step = 0
    for step, batch in enumerate(loader):
        for g in opt.param_groups:
            g["lr"] = _lr_at(step, config)
        loss, parts = window_loss(lambda b: bev.embed_map(b["bev_lidar"], b["bev_map"]), head, batch, config, device)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"tag loss is {float(loss)} at step {step} (logs {batch['log_id']})")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        lv = float(loss.detach())
        loss_avg = lv if math.isnan(loss_avg) else 0.95 * loss_avg + 0.05 * lv
        if step % config.log_every == 0 or step == config.steps - 1:
            rec = {"step": step, "loss": round(lv, 5), "loss_avg": round(loss_avg, 5),
                   **{k: round(v, 5) for k, v in parts.items()}, "s": round(time.perf_counter() - start, 2)}
            lines.append(json.dumps(rec))
            say(f"step {step}: loss {loss_avg:.4f} ({', '.join(f'{k} {v:.4f}' for k, v in parts.items())})")
    seconds = time.perf_counter() - start
    bev.eval()
    save_tagging(run, head, config, manifest, backbone=bev,
                 extra={"clips_dir": str(Path(clips_dir).resolve()),
                        "train": {"steps": step + 1, "seconds": round(seconds, 2), "logs": ds.log_ids,
                                  "train_backbone": train_backbone}})
    atomic_write_text(run / METRICS_FILE, "\n".join(lines) + "\n")
    return TagTrainResult(run, step + 1, loss_avg, seconds, (step + 1) * config.batch_size / max(seconds, 1e-9))


def attach_tagging(
    clips_dir: Path | str,
    model: nn.Module,
    config: TagTrainConfig | None = None,
    log: Callable[[str], None] | None = None,
    optimizer: torch.optim.Optimizer | None = None,
    shard: tuple[int, int] = (0, 1),
) -> TaggingObjective | None:
    """The joint-training hook: a :class:`TaggingObjective` for ``model`` (a DualEncoder).

    A and b are trained by ``optimizer`` (added as a parameter group without weight decay) when one is
    given, else by the objective's own AdamW (:meth:`TaggingObjective.step`), which keeps the main
    optimiser's state, and so its checkpoints, unchanged. ``shard``: (rank, processes) of data-parallel
    training. Returns None when ``config.mode`` is ``alone`` or the clips folder's training logs have
    no tag targets (``log`` says why).
    """
    from encoders.tagging.data import split_logs
    from encoders.tagging.targets import has_targets

    say = log or (lambda _line: None)
    config = config or TagTrainConfig()
    if config.mode != "joint":
        return None
    clips = Path(clips_dir)
    logs = split_logs(read_manifest(clips), "train")
    missing = [lid for lid in logs if not has_targets(clips, lid)]
    if not logs or missing:
        say(f"tagging off: {len(missing)} of {len(logs)} training logs have no tag targets "
            "(encoders.tagging.targets.add_attribute_targets writes them)")
        return None
    bev_cfg = getattr(getattr(model, "config", None), "bev", None)
    if isinstance(bev_cfg, BevConfig):
        # The tags ride on the dual encoder's own tower: record that one, not the default for ``alone``.
        config = dataclasses.replace(config, bev=bev_cfg)
    objective = TaggingObjective(clips, config, config.bev.embed_channels, shard=shard)
    objective.to(next(model.parameters()).device)
    params = list(objective.head.parameters())
    if optimizer is not None:
        optimizer.add_param_group({"params": params, "weight_decay": 0.0, "lr": optimizer.param_groups[0]["lr"]})
    else:
        objective.optimizer = torch.optim.AdamW(params, lr=config.lr, weight_decay=0.0)
    say(f"tagging on: {len(objective.dataset)} frames of {len(logs)} logs, {len(objective.head.names)} attributes, "
        f"weight {config.joint_weight}, inputs {config.inputs}")
    return objective
