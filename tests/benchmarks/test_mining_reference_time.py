"""The mining reference's tests over time, on grids small enough to check by hand."""

from __future__ import annotations

from benchmarks.mining_reference_time import FrameClock

#: One object, six frames 0.5 s apart.
CLOCK = FrameClock([0.0, 0.5, 1.0, 1.5, 2.0, 2.5], num_objects=1)


def test_runs_are_consecutive_selected_frames_of_one_object() -> None:
    sel = [[True, True, False, True, False, True]]
    assert list(CLOCK.runs(sel)) == [(0, 0, 2), (0, 3, 4), (0, 5, 6)]


def test_a_run_lasts_from_its_first_frame_to_one_interval_past_its_last() -> None:
    sel = [[True, True, False, True, False, False]]
    assert CLOCK.interval_s == 0.5
    assert CLOCK.runs_lasting(sel, 1.0) == [[True, True, False, False, False, False]]
    assert CLOCK.runs_lasting(sel, 0.5) == sel
    assert CLOCK.runs_lasting(sel, 1.5) == [[False] * 6]


def test_runs_holding_keep_whole_runs_with_a_marked_frame() -> None:
    sel = [[True, True, False, True, True, False]]
    marks = [[False, False, False, False, True, False]]
    assert CLOCK.runs_holding(sel, marks) == [[False, False, False, True, True, False]]


def test_reach_looks_one_way_and_not_at_the_frame_itself() -> None:
    frames = [False, False, True, False, False, False]
    assert CLOCK.in_reach(frames, 0, 1, 1.0)
    assert not CLOCK.in_reach(frames, 0, 1, 0.9)
    assert not CLOCK.in_reach(frames, 2, 1, 5.0)
    assert CLOCK.in_reach(frames, 4, -1, 1.0)


def test_a_chain_keeps_the_frames_of_each_step_that_lie_on_a_whole_chain() -> None:
    first = [[True, False, False, False, False, True]]
    second = [[False, True, False, False, False, False]]
    # The first step at 0 s leads to the second at 0.5 s; the first step at 2.5 s leads nowhere.
    assert CLOCK.chained([first, second], [1.0]) == [[True, True, False, False, False, False]]
    # A second step farther than the gap allows breaks the chain.
    assert CLOCK.chained([first, [[False, False, False, True, False, False]]], [1.0]) == [[False] * 6]
