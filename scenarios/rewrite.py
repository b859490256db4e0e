"""Rewrites of program nodes that the parser applies as it reads: a relation tightened or bounded, a
modifier negated, the states left out of a later step, the subject replaced, and two clauses joined
(in turn, at once, or as a list of kinds)."""

from __future__ import annotations

import dataclasses

from scenarios import program as p

#: "Passing too closely": within this gap (m) of the side, the passing distance cyclists are owed in
#: many traffic codes.
CLOSE_PASS_M = 1.5
#: Beyond what any sensor sees (m): how far a relation reaches when only a least distance is said ("more
#: than 60 m ahead"), which the relation's default reach would cut short.
UNBOUNDED_M = 1000.0


def closer(node: p.Node) -> p.Node:
    """``node`` with its relation tightened ("following closely": within 10 m; "near": within 3 m;
    "passing too closely": within :data:`CLOSE_PASS_M` of the side)."""
    if isinstance(node, p.Has) and node.relation in ("following", "near", "direction"):
        tight = 10.0 if node.relation != "near" else 3.0
        return within(node, tight)
    if isinstance(node, p.Has) and node.relation == "passed_by":
        return with_param(node, "lateral_m", CLOSE_PASS_M)
    return node


def stated(node: p.Node, predicate: str, params: tuple[p.Param, ...] = (), negate: bool = False) -> p.Node:
    """``node`` with one more predicate, unless it is the one ``node`` asks already ("a bus stopped at a
    stop": stopped once)."""
    if isinstance(node, p.Is) and (node.predicate, node.params, node.negate) == (predicate, params, negate):
        return node
    return p.Is(node, predicate, params, negate)


def stated_or_after(node: p.Node, predicate: str, params: tuple[p.Param, ...] = (), negate: bool = False) -> p.Node:
    """``node`` with one more predicate; a state that cannot hold with one ``node`` asks follows it instead,
    on the same objects ("slows down and stops", "slows down, stops": braking, then stopped)."""
    if not negate and excludes(node, predicate):
        return p.Then(node, p.Is(without_states(node), predicate, params))
    return stated(node, predicate, params, negate)


def within(node: p.Node, within_m: float | None, beyond_m: float | None = None) -> p.Node:
    """A relation ``node`` limited to boxes at most ``within_m`` apart (None: any distance) and more than
    ``beyond_m`` (a least distance); any other node, and a relation that takes no distance, as it is."""
    if not isinstance(node, p.Has) or node.relation in ("heading", "passed_by", "crossed_by"):
        return node
    node = with_param(node, "within_m", UNBOUNDED_M if within_m is None else within_m)
    return node if beyond_m is None else with_param(node, "beyond_m", beyond_m)


def with_param(node: p.Has, key: str, value: float | str) -> p.Has:
    """``node`` with its parameter ``key`` set to ``value``."""
    return dataclasses.replace(node, params=(*[(k, v) for k, v in node.params if k != key], (key, value)))


def negated(after: p.Node, before: p.Node) -> p.Node:
    """``after`` (``before`` with one more modifier) with that modifier negated."""
    if isinstance(after, p.Has) and after.reverse and after != before:
        # "a pedestrian not to the left of the bus": the objects of ``before`` but those the relation
        # answers (a reversed relation answers its other objects; negated, it would name none).
        return p.Excluding(before, after)
    if isinstance(after, p.Is | p.Has) and after != before:
        return dataclasses.replace(after, negate=not after.negate)
    return after


#: Predicates of what an object is doing at a moment: a later step of a sequence does not inherit them.
STATES = ("stopped", "moving", "parked", "stationary", "braking", "accelerating")
#: States an object cannot be in at once, whether still or under way.
_STILL = frozenset({"stopped", "parked", "stationary"})
_UNDER_WAY = frozenset({"moving", "braking", "accelerating", "turning", "changing_lanes"})


def excludes(node: p.Node, predicate: str) -> bool:
    """Whether ``predicate`` cannot hold at the same moment as a state that ``node`` asks of its objects
    ("slows down and stops", "accelerates and brakes"): the words then name one after the other."""
    states = set()
    while isinstance(node, p.Is):
        if not node.negate:
            states.add(node.predicate)
        node = node.subject
    opposite = {"braking": "accelerating", "accelerating": "braking"}.get(predicate)
    return bool((predicate in _STILL and states & _UNDER_WAY) or (predicate in _UNDER_WAY and states & _STILL)
                or opposite in states)


