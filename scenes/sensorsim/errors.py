"""Errors of the sensor simulation."""

from __future__ import annotations

from pathlib import Path

from scenes.errors import ScenesError, TrackFrameError


class SensorSimError(ScenesError):
    """Sensors cannot be rendered for a log."""


class BadObjectError(SensorSimError, TrackFrameError):
    """An object cannot be rendered: a box of non-positive size, or a box that holds a sensor.

    Attributes:
        path: the annotations file the object comes from (or the log folder); the track, the frame (on
            the log's frame grid) and the annotation field at fault as :class:`TrackFrameError`'s.
    """

    def __init__(self, path: Path | str, track_id: str, frame: int, timestamp_ns: int, field: str,
                 message: str) -> None:
        self.path = Path(path)
        super().__init__(f"{self.path}, track '{track_id}'", track_id, frame, timestamp_ns, field, message)
