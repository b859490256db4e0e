"""Scenario programs: a typed tree that names objects, tests them, relates them and composes in time.

A program is built from these nodes (frozen dataclasses; never code to ``eval``):

- :class:`Objects` ``kind``: every object of a kind (:mod:`scenarios.kinds`), or the ego.
- :class:`Is` a predicate (:mod:`scenarios.predicates`) on the subject's objects, or its negation.
- :class:`Has` a relation (:mod:`scenarios.relations`) of the subject to other objects, with at least
  ``min_count`` (and at most ``max_count``) of them; ``negate`` keeps subjects with none; ``reverse``
  answers the other objects instead of the subjects; ``nearest`` counts, at each frame, only the
  ``nearest`` others closest to each subject ("the lead vehicle": the nearest vehicle ahead).
- :class:`Between`: the subject has an object of one kind on its left and of the other on its right.
- :class:`AllOf`, :class:`AnyOf`, :class:`Excluding`: and, or, and "but not".
- :class:`Together`: the child's objects at frames where at least ``min_count`` of them are selected.
- :class:`ForAtLeast`: runs that last ``seconds``; :class:`Then`: the same object does one thing and
  then another within ``within_s`` (in a chain of them, each step after the one before);
  :class:`While`: the subject at frames where the condition holds for any object; :class:`Sequenced`:
  the subject's runs that begin within ``within_s`` before (or, ``after``, after) some other object's
  event begins ("a car stops, then a pedestrian crosses").

Every node renders two ways: :func:`to_text`, the program syntax users can write and edit
(:mod:`scenarios.syntax` reads it back), and :func:`describe`, a sentence a reader checks the parse by.
"""

from __future__ import annotations

from dataclasses import dataclass

Param = tuple[str, float | str]


@dataclass(frozen=True)
class Objects:
    kind: str


@dataclass(frozen=True)
class Is:
    subject: Node
    predicate: str
    params: tuple[Param, ...] = ()
    negate: bool = False


@dataclass(frozen=True)
class Has:
    subject: Node
    relation: str
    other: Node
    params: tuple[Param, ...] = ()
    min_count: int = 1
    max_count: int | None = None
    negate: bool = False
    reverse: bool = False
    nearest: int | None = None


@dataclass(frozen=True)
class Between:
    subject: Node
    left: Node
    right: Node
    lateral_m: float = 5.0


@dataclass(frozen=True)
class AllOf:
    children: tuple[Node, ...]


@dataclass(frozen=True)
class AnyOf:
    children: tuple[Node, ...]


@dataclass(frozen=True)
class Excluding:
    base: Node
    excluded: Node


@dataclass(frozen=True)
class Together:
    child: Node
    min_count: int = 2


@dataclass(frozen=True)
class ForAtLeast:
    child: Node
    seconds: float


@dataclass(frozen=True)
class Then:
    first: Node
    second: Node
    within_s: float = 5.0


@dataclass(frozen=True)
class While:
    child: Node
    condition: Node


@dataclass(frozen=True)
class Sequenced:
    child: Node
    event: Node
    within_s: float = 5.0
    after: bool = False


Node = Objects | Is | Has | Between | AllOf | AnyOf | Excluding | Together | ForAtLeast | Then | While | Sequenced


def subject_of(node: Node) -> Node:
    """The objects a node answers, before its modifiers: its innermost subject (the other side of a
    reversed relation)."""
    while True:
        match node:
            case Is(subject) | Between(subject) | Together(subject) | ForAtLeast(subject) | While(subject) \
                    | Sequenced(subject):
                node = subject
            case Has() if node.reverse:
                node = node.other
            case Has(subject):
                node = subject
            case Then(first) | AllOf((first, *_)):
                node = first
            case _:
                return node


