"""Time masks on a log's own timestamps: runs, beginnings, what follows what."""

from __future__ import annotations

import itertools

import numpy as np

from scenarios import timing


def test_durations_are_seconds_at_any_rate() -> None:
    mask = np.zeros((1, 40), bool)
    mask[0, 5:15] = True  # 10 frames
    t10 = np.arange(40) * 0.1
    assert timing.runs_lasting(mask, t10, 1.0).sum() == 10 and timing.runs_lasting(mask, t10, 1.1).sum() == 0
    t2 = np.arange(40) * 0.5
    assert timing.runs_lasting(mask, t2, 5.0).sum() == 10  # 10 frames at 2 Hz last 5 s
    stopped = np.zeros((1, 20), bool)
    moving = np.zeros((1, 20), bool)
    stopped[0, 2:6], moving[0, 8:14] = True, True
    t = np.arange(20) * 0.1
    both = timing.chained([stopped, moving], [0.5], t)
    assert both[0, 5] and both[0, 8] and not both[0, 2] and not both[0, 13]
    assert not timing.chained([moving, stopped], [5.0], t).any()  # the order matters


def test_beginnings_runs_and_reach_in_seconds() -> None:
    mask = np.array([[False, True, True, False, True, True, True]])
    assert np.flatnonzero(timing.onsets(mask)).tolist() == [1, 4]
    marks = np.zeros_like(mask)
    marks[0, 5] = True
    assert np.flatnonzero(timing.runs_holding(mask, marks)).tolist() == [4, 5, 6]
    t = np.arange(7) * 0.5
    later = np.zeros(7, bool)
    later[4] = True  # 2.0 s
    assert np.flatnonzero(timing.followed_within(mask, later, t, 1.0)).tolist() == [2]  # 1.0 s before, not at it
    assert np.flatnonzero(timing.preceded_within(mask, later, t, 1.0)).tolist() == [5, 6]


def test_a_chain_keeps_each_step_in_order() -> None:
    t = np.arange(10) * 1.0
    a, b, c = (np.zeros((1, 10), bool) for _ in range(3))
    a[0, 0], c[0, 2], b[0, 4] = True, True, True  # A, then C, then B: not "A, then B, then C"
    assert not timing.chained([a, b, c], [5.0, 5.0], t).any()
    c[0, 6] = True  # now C follows B too
    assert np.flatnonzero(timing.chained([a, b, c], [5.0, 5.0], t)).tolist() == [0, 4, 6]
    assert not timing.chained([a, b, c], [5.0, 1.0], t).any()  # C must follow B within its own time


def test_a_chain_is_every_frame_on_some_ordered_path() -> None:
    """Against the definition, on random masks: a frame is kept where it is step i of frames f0 < f1 < …
    of steps 0, 1, … with each within its time of the one before."""
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.2, 1.0, 9))
    gaps_s = [1.5, 0.8]
    for _ in range(200):
        steps = [rng.random((2, 9)) < 0.3 for _ in range(3)]
        expected = np.zeros((2, 9), bool)
        for o in range(2):
            for path in itertools.product(range(9), repeat=3):
                if all(steps[i][o, f] for i, f in enumerate(path)) and all(
                        0 < t[path[i + 1]] - t[path[i]] <= gaps_s[i] for i in range(2)):
                    expected[o, list(path)] = True
        assert (timing.chained(steps, gaps_s, t) == expected).all()


def test_the_steps_reached_in_order_end_the_chain() -> None:
    t = np.arange(8) * 1.0
    a, b, c = (np.zeros((1, 8), bool) for _ in range(3))
    a[0, 0], b[0, 2], c[0, [1, 5]] = True, True, True  # C at 1 s comes before B; C at 5 s after it
    reached = timing.reached_in_order([a, b, c], [5.0, 5.0], t)
    assert np.flatnonzero(reached[1]).tolist() == [2] and np.flatnonzero(reached[2]).tolist() == [5]
