"""Distances said after a phrase, read by the parser (:mod:`scenarios.parser`): the relation a distance
bounds ("within 5 m of a pedestrian", "10 m in front of us"), with a least distance ("more than 20 m
ahead", "between 5 and 10 m from us", "at least 30 m away": the relation's ``beyond_m``).
"""

from __future__ import annotations

from collections.abc import Callable

from scenarios import rewrite
from scenarios.lexicon import Lexeme
from scenarios.program import Excluding, ForAtLeast, Has, Is, Node, Objects, subject_of
from scenarios.relating import RelationReader, farther_than


class DistanceReader(RelationReader):
    """A relation reader that reads a distance said after the phrase it bounds."""

    unused: list[str]
    pending_s: float | None
    kind_after_states: Callable[[int], bool]

    def distance(self, node: Node, value: float, low: float | None, least: bool) -> Node:
        """``node`` bounded by ``value`` metres (a range from ``low``; ``least``: "more than ``value``")."""
        low, high = (value, None) if least else (low, value)
        if (self.role() in ("kind", "count") or self.kind_after_states(0)) \
                and self.skipped_before_next() & {"of", "from", "to"}:
            # "within 5 m of a pedestrian", "more than 10 meters from the ego vehicle": near, that close
            self.pending_m, self.pending_low_m = high, low
            other = self.phrase(need_kind=True)
            node = node if other is None else self.relate(node, Lexeme("rel", "near"), other)
            node, self.pending_s = (node, None) if self.pending_s is None else (ForAtLeast(node, self.pending_s), None)
            return node
        if isinstance(node, Has) and self.role() not in ("rel", "side", "kind"):  # "a car ahead of us, 10 m"
            if rewrite.within(node, value) == node:  # a heading or a passing: no distance
                self.unused.append(f"more than {value:g} m" if least else f"{value:g} m")
                return node
            return rewrite.within(node, high, low)
        if {"each", "another"} & self.skipped_before_next():  # "of each other"
            least_m = () if low is None else (("beyond_m", low),)
            return self.one_another(node, "near", (("within_m", rewrite.UNBOUNDED_M if high is None else high),
                                                   *least_m))
        if self.depth <= 1 and self.role() in ("end", "conj") and not self.unknown_before_next():
            # "a car within 5 m", "a car more than 30 m away": of us (not "of the kerb")
            if subject_of(node) == Objects("ego"):  # "when we are 20 m away": from what, it does not say
                self.unused.append(f"{value:g} m")
                return node
            near = Has(node, "near", Objects("ego"))
            return rewrite.within(near, high, low) if high is not None else farther_than(near, value)
        if self.role() == "pred" and self.name() == "near_intersection":  # a predicate: the nearer ones left out
            self.take()
            base = node if high is None else Is(node, "near_intersection", (("within_m", high),))
            return base if low is None else Excluding(base, Is(node, "near_intersection", (("within_m", low),)))
        self.pending_m, self.pending_low_m = high, low  # "10 m in front of us": the relation said next
        return node
