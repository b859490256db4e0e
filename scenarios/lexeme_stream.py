"""A description's lexemes as a stream that the parser (:mod:`scenarios.parser`) reads left to right:
filler words are stepped over, every word the lexicon does not know is kept as unused, and the filler
words that shape a sentence (a comma, "is", "it", "that") answer where a phrase or a clause ends."""

from __future__ import annotations

from typing import NamedTuple

from scenarios.kinds import within_kinds
from scenarios.lexicon import PLAIN_VERBS, PLURAL_KINDS, Lexeme
from scenarios.program import Node, Objects
from scenarios.quantities import FOOT_M

#: Predicates of where an object is: said after the noun, they say which objects "the nearest" is among
#: ("the closest vehicle in our lane brakes": the nearest of those in our lane, braking).
PLACES = frozenset({"ego_lane", "on_crosswalk", "at_crosswalk", "in_bike_lane", "in_bus_lane", "in_vehicle_lane",
                    "at_intersection", "near_intersection", "on_road"})
#: Words that open a clause about the noun before ("a bus, which is stopped"): what follows is the noun's.
RELATIVE = frozenset({"that", "which", "who"})
#: Auxiliaries that make the verb after them finite ("does not stop", "has stopped"), and those of a plural
#: subject ("do not move", "have stopped").
_FINITE_AUX = frozenset({"does", "doesn't", "did", "didn't", "fails", "failed", "has", "hasn't"})
_PLAIN_AUX = frozenset({"do", "don't", "fail", "have", "haven't"})
#: Words that end in "s" without being a verb's present ("across", "towards").
_NOT_VERBS = frozenset({"across", "towards", "always", "alongside", "backwards", "sideways", "besides", "perhaps"})


class Quantity(NamedTuple):
    """A number said with its unit ("m", "s", a speed unit, or "" for none); for a range ("5 to 20 m"),
    ``value`` is its upper end and ``low`` its lower end (None for a single number)."""

    value: float
    unit: str
    low: float | None = None


