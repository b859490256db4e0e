"""Clip → clip figures: action precision of neighbours, appearance bias, the share from the query's own log
and own moment."""

from __future__ import annotations

import numpy as np
import pytest

from retrieval.clip_neighbours import (
    action_precision_ceiling,
    clip_to_clip_figures,
    perfect_ranking_figures,
    random_clip_to_clip,
    same_moment,
)

#: Figures of the fixed set of ``test_the_log_figures_keep_their_values`` from the implementation before
#: the moment figures, which shares its helpers with the log figures now.
SNAPSHOT = {
    "action_precision@3": 0.3611111111111111, "appearance_bias": 0.9130434782608696,
    "appearance_share_neighbours": 0.30434782608695654, "appearance_share_chance": 0.3333333333333333,
    "action_precision@3_ceiling": 1.0, "same_log_share_neighbours": 0.30434782608695654,
    "same_log_share_chance": 0.25, "action_precision@3_other_logs": 0.4166666666666667,
    "appearance_bias_other_logs": 0.8571428571428571, "appearance_share_neighbours_other_logs": 0.2857142857142857,
    "appearance_share_chance_other_logs": 0.3333333333333333,
}


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


def test_other_log_figures_measure_appearance_apart_from_the_log() -> None:
    # Four logs, two per appearance; each log holds actions a and b twice. Embeddings cluster by
    # appearance: neighbours from other logs are the other log of the same appearance, half of them in
    # another action → bias 1 / chance.
    logs = [f"log{i // 4}" for i in range(16)]
    appearance = ["day" if i < 8 else "night" for i in range(16)]
    actions = ["a", "b", "a", "b"] * 4
    rng = np.random.default_rng(0)
    x = np.array([[1.0, 0.0] if a == "day" else [0.0, 1.0] for a in appearance]) + rng.normal(0, 0.01, (16, 2))
    figures = clip_to_clip_figures(x / np.linalg.norm(x, axis=1, keepdims=True), actions, appearance, k=3, logs=logs)
    # Among other logs' clips of the other action (6 per clip), 2 share the appearance: chance 1 / 3.
    assert figures["appearance_share_chance_other_logs"] == pytest.approx(1 / 3)
    assert figures["appearance_share_neighbours_other_logs"] == 1.0
    assert figures["appearance_bias_other_logs"] == pytest.approx(3.0)
    # Embeddings by action: other logs' neighbours share the action, the bias is undefined (no
    # differing neighbour) and precision is 1.
    y = np.array([[1.0, 0.0] if a == "a" else [0.0, 1.0] for a in actions]) + rng.normal(0, 0.01, (16, 2))
    by_action = clip_to_clip_figures(y / np.linalg.norm(y, axis=1, keepdims=True), actions, appearance, k=3, logs=logs)
    assert by_action["action_precision@3_other_logs"] == 1.0
    assert by_action["appearance_bias_other_logs"] is None
    chance = random_clip_to_clip(actions, appearance, k=3, logs=logs)
    # 12 clips in other logs, 6 of them in the same action.
    assert chance["action_precision@3_other_logs"] == pytest.approx(0.5)
    assert chance["appearance_bias_other_logs"] == 1.0
    # One appearance per log: the look cannot be told apart from the log among other logs.
    own = [f"look{i // 4}" for i in range(16)]
    assert clip_to_clip_figures(x, actions, own, k=3, logs=logs)["appearance_bias_other_logs"] is None
    assert random_clip_to_clip(actions, own, k=3, logs=logs)["appearance_bias_other_logs"] is None


def test_ceiling_is_what_a_perfect_ranking_reaches() -> None:
    # Three clips of "go", one of "stop", one of "turn": with k = 2 a "go" clip finds its two others, a
    # "stop" or "turn" clip none, whatever the embedding.
    actions = ["go", "go", "go", "stop", "turn"]
    assert action_precision_ceiling(actions, k=2) == pytest.approx(3 / 5)
    assert action_precision_ceiling(actions, k=5) == pytest.approx((3 * 2 / 4) / 5)  # k shrinks to N − 1 = 4
    perfect = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    figures = clip_to_clip_figures(perfect, actions, ["day"] * 5, k=2)
    assert figures["action_precision@2"] == pytest.approx(figures["action_precision@2_ceiling"])
    assert action_precision_ceiling(["go"], k=5) == 0.0


