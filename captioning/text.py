"""Caption text from unified tags: one canonical sentence per window, plus seeded paraphrases.

The canonical caption uses the first template of every slot, so it is a pure function of the
tags and the category. Paraphrases draw other templates with a generator seeded from the config
seed and the caption's identity (log, track, start and end), so a rerun reproduces them exactly.

Example: tags ``["left:approach", "host:constant"]`` for a car, host ``["cruising:heading_straight"]``::

    The ego vehicle is cruising straight. A car in the left lane approaches, then moves into the ego lane
    and keeps its distance.
"""

from __future__ import annotations

import random
from collections.abc import Sequence

from captioning.tags import HostDirection, HostMotion, Lane, Motion, split_tag
from scenes.categories import Category

CATEGORY_WORDS: dict[str, str] = {
    Category.CAR.value: "car",
    Category.TRUCK.value: "truck",
    Category.BUS.value: "bus",
    Category.PEDESTRIAN.value: "pedestrian",
    Category.CYCLIST.value: "cyclist",
    Category.MOTORCYCLE.value: "motorcycle",
    Category.OTHER.value: "object",
}

#: Where the neighbour is (first tag of a caption).
LANE_PHRASES: dict[str, tuple[str, ...]] = {
    Lane.LEFT: ("in the left lane", "in the lane to the left", "one lane to the left"),
    Lane.RIGHT: ("in the right lane", "in the lane to the right", "one lane to the right"),
    Lane.HOST: ("in the ego lane", "in the same lane as the ego vehicle", "in the ego vehicle's lane"),
    Lane.LEFT_LATERAL: ("crossing on the left", "crossing from the left side", "moving across on the left"),
    Lane.RIGHT_LATERAL: ("crossing on the right", "crossing from the right side", "moving across on the right"),
    Lane.HOST_LATERAL: ("crossing the ego lane", "crossing the ego vehicle's lane", "cutting across the ego lane"),
    Lane.ONCOMING: (
        "in the oncoming lane",
        "in the lane of oncoming traffic",
        "coming the other way in the oncoming lane",
    ),
}
#: A change of lane (later tags).
LANE_TRANSITIONS: dict[str, tuple[str, ...]] = {
    Lane.LEFT: ("moves into the left lane", "changes to the left lane", "shifts into the left lane"),
    Lane.RIGHT: ("moves into the right lane", "changes to the right lane", "shifts into the right lane"),
    Lane.HOST: ("moves into the ego lane", "cuts into the ego lane", "merges into the ego lane"),
    Lane.LEFT_LATERAL: ("starts crossing on the left", "turns across on the left", "veers across on the left"),
    Lane.RIGHT_LATERAL: ("starts crossing on the right", "turns across on the right", "veers across on the right"),
    Lane.HOST_LATERAL: ("starts crossing the ego lane", "turns across the ego lane", "cuts across the ego lane"),
    Lane.ONCOMING: ("moves into the oncoming lane", "swerves into the oncoming lane", "turns into the oncoming lane"),
}
MOTION_PHRASES: dict[str, tuple[str, ...]] = {
    Motion.APPROACH: ("approaches", "approaches the ego vehicle", "comes closer", "closes in"),
    Motion.AWAY: ("moves away", "moves away from the ego vehicle", "pulls away", "drives off into the distance"),
    Motion.CONSTANT: (
        "keeps its distance",
        "keeps a constant distance",
        "holds its distance",
        "stays at the same distance",
    ),
    Motion.STATIONARY: ("is stationary", "stands still", "is stopped", "does not move"),
}
#: Host motion as the first clause ("The ego vehicle ...") and after "then".
HOST_MOTION_FIRST: dict[str, tuple[str, ...]] = {
    HostMotion.STATIONARY: ("is stationary", "is standing still", "is stopped"),
    HostMotion.ACCELERATING: ("is accelerating", "is speeding up", "is gaining speed"),
    HostMotion.DECELERATING: ("is decelerating", "is slowing down", "is braking"),
    HostMotion.CRUISING: ("is cruising", "is driving at a steady speed", "is cruising along"),
}
HOST_MOTION_THEN: dict[str, tuple[str, ...]] = {
    HostMotion.STATIONARY: ("stops", "comes to a stop", "comes to a standstill"),
    HostMotion.ACCELERATING: ("accelerates", "speeds up", "gains speed"),
    HostMotion.DECELERATING: ("decelerates", "slows down", "brakes"),
    HostMotion.CRUISING: ("cruises", "keeps a steady speed", "drives on at a steady speed"),
}
HOST_DIRECTION_PHRASES: dict[str, tuple[str, ...]] = {
    HostDirection.HEADING_STRAIGHT: ("straight", "straight ahead", "in a straight line"),
    HostDirection.STEERING_LEFT: ("while steering left", "while turning left", "and steers to the left"),
    HostDirection.STEERING_RIGHT: ("while steering right", "while turning right", "and steers to the right"),
}

