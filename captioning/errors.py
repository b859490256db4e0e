"""Errors of the captioning stage."""

from __future__ import annotations

import scenesearch_base.config
from scenes.errors import ScenesError


class CaptioningError(ScenesError):
    """Base class of every error raised by :mod:`captioning`."""


class ConfigError(CaptioningError, scenesearch_base.config.ConfigError):
    """A captioning configuration is malformed or its thresholds contradict each other."""


class TrackDataError(CaptioningError, ValueError):
    """In-memory track or pose data that cannot be captioned (e.g. NaN); names log, track, frame, field."""

    def __init__(self, log_id: str, track_id: str, frame: int, timestamp_ns: int, field: str, message: str) -> None:
        self.log_id = log_id
        self.track_id = track_id
        self.frame = frame
        self.timestamp_ns = timestamp_ns
        self.field = field
        super().__init__(
            f"log {log_id}, track {track_id}, frame {frame} (timestamp_ns {timestamp_ns}), field '{field}': {message}"
        )
