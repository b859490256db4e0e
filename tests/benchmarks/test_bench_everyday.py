"""The everyday benchmark's judges and means (its search runs need the demo's index: not here)."""

from __future__ import annotations

import pytest

from benchmarks import bench_everyday as be

ROW = {"category": "car", "tags": ["left:approach", "host:constant:braking", "host:constant:stopped"],
       "host_tags": ["moving:steering_left"]}


def test_has_matches_one_step_with_every_part_and_lane_prefixes() -> None:
    assert be._has(ROW, lane="host", action="braking")
    assert be._has(ROW, lane="left*", motion="approach")
    assert not be._has(ROW, lane="left", action="braking")  # the parts must hold in the same step
    assert not be._has(ROW, lane="right*")


def test_then_needs_the_second_step_after_the_first() -> None:
    assert be._then(ROW, lambda s: s[0] == "left", lambda s: s[0] == "host")
    assert not be._then(ROW, lambda s: s[0] == "host", lambda s: s[0] == "left")
    assert be._then(ROW, lambda s: "braking" in s, lambda s: "stopped" in s)


def test_every_judge_reads_a_row_without_tags() -> None:
    for queries in be.SETS.values():
        for text, judge in queries.items():
            assert judge({}) is False, text


def test_means_count_sentences_at_the_base_rate_and_without_relevant_clips() -> None:
    figures = {"default": 0.0, "model": 0.0, "rule_captions": 0.0, "hybrid": 0.0, "ceiling": 0.0,
               "selection_precision": 0.0, "selection_recall": 0.0}
    per_query = {"a": {**figures, "default": 0.8, "base_rate": 0.1, "relevant": 12.0, "ceiling": 1.0,
                       "selection_precision": 0.5, "selection_recall": 1.0},
                 "b": {**figures, "base_rate": 0.0, "relevant": 0.0},
                 "c": {**figures, "default": 0.1, "base_rate": 0.1, "relevant": 3.0, "ceiling": 0.3}}
    means = be._means(per_query)
    assert means["default"] == pytest.approx(0.3)
    assert means["selection_precision"] == pytest.approx(0.5 / 3, abs=1e-3)
    assert means["at_or_below_base_rate"] == 2.0
    assert means["without_relevant_clips"] == 1.0
    assert means["at_or_below_base_rate_with_relevant_clips"] == 1.0
    assert means["default_share_of_ceiling"] == pytest.approx(round(0.3 / round(1.3 / 3, 3), 3))
