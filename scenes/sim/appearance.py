"""Appearance variables of a simulated log: time of day, weather and object colours.

They do not change what anyone does, so retrieval that follows them instead of behaviour can be
caught. They are recorded in the log metadata for the camera renderer.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from scenes.metadata import TimeOfDay, Weather

#: Chance of each :class:`TimeOfDay` and :class:`Weather`, in their declaration order.
TIME_OF_DAY_P = (0.6, 0.2, 0.2)
WEATHER_P = (0.6, 0.25, 0.15)
#: Common car paints (white, black, silver, grey, blue, red, green, beige), 0–255 RGB.
PAINTS = np.array([[235, 235, 235], [25, 25, 28], [180, 182, 186], [110, 112, 115], [30, 60, 140],
                   [160, 25, 30], [30, 90, 50], [200, 185, 150]], dtype=np.int64)
PAINT_JITTER = 12


def sample_appearance(rng: np.random.Generator, track_ids: list[str]) -> dict[str, Any]:
    """``{"time_of_day", "weather", "vehicle_colors": {track_id: [r, g, b]}}`` for one log."""
    time_of_day = list(TimeOfDay)[int(rng.choice(3, p=TIME_OF_DAY_P))]
    weather = list(Weather)[int(rng.choice(3, p=WEATHER_P))]
    paint = PAINTS[rng.integers(len(PAINTS), size=len(track_ids))]
    rgb = np.clip(paint + rng.integers(-PAINT_JITTER, PAINT_JITTER + 1, size=paint.shape), 0, 255)
    return {
        "time_of_day": time_of_day.value,
        "weather": weather.value,
        "vehicle_colors": {tid: [int(c) for c in color] for tid, color in zip(track_ids, rgb)},
    }
