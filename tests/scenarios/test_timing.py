"""Time masks on a log's own timestamps: runs, beginnings, what follows what."""

from __future__ import annotations

import numpy as np

from scenarios.timing import followed_within, onsets, preceded_within, runs_holding, runs_lasting, then_within


def test_durations_are_seconds_at_any_rate() -> None:
    mask = np.zeros((1, 40), bool)
    mask[0, 5:15] = True  # 10 frames
    t10 = np.arange(40) * 0.1
    assert runs_lasting(mask, t10, 1.0).sum() == 10 and runs_lasting(mask, t10, 1.1).sum() == 0
    t2 = np.arange(40) * 0.5
    assert runs_lasting(mask, t2, 5.0).sum() == 10  # 10 frames at 2 Hz last 5 s
    stopped = np.zeros((1, 20), bool)
    moving = np.zeros((1, 20), bool)
    stopped[0, 2:6], moving[0, 8:14] = True, True
    t = np.arange(20) * 0.1
    both = then_within(stopped, moving, t, 0.5)
    assert both[0, 5] and both[0, 8] and not both[0, 2] and not both[0, 13]
    assert not then_within(moving, stopped, t, 5.0).any()  # the order matters


def test_beginnings_runs_and_reach_in_seconds() -> None:
    mask = np.array([[False, True, True, False, True, True, True]])
    assert np.flatnonzero(onsets(mask)).tolist() == [1, 4]
    marks = np.zeros_like(mask)
    marks[0, 5] = True
    assert np.flatnonzero(runs_holding(mask, marks)).tolist() == [4, 5, 6]
    t = np.arange(7) * 0.5
    later = np.zeros(7, bool)
    later[4] = True  # 2.0 s
    assert np.flatnonzero(followed_within(mask, later, t, 1.0)).tolist() == [2]  # 1.0 s before, not at it
    assert np.flatnonzero(preceded_within(mask, later, t, 1.0)).tolist() == [5, 6]
