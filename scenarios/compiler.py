"""Descriptions in people's words → scenario programs, with no language model at query time.

:func:`compile_description` normalises the words, matches the lexicon's phrases
(:mod:`scenarios.lexicon`) and reads them with the grammar of :mod:`scenarios.parser`; a text in
the program syntax (:mod:`scenarios.syntax`) is read as a program. It returns the program, its text,
a rendering a reader checks the parse by, and every word that carries no meaning in the parse
(:attr:`Compiled.unused`), never dropped silently; a description with no usable word is refused
(:class:`DescriptionError`).
"""

from __future__ import annotations

from dataclasses import dataclass

from scenarios.lexicon import lexemes
from scenarios.parser import DescriptionError, Parser
from scenarios.predicates import ProgramError
from scenarios.program import Node, describe, to_text
from scenarios.syntax import MAX_PROGRAM_CHARS, parse_program
from scenarios.word_forms import normalize

__all__ = ["Compiled", "DescriptionError", "compile_description"]


@dataclass(frozen=True)
class Compiled:
    """A description and the program it compiled to.

    Attributes:
        description: the text given.
        program: the program.
        text: the program in the program syntax (:func:`scenarios.program.to_text`).
        rendering: what the program selects, in words (:func:`scenarios.program.describe`).
        unused: words of the description that the program does not use, in order.
    """

    description: str
    program: Node
    text: str
    rendering: str
    unused: tuple[str, ...]

    @property
    def complete(self) -> bool:
        """Whether every word of the description was used."""
        return not self.unused


def compile_description(text: str) -> Compiled:
    """Compile a description to a program; a program written in the program syntax is read as such.

    Args:
        text: the description ("vehicle with a bicycle to its right") or a program
            (``direction(vehicle, cyclist, side=right)``).

    Raises:
        DescriptionError: nothing in the text names objects, naming the words not understood.
    """
    if len(text) > MAX_PROGRAM_CHARS:
        raise DescriptionError(f"description of {len(text)} characters: at most {MAX_PROGRAM_CHARS}")
    stripped = text.strip()
    if "(" in stripped and stripped.endswith(")"):
        try:
            program = parse_program(stripped)
        except ProgramError as exc:  # syntax, an unknown name, or a parameter its call does not take
            raise DescriptionError(f"program {stripped!r}: {exc}") from None
        return Compiled(text, program, to_text(program), describe(program), ())
    items = lexemes(normalize(text))
    parser = Parser(items)
    try:
        program = parser.description()
    except DescriptionError:
        unknown = [w for it in items if it.role == "unknown" for w in it.words]
        raise DescriptionError(
            f"no object named in {text!r}" + (f"; words not understood: {', '.join(unknown)}" if unknown else "")
            + " (name what to find: a vehicle, pedestrian, cyclist, bus, the ego vehicle, ...)") from None
    parser.drop_rest()
    unused = [*parser.unused, *[w for it in items[parser.i:] if it.role == "unknown" for w in it.words]]
    return Compiled(text, program, to_text(program), describe(program), tuple(dict.fromkeys(unused)))

