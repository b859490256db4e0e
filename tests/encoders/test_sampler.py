"""The order of clips in an epoch (encoders.sampler): one process's batches are the processes' blocks in
rank order, the old permutation stays where no camera share applies, and a camera share fills every batch.
"""

from __future__ import annotations

import numpy as np
import pytest

from encoders.sampler import EpochSampler


def test_epoch_sampler_blocks_in_rank_order_are_the_one_process_batches() -> None:
    data = list(range(23))
    for epoch in (0, 1):
        one = EpochSampler(data, batch_size=6, steps=3, seed=7)
        one.set_epoch(epoch)
        parts = [EpochSampler(data, batch_size=3, steps=3, seed=7, rank=r, processes=2) for r in (0, 1)]
        for p in parts:
            p.set_epoch(epoch)
        mine = [list(p) for p in parts]
        whole = list(one)
        assert len(whole) == 18 and len(set(whole)) == 18 and len(mine[0]) == len(parts[0]) == 9
        assert [v for k in range(3) for m in mine for v in m[3 * k : 3 * k + 3]] == whole
        expected = np.random.default_rng([7, epoch]).permutation(23)[:18].tolist()
        assert whole == expected  # the order one process always trained in


def test_epoch_sampler_camera_share_fills_every_batch_and_splits_by_rank() -> None:
    data = list(range(40))
    camera = np.zeros(40, dtype=bool)
    camera[[3, 17, 25]] = True  # 3 of 40 clips have a camera view
    one = EpochSampler(data, batch_size=8, steps=5, seed=3, camera=camera, camera_share=0.25)
    assert one.camera_per_batch() == 2
    for epoch in (0, 1):
        one.set_epoch(epoch)
        whole = list(one)
        batches = [whole[8 * k : 8 * k + 8] for k in range(5)]
        assert all(sum(camera[i] for i in b) == 2 for b in batches)  # 10 camera slots from 3 clips: redrawn
        assert all(len(set(b)) == 8 for b in batches)  # ...but never twice in one batch here
        others = [i for i in whole if not camera[i]]
        assert len(others) == len(set(others)) == 30  # the other clips once each, as without the share
        parts = [EpochSampler(data, batch_size=4, steps=5, seed=3, rank=r, processes=2, camera=camera,
                              camera_share=0.25) for r in (0, 1)]
        for p in parts:
            p.set_epoch(epoch)
        mine = [list(p) for p in parts]
        assert [v for k in range(5) for m in mine for v in m[4 * k : 4 * k + 4]] == whole
    one.set_epoch(0)
    first = list(one)
    one.set_epoch(1)
    assert list(one) != first  # another draw each epoch


def test_epoch_sampler_camera_share_keeps_the_plain_order_when_cameras_are_common_enough() -> None:
    data = list(range(23))
    camera = np.arange(23) % 2 == 0  # 12 of 23
    for share, flags in ((0.0, camera), (0.5, camera), (0.5, None), (0.3, np.zeros(23, dtype=bool))):
        sampler = EpochSampler(data, batch_size=6, steps=3, seed=7, camera=flags, camera_share=share)
        sampler.set_epoch(1)
        assert sampler.camera_per_batch() == 0
        assert list(sampler) == np.random.default_rng([7, 1]).permutation(23)[:18].tolist()
    with pytest.raises(ValueError, match="2 camera flags for 23 clips"):
        EpochSampler(data, batch_size=6, steps=3, seed=7, camera=np.ones(2, dtype=bool), camera_share=0.5)
