"""The tags of a clip played backwards: time reversal as a training augmentation.

A clip whose frames run backwards is a clip of a real scene in which everything drives in reverse,
and the rules that caption a forward clip caption it too. Its steps come in reverse order, and every
tag that is a rate of change flips its sign:

    neighbour   approach ↔ away; left ↔ right lane change; left ↔ right turn (yaw rate);
                braking is dropped (the object speeds up, which has no tag); lanes, constant,
                stationary, parked, stopped and the map context stay
    host        accelerating ↔ decelerating; steering left ↔ right (yaw rate); stationary,
                cruising and heading straight stay

So ``left:approach, host:away`` (cutting in ahead, then pulling away) becomes
``host:approach, left:away``: the same frames under another caption, where the lanes' order is
reversed. The motions' order is not: a pass-by (``approach, away``) reads the same backwards, so the
order that the evaluation tests (a caption against its steps reversed, rates unchanged) is not what
this asks for. On the demo's clips, half of them played backwards cost recall and did not raise
order (README, "Order: what did not work yet").
"""

from __future__ import annotations

from collections.abc import Sequence

from captioning.tags import HostDirection, HostMotion, split_neighbor_tag, split_tag
from captioning.unify import collapse
from encoders.negatives import EGO_CATEGORY, FLIP_MOTION
from scenes.behavior import BehaviorLabel

_ACTION: dict[str, str | None] = {
    BehaviorLabel.LEFT_LANE_CHANGE.value: BehaviorLabel.RIGHT_LANE_CHANGE.value,
    BehaviorLabel.RIGHT_LANE_CHANGE.value: BehaviorLabel.LEFT_LANE_CHANGE.value,
    BehaviorLabel.LEFT_TURN.value: BehaviorLabel.RIGHT_TURN.value,
    BehaviorLabel.RIGHT_TURN.value: BehaviorLabel.LEFT_TURN.value,
    BehaviorLabel.BRAKING.value: None,
}
_HOST_MOTION = {HostMotion.ACCELERATING.value: HostMotion.DECELERATING.value,
                HostMotion.DECELERATING.value: HostMotion.ACCELERATING.value}
_HOST_DIRECTION = {HostDirection.STEERING_LEFT.value: HostDirection.STEERING_RIGHT.value,
                   HostDirection.STEERING_RIGHT.value: HostDirection.STEERING_LEFT.value}


def reversed_neighbor_tags(tags: Sequence[str]) -> list[str]:
    """A neighbour's unified tags (``lane:motion[:action][:context]``) for its clip played backwards."""
    out = []
    for tag in reversed(list(tags)):
        lane, motion, action, context = split_neighbor_tag(tag)
        action = _ACTION.get(action, action) if action else None
        parts = [lane, FLIP_MOTION.get(motion, motion), action, context]
        out.append(":".join(p for p in parts if p))
    return collapse(out)  # a dropped action can make two steps equal


def reversed_host_tags(host_tags: Sequence[str]) -> list[str]:
    """The host's unified tags (``motion:direction``) for its clip played backwards."""
    out = []
    for tag in reversed(list(host_tags)):
        motion, direction = split_tag(tag)
        out.append(f"{_HOST_MOTION.get(motion, motion)}:{_HOST_DIRECTION.get(direction, direction)}")
    return collapse(out)


def reversed_clip_tags(category: str, tags: Sequence[str], host_tags: Sequence[str]) -> tuple[list[str], list[str]]:
    """(tags, host tags) of a clip played backwards; an ``ego`` clip's steps are host tags."""
    host = reversed_host_tags(host_tags)
    return (reversed_host_tags(tags) if category == EGO_CATEGORY else reversed_neighbor_tags(tags)), host
