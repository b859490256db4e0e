"""Training checkpoints: what ``RUN_DIR/checkpoints/last.pt`` holds, writing and reading it, and the
checks before a run resumes from it.

A checkpoint holds what a resumed run needs to continue exactly as if it had not stopped: the model
(frozen pretrained text weights left out: they load from ``text.model``), every optimiser's state
(the tagging head's own, with its weights and how many windows it drew), the random states of
torch (and CUDA), numpy and Python, and the metrics rows so far. The learning rate is a function of
the step, so no scheduler holds state. It is plain tensors and data, with the metadata (epoch, step,
configs, metrics rows, the numbers of the random states) as one JSON string::

    {"format": 2, "meta": "<JSON>", "model": {name: tensor}, "optimizer": AdamW state dict,
     "tagging": None | {"attributes", "footprints", "head", "optimizer", "batches_drawn"}, "rng": {name: tensor}}

so :func:`read_checkpoint` loads it with ``torch.load(weights_only=True)``: a run folder cannot make
a resume unpickle arbitrary objects. A file that does not load that way is refused with
:class:`CheckpointError`, naming it.

Resuming checks that the configuration equals the checkpoint's (:func:`check_resume_config`,
:func:`check_resume_tagging`); the training loop is :mod:`encoders.train`.
"""

from __future__ import annotations

import json
import random
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from encoders.config import ConfigMismatchError
from encoders.train_config import TrainConfig
from scenesearch_base.atomic import atomic_path

if TYPE_CHECKING:
    from encoders.model import DualEncoder
    from encoders.tagging.training import TaggingObjective

CHECKPOINT_FORMAT = 2
#: Config keys that may differ when resuming.
RESUMABLE_KEYS = ("epochs", "num_workers", "device", "eval_batch_size")
#: Tagging config keys that may differ when resuming (joint training does not read them).
TAG_RESUMABLE_KEYS = ("device", "steps", "log_every")


class CheckpointError(ValueError):
    """A checkpoint cannot be read: not plain tensors and data, or not the layout this version writes."""


@dataclass(frozen=True)
class Checkpoint:
    """What ``checkpoints/last.pt`` holds, as :func:`read_checkpoint` returns it.

    Attributes:
        epoch: epochs done.
        step: optimiser steps done.
        config: the TrainConfig as a dict.
        history: the metrics rows of the epochs done.
        model: the model's saved state dict (:meth:`DualEncoder.saved_state_dict`).
        optimizer: the optimiser's state dict.
        tagging: None without a tagging objective, else ``{"config": TagTrainConfig dict,
            "state": TaggingObjective.training_state()}``.
        rng: random states (:func:`rng_state`).
    """

    epoch: int
    step: int
    config: dict[str, Any]
    history: list[dict[str, Any]]
    model: dict[str, torch.Tensor]
    optimizer: dict[str, Any]
    tagging: dict[str, Any] | None
    rng: dict[str, Any]


def rng_state() -> dict[str, Any]:
    """The random states of torch (CPU and CUDA), numpy and Python, as tensors plus JSON-safe numbers."""
    version, internal, gauss_next = random.getstate()
    _, keys, pos, has_gauss, cached_gaussian = np.random.get_state()
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        "numpy": torch.from_numpy(np.asarray(keys, dtype=np.int64)),  # (624,) MT19937 key
        "numpy_meta": [int(pos), int(has_gauss), float(cached_gaussian)],
        "python": torch.tensor(internal, dtype=torch.int64),  # (625,) MT19937 key and position
        "python_meta": [int(version), gauss_next],
    }


def restore_rng(state: dict[str, Any]) -> None:
    """Set the random states that :func:`rng_state` returned (CUDA only when the device count matches)."""
    torch.set_rng_state(state["torch"].cpu())
    cuda = state.get("cuda") or []
    if cuda and torch.cuda.is_available() and len(cuda) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all([t.cpu() for t in cuda])
    pos, has_gauss, cached_gaussian = state["numpy_meta"]
    keys = state["numpy"].numpy().astype(np.uint32)
    np.random.set_state(("MT19937", keys, int(pos), int(has_gauss), float(cached_gaussian)))
    version, gauss_next = state["python_meta"]
    random.setstate((int(version), tuple(int(v) for v in state["python"].tolist()), gauss_next))


