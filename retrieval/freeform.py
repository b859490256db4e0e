"""Held-out free-form queries: sentences in everyday words, with relevance decided from each clip's tags.

Caption queries only test whether the model learnt the caption templates. A user types "a car cuts in
front of us from the left", not "A car in the left lane approaches, then moves into the host lane". These
queries are written in a user's words, unlike the templates, and each one states which clips answer it
through the clip's own tags, never through its caption text:

- ``categories``: the object's category is one of these (empty: any);
- ``steps``: the object's tag sequence (``lane:motion`` per step, e.g. ``left:approach``) contains these
  patterns as a subsequence, in this order (``fnmatch`` patterns: ``left*:away`` matches ``left:away`` and
  ``left_lateral:away``);
- ``host``: the ego's tag sequence (``motion:direction``) contains these patterns in order.

:data:`FREEFORM_QUERIES` are a fixed evaluation set: figures on them are only worth something if nobody
tunes a model or a threshold on them. :data:`DEV_FREEFORM_QUERIES` are the development set, written the
same way in other words: what a setting is chosen on (the weight of hybrid search, :mod:`retrieval.hybrid`),
so that the held-out figures stay held out. :func:`freeform_relevance` gives the (Q, N) relevance, and
:func:`freeform_figures` the mean precision@k (:func:`encoders.metrics.precision_at_k`) that every report of
free-form queries quotes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fnmatch import fnmatchcase
from typing import Any

import numpy as np

from encoders.metrics import precision_at_k

#: Precision is read in the top this-many clips of each free-form query.
FREEFORM_K = 10
VEHICLES = frozenset({"car", "truck", "bus", "motorcycle"})


@dataclass(frozen=True)
class FreeformQuery:
    """A free-form sentence and the tags that make a clip relevant to it (see the module docstring)."""

    text: str
    categories: frozenset[str] = frozenset()
    steps: tuple[str, ...] = ()
    host: tuple[str, ...] = ()

    def matches(self, row: Mapping[str, Any]) -> bool:
        """Whether the clip ``row`` (a clip-table row: category, tags, host_tags) answers this query."""
        if self.categories and str(row.get("category")) not in self.categories:
            return False
        return _contains_in_order(row.get("tags") or [], self.steps) and \
            _contains_in_order(row.get("host_tags") or [], self.host)


def _contains_in_order(sequence: Sequence[str], patterns: Sequence[str]) -> bool:
    """Whether ``patterns`` match items of ``sequence`` in order (not necessarily adjacent)."""
    it = iter(sequence)
    return all(any(fnmatchcase(str(item), pattern) for item in it) for pattern in patterns)


#: Written once, before training; never tuned on. Order of steps matters where a query says "then".
FREEFORM_QUERIES: tuple[FreeformQuery, ...] = (
    FreeformQuery("a car cuts in front of us from the left", frozenset({"car"}), ("left:*", "host:*")),
    FreeformQuery("a vehicle merges into our lane from the right", VEHICLES, ("right:*", "host:*")),
    FreeformQuery("we brake and come to a stop", host=("decelerating:*", "stationary:*")),
    FreeformQuery("we are waiting, not moving at all", host=("stationary:*",)),
    FreeformQuery("we speed up while turning right", host=("accelerating:steering_right",)),
    FreeformQuery("we slow down in a left turn", host=("decelerating:steering_left",)),
    FreeformQuery("a cyclist next to us on the right", frozenset({"cyclist"}), ("right:*",)),
    FreeformQuery("someone walks across the street", frozenset({"pedestrian"}), ("*_lateral:*",)),
    FreeformQuery("a person crossing from the left comes closer", frozenset({"pedestrian"}),
                  ("left_lateral:approach",)),
    FreeformQuery("an oncoming car drives past us", frozenset({"car"}), ("oncoming:approach", "oncoming:away")),
    FreeformQuery("the vehicle ahead of us in our lane gets closer", VEHICLES, ("host:approach",)),
    FreeformQuery("the car in front of us pulls away", frozenset({"car"}), ("host:away",)),
    FreeformQuery("a bus or a truck heading towards us", frozenset({"bus", "truck"}), ("*:approach",)),
    FreeformQuery("a motorbike riding away on our left", frozenset({"motorcycle"}), ("left*:away",)),
    FreeformQuery("a car crosses our path from the right", frozenset({"car"}), ("right_lateral:*",)),
    FreeformQuery("something standing still on the right side", steps=("right*:stationary",)),
    FreeformQuery("a vehicle comes towards us and then drives off", VEHICLES, ("*:approach", "*:away")),
    FreeformQuery("a car drives away, then comes back towards us", frozenset({"car"}), ("*:away", "*:approach")),
    FreeformQuery("while we are stopped a pedestrian walks by", frozenset({"pedestrian"}), host=("stationary:*",)),
    FreeformQuery("a truck on the left side of the road", frozenset({"truck"}), ("left*:*",)),
)

#: Development queries: settings are chosen on these (with the validation clips), never on the held-out ones.
#: A step's pattern ends in ``*`` where the object's own action or context may follow (``left:away:braking``).
DEV_FREEFORM_QUERIES: tuple[FreeformQuery, ...] = (
    FreeformQuery("a car overtakes us on the left", frozenset({"car"}), ("left:away*",)),
    FreeformQuery("a van pulls into our lane ahead", VEHICLES, ("[lr]*:*", "host:*")),
    FreeformQuery("a car parked on the right side", frozenset({"car"}), ("right*:*:parked*",)),
    FreeformQuery("we pick up speed going straight", host=("accelerating:heading_straight",)),
    FreeformQuery("we take a gentle left while cruising", host=("cruising:steering_left",)),
    FreeformQuery("a cyclist riding on our left", frozenset({"cyclist"}), ("left*:*",)),
    FreeformQuery("a pedestrian steps onto the road from the right", frozenset({"pedestrian"}), ("right_lateral:*",)),
    FreeformQuery("oncoming traffic approaching us", VEHICLES, ("oncoming:approach*",)),
    FreeformQuery("the car ahead brakes and we catch up with it", frozenset({"car"}), ("host:approach:braking*",)),
    FreeformQuery("a truck driving off ahead of us", frozenset({"truck"}), ("host:away*",)),
    FreeformQuery("a parked vehicle on the left", VEHICLES, ("left*:*:parked*",)),
    FreeformQuery("a bus next to us on the right", frozenset({"bus"}), ("right*:*",)),
    FreeformQuery("someone on foot moving away from us", frozenset({"pedestrian"}), ("*:away*",)),
    FreeformQuery("a car keeps the same gap to us", frozenset({"car"}), ("*:constant*",)),
    FreeformQuery("we decelerate while going straight", host=("decelerating:heading_straight",)),
    FreeformQuery("a car turning left in front of us", frozenset({"car"}), ("*:*:left_turn*",)),
    FreeformQuery("a vehicle making a right turn", VEHICLES, ("*:*:right_turn*",)),
    FreeformQuery("a car braking on our right", frozenset({"car"}), ("right*:*:braking*",)),
    FreeformQuery("people on the zebra crossing", frozenset({"pedestrian"}), ("*on_crosswalk",)),
    FreeformQuery("traffic waiting at the junction", VEHICLES, ("*:stopped:at_intersection",)),
    FreeformQuery("a truck that has stopped", frozenset({"truck"}), ("*:*:stopped*",)),
    FreeformQuery("a motorcyclist on the right getting closer", frozenset({"motorcycle"}), ("right*:approach*",)),
    FreeformQuery("a pedestrian walking towards us from the left side", frozenset({"pedestrian"}),
                  ("left_lateral:approach*",)),
    FreeformQuery("we turn right slowly, braking", host=("decelerating:steering_right",)),
    FreeformQuery("we accelerate into a left turn", host=("accelerating:steering_left",)),
    FreeformQuery("we drive on at a steady speed", host=("cruising:*",)),
    FreeformQuery("a car switches to the left lane", frozenset({"car"}), ("*:*:left_lane_change*",)),
    FreeformQuery("a vehicle changing lanes to the right", VEHICLES, ("*:*:right_lane_change*",)),
    FreeformQuery("an oncoming bus", frozenset({"bus"}), ("oncoming:*",)),
    FreeformQuery("a cyclist gets nearer and then further away", frozenset({"cyclist"}), ("*:approach*", "*:away*")),
    FreeformQuery("a car slowing down in our lane", frozenset({"car"}), ("host:*:braking*",)),
    FreeformQuery("parked cars while we wait", frozenset({"car"}), ("*:*:parked*",), ("stationary:*",)),
    FreeformQuery("a pedestrian standing still by the road", frozenset({"pedestrian"}), ("*:*:stopped*",)),
    FreeformQuery("a vehicle crossing in front of us from left to right", VEHICLES,
                  ("left_lateral:*", "right_lateral:*")),
    FreeformQuery("a walker who gets closer, then moves away", frozenset({"pedestrian"}), ("*:approach*", "*:away*")),
    FreeformQuery("a truck on our right", frozenset({"truck"}), ("right*:*",)),
)


def freeform_relevance(queries: Sequence[FreeformQuery], rows: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """(Q, N) bool: clip n answers query q."""
    return np.asarray([[q.matches(r) for r in rows] for q in queries], dtype=bool).reshape(len(queries), len(rows))


def freeform_figures(sim: np.ndarray, relevant: np.ndarray, k: int = FREEFORM_K) -> dict[str, float | int | None]:
    """Mean precision@k over the free-form queries that have at least one relevant clip.

    Args:
        sim: (Q, N) scores of the free-form queries against the clips.
        relevant: (Q, N) bool from :func:`retrieval.freeform.freeform_relevance`.
    """
    answered = np.asarray(np.asarray(relevant, dtype=bool).any(axis=1))  # (Q,)
    precision = precision_at_k(sim, relevant, k)
    return {"queries": int(answered.shape[0]), "answered": int(answered.sum()),
            f"precision@{k}": float(np.nanmean(precision)) if answered.any() else None}