def without_states(node: p.Node) -> p.Node:
    """``node`` without its state predicates (:data:`STATES`) along its subjects: "a stopped vehicle in
    our lane" → "a vehicle in our lane", the objects a next step ("… then moves") is about."""
    match node:
        case p.Is(subject) if node.predicate in STATES:
            return without_states(subject)
        case p.Is(subject):
            return dataclasses.replace(node, subject=without_states(subject))
        case p.Has() if node.reverse:
            return dataclasses.replace(node, other=without_states(node.other))
        case p.Has(subject):
            return dataclasses.replace(node, subject=without_states(subject))
    return node


def with_subject(node: p.Node, subject: p.Node) -> p.Node:
    """``node`` with its innermost subject (:func:`scenarios.program.subject_of`) replaced by ``subject``."""
    match node:
        case p.Objects():
            return subject
        case p.Is(inner) | p.Between(inner) | p.Together(inner) | p.ForAtLeast(inner) | p.While(inner) \
                | p.Sequenced(inner):
            field = dataclasses.fields(node)[0].name
            return dataclasses.replace(node, **{field: with_subject(inner, subject)})  # type: ignore[arg-type]
        case p.Has() if node.reverse:
            return dataclasses.replace(node, other=with_subject(node.other, subject))
        case p.Has(inner):
            return dataclasses.replace(node, subject=with_subject(inner, subject))
        case p.Then(first):
            return dataclasses.replace(node, first=with_subject(first, subject))
        case p.AllOf((first, *rest)):
            return p.AllOf((with_subject(first, subject), *rest))
    return node


def ego_without(node: p.Node) -> p.Node | None:
    """"No pedestrians near us", "no cars in front of us": the ego at the moments when no such object
    is there; None when ``node`` does not relate its objects to the ego."""
    if not isinstance(node, p.Has):
        return None
    if node.reverse and node.subject == p.Objects("ego"):  # "cars in front of us": the ego has them
        return dataclasses.replace(node, reverse=False, negate=not node.negate, min_count=1)
    if node.relation == "near" and node.other == p.Objects("ego") and not node.reverse:  # near: either way
        return p.Has(p.Objects("ego"), "near", node.subject, node.params, negate=not node.negate)
    return None


def other_one(node: p.Node) -> p.Node | None:
    """The object a clause about the ego relates it to ("we follow a truck": trucks), what a later "it"
    names; None when the clause relates it to nothing."""
    while isinstance(node, p.Is | p.ForAtLeast | p.Together):
        node = node.subject if isinstance(node, p.Is) else node.child
    if not isinstance(node, p.Has):
        return None
    return without_states(p.subject_of(node.subject if node.reverse else node.other))


#: Relations that hold around a moment only: what "it" does next happens after it, not while it holds.
MOMENTARY = frozenset({"passed_by", "crossed_by", "yielding_to"})


def ego_related(node: p.Node) -> p.Node | None:
    """The objects a clause about the ego relates it to, as related ("we follow a truck": the trucks we
    follow), what a later "it" that opens a clause names; None when the clause is no such relation."""
    if not isinstance(node, p.Has) or node.negate or node.nearest is not None or node.relation in MOMENTARY:
        return None
    if node.subject == p.Objects("ego") and not node.reverse:
        return dataclasses.replace(node, reverse=True)
    if node.other == p.Objects("ego") and node.reverse:  # "we pass a cyclist": cyclists passed by us
        return dataclasses.replace(node, reverse=False)
    return None


def said_of(other: p.Node, objects: p.Node) -> bool:
    """Whether ``other`` is said of ``objects`` (they stand along its chain of subjects)."""
    while other != objects:
        match other:
            case p.Is(subject) | p.ForAtLeast(subject) | p.Together(subject):
                other = subject
            case p.Has():
                other = other.other if other.reverse else other.subject
            case _:
                return False
    return True


def any_of(kinds: list[str]) -> p.Node:
    """The objects of any of ``kinds``."""
    objects = tuple(p.Objects(kind) for kind in kinds)
    return objects[0] if len(objects) == 1 else p.AnyOf(objects)