def chain_steps(node: Then) -> tuple[list[Node], list[float]]:
    """The steps of a chain of ``then`` in order ("A, then B, then C", however nested) and the time each
    step follows the one before within."""
    first, first_gaps_s = chain_steps(node.first) if isinstance(node.first, Then) else ([node.first], [])
    second, second_gaps_s = chain_steps(node.second) if isinstance(node.second, Then) else ([node.second], [])
    return [*first, *second], [*first_gaps_s, node.within_s, *second_gaps_s]


def chain_under(node: Node) -> tuple[list[Node], list[float]] | None:
    """The steps and times of the ``then`` chain under ``node``'s filters (``Is``, ``ForAtLeast``,
    ``While``, ``Together``, ``Sequenced``), whose last step marks where ``node``'s selection begins
    ("drives off": where it moves); None where there is no chain."""
    while isinstance(node, Is | ForAtLeast | While | Together | Sequenced):
        node = node.subject if isinstance(node, Is) else node.child
    return chain_steps(node) if isinstance(node, Then) else None


def of_two_kinds(a: Node, b: Node) -> bool:
    """Whether ``a`` and ``b`` answer objects of two different named kinds (neither ``any``)."""
    kind_a, kind_b = subject_of(a), subject_of(b)
    return isinstance(kind_a, Objects) and isinstance(kind_b, Objects) and kind_a.kind != kind_b.kind \
        and "any" not in (kind_a.kind, kind_b.kind)


def _value(value: float | str | int) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _call(name: str, args: list[str], keywords: list[Param]) -> str:
    return f"{name}({', '.join([*args, *(f'{k}={_value(v)}' for k, v in keywords)])})"


def to_text(node: Node) -> str:
    """The program in the syntax of :mod:`scenarios.syntax` (``turning(vehicle, direction=left)``)."""
    match node:
        case Objects(kind):
            return kind
        case Is(subject, predicate, params, negate):
            text = _call(predicate, [to_text(subject)], list(params))
            return f"not({text})" if negate else text
        case Has(subject, relation, other, params, min_count, max_count, negate, reverse, nearest):
            keywords = list(params)
            if min_count != 1:
                keywords.append(("min_count", min_count))
            if max_count is not None:
                keywords.append(("max_count", max_count))
            if nearest is not None:
                keywords.append(("nearest", nearest))
            text = _call(relation, [to_text(subject), to_text(other)], keywords)
            text = f"not({text})" if negate else text
            return f"reverse({text})" if reverse else text
        case Between(subject, left, right, lateral_m):
            keywords = [] if lateral_m == 5.0 else [("lateral_m", lateral_m)]
            return _call("between", [to_text(subject), to_text(left), to_text(right)], keywords)
        case AllOf(children):
            return _call("and", [to_text(c) for c in children], [])
        case AnyOf(children):
            return _call("or", [to_text(c) for c in children], [])
        case Excluding(base, excluded):
            return _call("excluding", [to_text(base), to_text(excluded)], [])
        case Together(child, min_count):
            return _call("together", [to_text(child)], [("min_count", min_count)])
        case ForAtLeast(child, seconds):
            return _call("for_at_least", [to_text(child)], [("seconds", seconds)])
        case Then(first, second, within_s):
            return _call("then", [to_text(first), to_text(second)], [("within_s", within_s)])
        case While(child, condition):
            return _call("while", [to_text(child), to_text(condition)], [])
        case Sequenced(child, event, within_s, after):
            return _call("after" if after else "before", [to_text(child), to_text(event)], [("within_s", within_s)])
    raise TypeError(f"not a program node: {node!r}")


def _plural(kind: str) -> str:
    words = {"ego": "the ego vehicle", "any": "objects", "bus": "buses", "school_bus": "school buses",
             "articulated_bus": "articulated buses", "vulnerable_road_user": "vulnerable road users",
             "construction": "construction objects"}
    return words.get(kind, kind.replace("_", " ") + "s")


_SIDES = {"front": "in front of", "behind": "behind", "left": "to the left of", "right": "to the right of",
          "beside": "beside", "front_left": "to the front-left of", "front_right": "to the front-right of",
          "back_left": "to the back-left of", "back_right": "to the back-right of"}


