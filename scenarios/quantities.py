"""Numbers said with units in a description: speeds and distances, and how the words before them bound
them ("faster than 10 m/s", "under 5 km/h", "at 30 mph", "more than 20 m away")."""

from __future__ import annotations

from scenarios.program import Param

#: Metres per second in one of each speed unit.
SPEED_UNITS = {"mps": 1.0, "kmh": 1000.0 / 3600.0, "mph": 1609.344 / 3600.0}
#: Words before a speed that make it a floor ("faster than 10 m/s") or a ceiling ("under 5 km/h"); with
#: neither ("at 30 km/h"), the speed is a band of ±20 % around it.
SPEED_FLOOR = frozenset({"faster", "quicker", "above", "over", "exceeding", "more", "least"})
SPEED_CEILING = frozenset({"slower", "below", "under", "less", "most"})


#: Words before a distance that make it a least one ("more than 20 m away", "no closer than 5 m" with
#: the negation).
FARTHER = frozenset({"more", "least", "over", "beyond", "farther", "further"})
#: Metres in a foot: distances said in feet ("within 30 feet") are read in metres.
FOOT_M = 0.3048


def speed_bounds(speed: float, unit: str, fillers: set[str], low: float | None = None) -> tuple[Param, ...]:
    """The ``speed`` predicate's bounds (m/s) for a speed said in ``unit`` (one of :data:`SPEED_UNITS`) with
    the words ``fillers`` before it (a range "5 to 10 m/s" gives its ``low`` too)."""
    mps = SPEED_UNITS[unit]
    if low is not None:
        return ("min_mps", round(low * mps, 2)), ("max_mps", round(speed * mps, 2))
    if fillers & SPEED_FLOOR:
        return (("min_mps", round(speed * mps, 2)),)
    if fillers & SPEED_CEILING:
        return (("max_mps", round(speed * mps, 2)),)
    return ("min_mps", round(0.8 * speed * mps, 2)), ("max_mps", round(1.2 * speed * mps, 2))


def other_bound(fillers: set[str]) -> set[str] | None:
    """Words that say the other bound of a negated speed ("not faster than 10 m/s": under it); None for a
    speed said as a band ("not at 30 km/h"), which no bound negates."""
    if fillers & SPEED_FLOOR:
        return {"under"}
    if fillers & SPEED_CEILING:
        return {"over"}
    return None
