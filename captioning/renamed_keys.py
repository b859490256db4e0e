"""Config keys that older files hold and that no longer exist: refused with the key that replaces each.

The captioning rules' windows and runs were once counted in frames; they are now seconds, converted
at each log's own frame rate (:mod:`captioning.frames`). A file with a frame-count key is refused
rather than read, since a frame count means a different time at each rate.
"""

from __future__ import annotations

from collections.abc import Mapping

from captioning.errors import ConfigError

#: Frame-count keys of older config files → the seconds key that replaces each, and its default
#: in frames at 10 Hz (files with them are refused: a frame count means a different time at each rate).
RENAMED_KEYS: Mapping[str, tuple[str, str]] = {
    "smoothing.window_frames": ("smoothing.window_s", "0.9 s is 9 frames at 10 Hz"),
    "smoothing.min_run_frames": ("smoothing.min_run_s", "0.5 s is 5 frames at 10 Hz"),
    "smoothing.max_gap_frames": ("smoothing.max_gap_s", "0.3 s is 3 frames at 10 Hz"),
    "segments.min_frames": ("segments.min_s", "0.8 s is 8 frames at 10 Hz"),
    "segments.max_frames": ("segments.max_s", "30 s is 300 frames at 10 Hz"),
    "behavior.window_frames": ("behavior.window_s", "0.9 s is 9 frames at 10 Hz"),
    "behavior.accel_window_frames": ("behavior.accel_window_s", "0.5 s is 5 frames at 10 Hz"),
    "behavior.min_run_frames": ("behavior.min_run_s", "0.5 s is 5 frames at 10 Hz"),
}


def refuse_renamed_keys(data: object, source: str) -> None:
    """Raise :class:`ConfigError` naming every frame-count key of :data:`RENAMED_KEYS` in the nested
    mapping ``data`` and the seconds key that replaces it; anything else is left to the reader."""
    if not isinstance(data, Mapping):
        return
    found = [
        f"key '{old}' is now '{new}' (seconds, converted to frames at each log's frame rate; the default {note})"
        for old, (new, note) in RENAMED_KEYS.items()
        if isinstance(part := data.get(old.partition(".")[0]), Mapping) and old.partition(".")[2] in part
    ]
    if found:
        raise ConfigError(f"{source}: " + "; ".join(found))
