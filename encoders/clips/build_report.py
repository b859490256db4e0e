"""What ``scenesearch clips`` reports: the run's :class:`ClipsReport`, each log's progress line, the
error for captions that name logs or tracks not given, and the clips folder's ``manifest.json``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from encoders.clips.config import ClipsConfig
from encoders.clips.layout import CLIPS_FORMAT_VERSION
from encoders.clips.raster import MAP_CHANNELS
from encoders.clips.render import bev_grid, lidar_channel_names
from encoders.clips.table import ClipsInputError, Skipped
from scenesearch_base.storage import Location


@dataclass
class ClipsReport:
    """What a run produced and what it skipped (with reasons); ``failed``: logs whose task failed."""

    clips_dir: Location
    num_clips: int = 0
    logs: dict[str, dict[str, Any]] = field(default_factory=dict)
    skipped: list[dict[str, Any]] = field(default_factory=list)
    render_s: float = 0.0
    table_s: float = 0.0
    preview_s: float = 0.0
    reused_logs: int = 0
    failed: dict[str, str] = field(default_factory=dict)


def missing_error(captions_path: Location, missing_logs: dict[str, int],
                  missing_tracks: dict[tuple[str, str], int]) -> ClipsInputError:
    """The error of a strict run whose captions name logs not given (by their first row) or tracks
    not in their log (by their row)."""
    parts = []
    if missing_logs:
        named = ", ".join(f"{lid} (first at row {r})" for lid, r in list(missing_logs.items())[:10])
        more = f" and {len(missing_logs) - 10} more" if len(missing_logs) > 10 else ""
        parts.append(f"field 'log_id': {len(missing_logs)} log(s) not among the given logs: {named}{more}")
    if missing_tracks:
        named = ", ".join(f"{lid}/{tid} (row {r})" for (lid, tid), r in list(missing_tracks.items())[:10])
        more = f" and {len(missing_tracks) - 10} more" if len(missing_tracks) > 10 else ""
        parts.append(f"field 'track_id': {len(missing_tracks)} track(s) not in their log: {named}{more}")
    return ClipsInputError(f"{captions_path}: " + "; ".join(parts))


def log_line(log_id: str, num_clips: int, stats: dict[str, Any], rerendered: str | None, reused: bool) -> str:
    """One log's progress line: its clips and frames, and what went wrong or was reused."""
    extra = ""
    if stats.get("corrupt_sweeps"):
        extra += f", {len(stats['corrupt_sweeps'])} corrupt sweep(s) skipped"
    if stats.get("corrupt_camera_frames"):
        extra += f", {len(stats['corrupt_camera_frames'])} corrupt camera file(s) skipped"
    if stats.get("camera_frames") and stats.get("camera_mask_source") == "none":
        extra += (", no object masks from the camera: it has no intrinsics or no extrinsics row in the calibration "
                  "(so no clip has the camera)")
    if rerendered:
        extra += f"; rendered again, the earlier rendering not reused: {rerendered}"
    elif reused:
        extra += "; reused (every file verified)"
    return (f"{log_id}: {num_clips} clips, {stats.get('frames')} frames, bev={stats.get('bev_source')}, "
            f"camera frames={stats.get('camera_frames')}{extra}")


def manifest(config: ClipsConfig, report: ClipsReport, skipped: Skipped) -> dict[str, Any]:
    """The clips folder's ``manifest.json``: the clips' layout, every log's entry, what was skipped."""
    grid = bev_grid(config)
    return {
        "format_version": CLIPS_FORMAT_VERSION,
        "frames_per_clip": config.frames_per_clip,
        "camera": {
            "name": config.camera.camera_name,
            "height_px": config.camera.height_px,
            "width_px": config.camera.width_px,
            "channels": 4,
            "object_crops": True,
            "highlight_rgb": list(config.camera.highlight_rgb),
            "highlight_alpha": config.camera.highlight_alpha,
            "dim_factor": config.camera.dim_factor,
        },
        "bev": {
            "x_min_m": grid.x_min_m,
            "x_max_m": grid.x_max_m,
            "y_min_m": grid.y_min_m,
            "y_max_m": grid.y_max_m,
            "resolution_m": grid.resolution_m,
            "height_px": grid.height,
            "width_px": grid.width,
            "lidar_channels": lidar_channel_names(config.bev.z_bins_m),
            "map_channels": list(MAP_CHANNELS),
        },
        "logs": report.logs,
        "config": config.to_dict(),
        "skipped": skipped.items,
        "num_clips": report.num_clips,
    }
