"""The program syntax: what :func:`scenarios.program.to_text` writes, read back into a program.

A program is a kind or a call::

    program  := KIND | NAME "(" argument ("," argument)* ")"
    argument := program | KEY "=" VALUE

``NAME`` is a predicate (``turning(vehicle, direction=left)``), a relation
(``direction(vehicle, cyclist, side=right, within_m=5, min_count=2)``; ``nearest=1`` counts only the
closest), or one of ``not``, ``reverse``, ``between``, ``and``, ``or``, ``excluding``, ``together``
(``min_count=``), ``for_at_least`` (``seconds=``), ``then``, ``before`` and ``after`` (``within_s=``) and
``while``. ``VALUE`` is a number or a word. Nothing is evaluated as code; an error names the position and
what was expected there.
"""

from __future__ import annotations

import dataclasses
import re

from scenarios import program as p
from scenarios.kinds import KIND_NAMES
from scenarios.predicates import PREDICATES, ProgramError
from scenarios.relations import RELATIONS

_TOKEN = re.compile(r"\s*(?:(?P<word>[A-Za-z_][A-Za-z0-9_]*)|(?P<number>-?\d+(?:\.\d*)?(?:e-?\d+)?)|(?P<punct>[(),=]))")
#: The longest program text read (a program is a line, not a file).
MAX_PROGRAM_CHARS = 2000


class SyntaxProblem(ProgramError):
    """Program text that does not parse; the message names the position."""


class _Parser:
    def __init__(self, text: str) -> None:
        if len(text) > MAX_PROGRAM_CHARS:
            raise SyntaxProblem(f"program of {len(text)} characters: at most {MAX_PROGRAM_CHARS}")
        self.text = text
        self.tokens: list[tuple[str, str, int]] = []
        pos = 0
        while pos < len(text):
            if text[pos:].strip() == "":
                break
            match = _TOKEN.match(text, pos)
            if match is None:
                raise SyntaxProblem(f"at character {pos + 1}: unexpected {text[pos:].strip()[:12]!r}")
            kind = match.lastgroup or ""
            self.tokens.append((kind, match.group(kind), match.start(kind)))
            pos = match.end()
        self.i = 0

    def peek(self) -> tuple[str, str, int]:
        return self.tokens[self.i] if self.i < len(self.tokens) else ("end", "", len(self.text))

    def take(self, value: str | None = None, kind: str | None = None) -> str:
        k, v, pos = self.peek()
        if (value is not None and v != value) or (kind is not None and k != kind):
            want = repr(value) if value is not None else f"a {kind}"
            found = repr(v) if v else "the end"
            raise SyntaxProblem(f"at character {pos + 1}: expected {want}, found {found}")
        self.i += 1
        return v

    def program(self) -> p.Node:
        name = self.take(kind="word")
        if self.peek()[1] != "(":
            if name not in KIND_NAMES:
                raise SyntaxProblem(f"{name!r} is not a kind of object (kinds: {', '.join(KIND_NAMES)})")
            return p.Objects(name)
        self.take("(")
        args: list[p.Node] = []
        keywords: list[p.Param] = []
        while True:
            k, v, _ = self.peek()
            nxt = self.tokens[self.i + 1][1] if self.i + 1 < len(self.tokens) else ""
            if k == "word" and nxt == "=":
                self.take()
                self.take("=")
                kind, value, _ = self.peek()
                self.take()
                keywords.append((v, float(value) if kind == "number" else value))
            else:
                args.append(self.program())
            if self.peek()[1] == ",":
                self.take(",")
                continue
            self.take(")")
            return build(name, args, keywords)


def _number(keywords: dict[str, float | str], key: str, name: str) -> float:
    value = keywords.pop(key)
    if not isinstance(value, float):
        raise SyntaxProblem(f"{name}: {key}={value!r} is not a number")
    return value


def _whole(value: float, key: str, name: str) -> int:
    if value != int(value):
        raise SyntaxProblem(f"{name}: {key}={value:g} is not a whole number")
    return int(value)


def build(name: str, args: list[p.Node], keywords: list[p.Param]) -> p.Node:
    """The node a call ``name(args, keywords)`` stands for.

    Raises:
        SyntaxProblem: an unknown name, or arguments that do not fit it.
    """
    given = dict(keywords)

    def arity(n: int) -> None:
        if len(args) != n:
            raise SyntaxProblem(f"{name}(...) takes {n} program(s), got {len(args)}")

    def no_keywords() -> None:
        if given:
            raise SyntaxProblem(f"{name}(...) takes no {', '.join(given)}")

    if name in ("not", "reverse"):
        arity(1)
        no_keywords()
        inner = args[0]
        if name == "not" and isinstance(inner, p.Is | p.Has):
            return dataclasses.replace(inner, negate=not inner.negate)
        if name == "reverse" and isinstance(inner, p.Has):
            return dataclasses.replace(inner, reverse=True)
        raise SyntaxProblem(f"{name}(...) applies to a {'predicate or relation' if name == 'not' else 'relation'}")
    if name in ("and", "or"):
        no_keywords()
        if len(args) < 2:
            raise SyntaxProblem(f"{name}(...) takes at least 2 programs")
        return p.AllOf(tuple(args)) if name == "and" else p.AnyOf(tuple(args))
    if name in ("excluding", "while"):
        arity(2)
        no_keywords()
        return p.Excluding(args[0], args[1]) if name == "excluding" else p.While(args[0], args[1])
    if name == "together":
        arity(1)
        count = int(_number(given, "min_count", name)) if "min_count" in given else 2
        no_keywords()
        return p.Together(args[0], count)
    if name == "for_at_least":
        arity(1)
        seconds = _number(given, "seconds", name) if "seconds" in given else 1.0
        no_keywords()
        return p.ForAtLeast(args[0], seconds)
    if name in ("then", "before", "after"):
        arity(2)
        within = _number(given, "within_s", name) if "within_s" in given else 5.0
        no_keywords()
        return p.Then(args[0], args[1], within) if name == "then" else \
            p.Sequenced(args[0], args[1], within, after=name == "after")
    if name == "between":
        arity(3)
        lateral = _number(given, "lateral_m", name) if "lateral_m" in given else 5.0
        no_keywords()
        return p.Between(args[0], args[1], args[2], lateral)
    if name in PREDICATES:
        arity(1)
        spec = PREDICATES[name]
        spec.resolve(given)  # a bad parameter is refused here, named
        return p.Is(args[0], name, tuple(given.items()))
    if name in RELATIONS:
        arity(2)
        min_count = int(_number(given, "min_count", name)) if "min_count" in given else 1
        max_count = int(_number(given, "max_count", name)) if "max_count" in given else None
        nearest = _whole(_number(given, "nearest", name), "nearest", name) if "nearest" in given else None
        rel = RELATIONS[name]
        rel.resolve(given)
        return p.Has(args[0], name, args[1], tuple(given.items()), min_count, max_count, nearest=nearest)
    known = sorted({*PREDICATES, *RELATIONS, "not", "reverse", "and", "or", "excluding", "while", "for_at_least",
                    "then", "before", "after", "between", "together"})
    raise SyntaxProblem(f"unknown name {name!r} (known: {', '.join(known)})")


def parse_program(text: str) -> p.Node:
    """The program written in ``text`` (see the module docstring).

    Raises:
        SyntaxProblem: the text does not parse, naming the position and what was expected.
    """
    parser = _Parser(text)
    node = parser.program()
    if parser.peek()[0] != "end":
        raise SyntaxProblem(f"at character {parser.peek()[2] + 1}: unexpected {parser.peek()[1]!r} after the program")
    return node