def listed(node: p.Node) -> tuple[p.Objects, ...] | None:
    """The kinds ``node`` lists, as "cars, trucks and buses" does, or None."""
    kinds = node.children if isinstance(node, p.AnyOf) else (node,)
    objects = tuple(k for k in kinds if isinstance(k, p.Objects))
    return objects if len(objects) == len(kinds) else None


def join(node: p.Node, conj: str, other: p.Node, distinct: bool, spread: bool = True) -> p.Node:
    """Two clauses joined by ``conj`` ("and", "or", "then", "after", "while", "except"); ``distinct``:
    the second names other objects than the first ("a car stops and another car passes it"); ``spread``:
    what the second says after its noun is said of a list of kinds before it too ("cars and trucks in
    our lane"; not "pedestrians and parked cyclists")."""
    first, second, ego = p.subject_of(node), p.subject_of(other), p.Objects("ego")
    if conj in ("then", "after"):  # "a car stops, then a pedestrian crosses"; "… after it turns"
        return in_turn(node, other, conj == "after", distinct)
    if conj == "except":
        return p.Excluding(node, other)
    if conj == "and" and not distinct and (going_on := continued(node, other)) is not None:  # "stops and drives off"
        return going_on
    if conj in ("and", "while") and distinct and node == other:  # "a car brakes and another car brakes": two
        return p.Together(node, 2)
    if conj == "and" and ego not in (first, second) and (tied := tied_to(node, other)) is not None:
        return p.AnyOf((tied, other))  # "a bus stops and a pedestrian crosses in front of it": that bus
    if conj == "while" or (conj == "and" and distinct and first == second):
        return p.While(node, other)
    if conj == "and" and first == ego and (related := ego_related(node)) is not None and said_of(other, related):
        return other  # "we follow a truck and it turns left": the truck we follow, turning
    if conj == "and" and ego in (first, second) and first != second and node != first and other != second:
        return p.While(node, other)  # "we turn right and a cyclist is on our right": both at once
    kinds = listed(node)
    if spread and conj in ("and", "or") and kinds is not None and isinstance(second, p.Objects) \
            and second not in kinds and "any" not in (second.kind, *(k.kind for k in kinds)):
        # "buses and motorcycles", "cars, trucks and buses are stopped": the words name all, what follows
        # is said of all
        return with_subject(other, p.AnyOf((*kinds, second)))
    if conj == "and" and p.of_two_kinds(node, other):
        return p.AnyOf((node, other))  # "a stopped bus and a parked car": no object is both
    if conj == "or":
        return p.AnyOf((node, other))
    return p.AllOf((node, other))


def tied_to(node: p.Node, other: p.Node) -> p.Node | None:
    """``node``'s objects that ``other`` relates to them ("a bus stops and a pedestrian crosses in front of
    it": the buses a pedestrian crosses in front of), where ``other`` is one relation to ``node``; else None."""
    if not isinstance(other, p.Has) or other.negate or other.nearest is not None or other.min_count != 1 \
            or other.max_count is not None:
        return None
    if other.reverse and other.subject == node:
        return dataclasses.replace(other, reverse=False)
    if not other.reverse and other.other == node:  # "a truck turns and a car follows it": the truck followed
        return dataclasses.replace(other, reverse=True)
    return None


def in_turn(main: p.Node, event: p.Node, after: bool = False, distinct: bool = False) -> p.Node:
    """``main``, then ``event`` (or, ``after``, ``event`` first): one object doing both in turn where both
    name the same objects ("a car stops after it turns"), else, or where they are ``distinct`` ("a car
    brakes, then another car brakes"), ``main``'s objects at the moments that the other objects' event
    follows or precedes ("a pedestrian crosses, then we drive off")."""
    if p.subject_of(main) == p.subject_of(event) and not distinct:
        going_on = None if after else continued(main, event)
        if going_on is not None:
            return going_on
        return p.Then(event, main) if after else p.Then(main, event)
    return p.Sequenced(main, event, after=after)


def continued(main: p.Node, event: p.Node) -> p.Node | None:
    """``main`` going on into a sequence ``event`` that begins with ``main``'s last step ("stops, then drives
    off": the drive-off's own stop), that step said once; None where ``event`` begins otherwise."""
    if not isinstance(event, p.Then):
        return None
    steps, _ = p.chain_steps(main) if isinstance(main, p.Then) else ([main], [])
    if event.first != steps[-1]:
        return None
    return event if steps[-1] is main else p.Then(main, event.second, event.within_s)