def test_same_moment_is_the_same_log_with_windows_sharing_an_instant() -> None:
    # A window holds its first and last timestamps: windows that meet at one share that frame.
    logs = ["a", "a", "a", "b", "a"]
    windows_ns = [(0, 10), (10, 15), (16, 20), (0, 10), (16, 16)]
    expected = np.array([[1, 1, 0, 0, 0], [1, 1, 0, 0, 0], [0, 0, 1, 0, 1], [0, 0, 0, 1, 0], [0, 0, 1, 0, 1]],
                        dtype=bool)
    np.testing.assert_array_equal(same_moment(logs, windows_ns), expected)
    with pytest.raises(ValueError, match="windows_ns needs logs"):
        clip_to_clip_figures(np.eye(5), ["x"] * 5, ["day"] * 5, windows_ns=windows_ns)


def test_other_moment_figures_leave_out_the_objects_seen_at_the_same_time() -> None:
    # Two logs, each with two moments (windows 0-10 and 20-30) of four objects: actions a, b, c, d in every
    # moment, one appearance per log. Embeddings cluster by moment, and moments by log, so every neighbour
    # is another object of the query's own moment, in another action, and after them those of the log's
    # other moment.
    logs = [f"log{i // 8}" for i in range(16)]
    appearance = [f"look{i // 8}" for i in range(16)]
    actions = ["a", "b", "c", "d"] * 4
    windows_ns = [(0, 10) if i % 8 < 4 else (20, 30) for i in range(16)]
    rng = np.random.default_rng(0)
    moment = np.eye(4)[[i // 4 for i in range(16)]]
    x = np.hstack([np.eye(2)[[i // 8 for i in range(16)]], 0.5 * moment]) + rng.normal(0, 0.01, (16, 6))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    figures = clip_to_clip_figures(x, actions, appearance, k=3, logs=logs, windows_ns=windows_ns)
    # Each clip differs in action from 12 others, 3 of them in its moment.
    assert figures["same_moment_share_chance"] == pytest.approx(3 / 12)
    assert figures["same_moment_share_neighbours"] == 1.0
    assert figures["action_precision@3"] == 0.0 and figures["appearance_bias"] == pytest.approx(2.0)
    # Outside its moment a clip has 3 others of its action, so a perfect ranking reaches 1.
    assert figures["action_precision@3_ceiling_other_moments"] == 1.0
    # Outside the moment the nearest clips are the log's other moment, in its look; among other moments'
    # clips in another action (9 per clip) 3 share the look: chance 1 / 3.
    assert figures["appearance_share_chance_other_moments"] == pytest.approx(3 / 9)
    assert figures["appearance_share_neighbours_other_moments"] == 1.0
    assert figures["appearance_bias_other_moments"] == pytest.approx(3.0)
    # Embedded by action (and a little by moment), the neighbours outside the moment share the action.
    y = np.eye(4)[[i % 4 for i in range(16)]] + 0.3 * moment + rng.normal(0, 0.01, (16, 4))  # (16, 4)
    by_action = clip_to_clip_figures(y / np.linalg.norm(y, axis=1, keepdims=True), actions, appearance, k=3,
                                     logs=logs, windows_ns=windows_ns)
    assert by_action["action_precision@3_other_moments"] == 1.0
    assert by_action["same_moment_share_neighbours"] is None  # no neighbour differs in action
    chance = random_clip_to_clip(actions, appearance, k=3, logs=logs, windows_ns=windows_ns)
    assert chance["action_precision@3_other_moments"] == pytest.approx(3 / 12)
    assert chance["appearance_bias_other_moments"] == 1.0
    assert "same_moment_share_neighbours" not in clip_to_clip_figures(x, actions, appearance, k=3, logs=logs)


def test_the_ceiling_pools_as_the_precision_does_where_a_clip_has_fewer_candidates() -> None:
    # One log: moment 0-3 (actions a a b b) and moment 4-5 (a b). Outside its moment a clip of the second
    # moment has 4 candidates, one of the first only 2, fewer than k = 3.
    logs = ["log"] * 6
    windows_ns = [(0, 10)] * 4 + [(20, 30)] * 2
    actions = ["a", "a", "b", "b", "a", "b"]
    perfect = np.array([[1.0, 0.0] if a == "a" else [0.0, 1.0] for a in actions])
    figures = clip_to_clip_figures(perfect, actions, ["day"] * 6, k=3, logs=logs, windows_ns=windows_ns)
    # Found 1 of 2 by each clip of the first moment, 2 of 3 by each of the second: 8 of 14 neighbours.
    assert figures["action_precision@3_other_moments"] == pytest.approx(8 / 14)
    assert figures["action_precision@3_ceiling_other_moments"] == pytest.approx(8 / 14)


def test_the_log_figures_keep_their_values() -> None:
    # Figures of a fixed small set, as the evaluation reported them before the moments joined them.
    rng = np.random.default_rng(3)
    x = rng.normal(size=(12, 3))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    actions = ["a", "b", "c"] * 4
    appearance = ["day", "day", "night"] * 4
    logs = [f"log{i % 4}" for i in range(12)]
    figures = clip_to_clip_figures(x, actions, appearance, k=3, logs=logs)
    assert figures == pytest.approx(SNAPSHOT)
    # Random neighbours of clips of one look have no bias, in other logs as everywhere.
    chance = random_clip_to_clip(actions, ["day"] * 12, k=3, logs=logs)
    assert chance["appearance_bias"] is None and chance["appearance_bias_other_logs"] is None


def test_a_perfect_ranking_by_the_captions_takes_the_ego_motion_with_it() -> None:
    # Two logs, one look each; in each, the ego does one thing and its four objects do a, b, c, d. A
    # perfect ranking by what the captions say fills a clip's neighbours after its action with clips of the
    # ego's motion: its own log, its own look, bias 2 (chance 1 / 2).
    logs = ["log0"] * 4 + ["log1"] * 4
    looks = ["day"] * 4 + ["night"] * 4
    egos = ["cruising"] * 4 + ["stopping"] * 4
    actions = ["a", "b", "c", "d"] * 2
    figures = perfect_ranking_figures(actions, egos, looks, k=3, logs=logs)
    assert figures["appearance_bias_perfect_ranking"] == pytest.approx(2.0)
    assert set(figures) == {"appearance_bias_perfect_ranking", "appearance_bias_other_logs_perfect_ranking"}
    # The action comes first: a clip's one nearest neighbour is the clip of its action in the other log.
    assert perfect_ranking_figures(actions, egos, looks, k=1)["appearance_bias_perfect_ranking"] is None


def test_neighbours_sorted_by_rows_give_the_figures_of_a_whole_sort(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each clip's neighbours are sorted a few rows at a time (a large split's whole sort would not fit
    in memory): the same figures, ties and other-log neighbours included."""
    from retrieval import clip_neighbours

    rng = np.random.default_rng(5)
    x = np.eye(4)[rng.integers(0, 4, 23)] + 0.5 * np.eye(4)[rng.integers(0, 4, 23)]  # many equal scores
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    actions = [f"a{i}" for i in rng.integers(0, 3, 23)]
    looks = [f"l{i}" for i in rng.integers(0, 2, 23)]
    logs = [f"log{i}" for i in rng.integers(0, 4, 23)]
    windows = [(int(t), int(t) + 3) for t in rng.integers(0, 10, 23)]
    monkeypatch.setattr(clip_neighbours, "ROWS_AT_ONCE", 10**9)
    whole = clip_to_clip_figures(x, actions, looks, logs=logs, windows_ns=windows)
    monkeypatch.setattr(clip_neighbours, "ROWS_AT_ONCE", 4)
    assert clip_to_clip_figures(x, actions, looks, logs=logs, windows_ns=windows) == whole
