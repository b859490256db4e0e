"""Contrastive training of the :class:`~encoders.model.DualEncoder`, with validation and checkpoints.

``train(clips_dir, run_dir, config)`` writes, in ``run_dir``:

    config.json           the TrainConfig (model channels resolved from the data)
    metrics.jsonl         one line per epoch: loss and each of its terms, learning rate, samples/s,
                          validation retrieval metrics
    checkpoints/last.pt   everything a resumed run needs (:mod:`encoders.checkpoints`), atomically every epoch
    model.safetensors     final weights (frozen pretrained text weights are left out: they load from text.model)
    text_cache.npz        cached frozen caption embeddings (pretrained and slots text towers)
    model_card.md         data, metrics and limits (:mod:`encoders.model_card`)
    tensorboard/          when TensorBoard is installed

Determinism: the data order of epoch e is a permutation seeded by (seed, e), and before every step the
torch generator is re-seeded from (seed, step), so modality dropout and frame shuffling depend only on
the step, as do the paraphrases of hard negatives; the tagging objective's n-th batch of windows
depends only on (seed, n). The learning rate is a function of the step (no scheduler object holds
state). A run resumed from ``checkpoints/last.pt`` therefore continues exactly as if it had not
stopped (on CPU; CUDA kernels may add their own non-determinism), with or without tag targets and
with a trained or a frozen text tower.

Each step embeds its batch and the texts its loss adds (:func:`encoders.training_loss.forward_step`:
hard negatives, caption halves) and minimises :class:`encoders.training_loss.TrainingLoss`, whose
named terms (contrastive, partial, order, dense, view_camera, view_bev, tagging) are each logged as the
epoch's mean in ``train_terms``; what each term computes lives in :mod:`encoders.loss`.

Checkpoints (:mod:`encoders.checkpoints`) hold every optimiser's state (the tagging head's own
included), the random states and the metrics rows so far, as plain tensors and data read with
``torch.load(weights_only=True)``; a file that needs more is refused, never unpickled.

Resuming checks that the configuration equals the checkpoint's, except for ``epochs`` (which may be
extended; the cosine schedule then stretches to the new end), ``num_workers``, ``device`` and
``eval_batch_size``, and that the tagging configuration equals its (except ``device``, ``steps`` and
``log_every``, which joint training does not use); ``force`` skips the checks (a checkpoint without
tagging state then starts the head afresh).

With ``distributed`` (:mod:`encoders.distributed`), N processes train as one process with the whole
batch of N × ``batch_size`` clips: only rank 0 writes files and validates. Loading a finished run and
embedding clips and texts with it is :mod:`encoders.inference`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import random
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from encoders.calibration import CameraWeightChoice, calibrate_camera_weight
from encoders.checkpoints import (
    check_resume_config,
    check_resume_tagging,
    read_checkpoint,
    restore_rng,
    save_checkpoint,
)
from encoders.clips.frame_tags import FRAME_TAG_COLUMNS
from encoders.data import AugmentConfig
from encoders.distributed import Distributed
from encoders.inference import collate, evaluate, open_split, record_trained_clips, resolve_device
from encoders.model import DualEncoder
from encoders.model_card import MODEL_CARD_FILE, model_card
from encoders.negatives import NEGATIVE_FIELDS
from encoders.partial_queries import PARTIAL_FIELDS
from encoders.run_folder import claim_run_dir
from encoders.tagging.ablation import mask_inputs
from encoders.tagging.config import TagTrainConfig
from encoders.tagging.training import attach_tagging
from encoders.text import TEXT_CACHE_FILE, kept_apart
from encoders.train_config import TrainConfig
from encoders.training_loss import TOTAL, TrainingLoss, forward_step
from scenesearch_base.atomic import atomic_path, atomic_write_text
from scenesearch_base.memory import check_memory


class TrainingError(RuntimeError):
    """Training cannot start or cannot go on."""


class NoTrainingSplitError(TrainingError, ValueError):
    """The clips folder has no clip in the training split."""


class NonFiniteLossError(TrainingError):
    """The loss became NaN or infinite; the last good checkpoint is kept."""

    def __init__(self, step: int, epoch: int, clip_ids: Sequence[str], value: float) -> None:
        self.step = step
        self.epoch = epoch
        self.clip_ids = list(clip_ids)
        shown = ", ".join(self.clip_ids[:8]) + (" …" if len(self.clip_ids) > 8 else "")
        super().__init__(f"loss is {value} at step {step} (epoch {epoch + 1}), batch clips: {shown}; "
                         "stopped, the last good checkpoint is kept")


@dataclass
class TrainResult:
    """What a training run did."""

    run_dir: Path
    epochs: int
    steps: int
    val: dict[str, float]
    history: list[dict[str, Any]] = field(default_factory=list)


# --- setup -------------------------------------------------------------------------------------------
def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def _step_seed(seed: int, step: int, stream: int = 0) -> int:
    """A seed that depends only on (seed, step, stream)."""
    return int(np.random.SeedSequence([seed, stream, step]).generate_state(1)[0])


def _seed_worker(worker_id: int) -> None:
    s = torch.initial_seed() % 2**32
    np.random.seed(s)
    random.seed(s)


def _open_datasets(
    clips_dir: Path, config: TrainConfig, datasets: dict[str, Dataset[dict[str, Any]]] | None
) -> tuple[Dataset[dict[str, Any]], Dataset[dict[str, Any]] | None]:
    if datasets is not None:
        train_set, val_set = datasets.get("train"), datasets.get("val")
    else:
        if not clips_dir.is_dir():
            raise FileNotFoundError(f"{clips_dir}: clips folder not found")
        train_set = open_split(clips_dir, "train", augment=config.augment, seed=config.seed)
        val_set = open_split(clips_dir, "val", seed=config.seed)
    if config.model.camera.object_crop and not getattr(train_set, "has_crops", True):
        raise TrainingError(f"{clips_dir}: model.camera.object_crop (--camera-crop) reads object crops and these "
                            "clips have none; render them again with `scenesearch clips`")
    if train_set is None or len(train_set) == 0:  # type: ignore[arg-type]
        raise NoTrainingSplitError(f"{clips_dir}: no clips in the 'train' split (clips.parquet column 'split')")
    if train_set is not None and len(train_set) < 2:  # type: ignore[arg-type]
        raise NoTrainingSplitError(f"{clips_dir}: the 'train' split needs at least 2 clips for a contrastive loss")
    if val_set is not None and len(val_set) == 0:  # type: ignore[arg-type]
        val_set = None
    return train_set, val_set


def camera_flags(dataset: Dataset[dict[str, Any]]) -> np.ndarray:
    """(N,) bool: which of the dataset's clips have a camera view, from its table (``camera_flags``)."""
    flags = getattr(dataset, "camera_flags", None)
    if flags is None:  # reading every clip to find out would render the whole split once more
        raise TrainingError(f"camera_share needs the training dataset's camera_flags, which "
                            f"{type(dataset).__name__} lacks")
    return np.asarray(flags, dtype=bool)


