"""The tags of a clip played backwards."""

from __future__ import annotations

import random

from captioning.tags import LANES, MOTIONS
from encoders.time_reversal import reversed_clip_tags, reversed_host_tags, reversed_neighbor_tags


def test_steps_reverse_and_rates_flip() -> None:
    assert reversed_neighbor_tags(["left:approach", "host:away"]) == ["host:approach", "left:away"]
    assert reversed_neighbor_tags(["right:approach:left_lane_change", "host:constant:left_turn:at_intersection"]) == [
        "host:constant:right_turn:at_intersection", "right:away:right_lane_change"]
    # Standing objects and lanes stay; the ego's pass-by of a parked car reads the same both ways.
    assert reversed_neighbor_tags(["right:approach:parked", "right:away:parked"]) == [
        "right:approach:parked", "right:away:parked"]
    assert reversed_neighbor_tags(["oncoming:stationary:stopped"]) == ["oncoming:stationary:stopped"]


def test_braking_has_no_reverse_and_equal_steps_merge() -> None:
    assert reversed_neighbor_tags(["host:approach", "host:approach:braking", "left:approach"]) == [
        "left:away", "host:away"]


def test_host_tags_flip_speed_change_and_steering() -> None:
    assert reversed_host_tags(["accelerating:steering_left", "cruising:heading_straight"]) == [
        "cruising:heading_straight", "decelerating:steering_right"]
    assert reversed_host_tags(["stationary:heading_straight"]) == ["stationary:heading_straight"]
    tags, host = reversed_clip_tags("ego", ["decelerating:heading_straight", "stationary:heading_straight"],
                                    ["decelerating:heading_straight", "stationary:heading_straight"])
    assert tags == host == ["stationary:heading_straight", "accelerating:heading_straight"]
    tags, host = reversed_clip_tags("car", ["left:approach"], ["accelerating:steering_right"])
    assert (tags, host) == (["left:away"], ["decelerating:steering_left"])


def test_playing_backwards_twice_gives_the_clip_back() -> None:
    rng = random.Random(0)
    actions = ["", "parked", "stopped", "left_lane_change", "right_lane_change", "left_turn", "right_turn"]
    for _ in range(200):
        tags = [":".join(p for p in (rng.choice(LANES).value, rng.choice(MOTIONS).value, rng.choice(actions),
                                     rng.choice(["", "at_intersection", "on_crosswalk"])) if p)
                for _ in range(rng.randint(1, 4))]
        tags = [t for i, t in enumerate(tags) if i == 0 or t != tags[i - 1]]
        assert reversed_neighbor_tags(reversed_neighbor_tags(tags)) == tags
