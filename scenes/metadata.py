"""Log metadata beyond the AV2 layout: where a log came from and how its scene looks.

Written as ``<log>/log_metadata.json``; readers work when it is absent (real AV2 logs).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

METADATA_FILENAME = "log_metadata.json"
#: ``extra`` key: true when the producer left the log's map out on purpose (a simulated log written
#: without it, as track-only real logs come), though the scene was built on one.
MAP_WITHHELD_KEY = "map_withheld"


class TimeOfDay(StrEnum):
    """Lighting of a log: the ``appearance.time_of_day`` of its metadata."""

    DAY = "day"
    DUSK = "dusk"
    NIGHT = "night"


class Weather(StrEnum):
    """Visibility of a log: the ``appearance.weather`` of its metadata."""

    CLEAR = "clear"
    RAIN = "rain"
    FOG = "fog"


@dataclass(frozen=True)
class LogMetadata:
    """What is known about a log besides its sensor data.

    Attributes:
        log_id: the log folder's name.
        source: ``av2``, ``kitti``, ``sumo`` or another producer's name.
        city_name: city code of the map (AV2 uses e.g. ``PIT``; simulated logs ``SIM``).
        appearance: scene look, e.g. ``{"time_of_day": "night", "weather": "rain",
            "vehicle_colors": {track_id: [r, g, b]}}`` (values of :class:`TimeOfDay` and
            :class:`Weather`).
        extra: anything else a producer wants to keep (simulator seed, importer counts, …).
    """

    log_id: str
    source: str = "av2"
    city_name: str = "UNKNOWN"
    appearance: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "log_id": self.log_id,
            "source": self.source,
            "city_name": self.city_name,
            "appearance": self.appearance,
            "extra": self.extra,
        }

    @staticmethod
    def from_json_dict(data: dict[str, Any]) -> LogMetadata:
        return LogMetadata(
            log_id=str(data["log_id"]),
            source=str(data.get("source", "av2")),
            city_name=str(data.get("city_name", "UNKNOWN")),
            appearance=dict(data.get("appearance", {})),
            extra=dict(data.get("extra", {})),
        )
