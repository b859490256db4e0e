"""Caption text from unified tags: one canonical sentence per window, plus seeded paraphrases.

The canonical caption uses the first template of every slot, so it is a pure function of the
tags and the category. Paraphrases draw other templates with a generator seeded from the config
seed and the caption's identity (log, track, start and end), so a rerun reproduces them exactly.

Example: tags ``["left:approach", "host:constant"]`` for a car, host ``["cruising:heading_straight"]``::

    The ego vehicle is cruising straight. A car in the left lane approaches, then moves into the ego lane
    and keeps its distance.

Tags with the object's own action and context (``rules: behavior``, see :func:`captioning.tags.unified_neighbor_tag`)::

    ["left:approach:braking", "left:approach:left_turn"]
        A car in the left lane approaches while braking, then turns left at the intersection.
    ["host:approach:stopped"]        A truck stands in the ego lane as the ego approaches.
    ["right:constant:parked"]        A car is parked on the right.

A tag without action or context is phrased exactly as under the paper's rules.
"""

from __future__ import annotations

import random
from collections.abc import Sequence

from captioning.tags import (
    STILL_ACTIONS,
    Context,
    HostDirection,
    HostMotion,
    Lane,
    Motion,
    split_neighbor_tag,
    split_tag,
)
from scenes.behavior import BehaviorLabel
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

#: A moving object's own action, after its motion in the same clause ("approaches while braking").
ACTION_WHILE: dict[str, tuple[str, ...]] = {
    BehaviorLabel.BRAKING: ("while braking", "while slowing down hard", "and brakes"),
    BehaviorLabel.LEFT_TURN: ("while turning left at the intersection", "as it turns left at the intersection",
                              "and turns left at the junction"),
    BehaviorLabel.RIGHT_TURN: ("while turning right at the intersection", "as it turns right at the intersection",
                               "and turns right at the junction"),
    BehaviorLabel.LEFT_LANE_CHANGE: ("while changing lanes to the left", "as it moves over a lane to the left",
                                     "and changes lanes to the left"),
    BehaviorLabel.RIGHT_LANE_CHANGE: ("while changing lanes to the right", "as it moves over a lane to the right",
                                      "and changes lanes to the right"),
}
#: A moving object's own action as a step of its own ("then brakes").
ACTION_THEN: dict[str, tuple[str, ...]] = {
    BehaviorLabel.BRAKING: ("brakes", "slows down hard", "hits the brakes"),
    BehaviorLabel.LEFT_TURN: ("turns left at the intersection", "makes a left turn at the intersection",
                              "turns left at the junction"),
    BehaviorLabel.RIGHT_TURN: ("turns right at the intersection", "makes a right turn at the intersection",
                               "turns right at the junction"),
    BehaviorLabel.LEFT_LANE_CHANGE: ("changes lanes to the left", "moves over a lane to the left",
                                     "switches to the lane on its left"),
    BehaviorLabel.RIGHT_LANE_CHANGE: ("changes lanes to the right", "moves over a lane to the right",
                                      "switches to the lane on its right"),
}
#: An object that stands: how ("is parked") and where ("on the right").
STILL_FIRST: dict[str, tuple[str, ...]] = {
    BehaviorLabel.PARKED: ("is parked", "stands parked", "is parked at the roadside"),
    BehaviorLabel.STOPPED: ("stands", "is stopped", "waits"),
}
STILL_THEN: dict[str, tuple[str, ...]] = {
    BehaviorLabel.PARKED: ("parks", "pulls over and parks", "comes to a stop and parks"),
    BehaviorLabel.STOPPED: ("stops", "comes to a stop", "comes to a standstill"),
}
STILL_PLACES: dict[str, tuple[str, ...]] = {
    Lane.LEFT: ("on the left", "to the left", "on the left side"),
    Lane.RIGHT: ("on the right", "to the right", "on the right side"),
    Lane.HOST: ("in the ego lane", "in the same lane as the ego vehicle", "in the ego vehicle's lane"),
    Lane.LEFT_LATERAL: ("across the road on the left", "crosswise on the left", "sideways on the left"),
    Lane.RIGHT_LATERAL: ("across the road on the right", "crosswise on the right", "sideways on the right"),
    Lane.HOST_LATERAL: ("across the ego lane", "across the ego vehicle's path", "crosswise in the ego lane"),
    Lane.ONCOMING: ("in the oncoming lane", "on the other side of the road", "in the lane of oncoming traffic"),
}
#: Where a parked vehicle is: beside the road, whichever way it faces.
PARKED_PLACES: dict[str, tuple[str, ...]] = {
    **STILL_PLACES,
    Lane.LEFT_LATERAL: ("on the left", "to the left", "on the left side"),
    Lane.RIGHT_LATERAL: ("on the right", "to the right", "on the right side"),
    Lane.ONCOMING: ("on the other side of the road", "on the opposite side of the road", "across the road"),
}
#: The ego's part while an object stands: its distance shrinks (the ego approaches) or grows.
EGO_RELATION: dict[str, tuple[str, ...]] = {
    Motion.APPROACH: ("as the ego approaches", "while the ego vehicle approaches it",
                      "as the ego vehicle comes closer"),
    Motion.AWAY: ("as the ego moves away", "while the ego vehicle drives away from it",
                  "as the ego vehicle pulls away"),
}
EGO_RELATION_THEN: dict[str, tuple[str, ...]] = {
    Motion.APPROACH: ("the ego approaches it", "the ego vehicle comes closer", "the ego vehicle closes in on it"),
    Motion.AWAY: ("the ego moves away from it", "the ego vehicle drives away from it", "the ego vehicle pulls away"),
    Motion.CONSTANT: ("the ego stays at the same distance", "the ego vehicle holds its distance",
                      "the ego vehicle keeps the same distance"),
}
#: Starting to move after standing.
START_MOVING: tuple[str, ...] = ("starts moving", "drives off", "sets off")
CONTEXT_PHRASES: dict[str, tuple[str, ...]] = {
    Context.AT_INTERSECTION: ("at the intersection", "in the intersection", "at the junction"),
    Context.ON_CROSSWALK: ("on a crosswalk", "on the crosswalk", "on a pedestrian crossing"),
}


