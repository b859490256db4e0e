"""Data-parallel training on several processes with ``torch.distributed``: one step of N processes with
``b`` clips each is the step of one process with the whole batch of ``N·b`` clips.

    scenesearch train CLIPS --out RUN --nproc 2                    # this machine, torch's elastic launcher
    torchrun --standalone --nproc-per-node 2 -m retrieval.cli train CLIPS --out RUN
    torchrun --nnodes 2 --node-rank R --rdzv-backend c10d --rdzv-endpoint HOST:29500 \\
        --nproc-per-node 8 -m retrieval.cli train CLIPS --out RUN   # several machines

The launcher sets ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK`` and the rendezvous address;
:func:`process_group` joins the group (gloo on CPU, NCCL on CUDA, one GPU per process) and yields a
:class:`Distributed`, which :func:`encoders.train.train` threads through a step. Without a launcher it
is one process, and every method leaves the step as it was.

What makes N processes equal one process with the whole batch (tested on CPU, within 1e-5; sums taken
in another order differ in their last bits, as one process's do on 1 and on 2 threads):

- **Data**: :class:`encoders.sampler.EpochSampler` (a ``DistributedSampler``) cuts the epoch's permutation, seeded by
  (seed, epoch), into whole batches of ``N·b`` clips; process r takes the r-th block of ``b``, so the
  processes' blocks in rank order are the one-process batch. Augmentation is seeded per clip. The
  tagging objective's windows are shared out the same way (``TaggingObjective(shard=...)``).
- **Loss**: clip and caption embeddings are gathered with their gradients (:func:`gather_rows`, as
  open_clip's ``gather_features``), and so are the hard negatives, whose number differs between
  processes. The positives, the tag similarities and which negatives are a clip's own are computed
  over the whole batch; each process computes the loss terms of its own rows against every column
  (``contrastive_loss(rows=...)``), and the mean over processes is the loss of the whole batch.
- **Gradients**: after ``backward`` they are averaged over processes (:meth:`Distributed.average_gradients`,
  one all-reduce; a parameter no process used keeps no gradient, as with one process); clipping
  and the optimiser then see the whole batch's gradient.
- **Batch statistics**: every BatchNorm becomes a :class:`GlobalBatchNorm`, whose mean and variance
  in training are those of the whole batch (synchronised batch norm that also runs on CPU). All
  processes must run the same layers in the same order: the camera tower runs when any process's
  share of the batch has camera (``batch["run_camera"]``).
- **Random draws in a step** come from the torch generator re-seeded by (seed, step), one draw per
  clip in batch order (frame shuffling, then the fusion's modality dropout): process r skips the
  draws of the clips before its block (:meth:`Distributed.align_draws`). This is exact on CPU. Dropout
  inside a tower (``temporal.dropout`` > 0, a fine-tuned pretrained text tower) draws per element
  and per process: such runs are equal in distribution only, as are CUDA runs (Philox streams).

Only rank 0 writes files and validates; the others wait for it at their next collective. A run
records its number of processes in ``metrics.jsonl`` and resumes only with the same number (the
whole batch, and so the training, would change), unless forced.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import Any, TypeVar, cast

import numpy as np
import torch
import torch.distributed as dist
from numpy.typing import NDArray
from torch import nn
from torch.utils.data import Dataset

from encoders.config import ConfigMismatchError
from encoders.inference import resolve_device, shuffle_time
from encoders.sampler import EpochSampler

T = TypeVar("T")
#: How long a process waits at a collective (rank 0 validating while the others wait for it included).
TIMEOUT = timedelta(minutes=60)


class TooFewClipsError(ValueError):
    """The training split cannot fill one whole batch on every process."""


def check_processes(n_clips: int, batch_size: int, processes: int, where: Path | str) -> None:
    """Raise :class:`TooFewClipsError` unless ``n_clips`` fill one batch of ``batch_size`` per process."""
    if processes > 1 and n_clips < processes * batch_size:
        raise TooFewClipsError(
            f"{where}: {n_clips} training clips cannot fill one step of {processes} processes × batch size "
            f"{batch_size} = {processes * batch_size} clips; use fewer processes (--nproc) or a smaller --batch-size"
        )


# --- collectives that keep gradients ---------------------------------------------------------------------
class _SumOverRanks(torch.autograd.Function):
    """x summed over processes; the gradient of each process's x is the sum of every process's gradient."""

    @staticmethod
    def forward(ctx: Any, x: torch.Tensor) -> torch.Tensor:
        out = x.detach().clone()
        dist.all_reduce(out)
        return out

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> torch.Tensor:
        out = grad.contiguous().clone()
        dist.all_reduce(out)
        return out


class _GatherRows(torch.autograd.Function):
    """(n_r, ...) per process → (Σ n_r, ...) in rank order on every process; row counts may differ."""

    @staticmethod
    def forward(ctx: Any, x: torch.Tensor) -> torch.Tensor:
        world = dist.get_world_size()
        n = torch.tensor([x.shape[0]], dtype=torch.int64, device=x.device)
        sizes = [torch.zeros_like(n) for _ in range(world)]
        dist.all_gather(sizes, n)
        counts = [int(s) for s in sizes]
        rank = dist.get_rank()
        ctx.span = (sum(counts[:rank]), counts[rank])
        longest = max(counts)
        if longest == 0:
            return x.detach().clone()
        padded = x.new_zeros((longest, *x.shape[1:]))
        padded[: x.shape[0]] = x.detach()
        parts = [torch.empty_like(padded) for _ in range(world)]
        dist.all_gather(parts, padded)
        return torch.cat([p[:c] for p, c in zip(parts, counts)])

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> torch.Tensor:
        start, n = ctx.span
        out = grad.contiguous().clone()
        dist.all_reduce(out)  # every process's loss reads every row
        return out[start : start + n]


def gather_rows(x: torch.Tensor) -> torch.Tensor:
    """x: (n_r, ...) on each process → (Σ_r n_r, ...), rank order, differentiable (one process: x)."""
    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() == 1:
        return x
    out: torch.Tensor = _GatherRows.apply(x)
    return out


# --- batch norm over the whole batch ---------------------------------------------------------------------
class GlobalBatchNorm(nn.modules.batchnorm._BatchNorm):
    """Batch norm whose training statistics are those of the whole batch across processes.

    ``torch.nn.SyncBatchNorm`` runs on GPUs only; this one runs wherever the process group does. The
    variance is computed in two passes (the mean first), as one process's batch norm computes it, and
    the running statistics are updated as ``BatchNorm`` updates them (unbiased variance of the whole
    batch). Outside training, or on one process, it is the plain batch norm.
    """

    def _check_input_dim(self, input: torch.Tensor) -> None:
        if input.dim() < 2:
            raise ValueError(f"expected at least 2-D input (N, C, ...), got {input.dim()}-D")

    def forward(self, input: torch.Tensor) -> torch.Tensor:
        if not (self.training and dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1):
            return super().forward(input)
        self._check_input_dim(input)
        dims = [0, *range(2, input.dim())]
        shape = [1, -1] + [1] * (input.dim() - 2)
        x = input.float()  # statistics in float32, also under autocast
        count = torch.tensor([x.numel() // x.shape[1]], dtype=x.dtype, device=x.device)
        total = _SumOverRanks.apply(torch.cat([x.sum(dims), count]))  # (C + 1,)
        n = total[-1].detach()
        mean = total[:-1] / n  # (C,)
        centred = x - mean.reshape(shape)
        var = _SumOverRanks.apply((centred * centred).sum(dims)) / n  # (C,) biased, as in normalisation
        y = centred * torch.rsqrt(var + self.eps).reshape(shape)
        if self.affine:
            y = y * self.weight.reshape(shape) + self.bias.reshape(shape)
        if self.track_running_stats and self.running_mean is not None and self.running_var is not None:
            with torch.no_grad():
                assert self.num_batches_tracked is not None
                self.num_batches_tracked.add_(1)
                f = self.momentum if self.momentum is not None else 1.0 / float(self.num_batches_tracked)
                self.running_mean.mul_(1 - f).add_(mean.detach().to(self.running_mean.dtype), alpha=f)
                unbiased = var.detach() * (n / (n - 1).clamp_min(1))
                self.running_var.mul_(1 - f).add_(unbiased.to(self.running_var.dtype), alpha=f)
        return y.to(input.dtype)


def sync_batch_norms(module: nn.Module) -> nn.Module:
    """Every BatchNorm in ``module`` replaced by a :class:`GlobalBatchNorm` holding the same parameters
    and buffers (the same tensors: optimisers and state-dict keys are unchanged); returns ``module``."""
    for name, child in module.named_children():
        if isinstance(child, nn.modules.batchnorm._BatchNorm) and not isinstance(
            child, GlobalBatchNorm | nn.SyncBatchNorm
        ):
            new = GlobalBatchNorm(child.num_features, child.eps, child.momentum, child.affine,
                                  child.track_running_stats)
            if child.affine:
                new.weight, new.bias = child.weight, child.bias
            if child.track_running_stats:
                new.running_mean, new.running_var = child.running_mean, child.running_var
                new.num_batches_tracked = child.num_batches_tracked
            new.train(child.training)
            setattr(module, name, new)
        else:
            sync_batch_norms(child)
    return module


# --- one process's part in a step ----------------------------------------------------------------------
@dataclass(frozen=True)
class Distributed:
    """This process's place among the training processes (the defaults: one process, no group).

    Attributes:
        rank: this process, 0 … processes − 1; rank 0 writes the run's files.
        processes: how many processes train together (``WORLD_SIZE``).
        local_rank: this process on its machine: its GPU index on CUDA.
    """

    rank: int = 0
    processes: int = 1
    local_rank: int = 0

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.processes > 1

    def device(self, device: torch.device) -> torch.device:
        """The device of this process: CUDA device ``local_rank`` when ``device`` is CUDA."""
        return torch.device("cuda", self.local_rank) if self.active and device.type == "cuda" else device

    def steps_per_epoch(self, n_clips: int, batch_size: int, where: Path | str) -> tuple[int, int]:
        """→ (steps per epoch, clips per process and step); :class:`TooFewClipsError` when a step cannot be filled.

        One process with fewer clips than ``batch_size`` takes them all in one step.
        """
        check_processes(n_clips, batch_size, self.processes, where)
        if not self.active and n_clips < batch_size:
            return 1, n_clips
        return n_clips // (batch_size * self.processes), batch_size

    def sampler(self, dataset: Dataset[Any], batch_size: int, steps: int, seed: int,
                camera: NDArray[np.bool_] | None = None, camera_share: float = 0.0) -> EpochSampler:
        return EpochSampler(dataset, batch_size, steps, seed, self.rank, self.processes, camera, camera_share)

    def check_resume(self, history: Sequence[dict[str, Any]]) -> None:
        """Raise ConfigMismatchError when the checkpoint's run trained on another number of processes."""
        before = int(history[-1].get("processes", 1)) if history else self.processes
        if before != self.processes:
            raise ConfigMismatchError(
                f"the checkpoint was trained on {before} process(es) and this run has {self.processes}: the whole "
                "batch, and so the training, would change (resume with the same --nproc, or use --force)"
            )

    def prepare(self, *modules: nn.Module | None) -> None:
        """Batch norms over the whole batch, and every process starting from rank 0's weights."""
        if not self.active:
            return
        for module in modules:
            if module is None:
                continue
            sync_batch_norms(module)
            for tensor in [*module.parameters(), *module.buffers()]:
                dist.broadcast(tensor.data, src=0)

    def align_draws(self, batch: dict[str, Any], shuffle_frames: bool) -> dict[str, Any]:
        """The batch with its frames shuffled (``shuffle_frames``), and the step's random stream moved so
        that this process draws the whole batch's draws of its own clips (see the module doc)."""
        if not self.active:
            return shuffle_time(batch) if shuffle_frames else batch
        b, t = batch["bev_lidar"].shape[:2]
        before, after = self.rank * b, (self.processes - 1 - self.rank) * b
        if shuffle_frames:  # one permutation per clip: skip the earlier blocks', then the later ones'
            for _ in range(before):
                torch.randperm(t)
            batch = shuffle_time(batch)
            for _ in range(after):
                torch.randperm(t)
        # The fusion's modality dropout draws one number per clip on the model's device.
        device = torch.device("cuda", self.local_rank) if self._on_cuda() else torch.device("cpu")
        torch.rand(before, device=device)
        has_camera = bool(torch.as_tensor(batch["has_camera"]).any())
        return {**batch, "run_camera": self.any(has_camera)}

    def whole_batch(self, batch: dict[str, Any], keys: Sequence[Any]) -> tuple[dict[str, list[Any]], list[Any]]:
        """The whole batch's text fields (clip ids, categories, tags, captions) and positive keys, in rank order."""
        fields = ("clip_id", "category", "tags", "host_tags", "canonical_caption")
        if not self.active:
            return {k: list(batch[k]) for k in fields if k in batch}, list(keys)
        mine = ({k: list(batch[k]) for k in fields if k in batch}, list(keys))
        parts: list[Any] = [None] * self.processes
        dist.all_gather_object(parts, mine)
        whole = {k: [v for part in parts for v in part[0][k]] for k in mine[0]}
        return whole, [k for part in parts for k in part[1]]

    def gather(self, x: torch.Tensor) -> torch.Tensor:
        """x: (n_r, ...) → every process's rows (Σ n_r, ...), rank order, with gradients (:func:`gather_rows`)."""
        return gather_rows(x) if self.active else x

    def rows(self, n: int) -> slice | None:
        """This process's ``n`` rows of the whole batch (None on one process: all rows)."""
        return slice(self.rank * n, (self.rank + 1) * n) if self.active else None

    def means(self, values: dict[str, float]) -> dict[str, float]:
        """Each of ``values`` averaged over processes (one collective for all)."""
        if not self.active:
            return dict(values)
        t = torch.tensor(list(values.values()), dtype=torch.float64, device=self._collective_device())
        dist.all_reduce(t)
        return {k: float(v) / self.processes for k, v in zip(values, t.tolist())}

    def total(self, x: torch.Tensor) -> torch.Tensor:
        """x (counts, no gradient) summed over processes."""
        if not self.active:
            return x
        out = x.detach().to(self._collective_device(), copy=True)
        dist.all_reduce(out)
        return out.to(x.device)

    def any(self, flag: bool) -> bool:
        """Whether ``flag`` holds on any process."""
        if not self.active:
            return flag
        t = torch.tensor([int(flag)], dtype=torch.int64, device=self._collective_device())
        dist.all_reduce(t)
        return bool(t)

    def average_gradients(self, *modules: nn.Module | None) -> None:
        """Gradients averaged over processes, in one all-reduce. A parameter without a gradient here counts
        as zero; one without a gradient on every process keeps none (the optimiser then skips it)."""
        if not self.active:
            return
        params = [p for m in modules if m is not None for p in m.parameters() if p.requires_grad]
        if not params:
            return
        grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in params]
        has = torch.tensor([p.grad is not None for p in params], dtype=grads[0].dtype, device=grads[0].device)
        flat = torch.cat([*(g.reshape(-1) for g in grads), has])
        dist.all_reduce(flat)
        flat /= self.processes
        at = 0
        for p in params:
            n = p.numel()
            p.grad = flat[at : at + n].view_as(p).clone()
            at += n
        for p, present in zip(params, flat[at:].tolist()):
            if present == 0:
                p.grad = None

    def _on_cuda(self) -> bool:
        return dist.get_backend() == "nccl"

    def _collective_device(self) -> torch.device:
        return torch.device("cuda", self.local_rank) if self._on_cuda() else torch.device("cpu")


