"""Scenario programs: a typed tree that names objects, tests them, relates them and composes in time.

A program is built from these nodes (frozen dataclasses; never code to ``eval``):

- :class:`Objects` ``kind``: every object of a kind (:mod:`scenarios.kinds`), or the ego.
- :class:`Is` a predicate (:mod:`scenarios.predicates`) on the subject's objects, or its negation.
- :class:`Has` a relation (:mod:`scenarios.relations`) of the subject to other objects, with at least
  ``min_count`` (and at most ``max_count``) of them; ``negate`` keeps subjects with none; ``reverse``
  answers the other objects instead of the subjects.
- :class:`Between`: the subject has an object of one kind on its left and of the other on its right.
- :class:`AllOf`, :class:`AnyOf`, :class:`Excluding`: and, or, and "but not".
- :class:`Together`: the child's objects at frames where at least ``min_count`` of them are selected.
- :class:`ForAtLeast`: runs that last ``seconds``; :class:`Then`: the same object does one thing and
  then another within ``within_s``; :class:`While`: the subject at frames where the condition holds for
  any object.

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


Node = Objects | Is | Has | Between | AllOf | AnyOf | Excluding | Together | ForAtLeast | Then | While


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
        case Has(subject, relation, other, params, min_count, max_count, negate, reverse):
            keywords = list(params)
            if min_count != 1:
                keywords.append(("min_count", min_count))
            if max_count is not None:
                keywords.append(("max_count", max_count))
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
    raise TypeError(f"not a program node: {node!r}")


def _plural(kind: str) -> str:
    words = {"ego": "the ego vehicle", "any": "objects", "bus": "buses", "school_bus": "school buses",
             "articulated_bus": "articulated buses", "vulnerable_road_user": "vulnerable road users",
             "construction": "construction objects"}
    return words.get(kind, kind.replace("_", " ") + "s")


def _params_text(params: tuple[Param, ...], skip: tuple[str, ...] = ()) -> str:
    shown = [f"{k.removesuffix('_m').removesuffix('_s').replace('_', ' ')} {_value(v)}"
             f"{' m' if k.endswith('_m') else ' s' if k.endswith('_s') else ''}" for k, v in params if k not in skip]
    return f" ({', '.join(shown)})" if shown else ""


def describe(node: Node) -> str:
    """A sentence that says what the program selects, for a reader to check the parse against."""
    from scenarios.predicates import PREDICATES
    from scenarios.relations import RELATIONS

    match node:
        case Objects(kind):
            return _plural(kind)
        case Is(subject, predicate, params, negate):
            p = dict(params)
            phrase = PREDICATES[predicate].phrase.format(**{**PREDICATES[predicate].defaults, **p}) \
                if predicate in PREDICATES else predicate
            phrase = phrase.replace(" any", "").replace("  ", " ")
            named = tuple(k for k in p if "{" + k + "}" in PREDICATES.get(predicate, PREDICATES["moving"]).phrase)
            return f"{describe(subject)} that {'not ' if negate else ''}{phrase}{_params_text(params, named)}"
        case Has(subject, relation, other, params, min_count, max_count, negate, reverse):
            p = dict(params)
            count = ("no" if negate else f"at least {min_count}" if min_count > 1 else "") + \
                (f" at most {max_count}" if max_count is not None else "")
            other_text = f"{count} {describe(other)}".strip()
            spec = RELATIONS.get(relation)
            phrase = spec.phrase.format(other=other_text, **{**spec.defaults, **p}) if spec else relation
            phrase = phrase.replace(" on the any", "")
            named = tuple(k for k in p if spec is not None and "{" + k + "}" in spec.phrase)
            sentence = f"{describe(subject)} that {phrase}{_params_text(params, named)}"
            return f"the {describe(other)} related to: {sentence}" if reverse else sentence
        case Between(subject, left, right, _):
            return f"{describe(subject)} between {describe(left)} and {describe(right)}"
        case AllOf(children):
            return " and ".join(f"({describe(c)})" for c in children)
        case AnyOf(children):
            return " or ".join(f"({describe(c)})" for c in children)
        case Excluding(base, excluded):
            return f"{describe(base)}, except {describe(excluded)}"
        case Together(child, min_count):
            return f"{describe(child)}, when at least {min_count} of them are there at once"
        case ForAtLeast(child, seconds):
            return f"{describe(child)}, for at least {_value(seconds)} s"
        case Then(first, second, within_s):
            return f"{describe(first)}, then within {_value(within_s)} s: {describe(second)}"
        case While(child, condition):
            return f"{describe(child)}, while {describe(condition)}"
    raise TypeError(f"not a program node: {node!r}")
