"""Clip → clip figures: action precision of neighbours, appearance bias, the share from the query's own log."""

from __future__ import annotations

import numpy as np
import pytest

from retrieval.clip_neighbours import clip_to_clip_figures, random_clip_to_clip


def test_clip_to_clip_figures() -> None:
    # Two actions, two appearances; embeddings cluster by appearance → biased, imprecise neighbours.
    actions = ["go", "stop"] * 6
    appearance = ["day"] * 6 + ["night"] * 6
    x = np.array([[1.0, 0.0] if a == "day" else [0.0, 1.0] for a in appearance]) + \
        np.random.default_rng(0).normal(0, 0.01, (12, 2))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    by_look = clip_to_clip_figures(x, actions, appearance, k=5)
    assert by_look["appearance_bias"] is not None and by_look["appearance_bias"] > 1.5
    y = np.array([[1.0, 0.0] if a == "go" else [0.0, 1.0] for a in actions]) + \
        np.random.default_rng(1).normal(0, 0.01, (12, 2))
    by_action = clip_to_clip_figures(y / np.linalg.norm(y, axis=1, keepdims=True), actions, appearance, k=5)
    assert by_action["action_precision@5"] == 1.0
    chance = random_clip_to_clip(actions, appearance, k=5)
    assert chance["action_precision@5"] == pytest.approx(5 / 11)
    assert chance["appearance_bias"] == 1.0




def test_same_log_share_and_ties() -> None:
    # Two logs of 4 clips; every clip embeds the same: all scores tie. Ties are broken in a seeded random
    # order, not table order, so neighbours are not all taken from the first log.
    actions = ["a", "b", "c", "d"] * 2
    appearance = ["day"] * 4 + ["night"] * 4
    logs = ["log0"] * 4 + ["log1"] * 4
    x = np.ones((8, 2)) / np.sqrt(2)
    figures = clip_to_clip_figures(x, actions, appearance, k=3, logs=logs)
    # Each clip differs in action from 6 others, 3 of them in its own log.
    assert figures["same_log_share_chance"] == pytest.approx(0.5)
    assert figures["same_log_share_neighbours"] is not None and 0.0 < figures["same_log_share_neighbours"] < 1.0
    assert figures == clip_to_clip_figures(x, actions, appearance, k=3, logs=logs)  # seeded: the same again
    # Neighbours clustered by log: every differing neighbour is from the query's own log.
    y = np.array([[1.0, 0.0]] * 4 + [[0.0, 1.0]] * 4) + np.random.default_rng(0).normal(0, 0.01, (8, 2))
    by_log = clip_to_clip_figures(y / np.linalg.norm(y, axis=1, keepdims=True), actions, appearance, k=3, logs=logs)
    # Appearance follows the log here, so its bias is the same-log share over chance: 1 / 0.5.
    assert by_log["same_log_share_neighbours"] == 1.0 and by_log["appearance_bias"] == pytest.approx(2.0)
    assert "same_log_share_neighbours" not in clip_to_clip_figures(x, actions, appearance, k=3)
