"""Speeds said with units: converted to m/s and bounded by the words before them."""

from __future__ import annotations

import pytest

from scenarios.quantities import SPEED_UNITS, speed_bounds


def test_a_speed_is_a_floor_a_ceiling_a_band_or_a_range_by_its_words() -> None:
    assert speed_bounds(10.0, "mps", {"faster", "than"}) == (("min_mps", 10.0),)
    assert speed_bounds(10.0, "mps", {"under"}) == (("max_mps", 10.0),)
    assert speed_bounds(10.0, "mps", set()) == (("min_mps", 8.0), ("max_mps", 12.0))  # "at 10 m/s": ±20 %
    assert speed_bounds(10.0, "mps", set(), low=5.0) == (("min_mps", 5.0), ("max_mps", 10.0))


@pytest.mark.parametrize(("unit", "mps"), [("kmh", 10.0), ("mph", 16.09)])
def test_other_units_are_converted_to_metres_per_second(unit: str, mps: float) -> None:
    said = {"kmh": 36.0, "mph": 36.0}[unit]
    assert speed_bounds(said, unit, {"above"}) == (("min_mps", mps),)
    assert set(SPEED_UNITS) == {"mps", "kmh", "mph"}
