"""Eq. 8 collapsing, host segments, windows."""

from __future__ import annotations

import numpy as np

from captioning.tags import NO_TAG
from captioning.unify import collapse, collapse_codes, host_segments, sliding_windows


def test_collapse_keeps_one_entry_per_run_in_order() -> None:
    assert collapse(["a", "a", "b", "b", "b", "a", "c"]) == ["a", "b", "a", "c"]
    assert collapse([]) == []
    assert collapse_codes(np.array([3, 3, 1, 3])).tolist() == [3, 1, 3]


def test_host_segments_drop_short_runs_and_split_long_ones() -> None:
    codes = np.r_[np.full(5, 0), np.full(20, 1), np.full(650, 2), np.full(3, NO_TAG), np.full(8, 3)]
    segments = host_segments(codes, 8, 300)
    assert [(s.code, s.num_frames) for s in segments] == [(1, 20), (2, 216), (2, 217), (2, 217), (3, 8)]
    assert segments[1].start == 25 and segments[3].end == 674
    # Parts tile the run without gaps.
    assert [s.start for s in segments[1:4]] == [25, 241, 458]


def test_sliding_windows_cover_the_log() -> None:
    ts = (np.arange(100) * 1e8).astype(np.int64)  # 10 s at 10 Hz
    windows = sliding_windows(ts, 4.0, 2.0)
    assert [(w.start, w.end) for w in windows] == [(0, 39), (20, 59), (40, 79), (60, 99)]
