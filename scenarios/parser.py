"""The grammar of descriptions: lexemes read into a scenario program.

The compiler reads a description as a noun phrase about the objects it refers to, with modifiers:

    description := ["while" phrase] phrase (("then" | "while") phrase)*
    phrase      := [count] predicate* KIND modifier*
    modifier    := predicate | "not" predicate | relation phrase | "with" phrase [side]
                 | "between" phrase ["and" phrase] | ego-side ("ahead", "behind us")
                 | distance ("within 5 m", of the ego at the end; "within 5 m of" phrase: near it)
                 | duration ("for 3 s")

over the phrases of :mod:`scenarios.lexicon` (longest match first). A relation whose point of view is
the named object ("in front of the bus") is asked of that object and answers the subject
(``reverse``). A count on the referred objects keeps frames where that many are there together; a
"group of" them must stand near one another. Every word that carries no meaning in the parse is
reported in :attr:`Compiled.unused`, never dropped silently; a description with no usable word is
refused (:class:`DescriptionError`).
"""

from __future__ import annotations

import dataclasses

from scenarios import rewrite
from scenarios.distances import DistanceReader
from scenarios.kinds import within_vehicles
from scenarios.lexicon import Lexeme
from scenarios.program import (
    AnyOf,
    Between,
    Excluding,
    ForAtLeast,
    Has,
    Is,
    Node,
    Objects,
    Sequenced,
    Then,
    Together,
    While,
    of_two_kinds,
    subject_of,
)
from scenarios.quantities import FARTHER, SPEED_UNITS, other_bound, speed_bounds
from scenarios.relating import side_relation

#: Where a motion goes: "not moving toward us" negates the approach, not the motion.
WHITHER = frozenset({"approaching_ego", "moving_away_from_ego", "heading_toward", "heading_away_from", "passed_by"})
#: "Running" is fast of people and animals; a vehicle that runs ("runs into our lane") just moves.
RUNS = frozenset({("running",), ("runs",), ("run",), ("ran",)})
#: Within this distance (m), "a group of" objects stand together.
GROUP_RADIUS_M = 5.0


class DescriptionError(ValueError):
    """A description the compiler cannot use: it names the words it did not understand."""