#: What a passing's ``way`` adds to its phrase.
_WAYS = {"overtaking": "", "either": " either way"}


def _params_text(params: dict[str, float | str], shown: str) -> str:
    """The parameters a phrase does not say already (as ``{key}`` or ``{key_of}``), as "(within 5 m, …)"."""
    rest = [(k, v) for k, v in params.items() if "{" + k + "}" not in shown and "{" + k + "_of}" not in shown
            and k != "side"]
    text = [f"{k.removesuffix('_m').removesuffix('_s').removesuffix('_deg').replace('_', ' ')} {_value(v)}"
            f"{' m' if k.endswith('_m') else ' s' if k.endswith('_s') else '°' if k.endswith('_deg') else ''}"
            for k, v in rest]
    return f" ({', '.join(text)})" if text else ""


def _nested(node: Node) -> str:
    """``describe(node)``, in parentheses when it is more than a kind."""
    text = describe(node)
    return text if isinstance(node, Objects) else f"({text})"


def describe(node: Node) -> str:
    """A phrase that says what the program selects, for a reader to check the parse against."""
    from scenarios.predicates import PREDICATES
    from scenarios.relations import RELATIONS

    match node:
        case Objects(kind):
            return _plural(kind)
        case Is(subject, predicate, params, negate):
            pred = PREDICATES.get(predicate)
            known = {**(pred.defaults if pred else {}), **dict(params)}
            phrase = pred.words(known).replace(" any", "") if pred else predicate
            extra = _params_text(dict(params), pred.phrase if pred else "")
            return f"{describe(subject)} {'not ' if negate else ''}{phrase}{extra}"
        case Has(subject, relation, other, params, min_count, max_count, negate, reverse, nearest):
            spec = RELATIONS.get(relation)
            values = {**(spec.defaults if spec else {}), **dict(params)}
            side = str(values.get("side", ""))
            values["side_of"] = _SIDES.get(side, side)
            values["way_of"] = _WAYS.get(str(values.get("way", "")), "")
            count = ("no " if negate else f"at least {min_count} " if min_count > 1 else "") + \
                (f"at most {max_count} " if max_count is not None else "")
            template = (spec.reverse_phrase if reverse else spec.phrase) if spec else relation + " {other}"
            phrase = template.format(other=count + _nested(other), subject=_nested(subject),
                                     **{k: v for k, v in values.items() if k not in ("other", "subject")})
            phrase = phrase.replace(" on the any", "")
            extra = _params_text(dict(params), template)
            named = describe(other) if reverse else describe(subject)
            if nearest is not None and reverse:  # "the nearest of the vehicles in front of the ego vehicle"
                named = f"the nearest{'' if nearest == 1 else f' {nearest}'} of the {named}"
            elif nearest is not None:
                extra += f" (counting the nearest{'' if nearest == 1 else f' {nearest}'} only)"
            return f"{named} {phrase}{extra}"
        case Between(subject, left, right, _):
            return f"{describe(subject)} between {_nested(left)} and {_nested(right)}"
        case AllOf(children):
            return " and ".join(_nested(c) for c in children)
        case AnyOf(children):
            return " or ".join(_nested(c) for c in children)
        case Excluding(base, excluded):
            return f"{describe(base)}, except {_nested(excluded)}"
        case Together(child, min_count):
            return f"{describe(child)}, at least {min_count} at once"
        case ForAtLeast(child, seconds):
            return f"{describe(child)}, for at least {_value(seconds)} s"
        case Then(first, second, within_s):
            return f"{_nested(first)}, then within {_value(within_s)} s {_nested(second)}"
        case While(child, condition):
            return f"{describe(child)}, while there are {_nested(condition)}"
        case Sequenced(child, event, within_s, after):
            return f"{describe(child)}, within {_value(within_s)} s {'after' if after else 'before'} {_nested(event)}"
    raise TypeError(f"not a program node: {node!r}")