def save_checkpoint(path: Path, model: DualEncoder, opt: torch.optim.Optimizer, config: TrainConfig, epoch: int,
                    step: int, history: list[dict[str, Any]], tagging: TaggingObjective | None = None) -> None:
    """Write a checkpoint atomically: tensors and plain data only (see the module doc)."""
    rng = rng_state()
    meta = {
        "epoch": epoch,
        "step": step,
        "config": config.to_dict(),
        "history": history,
        "tagging_config": tagging.config.to_dict() if tagging is not None else None,
        "rng": {"numpy": rng.pop("numpy_meta"), "python": rng.pop("python_meta")},
    }
    state = {
        "format": CHECKPOINT_FORMAT,
        "meta": json.dumps(meta, sort_keys=True),
        "model": model.saved_state_dict(),
        "optimizer": opt.state_dict(),
        "tagging": tagging.training_state() if tagging is not None else None,
        "rng": rng,
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def _load_failure(exc: Exception) -> str:
    """The reason in a ``torch.load`` error, without torch's advice to load with ``weights_only=False``."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", str(exc))
    _, marker, rest = text.partition("WeightsUnpickler error:")
    if marker:
        reason = next((line.strip() for line in rest.splitlines() if line.strip()), "")
        return reason.split(" was not an allowed global")[0].split(". Please")[0] or "refused by the unpickler"
    return next((line.strip() for line in text.splitlines() if line.strip()), type(exc).__name__)


def read_checkpoint(path: Path | str) -> Checkpoint:
    """Read a checkpoint with ``torch.load(weights_only=True)``, on the CPU.

    Raises:
        FileNotFoundError: no file at ``path``.
        CheckpointError: the file needs more than tensors and plain data to load (e.g. a pickled
            object), is damaged, or lacks a part of a checkpoint; the message names the file and part.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no checkpoint to resume from")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # whatever the unpickler refuses (or a damaged file), the answer is the same
        raise CheckpointError(
            f"{path}: not a checkpoint that loads as plain tensors and data (weights_only): {_load_failure(exc)}; "
            "it is not unpickled any further (start a new run with another --out if an older version wrote it)"
        ) from None

    def part(container: Any, key: str, kind: type | tuple[type, ...], where: str = "") -> Any:
        value = container.get(key) if isinstance(container, dict) else None
        if not isinstance(value, kind):
            names = kind if isinstance(kind, tuple) else (kind,)
            raise CheckpointError(f"{path}: checkpoint part '{where}{key}' is missing or not "
                                  f"{' or '.join(n.__name__ for n in names)}")
        return value

    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: not a checkpoint (a {type(state).__name__}, not a dict)")
    if state.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: checkpoint format {state.get('format')!r}, this version reads "
                              f"{CHECKPOINT_FORMAT}; start a new run (another --out)")
    try:
        meta = json.loads(part(state, "meta", str))
    except json.JSONDecodeError as exc:
        raise CheckpointError(f"{path}: checkpoint part 'meta' is not valid JSON ({exc})") from None
    rng = dict(part(state, "rng", dict))
    rng_meta = part(meta, "rng", dict, "meta.")
    rng["numpy_meta"] = part(rng_meta, "numpy", list, "meta.rng.")
    rng["python_meta"] = part(rng_meta, "python", list, "meta.rng.")
    for key in ("torch", "numpy", "python"):
        part(rng, key, torch.Tensor, "rng.")
    tagging = state.get("tagging")
    if tagging is not None:
        part(tagging, "head", dict, "tagging.")
        part(tagging, "batches_drawn", int, "tagging.")
        tagging = {"config": part(meta, "tagging_config", dict, "meta."), "state": tagging}
    return Checkpoint(
        epoch=part(meta, "epoch", int, "meta."),
        step=part(meta, "step", int, "meta."),
        config=part(meta, "config", dict, "meta."),
        history=part(meta, "history", list, "meta."),
        model=part(state, "model", dict),
        optimizer=part(state, "optimizer", dict),
        tagging=tagging,
        rng=rng,
    )


def _config_differences(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> list[str]:
    diffs = []
    for key in sorted(set(a) | set(b)):
        va, vb = a.get(key), b.get(key)
        if isinstance(va, dict) and isinstance(vb, dict):
            diffs += _config_differences(va, vb, f"{prefix}{key}.")
        elif va != vb:
            diffs.append(f"{prefix}{key}: {vb!r} -> {va!r}")
    return diffs


def check_resume_config(new: TrainConfig, saved: dict[str, Any], done_epochs: int, source: str = "checkpoint") -> None:
    """Raise :class:`ConfigMismatchError` when ``new`` differs from the checkpoint's config beyond RESUMABLE_KEYS.

    ``saved`` is read as a run's config (:meth:`TrainConfig.from_run_dict`: a checkpoint that lacks a
    key was written by an older version and is refused); ``source`` names the checkpoint in errors about it.
    """
    a = {k: v for k, v in new.to_dict().items() if k not in RESUMABLE_KEYS}
    b = {k: v for k, v in TrainConfig.from_run_dict(saved, f"{source}: config").to_dict().items()
         if k not in RESUMABLE_KEYS}
    diffs = _config_differences(a, b)
    if diffs:
        raise ConfigMismatchError(
            "resuming with a different configuration (use --force to resume anyway): " + "; ".join(diffs)
        )
    if new.epochs < done_epochs:
        raise ConfigMismatchError(f"the checkpoint has {done_epochs} epochs done; epochs={new.epochs} is fewer")


def check_resume_tagging(new: TaggingObjective | None, saved: dict[str, Any] | None) -> None:
    """Raise :class:`ConfigMismatchError` when the tagging objective differs from the checkpoint's.

    ``saved`` is the checkpoint's tagging config dict (None: it trained no tagging head).
    """
    if new is None and saved is None:
        return
    if new is None or saved is None:
        had, has = ("no", "a") if saved is None else ("a", "no")
        raise ConfigMismatchError(
            f"the checkpoint has {had} tagging head and this run has {has} (tag targets in the clips folder, "
            "--tag-weight, tagging mode); resuming would not continue the same training (use --force to resume "
            "anyway)"
        )
    from encoders.tagging.config import TagTrainConfig

    a = {k: v for k, v in new.config.to_dict().items() if k not in TAG_RESUMABLE_KEYS}
    # Keys added since the checkpoint was written take their defaults: what they weigh (the presence terms)
    # has no row in an older head, whose state resumes with every density regressed.
    b = {k: v for k, v in TagTrainConfig.from_dict(saved, "checkpoint: tagging config").to_dict().items()
         if k not in TAG_RESUMABLE_KEYS}
    diffs = _config_differences(a, b, "tagging.")
    if diffs:
        raise ConfigMismatchError(
            "resuming with a different tagging configuration (use --force to resume anyway): " + "; ".join(diffs)
        )
