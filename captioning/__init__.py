"""Rule-based temporal captions from object tracks (host tags, neighbour lane/motion tags, text).

Public API::

    from captioning import CaptioningConfig, caption_log, caption_logs, write_outputs
"""

from captioning.config import CaptioningConfig
from captioning.errors import CaptioningError, ConfigError, TrackDataError
from captioning.pipeline import (
    BatchResult,
    Caption,
    LogCaptions,
    caption_arrays,
    caption_dense,
    caption_log,
    caption_logs,
    write_outputs,
)

__all__ = [
    "BatchResult",
    "Caption",
    "CaptioningConfig",
    "CaptioningError",
    "ConfigError",
    "LogCaptions",
    "TrackDataError",
    "caption_arrays",
    "caption_dense",
    "caption_log",
    "caption_logs",
    "write_outputs",
]
