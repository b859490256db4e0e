"""Dense supervision: per-frame tag targets, the loss over tagged frames, and heads that learn them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from encoders.dense import DENSE_TASKS, DenseHeads, dense_accuracy, dense_loss, frame_targets, stream_dense_loss

NUM_CLASSES = sum(len(c) for c in DENSE_TASKS.values())


def test_frame_targets_index_each_task_and_mark_untagged_frames() -> None:
    columns = {
        "frame_lane": ["left", None, "host"],
        "frame_motion": ["approach", "away", "not-a-motion"],
        "frame_host_motion": ["cruising"] * 3,
        "frame_action": ["braking", None, "none"],
    }  # no frame_host_direction and frame_context columns: a table written without them
    out = frame_targets(columns, 3)
    assert list(DENSE_TASKS) == ["lane", "motion", "host_motion", "host_direction", "action", "context"]
    assert out.shape == (3, 6)
    lane, motion, host_motion, _host_direction, action, _context = DENSE_TASKS.values()
    np.testing.assert_array_equal(out[:, 0], [lane.index("left"), -1, lane.index("host")])
    np.testing.assert_array_equal(out[:, 1], [motion.index("approach"), motion.index("away"), -1])
    np.testing.assert_array_equal(out[:, 2], [host_motion.index("cruising")] * 3)
    np.testing.assert_array_equal(out[:, 3], [-1, -1, -1])
    # "none" is a class: the frame is tagged and its unified tag names no action.
    np.testing.assert_array_equal(out[:, 4], [action.index("braking"), -1, action.index("none")])
    np.testing.assert_array_equal(out[:, 5], [-1, -1, -1])
    with pytest.raises(ValueError, match="frame_lane: 2 values for a clip of 3 frames"):
        frame_targets({"frame_lane": ["left", "left"]}, 3)


def test_dense_loss_counts_tagged_frames_and_kept_clips_only() -> None:
    torch.manual_seed(0)
    logits = torch.randn(2, 5, NUM_CLASSES)
    targets = torch.full((2, 5, len(DENSE_TASKS)), -1, dtype=torch.long)
    assert float(dense_loss(logits, targets)) == 0.0
    targets[0, :, 0] = 1
    one = dense_loss(logits, targets)
    changed = logits.clone()
    changed[1] += 10.0  # clip 1 has no targets: its logits do not matter
    changed[0, :, len(DENSE_TASKS["lane"]):] += 5.0  # nor do the other tasks' logits of clip 0
    assert torch.allclose(dense_loss(changed, targets), one)
    lane = len(DENSE_TASKS["lane"])
    expected = torch.nn.functional.cross_entropy(logits[0, :, :lane], targets[0, :, 0]) / len(DENSE_TASKS)
    assert torch.allclose(one, expected)
    assert float(dense_loss(logits, targets, keep=torch.tensor([False, True]))) == 0.0
    # The camera stream counts the clips with camera only.
    streams = {"camera": logits, "track": logits}
    both = stream_dense_loss(streams, targets, torch.tensor([False, False]))
    assert torch.allclose(both, one / 2)


def test_heads_of_some_tasks_read_their_own_targets_only() -> None:
    """A model of the first four tasks (``dense_tasks``): its loss and accuracy read those targets of a
    six-task batch, and its heads have their outputs only."""
    old = ("lane", "motion", "host_motion", "host_direction")
    gen = torch.Generator().manual_seed(2)
    targets = torch.stack([torch.randint(-1, len(c), (3, 5), generator=gen) for c in DENSE_TASKS.values()], -1)
    heads = DenseHeads(8, old)
    logits = heads(torch.randn(3, 5, 8, generator=gen))
    assert logits.shape == (3, 5, sum(len(DENSE_TASKS[t]) for t in old))
    full = torch.cat([logits, torch.zeros(3, 5, NUM_CLASSES - logits.shape[-1])], -1)
    untagged = targets.clone()
    untagged[..., 4:] = -1  # the full heads without action and context targets: the same four tasks
    assert torch.allclose(dense_loss(logits, targets, tasks=old), dense_loss(full, untagged) * 6 / 4)
    assert set(dense_accuracy(logits, targets, old)) == set(old)


def test_dense_heads_learn_per_frame_tags_from_tokens() -> None:
    """Tokens that hold the answer linearly: the heads reach it; untrained they are near chance."""
    g = torch.Generator().manual_seed(0)
    b, t, w = 64, 8, 16
    targets = torch.stack([torch.randint(len(c), (b, t), generator=g) for c in DENSE_TASKS.values()], dim=-1)
    codes = torch.randn(max(len(c) for c in DENSE_TASKS.values()), len(DENSE_TASKS), w, generator=g)
    tokens = sum(codes[targets[..., k], k] for k in range(len(DENSE_TASKS)))  # (B, T, W)
    torch.manual_seed(0)
    heads = DenseHeads(w)
    before = dense_accuracy(heads(tokens), targets)
    opt = torch.optim.Adam(heads.parameters(), lr=0.05)
    for _ in range(200):
        opt.zero_grad()
        dense_loss(heads(tokens), targets).backward()
        opt.step()
    after = dense_accuracy(heads(tokens), targets)
    assert all(after[k] > 0.95 for k in DENSE_TASKS), after
    assert all(before[k] < 0.6 for k in DENSE_TASKS), before


def test_shares_of_a_batch_over_the_whole_batch_frames_add_up_to_its_loss() -> None:
    """Data-parallel processes hold unequal shares of tagged frames; divided by the whole batch's count,
    their losses add up to the whole batch's (the mean over processes of ``processes`` × each)."""
    gen = torch.Generator().manual_seed(1)
    logits = torch.randn(6, 5, NUM_CLASSES, generator=gen)
    targets = torch.stack([torch.randint(-1, len(c), (6, 5), generator=gen) for c in DENSE_TASKS.values()], -1)
    targets[:2] = -1  # the first process's first clips are untagged
    whole_counts = (targets >= 0).flatten(0, 1).sum(0)
    parts = [dense_loss(logits[s], targets[s], whole=lambda _c: whole_counts) for s in (slice(0, 3), slice(3, 6))]
    assert float(sum(parts)) == pytest.approx(float(dense_loss(logits, targets)), abs=1e-6)
    # Each part over its own frames instead: not the whole batch's loss.
    own = [dense_loss(logits[s], targets[s]) for s in (slice(0, 3), slice(3, 6))]
    assert float(sum(own)) / 2 != pytest.approx(float(dense_loss(logits, targets)), abs=1e-3)
