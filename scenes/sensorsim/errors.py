"""Errors of the sensor simulation."""

from __future__ import annotations

from pathlib import Path

from scenes.errors import ScenesError


class SensorSimError(ScenesError):
    """Sensors cannot be rendered for a log."""


class BadObjectError(SensorSimError):
    """An object cannot be rendered: a box of non-positive size, or a box that holds a sensor.

    Attributes:
        path: the annotations file the object comes from (or the log folder).
        track_id: the object's track.
        frame: 0-based frame index on the log's frame grid.
        timestamp_ns: the frame's timestamp.
        field: the annotation field at fault.
    """

    def __init__(self, path: Path | str, track_id: str, frame: int, timestamp_ns: int, field: str,
                 message: str) -> None:
        self.path = Path(path)
        self.track_id = track_id
        self.frame = frame
        self.timestamp_ns = timestamp_ns
        self.field = field
        super().__init__(
            f"{self.path}, track '{track_id}', frame {frame} (timestamp_ns {timestamp_ns}), field '{field}': {message}"
        )
