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

They are a fixed evaluation set: figures on them are only worth something if nobody tunes a model or a
threshold on them. :func:`freeform_relevance` gives the (Q, N) relevance that
:func:`encoders.metrics.precision_at_k` scores.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fnmatch import fnmatchcase
from typing import Any

import numpy as np

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


def freeform_relevance(queries: Sequence[FreeformQuery], rows: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """(Q, N) bool: clip n answers query q."""
    return np.asarray([[q.matches(r) for r in rows] for q in queries], dtype=bool).reshape(len(queries), len(rows))