def _pick(options: tuple[str, ...], rng: random.Random | None) -> str:
    return options[0] if rng is None else options[rng.randrange(len(options))]


def category_noun(category: str) -> str:
    """Category word with its article: ``a car``, ``an object``."""
    word = CATEGORY_WORDS.get(category, "object")
    return f"{'an' if word[0] in 'aeiou' else 'a'} {word}"


#: How every ego sentence opens (:func:`host_sentence`), and so every caption (:func:`caption_halves`).
HOST_SENTENCE_START = "The ego vehicle "


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
    return HOST_SENTENCE_START + ", ".join(clauses) + "."


def neighbor_sentence(category: str, tags: Sequence[str], rng: random.Random | None = None) -> str:
    """One sentence for a neighbour's unified tags (``lane:motion[:action][:context]``); class, lane and
    motion (or, for an object that stands, its action and the ego's approach) always appear."""
    clauses: list[str] = []
    previous: tuple[str, str, str | None, str | None] | None = None
    for tag in tags:
        lane, motion, action, context = split_neighbor_tag(tag)
        if action in STILL_ACTIONS:
            clause = _still_clause(lane, motion, action, context, previous, rng)
        else:
            clause = _moving_clause(lane, motion, action, context, previous, rng)
        if clause:
            clauses.append(clause)
        previous = (lane, motion, action, context)
    if not clauses:
        return ""
    noun = category_noun(category)
    return noun[0].upper() + noun[1:] + " " + ", ".join(clauses) + "."


