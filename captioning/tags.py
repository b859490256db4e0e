"""Tag vocabularies (public strings) and the one place where the paper's lateral sign is converted.

Sign convention
---------------
The paper measures the lateral offset ``y`` positive to the **right** of the host. Our ego frame
(av2-api) has ``y`` positive to the **left**. :func:`paper_lateral_m` converts; nothing else in
this package flips signs. A neighbour at ego-frame ``y = +3 m`` has paper ``y = −3 m`` and is ``left``.
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from scenes.behavior import BehaviorLabel


class HostMotion(StrEnum):
    """Eq. 1."""

    STATIONARY = "stationary"
    ACCELERATING = "accelerating"
    DECELERATING = "decelerating"
    CRUISING = "cruising"


class HostDirection(StrEnum):
    """Eq. 2 (ω positive = turning left)."""

    STEERING_LEFT = "steering_left"
    STEERING_RIGHT = "steering_right"
    HEADING_STRAIGHT = "heading_straight"


class BaselineLane(StrEnum):
    """Eq. 4, from the neighbour's heading relative to the host."""

    ONGOING = "ongoing"
    LATERAL = "lateral"
    ONCOMING = "oncoming"


class Lane(StrEnum):
    """Eq. 5."""

    LEFT = "left"
    RIGHT = "right"
    HOST = "host"
    LEFT_LATERAL = "left_lateral"
    RIGHT_LATERAL = "right_lateral"
    HOST_LATERAL = "host_lateral"
    ONCOMING = "oncoming"


class Motion(StrEnum):
    """Eqs. 6, 7, relative to the host."""

    APPROACH = "approach"
    AWAY = "away"
    CONSTANT = "constant"
    STATIONARY = "stationary"


class Context(StrEnum):
    """Where an object is, from the map (:mod:`captioning.map_context`)."""

    AT_INTERSECTION = "at_intersection"
    ON_CROSSWALK = "on_crosswalk"


#: Own actions that enter a neighbour's unified tags, one per frame: the first that holds, in this order.
ACTIONS: list[BehaviorLabel] = [
    BehaviorLabel.PARKED,
    BehaviorLabel.STOPPED,
    BehaviorLabel.LEFT_LANE_CHANGE,
    BehaviorLabel.RIGHT_LANE_CHANGE,
    BehaviorLabel.LEFT_TURN,
    BehaviorLabel.RIGHT_TURN,
    BehaviorLabel.BRAKING,
]
#: Actions of an object that stands; their motion tag is the ego's approach or departure.
STILL_ACTIONS: frozenset[str] = frozenset({BehaviorLabel.PARKED.value, BehaviorLabel.STOPPED.value})
CONTEXTS: list[Context] = list(Context)
#: ``frame_tags.parquet``'s ``action`` / ``context`` on a tagged frame whose unified tag names none.
NOTHING_NAMED = "none"

#: Integer codes used in (K, T) arrays: the index into each enum's member list; −1 = no tag.
NO_TAG = -1
HOST_MOTIONS: list[HostMotion] = list(HostMotion)
HOST_DIRECTIONS: list[HostDirection] = list(HostDirection)
BASELINE_LANES: list[BaselineLane] = list(BaselineLane)
LANES: list[Lane] = list(Lane)
MOTIONS: list[Motion] = list(Motion)

#: Lane → its baseline lane.
BASELINE_OF_LANE: dict[Lane, BaselineLane] = {
    Lane.LEFT: BaselineLane.ONGOING,
    Lane.RIGHT: BaselineLane.ONGOING,
    Lane.HOST: BaselineLane.ONGOING,
    Lane.LEFT_LATERAL: BaselineLane.LATERAL,
    Lane.RIGHT_LATERAL: BaselineLane.LATERAL,
    Lane.HOST_LATERAL: BaselineLane.LATERAL,
    Lane.ONCOMING: BaselineLane.ONCOMING,
}
#: (len(LANES),) baseline-lane code of each lane code.
BASELINE_CODE_OF_LANE_CODE = np.array([BASELINE_LANES.index(BASELINE_OF_LANE[lane]) for lane in LANES])

#: Lanes off the host band that measure motion along the lateral axis (generalised eqs. 6, 7).
LATERAL_AXIS_LANES = (Lane.LEFT_LATERAL, Lane.RIGHT_LATERAL)


def paper_lateral_m(y_ego_m: NDArray[np.floating]) -> NDArray[np.float64]:
    """Ego-frame lateral offset (left positive) → the paper's lateral offset (right positive).

    Args:
        y_ego_m: (...) lateral offsets in the ego frame.
    """
    return -np.asarray(y_ego_m, dtype=np.float64)


def unified_neighbor_tag(
    lane: Lane | str, motion: Motion | str, action: BehaviorLabel | str | None = None,
    context: Context | str | None = None,
) -> str:
    """Eq. 8 neighbour tag ``lane:motion``, followed by the own action and the context when there are
    any: ``left:approach:braking``, ``host:approach:stopped:at_intersection``, ``right:away:on_crosswalk``
    (a missing part is left out; action and context words never coincide, so the tag stays unambiguous)."""
    parts = [Lane(lane).value, Motion(motion).value]
    if action:
        parts.append(BehaviorLabel(action).value)
    if context:
        parts.append(Context(context).value)
    return ":".join(parts)


_CONTEXT_VALUES = frozenset(c.value for c in Context)


def split_neighbor_tag(tag: str) -> tuple[str, str, str | None, str | None]:
    """``"left:approach:braking:on_crosswalk"`` → ``("left", "approach", "braking", "on_crosswalk")``;
    missing parts are None (actions and contexts have disjoint words)."""
    parts = tag.split(":")
    lane, motion = parts[0], parts[1] if len(parts) > 1 else ""
    action = context = None
    for part in parts[2:]:
        if part in _CONTEXT_VALUES:
            context = part
        elif part:
            action = part
    return lane, motion, action, context


def unified_host_tag(motion: HostMotion | str, direction: HostDirection | str) -> str:
    """Eq. 8 host tag ``motion:direction``."""
    return f"{HostMotion(motion).value}:{HostDirection(direction).value}"


def split_tag(tag: str) -> tuple[str, str]:
    """``"left:approach"`` → ``("left", "approach")``."""
    first, _, second = tag.partition(":")
    return first, second
