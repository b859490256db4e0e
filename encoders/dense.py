"""Dense supervision: each frame's rule tags, predicted from a temporal stream's frame tokens.

One contrastive target per clip says *what* the object does in order, never *when*: a clip's caption is
its per-frame tags collapsed (eq. 8), so the frames hold supervision that the caption throws away. The
tags at each clip frame (:mod:`encoders.clips.frame_tags`) are the targets of linear heads over a
stream's frame tokens (:data:`DENSE_TASKS`): the object's lane and its motion relative to the ego, the
ego's motion and its direction, and the object's own action and map context as its unified tag names
them (``none`` where it names none: a caption's steps can differ in these alone, "moves away, then
moves away braking"). A model predicts the tasks of its ``DualEncoderConfig.dense_tasks``. A frame the
rules did not tag has target −1 and adds no loss.

    tokens (B, T, W) ─ DenseHeads ─ (B, T, ΣC) ─ per task: cross-entropy over tagged frames ─ mean
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray
from torch import nn

from captioning.tags import ACTIONS, CONTEXTS, HOST_DIRECTIONS, HOST_MOTIONS, LANES, MOTIONS, NOTHING_NAMED
from encoders.clips.frame_tags import FRAME_TAG_COLUMNS
from encoders.config import DENSE_TASK_NAMES

_CLASSES: dict[str, tuple[str, ...]] = {
    "lane": tuple(v.value for v in LANES),
    "motion": tuple(v.value for v in MOTIONS),
    "host_motion": tuple(v.value for v in HOST_MOTIONS),
    "host_direction": tuple(v.value for v in HOST_DIRECTIONS),
    "action": (NOTHING_NAMED, *(v.value for v in ACTIONS)),
    "context": (NOTHING_NAMED, *(v.value for v in CONTEXTS)),
}
#: Task (a frame_tags.parquet column, :data:`encoders.config.DENSE_TASK_NAMES`) → its classes, in the
#: order of the heads' outputs.
DENSE_TASKS: dict[str, tuple[str, ...]] = {task: _CLASSES[task] for task in DENSE_TASK_NAMES}
#: Task → the clip-table column that holds it.
_TASK_COLUMNS = {task: column for column, task in FRAME_TAG_COLUMNS.items()}
_INDEX = {task: {name: i for i, name in enumerate(classes)} for task, classes in DENSE_TASKS.items()}


def frame_targets(columns: Mapping[str, Sequence[str | None] | None], num_frames: int) -> NDArray[np.int64]:
    """A clip's frame-tag columns → (T, K) class indices of the K :data:`DENSE_TASKS`, −1 where untagged.

    A missing column (a clip table written without frame tags) or an unknown value gives −1.
    """
    out = np.full((num_frames, len(DENSE_TASKS)), -1, dtype=np.int64)
    for k, task in enumerate(DENSE_TASKS):
        column = _TASK_COLUMNS[task]
        values = columns.get(column)
        if not values:
            continue
        if len(values) != num_frames:
            raise ValueError(f"{column}: {len(values)} values for a clip of {num_frames} frames")
        index = _INDEX[task]
        out[:, k] = [index.get(v, -1) if v is not None else -1 for v in values]
    return out


def task_logits(logits: torch.Tensor, tasks: Sequence[str] = DENSE_TASK_NAMES) -> dict[str, torch.Tensor]:
    """logits: (..., ΣC) of :class:`DenseHeads` over ``tasks`` → task → its logits (..., C_task)."""
    return dict(zip(tasks, logits.split([len(DENSE_TASKS[t]) for t in tasks], dim=-1)))


def task_targets(targets: torch.Tensor, tasks: Sequence[str]) -> torch.Tensor:
    """targets: (..., K) of every :data:`DENSE_TASKS` (:func:`frame_targets`) → (..., len(tasks)) of ``tasks``."""
    return targets[..., [DENSE_TASK_NAMES.index(t) for t in tasks]]


class DenseHeads(nn.Module):
    """Frame tokens (B, T, W) → logits (B, T, ΣC) of each of ``tasks``, one linear map."""

    def __init__(self, width: int, tasks: Sequence[str] = DENSE_TASK_NAMES) -> None:
        super().__init__()
        self.proj = nn.Linear(width, sum(len(DENSE_TASKS[t]) for t in tasks))

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        return self.proj(tokens)  # (B, T, ΣC)


def dense_loss(logits: torch.Tensor, targets: torch.Tensor, keep: torch.Tensor | None = None,
               whole: Callable[[torch.Tensor], torch.Tensor] | None = None,
               tasks: Sequence[str] = DENSE_TASK_NAMES) -> torch.Tensor:
    """logits: (B, T, ΣC) over ``tasks``; targets: (B, T, K) of every task (−1: no target); keep: (B,) bool
    clips that count → the mean over ``tasks`` of each one's cross-entropy over its tagged frames (a task
    with none adds 0).

    ``whole`` sums a (k,) count over the processes of a data-parallel step: each task's cross-entropy is
    then summed here and divided by the whole batch's tagged frames, so that the processes' losses add
    up to the loss of the whole batch on one process, whatever each one's share of tagged frames.
    """
    targets = task_targets(targets, tasks)  # (B, T, k)
    if keep is not None:
        targets = targets.masked_fill(~keep.reshape(-1, 1, 1), -1)
    tagged = (targets >= 0).flatten(0, 1).sum(0)  # (k,)
    if whole is not None:
        tagged = whole(tagged)
    total = logits.sum() * 0.0  # a graph to every head even when no frame is tagged here
    for k, (part, n) in enumerate(zip(task_logits(logits, tasks).values(), tagged.tolist())):
        if n > 0:
            loss = F.cross_entropy(part.flatten(0, 1).float(), targets[..., k].flatten(), ignore_index=-1,
                                   reduction="sum")
            total = total + loss / n
    return total / len(tasks)


def stream_dense_loss(logits: Mapping[str, torch.Tensor], targets: torch.Tensor, has_camera: torch.Tensor,
                      whole: Callable[[torch.Tensor], torch.Tensor] | None = None,
                      tasks: Sequence[str] = DENSE_TASK_NAMES) -> torch.Tensor:
    """stream → logits (B, T, ΣC) over ``tasks``; targets (B, T, K); has_camera (B,) bool → the mean of the
    streams' :func:`dense_loss` (the camera stream's over the clips with camera only); ``whole`` as there."""
    losses = [dense_loss(x, targets, has_camera.reshape(-1) if name == "camera" else None, whole, tasks)
              for name, x in logits.items()]
    return torch.stack(losses).mean() if losses else targets.new_zeros((), dtype=torch.float32)


@torch.no_grad()
def dense_accuracy(logits: torch.Tensor, targets: torch.Tensor,
                   tasks: Sequence[str] = DENSE_TASK_NAMES) -> dict[str, float]:
    """logits: (B, T, ΣC) over ``tasks``; targets: (B, T, K) of every task → task → accuracy over its tagged
    frames (NaN with none)."""
    targets = task_targets(targets, tasks)
    out: dict[str, float] = {}
    for k, (task, part) in enumerate(task_logits(logits, tasks).items()):
        valid = targets[..., k] >= 0  # (B, T)
        hits = part.argmax(-1)[valid] == targets[..., k][valid]
        out[task] = float(hits.float().mean()) if bool(valid.any()) else float("nan")
    return out


def frame_tag_report(logits: Mapping[str, torch.Tensor], targets: torch.Tensor,
                     has_camera: torch.Tensor, tasks: Sequence[str] = DENSE_TASK_NAMES) -> dict[str, Any]:
    """stream → logits (N, T, ΣC) over ``tasks``; targets (N, T, K) of every task; has_camera (N,) bool →
    the dense heads' figures.

    ``{"streams": {stream: {task: accuracy}}, "majority": {task: accuracy}, "frames": {task: n},
    "first_last_motion": {stream: [first, last]}}``: each stream's :func:`dense_accuracy` (the camera
    stream's over clips with camera), beside always answering each task's most frequent tag; the motion
    right at each clip's first and last tagged frame, the ends a caption's order is made of.
    """
    own = task_targets(targets, tasks)  # (N, T, k)
    counts = [torch.bincount(own[..., k][own[..., k] >= 0], minlength=len(DENSE_TASKS[t]))
              for k, t in enumerate(tasks)]
    constant = torch.cat([F.one_hot(n.argmax(), len(n)).float() for n in counts])  # (ΣC,) the most frequent
    motion = DENSE_TASK_NAMES.index("motion")
    streams, ends = {}, {}
    for name, x in logits.items():
        keep = has_camera.reshape(-1) if name == "camera" else slice(None)
        x, y = x[keep], targets[keep]
        streams[name] = dense_accuracy(x, y, tasks)
        if "motion" in tasks:
            ends[name] = _end_accuracy(task_logits(x, tasks)["motion"].argmax(-1), y[..., motion])
    return {"streams": streams,
            "majority": dense_accuracy(constant.expand(*targets.shape[:2], -1), targets, tasks),
            "frames": dict(zip(tasks, (own >= 0).flatten(0, 1).sum(0).tolist())),
            "first_last_motion": ends}


def _end_accuracy(predicted: torch.Tensor, target: torch.Tensor) -> list[float]:
    """predicted, target: (N, T) (−1: untagged) → accuracy at each clip's first and last tagged frame."""
    tagged = target >= 0  # (N, T)
    rows = tagged.any(1)
    if not bool(rows.any()):
        return [float("nan"), float("nan")]
    t = torch.arange(target.shape[1]).expand_as(target)
    first = torch.where(tagged, t, target.shape[1]).min(1).values[rows]
    last = torch.where(tagged, t, -1).max(1).values[rows]
    n = torch.arange(target.shape[0])[rows]
    return [float((predicted[n, i] == target[n, i]).float().mean()) for i in (first, last)]
