"""How the parser (:mod:`scenarios.parser`) turns relation words into program nodes: a relation asked
of the ego or of another object, from whose point of view it holds, the distance said before its
object, the side that follows it, and the sequences some phrases name ("drives off", "cuts in")."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable

from scenarios.kinds import within_kinds
from scenarios.lexeme_stream import LexemeStream
from scenarios.lexicon import SLOWING_FOR, Lexeme
from scenarios.program import AllOf, AnyOf, Between, Has, Is, Node, Objects, Then, subject_of
from scenarios.rewrite import UNBOUNDED_M, other_one, stated, with_param, with_subject, within, without_states

#: The two steps of "drives off" or "cuts into my lane" happen within this many seconds.
CUT_IN_WITHIN_S = 4.0
#: A path from one side of the ego to the other reaches it within this many seconds: a pedestrian at
#: 1 m/s crosses the ego's width and a metre either side of it.
SIDE_TO_SIDE_WITHIN_S = 5.0
#: Ahead in the same lane, as "the lead vehicle" and each link of "two cars ahead" are: in front, within
#: the lane's band beside the box.
AHEAD_IN_LANE: tuple[tuple[str, float | str], ...] = (("side", "front"), ("lateral_m", 1.5), ("within_m", 40.0))
#: What "the nearest" ("closest") and "the lead" ("leading", "the first") object is nearest to the anchor by.
_NEAREST: dict[str, tuple[str, tuple[tuple[str, float | str], ...]]] = {
    "near": ("near", (("within_m", 100.0),)), "ahead": ("direction", AHEAD_IN_LANE)}
#: What "the lead" is the nearest of, whatever kind the words name: whoever drives ahead in the lane (a
#: motorcycle or a bicycle leads as a car does). "The lead car" is the lead, when it is a car.
LEAD_KINDS = ("vehicle", "motorcycle", "cyclist")


#: The relation "on each side" names: the subject between two of the other objects.
BOTH_SIDES = "both_sides"


def farther_than(related: Has, least_m: float) -> Has:
    """``related`` with a least distance alone: farther than ``least_m`` from every other object where it
    is a nearness ("a car more than 20 m from a pedestrian": none within 20 m), else as far as the
    objects go (``beyond_m``: "a truck more than 20 m in front of a car")."""
    if related.relation == "near" and not related.reverse:
        return dataclasses.replace(with_param(related, "within_m", least_m), negate=not related.negate)
    return with_param(with_param(related, "within_m", UNBOUNDED_M), "beyond_m", least_m)


class RelationReader(LexemeStream):
    """A lexeme stream that builds relations; ``pending_m`` holds a distance said before the object
    of the relation that takes it ("within 5 m of", "pedestrian 5 m ahead"), ``antecedent`` what "it"
    names as one."""

    #: A noun phrase read from the stream (:meth:`scenarios.parser.Parser.phrase`): the object said after a word.
    phrase: Callable[..., tuple[Node, int] | None]

    def __init__(self, items: list[Lexeme]) -> None:
        super().__init__(items)
        self.pending_m: float | None = None
        #: A least distance said with it ("more than 20 m ahead of us", "5 to 10 m from a bus").
        self.pending_low_m: float | None = None
        #: What "it" and "them" name in a later clause: the clause before ("a car turns left while a
        #: pedestrian crosses in front of it"); in the first clause they name the ego, as "ahead" does.
        self.antecedent: Node | None = None
        #: The relation "each other" made, of the clause's own kind (another kind's when an "and" names two).
        self.each_other: Has | None = None
        #: Whether "it" has named the antecedent since the flag was cleared ("the car behind it": another car).
        self.named_it = False
        #: How deep in the phrases named by relations: "and"/"while" + modifier join the referred phrase only.
        self.depth = 0

    def it(self, words: Iterable[str], node: Node) -> tuple[Node, int] | None:
        """What "it" or "them" in ``words`` names, as a relation's object (noted in :attr:`named_it`): the
        antecedent; in the first clause, the object ``node`` (the phrase so far) relates its subject to
        ("a cyclist behind a car passes it": the car), else the ego; inside a relation's object, nothing."""
        if not {"it", "its", "them"} & set(words):
            return None
        named = self.antecedent if self.antecedent is not None else other_one(node)
        if named is None:  # inside a relation's object ("a cyclist in front of a car that passes it"): unknown
            return None if self.depth > 1 else (Objects("ego"), 0)
        self.named_it = True
        return named, 0

    def one_another(self, node: Node, relation: str, params: tuple[tuple[str, float | str], ...]) -> Node:
        """``node`` in ``relation`` to other objects of its own kind ("side by side", "within 5 m of each
        other"), kept as :attr:`each_other` for an "and" that names two kinds."""
        self.each_other = Has(node, relation, without_states(subject_of(node)), params)
        return self.each_other

    def ego_relation(self, node: Node, side: str, params: tuple[tuple[str, float | str], ...] = ()) -> Has:
        """``node``'s objects on ``side`` of the ego (a relation asked of the ego)."""
        return Has(Objects("ego"), "direction", node, (("side", side), *params), reverse=True)

    def ego_side(self, node: Node, side: str, params: tuple[tuple[str, float | str], ...] = ()) -> Node:
        """:meth:`ego_relation` at the distances said before it ("10 m ahead", "more than 20 m behind")."""
        upper = self.pending_m is not None
        related = self.ego_relation(node, side, (*params, *self.distance_params((), "direction")))
        return self.beyond_pending(related, upper)

    def distance_params(self, params: tuple[tuple[str, float | str], ...], name: str
                        ) -> tuple[tuple[str, float | str], ...]:
        """``params`` of relation ``name`` with the pending distance, which it takes (the reach ahead for
        a crossing; none for a heading or a passing, which have no distance)."""
        key = "forward_m" if name == "crossed_by" else "within_m"
        if self.pending_m is None or name in ("heading", "passed_by"):
            return params
        within, self.pending_m = self.pending_m, None
        return (*[(k, v) for k, v in params if k != key], (key, within))

    def relate(self, node: Node, item: Lexeme, other: tuple[Node, int]) -> Node:
        """``node`` related by ``item`` to ``other`` (its node and the count said for it)."""
        other_node, count = other
        if item.name == BOTH_SIDES:  # "a bus with a car on each side": between two of them
            return Between(node, other_node, other_node)
        if item.name == SLOWING_FOR:
            return self.slowing_for(node, item, other_node)
        upper = self.pending_m is not None
        params = self.distance_params(item.params, item.name)
        if item.reverse:  # the relation holds from the other object's point of view
            return self.beyond_pending(Has(other_node, item.name, node, params, reverse=True), upper)
        return self.beyond_pending(Has(node, item.name, other_node, params, min_count=max(1, count)), upper)

    def slowing_for(self, node: Node, item: Lexeme, other: Node) -> Has:
        """``node`` braking (as ``item`` says: "braking hard for") for ``other``: behind it, of a vehicle
        ("braking for the car ahead"); else with it in front ("slowing down for a pedestrian"), not only
        while it crosses (``docs/research/scenario-queries.md``)."""
        braking, kind = stated(node, "braking", item.params), subject_of(other)
        if isinstance(kind, Objects) and kind.kind != "any" and within_kinds(kind.kind, ("vehicle", "motorcycle")):
            return Has(braking, "following", other, self.distance_params((), "following"))
        return Has(braking, "direction", other, (("side", "front"),))

    def beyond_pending(self, related: Has, upper: bool) -> Has:
        """``related`` (the relation just read) farther than the pending least distance, which it takes
        (``beyond_m``); without an ``upper`` bound it reaches as far as the objects go."""
        low, self.pending_low_m = self.pending_low_m, None
        if low is None:
            return related
        if within(related, low) == related:  # a heading or a passing: no distance
            self.unused.append(f"more than {low:g} m")
            return related
        if not upper:
            return farther_than(related, low)
        return with_param(related, "beyond_m", low)

    def chain(self, node: Node) -> Node:
        """"two cars ahead (of X)": the object of ``node``'s kind in front of the one in front of X (the ego
        by default), through as many vehicles as the count says."""
        count_item = self.take()
        n = count_item.count or int(float(count_item.name))
        link = Objects(self.take().name)
        where = self.take()
        anchor: Node = Objects("ego")
        if where.role in ("rel", "side") and self.role() == "kind":
            found = self.phrase()
            anchor = found[0] if found is not None else anchor
        for _ in range(max(0, n - 1)):  # each link the nearest ahead of the one before
            anchor = Has(anchor, "direction", link, AHEAD_IN_LANE, reverse=True, nearest=1)
        return Has(anchor, "direction", node, AHEAD_IN_LANE, reverse=True, nearest=1)

    def nearest(self, node: Node, item: Lexeme, n: int = 1) -> Node:
        """The ``n`` of ``node``'s objects nearest the ego, or the object named after "to" ("the closest
        car to the bus"), by what ``item`` says ("closest": anywhere within 100 m; "lead": ahead in the
        lane band). A side of ours that ``node`` says already is where "closest" looks: "the nearest
        pedestrian on our right"."""
        anchor: Node = Objects("ego")
        if item.name == "near" and self.role() in ("kind", "nearest") and self.skipped_before_next() & {"to", "from"}:
            found = self.phrase(bare=True, need_kind=True)  # what follows is the subject's: "… is stopped"
            anchor = found[0] if found is not None else anchor
        if item.name == "near" and anchor == Objects("ego") and isinstance(node, Has) and node.reverse \
                and node.subject == anchor and node.relation == "direction":
            return dataclasses.replace(node, nearest=n)
        relation, params = _NEAREST[item.name]
        kind = subject_of(node)
        if item.name == "near" or not isinstance(kind, Objects) or not (
                kind.kind == "any" or within_kinds(kind.kind, LEAD_KINDS)):  # "the lead pedestrian": of them
            return Has(anchor, relation, node, params, reverse=True, nearest=n)
        among = with_subject(node, AnyOf(tuple(Objects(k) for k in LEAD_KINDS)))
        lead = Has(anchor, relation, among, params, reverse=True, nearest=n)
        return lead if kind.kind in ("vehicle", "any") else AllOf((kind, lead))

    def without_object(self, node: Node, item: Lexeme) -> Node:
        """A relation phrase that names no object: of the ego, by anyone, or no relation at all."""
        if item.name in ("heading_toward", "heading_away_from"):
            place = self.role() == "pred"  # "heading toward the intersection": the place word says where
            if not place and item.words[-1] not in ("toward", "from"):  # "approaching": the ego
                return Is(node, "approaching_ego" if item.name == "heading_toward" else "moving_away_from_ego")
            if not place or item.name == "heading_away_from":  # "toward the road"; no predicate says leaving
                self.unused.extend(item.words)
            return node
        if item.name == "yielding_to" and item.words[0].startswith(("wait", "stop", "halt")):  # "… for 10 s"
            return Is(node, "stopped")
        if item.name == SLOWING_FOR:  # "slowing down for 5 s"
            return stated(node, "braking", item.params)
        if item.name == "direction":
            side = str(dict(item.params)["side"])
            return self.ego_side(node, side)
        if item.words == ("at",) or (item.words == ("around",) and self.role() == "number"):
            return node  # "at" before a place word the lexicon reads itself; "around 20 km/h": about
        if item.name == "near" and self.skipped_before_next() & {"road", "street"}:  # "near the road": not an object
            self.unused.extend((*item.words, "road"))
            return node
        if item.words == ("past",):  # "stopped past the stop line": beyond, no passing
            self.unused.extend(item.words)
            return node
        if item.reverse and item.name == "passed_by" and "side" in dict(item.params):  # "passes on the left": us
            return self.relate(node, item, (Objects("ego"), 0))
        if item.reverse and item.name == "passed_by":  # "passing between ...": moving past
            return stated(node, "moving")
        if item.reverse and item.name == "crossed_by":  # "a pedestrian crosses at the crosswalk"
            kind = subject_of(node)  # a vehicle that crosses an intersection drives through it
            through = isinstance(kind, Objects) and kind.kind != "any" and within_kinds(kind.kind, ("vehicle",
                                                                                                   "motorcycle"))
            return Is(node, "moving" if through else "crossing_road")
        if item.name in ("following", "crossed_by", "passed_by", "near", "yielding_to"):  # "being overtaken": by anyone
            return self.relate(node, item, (Objects("any"), 0))
        self.unused.extend(item.words)
        return node

    def sequence(self, node: Node, item: Lexeme) -> Node:
        """A sequence the words name: "drives off" (stops, then moves), "cuts into my lane [from the left]"
        (in a lane beside the ego's, then in the ego's), "leaves our lane" (the other way), "from left to
        right" (on the ego's left, then on its right)."""
        if item.name == "side_to_side":  # "crossing from left to right": on our left, then on our right
            start = str(dict(item.params)["side"])
            end = "right" if start == "left" else "left"
            return Then(self.ego_relation(node, start), self.ego_relation(node, end), SIDE_TO_SIDE_WITHIN_S)
        if item.name == "drive_off":  # "stopped vehicle that starts moving": stopped once, then moving
            first = node if isinstance(node, Is) and node.predicate in ("stopped", "parked") and not node.negate \
                else Is(node, "stopped")
            return Then(first, Is(without_states(node), "moving"), CUT_IN_WITHIN_S)
        side = "adjacent"
        if self.role() == "side" and self.name() in ("left", "right"):
            side = self.take().name
        # A lane said before ("a car in the left lane cuts in") is the steps' to say, each in turn: taken off
        # the subject, where it could never hold in both steps, and kept as the side a cut-in comes from.
        while isinstance(node, Is) and node.predicate == "ego_lane":
            lane = str(dict(node.params).get("lane"))
            if side == "adjacent" and lane in ("left", "right") and item.name == "cut_in":
                side = lane
            node = node.subject
        beside, ours = Is(node, "ego_lane", (("lane", side),)), Is(node, "ego_lane", (("lane", "host"),))
        if item.name == "cut_out":  # "leaves our lane [to the left]": from the ego's lane to one beside it
            return Then(ours, beside, CUT_IN_WITHIN_S)
        return Then(beside, ours, CUT_IN_WITHIN_S)

    def acted_on(self, node: Node, rel: Lexeme, acting: tuple[Node, int]) -> Node:
        """``node`` that the objects of ``acting`` do ``rel`` to ("with a dog crossing", "with a car following
        it"): the relation from the other side; and where they are, if a side of "it" follows ("with a
        crossing pedestrian in front of it", "with an approaching car behind it")."""
        acted = self.relate(node, dataclasses.replace(rel, reverse=not rel.reverse), acting)
        if self.role() != "side" or not {"it", "its", "them", "their"} & set(self.words()):
            return acted
        side = self.take()
        if rel.name == "crossed_by" and side.name == "front":  # a crossing is in front already
            return acted
        return AllOf((acted, self.relate(node, side_relation(side), acting)))

    def with_side(self, item: Lexeme) -> Lexeme:
        """``item`` with the side that follows it ("being overtaken on the left")."""
        if item.name == "passed_by" and self.role() == "side" \
                and self.name() in ("left", "right", "beside"):
            side = self.take().name.replace("beside", "any")
            return dataclasses.replace(item, params=(*[(k, v) for k, v in item.params if k != "side"], ("side", side)))
        return item


def side_relation(item: Lexeme) -> Lexeme:
    """The relation a side phrase names ("in front of it": a direction; "in its lane", "nearby"; "on each
    side", "on both sides": one on either side, :data:`BOTH_SIDES`)."""
    if item.name == "beside" and {"both", "each"} & set(item.words):
        return Lexeme("rel", BOTH_SIDES)
    side = item.name
    return Lexeme("rel", side) if side in ("same_lane", "near") else Lexeme("rel", "direction", (("side", side),))
