"""Caption text: canonical sentence, words that must appear, seeded paraphrases."""

from __future__ import annotations

import pytest

from captioning.tags import Lane, Motion, split_neighbor_tag, unified_neighbor_tag
from captioning.text import caption_text, host_sentence, neighbor_sentence, paraphrases


def test_canonical_caption_reads_like_the_issue_example() -> None:
    text = caption_text("car", ["left:approach", "host:constant"], ["cruising:heading_straight"])
    assert text == (
        "The ego vehicle is cruising straight. "
        "A car in the left lane approaches, then moves into the ego lane and keeps its distance."
    )


def test_host_sentences() -> None:
    assert host_sentence(["stationary:heading_straight"]) == "The ego vehicle is stationary."
    assert host_sentence(["decelerating:heading_straight", "stationary:heading_straight"]) == (
        "The ego vehicle is decelerating straight, then stops."
    )
    assert host_sentence(["accelerating:steering_left"]) == "The ego vehicle is accelerating while steering left."


def test_motion_change_in_the_same_lane_names_only_the_motion() -> None:
    assert neighbor_sentence("pedestrian", ["right:approach", "right:stationary"]) == (
        "A pedestrian in the right lane approaches, then is stationary."
    )
    assert neighbor_sentence("other", ["oncoming:away"]) == "An object in the oncoming lane moves away."


LANE_WORD = {
    Lane.LEFT: "left", Lane.RIGHT: "right", Lane.HOST: "ego lane", Lane.LEFT_LATERAL: "left",
    Lane.RIGHT_LATERAL: "right", Lane.HOST_LATERAL: "ego", Lane.ONCOMING: "oncoming",
}
MOTION_WORD = {Motion.APPROACH: "approaches", Motion.AWAY: "away", Motion.CONSTANT: "distance",
               Motion.STATIONARY: "stationary"}


@pytest.mark.parametrize("lane", list(Lane))
@pytest.mark.parametrize("motion", list(Motion))
def test_class_lane_and_motion_words_always_appear(lane: Lane, motion: Motion) -> None:
    text = neighbor_sentence("truck", [f"{lane.value}:{motion.value}"])
    assert "truck" in text and LANE_WORD[lane] in text and MOTION_WORD[motion] in text


def test_paraphrases_are_seeded_distinct_and_keep_the_class() -> None:
    args = ("bus", ["right:approach", "host:away"], ["cruising:heading_straight"])
    first = paraphrases(*args, count=3, seed=7, key=("log", "t1", 0))
    again = paraphrases(*args, count=3, seed=7, key=("log", "t1", 0))
    other = paraphrases(*args, count=3, seed=8, key=("log", "t1", 0))
    assert first == again
    assert first != other
    assert len(set(first)) == 3
    assert caption_text(*args) not in first
    assert all("bus" in p and "then" in p for p in first)


def test_own_action_and_context_in_the_neighbour_sentence() -> None:
    assert neighbor_sentence("car", ["left:approach:braking", "left:approach:left_turn"]) == (
        "A car in the left lane approaches while braking, then turns left at the intersection.")
    assert neighbor_sentence("truck", ["host:approach:stopped"]) == (
        "A truck stands in the ego lane as the ego approaches.")
    assert neighbor_sentence("car", ["right:constant:parked"]) == "A car is parked on the right."
    assert neighbor_sentence("car", ["host:approach", "host:approach:braking:on_crosswalk",
                                     "host:approach:stopped:on_crosswalk", "host:away"]) == (
        "A car in the ego lane approaches, then brakes on a crosswalk, then stops on a crosswalk as the ego "
        "approaches, then starts moving and moves away.")
    # A parked car passed by the ego: its lane relative to the ego changes, it does not.
    assert neighbor_sentence("car", ["right:approach:parked", "right_lateral:away:parked"]) == (
        "A car is parked on the right as the ego approaches, then the ego moves away from it.")


def test_paraphrases_cover_the_new_words() -> None:
    tags = ["left:approach:braking", "left:approach:left_turn"]
    texts = paraphrases("car", tags, ["cruising:heading_straight"], 3, 0, ("log", "t", 0, 1))
    assert len(set(texts)) == 3
    assert all(any(w in t for w in ("brak", "slow")) and "left" in t for t in texts)
    seen = {paraphrases("car", ["host:constant:stopped"], [], 3, seed, ("k",))[0] for seed in range(20)}
    assert any("is stopped" in t for t in seen) and any("waits" in t for t in seen)


def test_neighbour_tags_with_action_and_context_round_trip() -> None:
    for parts in (("left", "approach", None, None), ("host", "approach", "stopped", "at_intersection"),
                  ("right", "away", None, "on_crosswalk"), ("oncoming", "constant", "braking", None)):
        assert split_neighbor_tag(unified_neighbor_tag(*parts)) == parts
    assert unified_neighbor_tag("right", "away", None, "on_crosswalk") == "right:away:on_crosswalk"


def test_caption_halves_are_the_two_sentences_that_caption_text_joins() -> None:
    from captioning.text import caption_halves

    host = ["decelerating:heading_straight", "stationary:heading_straight"]
    tags = ["left:approach", "host:constant"]
    caption = caption_text("car", tags, host)
    assert caption_halves(caption) == (host_sentence(host), neighbor_sentence("car", tags))
    for paraphrase in paraphrases("car", tags, host, count=3, seed=0, key=("log", "track")):
        ego, obj = caption_halves(paraphrase)
        assert ego is not None and obj is not None and f"{ego} {obj}" == paraphrase
    assert caption_halves(caption_text(None, host, host)) == (host_sentence(host), None)  # an ego clip's caption
    assert caption_halves("A car approaches. Then it stops.") == (None, None)  # no ego sentence first