class Parser(DistanceReader):
    """One description's lexemes, read left to right into a program (see the module docstring)."""

    def __init__(self, items: list[Lexeme]) -> None:
        super().__init__(items)
        #: A duration said inside a relation's object ("following a truck for 10 s"): the relation's.
        self.pending_s: float | None = None
        #: "… then stops within 4 seconds": the time the steps of a sequence fall within (not a duration).
        self.within_s: float | None = None
        self.in_condition = False  # reading a condition that opens the sentence: "after the bus stops, …"
        #: Whether the clause's count was a group's ("a group of pedestrians", "a crowd"): near one another.
        self.grouped = False
        #: A negation before a distance ("not within 10 m", "no closer than 5 m"): the other bound.
        self.distance_negated = False

    def take_count(self) -> int:
        """The count the next count word or number says, taken: "more than two" is three; a group's
        words ("a group of", "a crowd") mark the clause's objects as standing together."""
        more = int("more" in self.skipped_before_next())
        item = self.take()
        if item.role == "number":
            return int(float(item.name)) + more
        self.grouped = self.grouped or (self.depth == 0 and item.name == "group")
        return item.count + more

    # -- phrases -----------------------------------------------------------------------------------------
    def phrase(self, bare: bool = False, need_kind: bool = False) -> tuple[Node, int] | None:
        """A noun phrase: the node of the objects it names, and the count given for them (0: none).

        A ``bare`` phrase stops after its kind ("between construction barriers | with ..."), so that
        what follows modifies the phrase before it. A phrase that ``need_kind`` (the object of a
        relation) names its kind: "crosses at the crosswalk" has no object.
        """
        start, grouped = self.i, self.grouped
        count, preds, nearest = 0, [], None
        while True:
            role = self.role()
            if role == "count":
                count = max(count, self.take_count())
            elif role == "number" and self.role(1) in ("kind", "pred"):
                count = self.take_count()
            elif role in ("pred", "fixed"):
                preds.append(self.take())
            elif role == "nearest" and nearest is None:  # "the closest parked car", "the lead vehicle"
                nearest = self.take()
            elif role == "rel" and self.role(1) == "kind" and self.name() in ("crossed_by", "passed_by") \
                    and getattr(self.peek(), "reverse", False) and self.words()[0].endswith("ing") \
                    and not self.object_after_next():
                item = self.take()  # "crossing pedestrians": pedestrians that cross the road
                preds.append(Lexeme("pred", "crossing_road" if item.name == "crossed_by" else "moving"))
            elif role == "not" and self.role(1) == "pred":
                self.take()
                item = self.take()
                preds.append(dataclasses.replace(item, role="notpred"))
            else:
                break
        if self.role() == "kind" and not (self.depth and self.words() == ("we",)):
            node: Node = Objects(self.take_kind(count).name)  # "we" opens a clause: "… crosses, we drive off"
            if need_kind and self.depth and node == Objects("ego"):  # "next to us on the right": of the subject
                return node, count
            if self.role() == "count" and self.count_ahead() >= 3:  # "pedestrian group"
                count = max(count, self.take_count())
        elif preds and not need_kind:
            node = Objects("any")
        else:
            self.i, self.grouped = start, grouped  # no phrase here: its words are left for what follows
            return None
        for item in preds:
            if item.role == "fixed":
                node = Has(node, item.name, Objects(item.other), item.params, min_count=max(1, item.count),
                           negate=item.negate)
            else:
                node = rewrite.stated(node, item.name, item.params, item.role == "notpred" or item.negate)
        self.depth += 1
        try:
            modified = node if bare else self.modifiers(node, None if nearest is None else nearest.name)
            if nearest is not None:  # "the nearest two pedestrians": the two nearest, not two at once
                at, said_of_it = self.i, self.ends_phrase(False, False, nearest.name)
                modified, count = self.nearest(modified, nearest, max(1, count)), 0
                if not bare and (said_of_it or self.i != at):  # "the closest car to us is parked"
                    modified = self.modifiers(modified)
            return modified, count
        finally:
            self.depth -= 1

    def modifiers(self, node: Node, choosing: str | None = None) -> Node:
        """``node`` with the modifiers that follow, up to where they end (:meth:`ends_phrase`); ``choosing``
        ("near" or "ahead"): only those that say which objects "the nearest" is among."""
        while not self.ends_phrase(self.depth > 1, self.depth > 1 or self.in_condition, choosing):
            role = self.role()
            if role == "pred":
                item = self.take()
                if item.negate and item.name == "moving" and self.name() in WHITHER:  # "isn't moving toward us"
                    after = self.modifiers_one(node)
                    node = rewrite.negated(after, node) if after is not None else node
                    continue
                name = "moving" if item.words in RUNS and within_vehicles(subject_of(node)) else item.name
                node = rewrite.stated_or_after(node, name, item.params, item.negate)  # "slows down, stops"
            elif role == "fixed":
                item = self.take()
                node = Has(node, item.name, Objects(item.other), item.params, min_count=max(1, item.count),
                           negate=item.negate)
            elif role == "seq":
                node = self.sequence(node, self.take())
            elif role == "mutual":  # "side by side", "near each other": with others of its kind
                item = self.take()
                node = self.one_another(node, item.name, item.params)
            elif role == "closely" and isinstance(node, Has):
                self.take()
                node = rewrite.closer(node)
            elif role == "nearest" and self.name() == "ahead" and self.role(1) in ("kind", "count") \
                    and self.words() != ("lead",):
                self.take()  # "a car leading a truck": the truck follows it
                other = self.phrase(need_kind=True)
                node = node if other is None else self.relate(node, Lexeme("rel", "following", reverse=True), other)
            elif role == "nearest":  # "the car closest to us", "… nearest to the bus"
                item = self.take()
                if item.name == "near" and (self.skipped_before_next() & {"to", "from"} or (
                        self.role() in ("end", "conj") and not self.unknown_before_next())):
                    node = self.nearest(node, item)
                else:  # "first in line", "at the closest intersection": not of the objects
                    self.unused.extend(item.words)
            elif role in ("count", "number") and self.role(1) == "kind" and self.ahead_word(2) and not self.at_comma():
                node = self.chain(node)
            elif role == "not" and self.role(1) == "kind" and self.role(2) == "side":  # "without a car ahead of it"
                node = rewrite.negated(self.with_phrase(node, self.take()), node)
            elif self.not_a_kind():  # "a vehicle that is not a bus [or a truck]"
                self.take()
                kinds = self.take_kinds(subject_of(node))  # none: "a pedestrian who is not a child"
                node = Excluding(node, rewrite.any_of(kinds)) if kinds else node
            elif role == "not" and self.role(1) == "kind":  # "truck without trailer"
                self.take()
                node = Has(node, "near", Objects(self.take().name), (("within_m", 5.0),), negate=True)
            elif role == "not" and self.role(1) == "number":  # "not within 10 m of us", "no closer than 5 m"
                self.take()
                self.distance_negated = True
            elif role == "not" and self.role(1) in ("pred", "rel", "with", "fixed", "ego", "side"):
                self.take()
                after = self.modifiers_one(node)
                node = rewrite.negated(after, node) if after is not None else node
            elif role in ("rel", "ego", "side", "with", "between"):
                updated = self.modifiers_one(node)
                if updated is None:
                    break
                node = updated if self.pending_s is None else ForAtLeast(updated, self.pending_s)
                self.pending_s = None
            elif role == "number":
                after_within, fillers = self.after_word("within"), self.skipped_before_next()
                found = self.quantity()
                if found is None:
                    break
                value, unit, low = found
                negated, self.distance_negated = self.distance_negated, False
                if negated and unit != "m":  # "not faster than 30 km/h": under it
                    flipped = other_bound(fillers) if unit in SPEED_UNITS else None
                    if flipped is None:  # "not for 5 s", "not at 30 km/h": no bound to flip
                        self.unused.append(f"not {value:g} {unit}".rstrip())
                        continue
                    fillers = flipped
                if unit in SPEED_UNITS:
                    node = Is(node, "speed", speed_bounds(value, unit, fillers, low))
                elif unit == "s" and after_within:
                    self.within_s = value
                elif unit == "s" and self.depth > 1:  # "following a truck for 10 s": the relation lasts
                    self.pending_s = value
                elif unit == "s":
                    node = ForAtLeast(node, value if low is None else low)  # "for 5 to 10 s": 5 at least
                elif unit == "m":
                    least = bool(fillers & FARTHER) != negated  # "not more than 20 m": at most
                    node = self.distance(node, value, None if least else low, least)
                else:
                    self.unused.append(f"{value:g}")
            elif role == "conj" and self.depth <= 1 and self.name() in ("and", "while") \
                    and self.role(1) in ("pred", "rel", "ego", "side", "with", "not") \
                    and not self.kind_after_states(1) \
                    and not (self.it_after_next() and subject_of(node) == Objects("ego")):  # "it": not us
                self.take()  # "facing and heading toward", "… while being overtaken": one more modifier
            else:
                break
        return node

    def kind_after_states(self, ahead: int) -> bool:
        """Whether the words from ``ahead`` on are states naming a kind ("… and parked cyclists"): a phrase
        of its own, not one more modifier."""
        while self.role(ahead) in ("pred", "not", "nearest"):
            ahead += 1
        return self.role(ahead) == "kind"

    def modifiers_one(self, node: Node) -> Node | None:
        """One relation-like modifier of ``node``; None when the words do not make one."""
        item = self.take()
        if item.role == "pred":
            return rewrite.stated(node, item.name, item.params, item.negate)
        if item.role == "fixed":
            return Has(node, item.name, Objects(item.other), item.params, min_count=max(1, item.count),
                       negate=item.negate)
        if item.role == "ego":  # "ahead of us"; "directly ahead" also gives the lane's width
            params = dict(item.params)
            side = str(params.pop("side"))
            return self.ego_side(node, side, tuple(params.items()))
        if item.role == "side" and item.name in ("near", "same_lane"):  # "nearby", "in its lane" with no object
            it = self.it(item.words, node)
            return node if it is None else self.relate(node, Lexeme("rel", item.name), it)
        if item.role == "side":
            other = (None if self.at_comma() else self.phrase(need_kind=True)) or self.it(item.words, node)
            if other is None:  # "ahead", "behind": of the ego
                return self.ego_side(node, item.name)
            return self.relate(node, Lexeme("rel", "direction", (("side", item.name),), reverse=True), other)
        if item.role == "rel":
            it = self.it(self.skipped_before_next(), node)  # before the side: "passes it on the left"
            item = self.with_side(item)
            other = None if self.at_comma() else self.phrase(bare=item.name == "passed_by", need_kind=True)
            if other is not None and item.name == "passed_by":  # "passed by a motorcycle on either side"
                item = self.with_side(item)
                other = (self.modifiers_bare(other[0]), other[1])
            if other is None and self.role() == "conj" and self.role(1) == "rel":  # "facing and heading toward X"
                self.take()
                also = self.with_side(self.take())
                other = self.phrase()
                if other is not None:
                    return self.relate(self.relate(node, item, other), also, other)
            other = other or it
            if other is None:
                return self.without_object(node, item)
            return self.relate(node, item, other)
        if item.role == "with":
            return self.with_phrase(node, item)
        if item.role == "between":
            if self.role() == "number":  # "between 5-20 meters away": a distance
                found = self.quantity()
                if found is not None and found.unit == "m":
                    return self.distance(node, found.value, found.low, least=False)
            first = self.phrase(bare=True)
            if first is None:
                self.unused.extend(item.words)
                return node
            second = first
            if self.role() == "conj" and self.name() == "and" \
                    and self.role(1) in ("kind", "pred", "count", "nearest"):
                self.take()
                second = self.phrase(bare=True) or first
            if self.role() == "side" and self.name() == "beside":  # "... on both sides"
                self.take()
            return Between(node, first[0], second[0])
        self.unused.extend(item.words)
        return node

    def with_phrase(self, node: Node, item: Lexeme) -> Node:
        """``node`` with the object named after "with" (``item``), where the words after it say it is."""
        if self.role() == "not" and self.role(1) == "kind":  # "with no car behind it"
            self.take()
            return rewrite.negated(self.with_phrase(node, item), node)
        if self.role() == "side" and self.name() == "near":  # "with nearby X"
            self.take()
        if self.role() == "rel":  # "with crossing dog", "with approaching vehicle": the other acts on the node
            rel = self.take()
            acting = self.phrase(bare=True)
            if acting is None:
                self.unused.extend((*item.words, *rel.words))
                return node
            return self.acted_on(node, rel, acting)
        other = self.phrase(bare=True)
        if other is not None:
            other = (self.modifiers_bare(other[0]), other[1])
        if other is None:
            self.unused.extend(item.words)
            return node
        if self.role() == "rel" and self.role(1) not in ("kind", "count", "pred", "number"):
            return self.acted_on(node, self.with_side(self.take()), other)  # "with a car passing it on the left"
        distance = self.quantity() if self.role() == "number" else None
        rel = side_relation(self.take()) if self.role() == "side" else Lexeme("rel", "near", ())
        if distance is not None and distance.unit == "m":
            self.pending_m, self.pending_low_m = distance.value, distance.low
        return self.relate(node, rel, other)

    def modifiers_bare(self, node: Node) -> Node:
        """The predicates right after a bare phrase ("with lane-changing vehicles", "with stroller jaywalking"
        keeps "jaywalking" for the subject): only those that follow with no relation in between."""
        while self.role() == "pred" and self.name() not in ("jaywalking", "appearance") \
                and not self.ends_phrase(True, True, None):
            item = self.take()
            node = rewrite.stated(node, item.name, item.params, item.negate)
        return node

    # -- the description -------------------------------------------------------------------------------
    def description(self) -> Node:
        node = self.clauses()
        if self.within_s is not None:  # "… then stops within 4 seconds": the sequence's time
            if isinstance(node, Then | Sequenced):
                node = dataclasses.replace(node, within_s=self.within_s)
            else:
                self.unused.append(f"within {self.within_s:g} s")
        return node

    def clauses(self) -> Node:
        if self.role() == "not" and self.role(1) in ("kind", "count", "nearest"):  # "no pedestrians near us"
            no = self.take()
            found = self.phrase()
            none = rewrite.ego_without(self.referred(*found)) if found is not None else None
            if none is not None:
                return none
            self.unused.extend(no.words)
            if found is not None:
                return self.referred(*found)
        if self.role() == "conj" and (self.name() in ("while", "after") or self.words() == ("before",)):  # "while …, …"
            start, unused = self.i, len(self.unused)
            lead, self.in_condition = self.take(), True  # the condition ends at a comma
            condition, self.in_condition = self.phrase(), False
            if condition is not None and (self.role() in ("kind", "count", "nearest") or self.it_next()
                                          or (self.role() == "pred" and self.kind_after_states(0))):
                self.antecedent = first = self.referred(*condition)  # "while a bus is stopped, a car passes it"
                main = self.clauses()
                after = lead.name == "after"  # "before the pedestrian crosses, we stop": we stop, then it crosses
                return While(main, first) if lead.name == "while" else rewrite.in_turn(main, first, after)
            self.i, self.unused[unused:], self.grouped = start, [], False  # no main clause: "while" says nothing
            self.unused.extend(self.take().words)
        if self.antecedent is not None and self.it_next():  # "after the bus stops, it drives off"
            self.pass_fillers()
            found = (self.modifiers(rewrite.without_states(subject_of(self.antecedent))), 0)
        else:
            found = self.phrase()
        if found is None:
            raise DescriptionError("")
        node = self.referred(*found)
        # A comma before a new subject joins clauses as "and" does: "a car is parked on the left, a truck …"
        at = -1
        while (self.role() == "conj" or self.comma_clause(rewrite.listed(node) is not None)) and self.i != at:
            at = self.i  # a clause that reads nothing ends the loop
            conj = self.take() if self.role() == "conj" else Lexeme("conj", "and", words=(",",))
            self.end_clause()
            # "… while a pedestrian crosses in front of it"; "a car brakes after we pass it": before it brakes
            self.antecedent = rewrite.without_states(node) if conj.name == "after" else node
            another = bool(self.skipped_before_next() & {"another", "other", "a", "an"})  # "… then another car"
            own = self.role() in ("pred", "not") and self.kind_after_states(0)  # "and parked cyclists": theirs
            it_said = self.it_next()
            if conj.words == (",",):
                self.pass_fillers()  # the comma, and an "it" that opens the clause
            self.named_it = False
            nxt = self.phrase(need_kind=True)  # none: "brakes and then stops" goes on about the same objects
            another = another or (nxt is not None and self.named_it)  # "the car behind it"
            if nxt is None:  # "stopped then moving": the same objects, unless an unknown noun says otherwise
                head = rewrite.without_states(subject_of(node))
                if it_said and head == Objects("ego"):  # "we follow a truck, it turns": the truck we follow
                    head = rewrite.ego_related(node) or rewrite.other_one(node) or head
                if self.role() in ("pred", "rel", "ego", "side", "with", "between", "not", "seq", "fixed") \
                        and not self.unknown_before_next():
                    self.antecedent = rewrite.other_one(node) or node  # "follows a truck, then passes it": the truck
                    nxt = (self.modifiers(head), 0)
                else:
                    self.unused.extend(w for w in conj.words if w != ",")
                    break
            other = self.referred(*nxt)
            while conj.name == "except" and self.role() == "conj" and self.name() == "and" \
                    and self.role(1) in ("kind", "count", "nearest"):  # "vehicles except buses and trucks"
                self.take()
                more = self.phrase(need_kind=True)
                other = AnyOf((other, self.referred(*more))) if more is not None else other
            if conj.name != "except" and subject_of(node) == Objects("any") and subject_of(other) != Objects("any"):
                node = rewrite.with_subject(node, subject_of(other))  # "parked or stopped vehicle": both of vehicles
            if conj.name == "and" and other is self.each_other and of_two_kinds(node, other):
                # "a car and a truck within 5 m of each other": each near the other, both answered
                near = dataclasses.replace(self.each_other, subject=node, other=self.each_other.subject)
                node = AnyOf((near, dataclasses.replace(near, reverse=True)))
            else:
                node = rewrite.join(node, conj.name, other, another, spread=not own)
        self.end_clause()
        return node

    def end_clause(self) -> None:
        """A clause ends: a distance or a duration that no relation of it took is said unused, not carried
        into the next clause."""
        if self.pending_m is not None:
            self.unused.append(f"{self.pending_m:g} m")
        if self.pending_low_m is not None:
            self.unused.append(f"more than {self.pending_low_m:g} m")
        if self.pending_s is not None:
            self.unused.append(f"for {self.pending_s:g} s")
        self.pending_m = self.pending_low_m = self.pending_s = None

    def referred(self, node: Node, count: int) -> Node:
        """The referred objects of a clause with the count said for them: "a group of" stands together,
        "three" are there at once."""
        grouped, self.grouped = self.grouped, False
        if grouped and subject_of(node) == node:
            return Has(node, "near", node, (("within_m", GROUP_RADIUS_M),), min_count=count - 1)
        if count >= 2:
            return Together(node, count)
        return node
