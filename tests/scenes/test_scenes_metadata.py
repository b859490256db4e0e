"""The appearance vocabulary of the log metadata: what the simulator writes, the camera reads."""

from __future__ import annotations

import numpy as np

from scenes.metadata import LogMetadata, TimeOfDay, Weather
from scenes.sensorsim.appearance import Appearance
from scenes.sim.appearance import TIME_OF_DAY_P, WEATHER_P, sample_appearance


def test_each_value_has_a_probability() -> None:
    assert len(TIME_OF_DAY_P) == len(TimeOfDay) and len(WEATHER_P) == len(Weather)


def test_sampled_appearance_is_read_back_by_the_camera() -> None:
    seen: set[tuple[TimeOfDay, Weather]] = set()
    for seed in range(40):
        written = sample_appearance(np.random.default_rng(seed), ["a", "b"])
        meta = LogMetadata.from_json_dict(LogMetadata("log", appearance=written).to_json_dict())
        look = Appearance.from_metadata(meta.appearance)
        assert (look.time_of_day.value, look.weather.value) == (written["time_of_day"], written["weather"])
        assert set(look.vehicle_colors) == {"a", "b"}
        seen.add((look.time_of_day, look.weather))
    assert {t for t, _ in seen} == set(TimeOfDay)
    assert {w for _, w in seen} == set(Weather)