def _context(context: str | None, action: str | None, rng: random.Random | None) -> str:
    """" at the intersection" and the like; a turn says where it happens already."""
    if not context or action in (BehaviorLabel.LEFT_TURN, BehaviorLabel.RIGHT_TURN):
        return ""
    return f" {_pick(CONTEXT_PHRASES[context], rng)}"


def _moving_clause(
    lane: str, motion: str, action: str | None, context: str | None,
    previous: tuple[str, str, str | None, str | None] | None, rng: random.Random | None,
) -> str | None:
    """A step of an object that moves. Without action and context: the paper's phrasing, word for word.
    An action or a context is said when it begins, not again at every later step it lasts."""
    motion_phrase = _pick(MOTION_PHRASES[motion], rng)
    new_action = action if previous is None or action != previous[2] else None
    new_context = context if previous is None or context != previous[3] else None
    if previous is None:
        clause = f"{_pick(LANE_PHRASES[lane], rng)} {motion_phrase}"
    elif previous[2] in STILL_ACTIONS:
        clause = f"then {_pick(START_MOVING, rng)} and {motion_phrase}"
    elif lane != previous[0]:
        clause = f"then {_pick(LANE_TRANSITIONS[lane], rng)} and {motion_phrase}"
    elif new_action:
        # A new action is the step; the motion is said again only when it changed too.
        clause = f"then {_pick(ACTION_THEN[new_action], rng)}"
        if motion != previous[1]:
            clause += f" and {motion_phrase}"
        return clause + _context(new_context, action, rng)
    elif motion == previous[1] and not _context(new_context, action, None):
        return None  # only a context that goes unsaid changed
    else:
        clause = f"then {motion_phrase}"
    if new_action:
        clause += " " + _pick(ACTION_WHILE[new_action], rng)
    return clause + _context(new_context, action, rng)


def _still_clause(
    lane: str, motion: str, action: str, context: str | None,
    previous: tuple[str, str, str | None, str | None] | None, rng: random.Random | None,
) -> str | None:
    """A step of an object that stands (parked or stopped). Its motion and lane are the ego's doing
    (the ego approaches it, passes it); None when the step says nothing new."""
    places = PARKED_PLACES if action == BehaviorLabel.PARKED else STILL_PLACES
    relation = " " + _pick(EGO_RELATION[motion], rng) if motion in EGO_RELATION else ""
    if previous is None:
        return f"{_pick(STILL_FIRST[action], rng)} {_pick(places[lane], rng)}{_context(context, action, rng)}{relation}"
    if previous[2] != action:
        return f"then {_pick(STILL_THEN[action], rng)}{_context(context, action, rng)}{relation}"
    if motion != previous[1]:
        return f"then {_pick(EGO_RELATION_THEN[motion], rng)}"
    if context and context != previous[3]:
        return f"then stands{_context(context, action, rng)}"
    return None


def caption_text(
    category: str | None, tags: Sequence[str], host_tags: Sequence[str], rng: random.Random | None = None
) -> str:
    """Host sentence, then (for a neighbour, ``category`` not None) the neighbour sentence."""
    parts = [host_sentence(host_tags, rng)]
    if category is not None:
        parts.append(neighbor_sentence(category, tags, rng))
    return " ".join(p for p in parts if p)


#: Index of each half in :func:`caption_halves`' pair: the ego's sentence, the object's.
HOST_HALF, OBJECT_HALF = 0, 1


def caption_halves(caption: str) -> tuple[str | None, str | None]:
    """A caption's two halves, as :func:`caption_text` joins them: the ego's sentence and the object's
    ("The ego vehicle is cruising straight.", "A car in the left lane approaches."). An ego clip's
    caption is its ego sentence alone (object None); a text that does not open with an ego sentence has
    neither (None, None)."""
    if not caption.startswith(HOST_SENTENCE_START):
        return None, None
    if ". " not in caption:
        return caption, None
    host, rest = caption.split(". ", 1)
    return host + ".", rest.strip() or None


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