class LexemeStream:
    """A cursor over lexemes: ``i`` the next one; ``unused`` the words stepped over that mean something
    the parse did not take (unknown words, and whatever :meth:`drop_rest` drops)."""

    def __init__(self, items: list[Lexeme]) -> None:
        self.items = items
        self.i = 0
        self.unused: list[str] = []
        #: Whether the last noun read names one object ("a bus", not "buses" or "two cars"): a verb's plain
        #: form after it is said of a plural subject before ("cars behind a bus wait": the cars do).
        self.singular_noun = False

    def peek(self, ahead: int = 0) -> Lexeme | None:
        j, seen = self.i, -1
        while j < len(self.items):
            if self.items[j].role not in ("skip", "unknown"):
                seen += 1
                if seen == ahead:
                    return self.items[j]
            j += 1
        return None

    def take(self) -> Lexeme:
        self.pass_fillers()
        item = self.items[self.i]
        self.i += 1
        return item

    def take_kind(self, count: int) -> Lexeme:
        """The kind named next (with ``count`` said for it), taken; notes whether it names one object."""
        item = self.take()
        self.singular_noun = not count and item.words not in PLURAL_KINDS
        return item

    def pass_fillers(self) -> None:
        """Step over the filler words before the next meaningful item (unknown ones are unused)."""
        while self.i < len(self.items) and self.items[self.i].role in ("skip", "unknown"):
            if self.items[self.i].role == "unknown":
                self.unused.append(self.items[self.i].name)
            self.i += 1

    def drop_rest(self) -> None:
        while self.i < len(self.items):
            item = self.items[self.i]
            if item.role != "skip":
                self.unused.extend(item.words)
            self.i += 1

    def fillers(self, start: int | None = None) -> list[Lexeme]:
        """The filler lexemes (skipped and unknown words) between here (or ``start``) and the next
        meaningful item."""
        i = j = self.i if start is None else start
        while j < len(self.items) and self.items[j].role in ("skip", "unknown"):
            j += 1
        return self.items[i:j]

    def skipped_after_next(self) -> set[str]:
        """The filler words between the next meaningful item and the one after it."""
        return {word for item in self.fillers(self.i + len(self.fillers()) + 1) for word in item.words}

    def object_after_next(self) -> bool:
        """Whether the meaningful item after the next is the next one's object: the ego, or opened by "a",
        "an" or "the" ("passing a truck", "passing us" are a verb and its object, "passing cars" cars that
        pass)."""
        return self.name(1) == "ego" or bool(self.skipped_after_next() & {"a", "an", "the"})

    def unknown_before_next(self) -> bool:
        """Whether a word the lexicon does not know stands between here and the next meaningful item."""
        return any(item.role == "unknown" for item in self.fillers())

    def after_word(self, word: str) -> bool:
        """Whether the next meaningful item comes right after ``word`` (a filler the stream skips)."""
        j = self.i + len(self.fillers())
        return j > 0 and self.items[j - 1].words == (word,)

    def at_comma(self) -> bool:
        """Whether a comma stands before the next meaningful item: a clause ends there ("after the
        pedestrian crosses, a car stops": the car is not what the pedestrian crosses)."""
        return "," in self.skipped_before_next()

    def it_next(self) -> bool:
        """Whether "it" or "they" stands before the next meaningful item (a clause about the objects before)."""
        return bool(self.skipped_before_next() & {"it", "they"})

    def it_after_next(self) -> bool:
        """Whether "it" or "they" stands right after the next meaningful item ("… and it turns left": a
        clause about the objects before, not one more modifier)."""
        return bool(self.skipped_after_next() & {"it", "they"})

    def not_a_kind(self) -> bool:
        """Whether the next words say that the object is not of a kind ("that is not a bus", "which isn't a
        car"), not that it is without one ("a truck without a trailer")."""
        item = self.peek()
        return item is not None and item.role == "not" and self.role(1) == "kind" and bool(
            self.skipped_before_next() & {"is", "are"} or item.words in (("isn't",), ("aren't",)))

    def take_kinds(self, subject: Node) -> list[str]:
        """The kinds named next, listed with "or" ("not a car or a truck"), taken; one that the ``subject``
        node's objects all are ("a pedestrian who is not a child": no kind of its own) is unused."""
        items = [self.take()]
        while self.role() == "conj" and self.name() == "or" and self.role(1) == "kind":
            self.take()
            items.append(self.take())
        names = [item.name for item in items]
        for item in items:
            if isinstance(subject, Objects) and within_kinds(subject.kind, (item.name,)):
                self.unused.extend(item.words)
                names.remove(item.name)
        return names

    def finite_verb(self, plain: bool = False) -> bool:
        """Whether the next meaningful item is a verb said in the present ("brakes", "passes a cyclist",
        "never moves", "has stopped"), not a participle ("braking", "parked on the left"): a new predicate
        of the clause's subject; ``plain``: its plain form too ("wait", "slow down"; not "to cross")."""
        item = self.peek()
        if item is not None and item.role == "not" and self.role(1) in ("pred", "seq", "rel"):  # "does not stop"
            return item.words[0] in _FINITE_AUX or (plain and item.words[0] in _PLAIN_AUX)
        if item is None or item.role not in ("pred", "seq", "rel"):
            return False
        word = item.words[1] if item.words[0] == "never" and len(item.words) > 1 else item.words[0]
        if word in _FINITE_AUX or (plain and (word in PLAIN_VERBS or word in _PLAIN_AUX)
                                   and "to" not in self.skipped_before_next()):
            return True
        return len(word) > 3 and word.endswith("s") and not word.endswith("ss") and word not in _NOT_VERBS

    def ends_phrase(self, nested: bool, comma_ends: bool, choosing: str | None) -> bool:
        """Whether the next words are no longer the phrase's own modifiers: after "is" or a present verb
        for the object of a relation (``nested``: "the car in front of the bus is stopped", "… brakes": the
        car does), after a comma where it ends the clause (``comma_ends``); for "the nearest" (``choosing``)
        after "is", and after a present verb ("closest", ``near``) or anything but a place or our side
        ("lead", ``ahead``: "the lead vehicle braking" is the lead, braking). Never inside a "that",
        "which" or "who" clause, which is the phrase's ("a bus, which is stopped")."""
        if self.skipped_before_next() & RELATIVE:
            return False
        if (self.at_copula() and (nested or choosing)) or (self.at_comma() and (comma_ends or self.it_next())):
            return True
        if (nested or choosing == "near") and self.finite_verb(plain=nested and self.singular_noun):
            return True
        return choosing == "ahead" and self.role() in ("pred", "seq", "rel", "fixed", "with") \
            and self.name() not in PLACES

    def comma_clause(self, listing: bool) -> bool:
        """Whether a comma here starts a clause of its own: a subject ("a car", "two pedestrians", "the
        lead vehicle") that something is said of ("…, a truck is parked"), or that a ``listing`` of kinds
        goes on with ("cars, trucks and buses"); not one more object of a relation ("a car near a
        truck, a bus and a cyclist")."""
        if self.at_comma() and self.it_next():  # "…, it turns left"
            return True
        if not self.at_comma() or self.role() not in ("kind", "count", "number", "nearest"):
            return False
        said = self.role(1 if self.role() == "kind" else 2)
        return listing or said not in ("conj", "end", "kind")

    def at_copula(self) -> bool:
        """Whether "is" or "are" stands before the next meaningful item, other than in "that is" ("the
        closest car is parked" says it of the car; "the closest car that is parked" names which)."""
        words = self.skipped_before_next()
        return bool(words & {"is", "are", "was", "were"}) and not words & RELATIVE

    def ahead_word(self, ahead: int) -> bool:
        """Whether the ``ahead``-th meaningful item says "ahead" or "in front of" ("two cars ahead")."""
        item = self.peek(ahead)
        return item is not None and item.role in ("side", "ego", "rel") \
            and (item.name == "front" or dict(item.params).get("side") == "front")

    def skipped_before_next(self) -> set[str]:
        """The filler words between here and the next meaningful item."""
        return {word for item in self.fillers() for word in item.words}

    def words(self, ahead: int = 0) -> tuple[str, ...]:
        """The words of the ``ahead``-th meaningful item (("",) past the end)."""
        item = self.peek(ahead)
        return item.words if item is not None else ("",)

    def role(self, ahead: int = 0) -> str:
        item = self.peek(ahead)
        return item.role if item is not None else "end"

    def name(self, ahead: int = 0) -> str:
        item = self.peek(ahead)
        return item.name if item is not None else ""

    def count_ahead(self) -> int:
        item = self.peek()
        return item.count if item is not None else 0

    # -- numbers -----------------------------------------------------------------------------------------
    def quantity(self) -> Quantity | None:
        """A number (or range "5 to 20") with its unit, consumed."""
        if self.role() != "number":
            return None
        j, low = 1, None
        value = float(self.name())
        if self.role(1) == "number":  # "5 to 20": "to" is filler between them
            low, value, j = value, float(self.name(1)), 2
        unit = self.peek(j)
        if unit is None or unit.role != "unit":
            if self.role(j) == "kind":
                return None  # "two vehicles": a count, not a quantity
            for _ in range(j):
                self.take()
            return Quantity(value, "", low)
        for _ in range(j + 1):
            self.take()
        if unit.name == "ft":  # in metres, as every distance of a program
            return Quantity(round(value * FOOT_M, 2), "m", None if low is None else round(low * FOOT_M, 2))
        return Quantity(value, unit.name, low)