def resolve_channels(config: TrainConfig, item: dict[str, Any]) -> TrainConfig:
    """The config with the BEV and camera channel counts of the data."""
    bev = dataclasses.replace(config.model.bev, lidar_channels=int(item["bev_lidar"].shape[1]),
                              map_channels=int(item["bev_map"].shape[1]))
    camera = dataclasses.replace(config.model.camera, in_channels=int(item["camera"].shape[1]))
    model = dataclasses.replace(config.model, bev=bev, camera=camera)
    return dataclasses.replace(config, model=model)


def batch_bytes(sample: dict[str, Any], batch_size: int) -> int:
    """About the memory a batch of ``batch_size`` clips like ``sample`` takes as input: its tensors, held
    by the loader, the collated batch and the model's first activations (three copies)."""
    one = sum(int(v.numel() * v.element_size()) for v in sample.values() if isinstance(v, torch.Tensor))
    return 3 * one * batch_size


def build_optimizer(model: DualEncoder, config: TrainConfig) -> torch.optim.Optimizer:
    """AdamW; no weight decay on biases, norms, embeddings, time positions and the logit scale."""
    decay: list[torch.nn.Parameter] = []
    no_decay: list[torch.nn.Parameter] = []
    for name, p in model.named_parameters():
        if not p.requires_grad:
            continue
        plain = p.ndim < 2 or any(s in name for s in ("time", "query", "positions", "tokens", "logit_scale"))
        (no_decay if plain else decay).append(p)
    groups = [{"params": decay, "weight_decay": config.weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
    return torch.optim.AdamW(groups, lr=config.lr, betas=(0.9, 0.98), eps=1e-6)


def learning_rate(config: TrainConfig, step: int, total_steps: int) -> float:
    """Linear warm-up over ``warmup_steps``, then cosine decay to 0 at ``total_steps``."""
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    span = max(1, total_steps - config.warmup_steps)
    progress = min(1.0, (step - config.warmup_steps) / span)
    return config.lr * 0.5 * (1.0 + math.cos(math.pi * progress))


def _append_metrics(path: Path, row: dict[str, Any]) -> None:
    with open(path, "a") as fh:
        fh.write(json.dumps(row, sort_keys=True) + "\n")
        fh.flush()


# --- training ----------------------------------------------------------------------------------------
def _tensorboard(run_dir: Path) -> Any:
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        return None
    return SummaryWriter(str(run_dir / "tensorboard"))


def train(
    clips_dir: Path | str, run_dir: Path | str, config: TrainConfig, resume: bool = False, force: bool = False,
    datasets: dict[str, Dataset[dict[str, Any]]] | None = None, tagging: TagTrainConfig | None = None,
    on_epoch_end: Callable[[int], None] | None = None, log: Callable[[str], None] | None = None,
    progress: bool | None = None, distributed: Distributed | None = None,
) -> TrainResult:
    """Train a DualEncoder on the 'train' split of ``clips_dir``, validating on 'val'; see the module doc.

    ``datasets`` ({"train": ..., "val": ...}) replaces reading the clips folder; ``on_epoch_end(epoch)``
    runs after each epoch's checkpoint and metrics are written; ``progress`` None shows a bar on a terminal.
    ``distributed``: this process's place in data-parallel training (default: the only process).
    """
    dp = distributed or Distributed()
    log = (log or (lambda msg: print(msg, file=sys.stderr))) if dp.is_main else (lambda _msg: None)
    run_dir = Path(run_dir)
    train_set, val_set = _open_datasets(Path(clips_dir), config, datasets)
    first = train_set[0]
    check_memory(batch_bytes(first, config.batch_size), f"a training batch of {config.batch_size} clips",
                 "--batch-size (or the clips' frames and sizes)")
    config = resolve_channels(config, first)
    missing = [k for k in NEGATIVE_FIELDS if k not in first] if config.hard_negatives else []
    if missing:
        raise TrainingError(f"{clips_dir}: hard_negatives needs each clip's {', '.join(missing)}, which the clips lack")
    missing = [k for k in PARTIAL_FIELDS if k not in first] if config.partial_weight > 0 else []
    if missing:
        raise TrainingError(f"{clips_dir}: partial_weight needs each clip's {', '.join(missing)}, which the clips lack")
    if config.dense_weight > 0 and not getattr(train_set, "has_frame_tags", "frame_targets" in first):
        raise TrainingError(f"{clips_dir}: dense_weight needs the clip frames' rule tags "
                            f"({', '.join(FRAME_TAG_COLUMNS)}), which the clip table lacks: make the clips from "
                            "captions with their frame_tags.parquet beside")
    ckpt_path = run_dir / "checkpoints" / "last.pt"
    metrics_path = run_dir / "metrics.jsonl"
    if not resume and (ckpt_path.exists() or metrics_path.exists()):
        raise FileExistsError(f"{run_dir} already holds a run; pass --resume to continue it or choose another --out")
    if dp.is_main:
        claim_run_dir(run_dir, clips_dir)

    device = dp.device(resolve_device(config.device))
    checkpoint = read_checkpoint(ckpt_path) if resume else None
    if checkpoint is not None and not force:
        check_resume_config(config, checkpoint.config, checkpoint.epoch, str(ckpt_path))
        dp.check_resume(checkpoint.history)
    seed_everything(config.seed)
    model = DualEncoder(config.model).to(device)
    opt = build_optimizer(model, config)
    # -- tagging hook (encoders/tagging): the tag loss joins the contrastive loss when the clips have tag targets
    tag_config = tagging or TagTrainConfig()
    tag_objective = attach_tagging(clips_dir, model, tag_config, log, shard=(dp.rank, dp.processes)) \
        if datasets is None else None
    start_epoch, step = 0, 0
    history: list[dict[str, Any]] = []
    val: dict[str, float] = {}
    if checkpoint is not None:
        saved_tagging = checkpoint.tagging["config"] if checkpoint.tagging is not None else None
        if not force:
            check_resume_tagging(tag_objective, saved_tagging)
        model.load_saved_state_dict(checkpoint.model)
        opt.load_state_dict(checkpoint.optimizer)
        if tag_objective is not None and checkpoint.tagging is not None:
            tag_objective.load_training_state(checkpoint.tagging["state"])
        elif tag_objective is not None:
            log("the checkpoint has no tagging state: the tagging head starts afresh (--force)")
        restore_rng(checkpoint.rng)
        start_epoch, step, history = checkpoint.epoch, checkpoint.step, list(checkpoint.history)
        val = next((dict(r["val"]) for r in reversed(history) if isinstance(r.get("val"), dict)), {})
        # The checkpoint's rows are the truth: a kill after it was written may have cut the file short.
        if dp.is_main:
            atomic_write_text(metrics_path, "".join(json.dumps(r, sort_keys=True) + "\n" for r in history))
        log(f"resuming {run_dir} after epoch {start_epoch} (step {step})")
    dp.prepare(model, tag_objective)  # batch norms over the whole batch, rank 0's weights everywhere
    text_cache = model.text.cache
    cache_path = run_dir / TEXT_CACHE_FILE
    if text_cache is not None:
        text_cache.load(cache_path)
    val_texts: dict[str, np.ndarray] = {}  # what validation encodes, kept out of training's cache (kept_apart)
    if dp.is_main:
        atomic_write_text(run_dir / "config.json", config.to_json())

    n = len(train_set)  # type: ignore[arg-type]
    batches_per_epoch, size = dp.steps_per_epoch(n, config.batch_size, clips_dir)
    if config.max_steps_per_epoch:
        batches_per_epoch = min(batches_per_epoch, config.max_steps_per_epoch)
    total_steps = batches_per_epoch * config.epochs
    camera = camera_flags(train_set) if config.camera_share > 0 else None
    use_amp = config.amp and device.type == "cuda"
    loss_fn = TrainingLoss(config, dp, tag_objective)
    # Negatives are paraphrased as often as the positives are.
    negative_paraphrases = AugmentConfig().paraphrase_probability if config.augment else 0.0
    writer = _tensorboard(run_dir) if dp.is_main else None
    log(f"training on {n} clips, {batches_per_epoch} steps/epoch, {config.epochs} epochs, device {device}"
        + (f", {dp.processes} processes × {size} clips per step" if dp.active else ""))

    for epoch in range(start_epoch, config.epochs):
        model.train()
        if hasattr(train_set, "set_epoch"):
            train_set.set_epoch(epoch)  # the augmentation draw of this epoch
        sampler = dp.sampler(train_set, size, batches_per_epoch, config.seed, camera, config.camera_share)
        sampler.set_epoch(epoch)  # the order of this epoch: a permutation seeded by (seed, epoch)
        loader = DataLoader(
            train_set,
            batch_size=size,
            sampler=sampler,
            collate_fn=collate,
            num_workers=config.num_workers,
            worker_init_fn=_seed_worker,
            generator=torch.Generator().manual_seed(_step_seed(config.seed, epoch, stream=1)),
            persistent_workers=False,
        )
        losses: list[float] = []
        terms: dict[str, list[float]] = {}  # each term's values over the epoch's steps
        seen, t0 = 0, time.perf_counter()
        bar = _progress(loader, total=batches_per_epoch, desc=f"epoch {epoch + 1}/{config.epochs}",
                        enable=progress if dp.is_main else False)
        for batch in bar:
            torch.manual_seed(_step_seed(config.seed, step))
            for group in opt.param_groups:
                group["lr"] = learning_rate(config, step, total_steps)
            batch = mask_inputs(batch, tag_config.inputs)  # tagging hook: input ablation (none/map/lidar/both)
            batch = dp.align_draws(batch, config.shuffle_frames)  # frames shuffled in time (the baseline)
            with torch.autocast(device_type=device.type, dtype=torch.bfloat16, enabled=use_amp):
                out = forward_step(model, batch, config, step, dp, negative_paraphrases)
                step_loss = loss_fn(model, out)
            values = dp.means(step_loss.values())  # the whole batch's loss and terms
            value = values.pop(TOTAL)
            if not math.isfinite(value):
                raise NonFiniteLossError(step, epoch, out.clip_ids, value)
            opt.zero_grad(set_to_none=True)
            step_loss.total.backward()
            dp.average_gradients(model, tag_objective)
            if config.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(model.parameters(), config.grad_clip)
            opt.step()
            if tag_objective is not None:  # tagging hook
                tag_objective.step(opt.param_groups[0]["lr"])
            step += 1
            seen += len(batch["clip_id"]) * dp.processes
            losses.append(value)
            for name, term in values.items():
                terms.setdefault(name, []).append(term)
            rate = seen / max(time.perf_counter() - t0, 1e-9)
            if hasattr(bar, "set_postfix"):
                bar.set_postfix(loss=f"{value:.3f}", samples_s=f"{rate:.1f}")
        epoch_s = time.perf_counter() - t0
        done = epoch + 1
        if dp.is_main and val_set is not None and (done % config.eval_every == 0 or done == config.epochs):
            with kept_apart(text_cache, val_texts):
                val = evaluate(model, val_set, batch_size=config.eval_batch_size)
        row: dict[str, Any] = {
            "epoch": done,
            "step": step,
            "train_loss": float(np.mean(losses)) if losses else float("nan"),
            "train_terms": {name: float(np.mean(v)) for name, v in terms.items()},
            "lr": opt.param_groups[0]["lr"],
            "logit_scale": float(model.logit_scale.detach()),
            "samples_per_s": seen / max(epoch_s, 1e-9),
            "epoch_s": epoch_s,
        }
        if val and (done % config.eval_every == 0 or done == config.epochs):
            row["val"] = val
        if dp.active:
            row["processes"] = dp.processes
        history.append(row)
        if dp.is_main:
            if text_cache is not None:
                # Before the checkpoint: a resumed run then finds every caption embedding it had.
                text_cache.save(cache_path)
            save_checkpoint(ckpt_path, model, opt, config, done, step, history, tag_objective)
            _append_metrics(metrics_path, row)
        if writer is not None:
            writer.add_scalar("train/loss", row["train_loss"], step)
            for k, v in row["train_terms"].items():
                writer.add_scalar(f"train/{k}", v, step)
            writer.add_scalar("train/samples_per_s", row["samples_per_s"], step)
            for k, v in row.get("val", {}).items():
                writer.add_scalar(f"val/{k}", v, step)
        log(f"epoch {done}: loss {row['train_loss']:.4f}, {row['samples_per_s']:.1f} samples/s"
            + (f", val R@1 {val.get('R@1', float('nan')):.3f} R@5 {val.get('R@5', float('nan')):.3f}" if val else ""))
        if on_epoch_end is not None:
            on_epoch_end(done)
    if writer is not None:
        writer.close()
    if dp.is_main:
        # After the last checkpoint: a resumed run trains with the equal mean, as this one did.
        with kept_apart(text_cache, val_texts):
            camera_weight = (calibrate_camera_weight(model, val_set, config.eval_batch_size) if config.calibrate_camera
                             else CameraWeightChoice(float(model.fusion.camera_weight), {}, "calibrate_camera is off"))
        if text_cache is not None and val_texts:  # training is done: the run's cache serves validation's captions too
            text_cache.merge(val_texts).save(cache_path)
        log(camera_weight.describe())
        _write_final(run_dir, model, config, history, n, val_set, clips_dir, camera_weight)
        if tag_objective is not None:  # tagging hook
            tag_objective.save(run_dir)
    return TrainResult(run_dir=run_dir, epochs=config.epochs, steps=step, val=val, history=history)


def _progress(iterable: Any, total: int, desc: str, enable: bool | None) -> Any:
    try:
        from tqdm import tqdm
    except ImportError:
        return iterable
    return tqdm(iterable, total=total, desc=desc, unit="batch", disable=(None if enable is None else not enable),
                leave=False)


def _write_final(run_dir: Path, model: DualEncoder, config: TrainConfig, history: list[dict[str, Any]],
                 n_train: int, val_set: Dataset[dict[str, Any]] | None, clips_dir: Path | str,
                 camera_weight: CameraWeightChoice) -> None:
    from safetensors.torch import save_file

    state = {k: v.detach().cpu().contiguous().clone() for k, v in model.saved_state_dict().items()}
    with atomic_path(run_dir / "model.safetensors") as tmp:
        save_file(state, str(tmp), metadata={"format": "scenesearch.DualEncoder"})
    atomic_write_text(run_dir / "config.json", config.to_json())
    record_trained_clips(run_dir, clips_dir)  # the clip shape this model takes (check_clips_fit)
    atomic_write_text(run_dir / MODEL_CARD_FILE, model_card(config, history, n_train, val_set, clips_dir,
                                                                  camera_weight))