def _pick(options: tuple[str, ...], rng: random.Random | None) -> str:
    return options[0] if rng is None else options[rng.randrange(len(options))]


def category_noun(category: str) -> str:
    """Category word with its article: ``a car``, ``an object``."""
    word = CATEGORY_WORDS.get(category, "object")
    return f"{'an' if word[0] in 'aeiou' else 'a'} {word}"


def host_sentence(host_tags: Sequence[str], rng: random.Random | None = None) -> str:
    """One sentence for the host's unified tags (``motion:direction``); empty for no tags."""
    clauses: list[str] = []
    for i, tag in enumerate(host_tags):
        # str Enums hash and compare like their values: the tag's strings index the tables directly.
        motion, direction = split_tag(tag)
        verb = _pick((HOST_MOTION_FIRST if i == 0 else HOST_MOTION_THEN)[motion], rng)
        clause = verb
        # A stopped vehicle heading straight needs no direction.
        if not (motion == HostMotion.STATIONARY and direction == HostDirection.HEADING_STRAIGHT):
            clause += " " + _pick(HOST_DIRECTION_PHRASES[direction], rng)
        clauses.append(clause if i == 0 else "then " + clause)
    if not clauses:
        return ""
    return "The ego vehicle " + ", ".join(clauses) + "."


def neighbor_sentence(category: str, tags: Sequence[str], rng: random.Random | None = None) -> str:
    """One sentence for a neighbour's unified tags (``lane:motion``); class, lane and motion always appear."""
    clauses: list[str] = []
    previous_lane: str | None = None
    for i, tag in enumerate(tags):
        lane, motion = split_tag(tag)
        motion_phrase = _pick(MOTION_PHRASES[motion], rng)
        if i == 0:
            clauses.append(f"{_pick(LANE_PHRASES[lane], rng)} {motion_phrase}")
        elif lane != previous_lane:
            clauses.append(f"then {_pick(LANE_TRANSITIONS[lane], rng)} and {motion_phrase}")
        else:
            clauses.append(f"then {motion_phrase}")
        previous_lane = lane
    if not clauses:
        return ""
    noun = category_noun(category)
    return noun[0].upper() + noun[1:] + " " + ", ".join(clauses) + "."


def caption_text(
    category: str | None, tags: Sequence[str], host_tags: Sequence[str], rng: random.Random | None = None
) -> str:
    """Host sentence, then (for a neighbour, ``category`` not None) the neighbour sentence."""
    parts = [host_sentence(host_tags, rng)]
    if category is not None:
        parts.append(neighbor_sentence(category, tags, rng))
    return " ".join(p for p in parts if p)


def paraphrase_rng(seed: int, *key: object) -> random.Random:
    """A generator seeded by ``seed`` and ``key`` (string seeds hash with SHA-512: stable across runs,
    unlike Python's salted ``hash``)."""
    return random.Random("\x1f".join(map(str, (seed, *key))))


def paraphrases(
    category: str | None,
    tags: Sequence[str],
    host_tags: Sequence[str],
    count: int,
    seed: int,
    key: tuple[object, ...],
    canonical: str | None = None,
) -> list[str]:
    """Up to ``count`` distinct paraphrases, different from the canonical caption when possible."""
    rng = paraphrase_rng(seed, *key)
    canonical = caption_text(category, tags, host_tags) if canonical is None else canonical
    out: list[str] = []
    for _ in range(count * 8):
        if len(out) == count:
            break
        text = caption_text(category, tags, host_tags, rng)
        if text != canonical and text not in out:
            out.append(text)
    return out
