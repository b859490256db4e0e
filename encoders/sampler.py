"""The clips of each training step, in order: :class:`EpochSampler`, one job shared by one process and
many (``encoders.distributed``): the epoch's order is drawn once from (seed, epoch), whole batch after
whole batch, and each process takes its block of every whole batch.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray
from torch.utils.data import Dataset
from torch.utils.data.distributed import DistributedSampler


class EpochSampler(DistributedSampler[int]):
    """This process's clips of each step: block ``rank`` of the step's ``processes × batch_size`` clips.

    The epoch's order is ``numpy.random.default_rng([seed, epoch]).permutation(n)`` (:meth:`set_epoch`);
    step k's whole batch is its k-th run of ``processes × batch_size`` entries, and the processes'
    blocks, in rank order, are that batch. Yields ``steps × batch_size`` indices (batch them by
    ``batch_size``); the clips left over at the end of an epoch are not drawn.

    With ``camera`` ((N,) bool, which clips have a camera view) and ``camera_share`` > 0, and when
    the camera clips are fewer than that share of the clips, every whole batch holds
    ``ceil(camera_share × processes × batch_size)`` camera clips, dealt from shuffled decks (a new
    deck when one runs out, no clip twice in a batch), the rest from the other clips, in a shuffled
    order. The camera view's own loss needs several camera clips in a batch to have
    negatives: where a tenth of the clips have a camera, most batches of 16 hold one or none.
    """

    def __init__(self, dataset: Dataset[Any], batch_size: int, steps: int, seed: int, rank: int = 0,
                 processes: int = 1, camera: NDArray[np.bool_] | None = None, camera_share: float = 0.0) -> None:
        super().__init__(dataset, num_replicas=processes, rank=rank, shuffle=True, seed=seed, drop_last=True)
        self.batch_size, self.steps = batch_size, steps
        self.n = len(dataset)  # type: ignore[arg-type]
        self.camera = None if camera is None else np.asarray(camera, dtype=bool).reshape(-1)
        if self.camera is not None and len(self.camera) != self.n:
            raise ValueError(f"EpochSampler: {len(self.camera)} camera flags for {self.n} clips")
        self.camera_share = float(camera_share)

    def camera_per_batch(self) -> int:
        """Camera clips in every whole batch; 0 when batches are drawn from one permutation."""
        whole = self.batch_size * self.num_replicas
        if self.camera is None or self.camera_share <= 0:
            return 0
        k = min(whole, math.ceil(self.camera_share * whole - 1e-9))
        n_camera = int(self.camera.sum())
        if n_camera == 0 or n_camera >= self.camera_share * self.n:
            return 0  # no camera clips to draw, or already that share without stratifying
        return k

    def whole_order(self) -> NDArray[np.int64]:
        """(steps × processes × batch_size,) the epoch's clips, whole batch after whole batch."""
        rng = np.random.default_rng([self.seed, self.epoch])
        whole = self.batch_size * self.num_replicas
        k = self.camera_per_batch()
        if k == 0:
            return rng.permutation(self.n)[: self.steps * whole].astype(np.int64)
        assert self.camera is not None
        camera = _dealt(np.flatnonzero(self.camera), self.steps, k, rng)  # (steps, k)
        others = _dealt(np.flatnonzero(~self.camera), self.steps, whole - k, rng)  # (steps, whole − k)
        batches = rng.permuted(np.concatenate([camera, others], axis=1), axis=1)  # (steps, whole), rows shuffled
        return batches.reshape(-1).astype(np.int64)

    def __iter__(self) -> Iterator[int]:
        order = self.whole_order()
        whole = self.batch_size * self.num_replicas
        for k in range(self.steps):
            start = k * whole + self.rank * self.batch_size
            yield from order[start : start + self.batch_size].tolist()

    def __len__(self) -> int:
        return self.steps * self.batch_size


def _dealt(indices: NDArray[np.intp], rows: int, per_row: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """(rows, per_row) of ``indices`` dealt row by row from decks shuffled by ``rng``: each index once
    per deck, the next deck drawn when one runs out, and no index twice in a row that the set can fill.
    """
    if rows * per_row and len(indices) == 0:
        raise ValueError("cannot draw clips from an empty set")
    deck: list[int] = []
    out = np.empty((rows, per_row), dtype=np.int64)
    for r in range(rows):
        hand: list[int] = []
        while len(hand) < per_row:
            fresh = len(hand) < len(indices)  # otherwise a repeat cannot be avoided
            pick = next((j for j, c in enumerate(deck) if not fresh or c not in hand), None)
            if pick is None:  # the deck is spent, or holds only clips of this row: the next deck
                deck += rng.permutation(indices).tolist()
                continue
            hand.append(deck.pop(pick))
        out[r] = hand
    return out