# --- process group and launcher ------------------------------------------------------------------------
@contextmanager
def process_group(device: str = "auto") -> Iterator[Distributed]:
    """Join the process group that a launcher (torchrun, :func:`launch`) described in the environment;
    one process when ``WORLD_SIZE`` is unset or 1.

    NCCL when ``device`` resolves to CUDA (each process on GPU ``LOCAL_RANK``), gloo otherwise; on CPU
    the machine's cores are shared out between its processes. Leaves the group on exit, after every
    process got there.
    """
    processes = int(os.environ.get("WORLD_SIZE", "1"))
    if processes <= 1:
        yield Distributed()
        return
    rank, local_rank = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0"))
    cuda = resolve_device(device).type == "cuda"
    if cuda:
        torch.cuda.set_device(local_rank)
    elif "OMP_NUM_THREADS" not in os.environ:  # torchrun sets it; torch's launcher API does not
        local = int(os.environ.get("LOCAL_WORLD_SIZE", processes))
        torch.set_num_threads(max(1, torch.get_num_threads() // local))
    created = not dist.is_initialized()
    if created:
        dist.init_process_group("nccl" if cuda else "gloo", timeout=TIMEOUT)
    try:
        yield Distributed(rank, processes, local_rank)
        dist.barrier(device_ids=[local_rank] if cuda else None)
    finally:
        if created:
            dist.destroy_process_group()


def _recorded(fn: Callable[..., T], *args: Any) -> T:
    from torch.distributed.elastic.multiprocessing.errors import record

    return cast(T, record(fn)(*args))  # record's annotation allows None; fn's result passes through


def launch(processes: int, fn: Callable[..., T], *args: Any) -> T:
    """``fn(*args)`` in ``processes`` processes on this machine through torch's elastic launcher (as
    ``torchrun --standalone`` starts them); returns rank 0's result.

    ``fn`` and ``args`` must pickle (a module-level function). A process that fails stops the others;
    the launcher then raises ``ChildFailedError`` with its traceback.
    """
    from torch.distributed.launcher.api import LaunchConfig, elastic_launch

    config = LaunchConfig(min_nodes=1, max_nodes=1, nproc_per_node=processes, run_id=uuid.uuid4().hex,
                          rdzv_backend="c10d", rdzv_endpoint="localhost:0", max_restarts=0, monitor_interval=0.1,
                          start_method="spawn")
    results = elastic_launch(config, _recorded)(fn, *args)
    return results[0]
