"""Errors of the captioning stage."""

from __future__ import annotations

import scenesearch_base.config
from scenes.errors import ScenesError, TrackFrameError


class CaptioningError(ScenesError):
    """Base class of every error raised by :mod:`captioning`."""


class ConfigError(CaptioningError, scenesearch_base.config.ConfigError):
    """A captioning configuration is malformed or its thresholds contradict each other."""


class TrackDataError(CaptioningError, TrackFrameError, ValueError):
    """In-memory track or pose data that cannot be captioned (e.g. NaN); names log, track, frame, field."""

    def __init__(self, log_id: str, track_id: str, frame: int, timestamp_ns: int, field: str, message: str) -> None:
        self.log_id = log_id
        super().__init__(f"log {log_id}, track {track_id}", track_id, frame, timestamp_ns, field, message)
