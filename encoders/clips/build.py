"""``scenesearch clips``: captions + logs → rendered per-log arrays, a clip table and previews.

>>> report = build_clips([Path("logs/a"), Path("logs/b")], Path("captions"), Path("clips"), ClipsConfig())
>>> report.num_clips, report.skipped
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from captioning.pipeline import CAPTIONS_FILENAME
from common.atomic import atomic_write_text
from encoders.clips.config import ClipsConfig
from encoders.clips.layout import (
    CAMERA_PIXEL_COUNTS_FILE,
    MANIFEST_FILE,
    PREVIEWS_DIR,
    preview_file_name,
    rendered_log_dir,
)
from encoders.clips.raster import MAP_CHANNELS
from encoders.clips.render import bev_grid, lidar_channel_names, render_log
from encoders.clips.render_stats import LogRenderStats, read_render_stats, rendered_log_ok
from encoders.clips.splits import assign_splits
from encoders.clips.table import (
    CaptionRow,
    ClipsInputError,
    Skipped,
    read_captions,
    sample_frame_indices,
    window_frames,
    write_clip_table,
)
from scenes.errors import LogFormatError
from scenes.log import Log
from scenes.tracks import DenseTracks

FORMAT_VERSION = 1


@dataclass
class ClipsReport:
    """What a run produced and what it skipped (with reasons)."""

    clips_dir: Path
    num_clips: int = 0
    logs: dict[str, dict[str, Any]] = field(default_factory=dict)
    skipped: list[dict[str, Any]] = field(default_factory=list)
    render_s: float = 0.0
    table_s: float = 0.0
    preview_s: float = 0.0
    reused_logs: int = 0


def _check_references(
    captions_path: Path, rows: list[CaptionRow], logs: dict[str, Log], dense: dict[str, DenseTracks],
    unreadable: set[str], config: ClipsConfig, skipped: Skipped,
) -> list[CaptionRow]:
    """Captions whose log and track exist; the others raise (strict) or are skipped."""
    missing_logs: dict[str, int] = {}
    missing_tracks: dict[tuple[str, str], int] = {}
    kept: list[CaptionRow] = []
    track_sets = {log_id: {str(t) for t in d.track_ids} for log_id, d in dense.items()}
    for row in rows:
        if row.log_id in unreadable:
            skipped.add("log could not be opened", clip=row.clip_id)
        elif row.log_id not in logs:
            missing_logs.setdefault(row.log_id, row.row)
        elif row.track_id not in track_sets[row.log_id]:
            missing_tracks.setdefault((row.log_id, row.track_id), row.row)
        else:
            kept.append(row)
    if missing_logs or missing_tracks:
        parts = []
        if missing_logs:
            named = ", ".join(f"{lid} (first at row {r})" for lid, r in list(missing_logs.items())[:10])
            more = f" and {len(missing_logs) - 10} more" if len(missing_logs) > 10 else ""
            parts.append(f"field 'log_id': {len(missing_logs)} log(s) not among the given logs: {named}{more}")
        if missing_tracks:
            named = ", ".join(f"{lid}/{tid} (row {r})" for (lid, tid), r in list(missing_tracks.items())[:10])
            more = f" and {len(missing_tracks) - 10} more" if len(missing_tracks) > 10 else ""
            parts.append(f"field 'track_id': {len(missing_tracks)} track(s) not in their log: {named}{more}")
        if config.strict:
            raise ClipsInputError(f"{captions_path}: " + "; ".join(parts))
        for lid, r in missing_logs.items():
            skipped.add("log not given", log_id=lid, row=r)
        for (lid, tid), r in missing_tracks.items():
            skipped.add("track not in log", log_id=lid, track_id=tid, row=r)
    return kept


def build_clips(
    log_dirs: Sequence[Path],
    captions_dir: Path,
    clips_dir: Path,
    config: ClipsConfig,
    progress: Callable[[str], None] | None = None,
    reuse: bool = True,
) -> ClipsReport:
    """Render every log once, then write ``clips.parquet``, ``manifest.json`` and previews.

    Args:
        log_dirs: log folders (AV2 layout).
        captions_dir: folder holding ``captions.parquet`` (or the file itself).
        clips_dir: output folder.
        config: rendering and sampling options.
        progress: called with one line per log.
        reuse: keep a log's rendered arrays when they were made with an equivalent config.

    Raises:
        ClipsInputError: captions name logs that are not given or tracks not in their log (with
            ``config.strict``), or a caption row is malformed.
    """
    say = progress or (lambda _line: None)
    clips_dir = Path(clips_dir)
    captions_path = Path(captions_dir)
    if captions_path.is_dir():
        captions_path = captions_path / CAPTIONS_FILENAME
    rows = read_captions(captions_path)
    report = ClipsReport(clips_dir=clips_dir)
    skipped = Skipped()

    logs: dict[str, Log] = {}
    dense: dict[str, DenseTracks] = {}
    unreadable: set[str] = set()
    for log_dir in log_dirs:
        try:
            log = Log.open(log_dir)
        except LogFormatError as exc:
            unreadable.add(Path(log_dir).name)
            skipped.add(f"log could not be opened: {exc}", log_id=Path(log_dir).name)
            continue
        if log.log_id in logs:
            skipped.add(f"log given twice (kept {logs[log.log_id].log_dir})", log_id=log.log_id)
            continue
        logs[log.log_id] = log
        dense[log.log_id] = log.dense_tracks()
    rows = _check_references(captions_path, rows, logs, dense, unreadable, config, skipped)

    by_log: dict[str, list[CaptionRow]] = {}
    for row in rows:
        by_log.setdefault(row.log_id, []).append(row)
    for log_id in logs:
        if log_id not in by_log:
            skipped.add("no neighbour captions for this log", log_id=log_id)
    splits = assign_splits(logs.keys(), config.split)
    grid = bev_grid(config)

    clip_rows: list[dict[str, Any]] = []
    seen: set[str] = set()
    for log_id, log_rows in by_log.items():
        log = logs[log_id]
        folder = rendered_log_dir(clips_dir, log_id)
        t0 = time.perf_counter()
        try:
            if reuse and rendered_log_ok(folder, config, dense[log_id]):
                stats = read_render_stats(folder)
                report.reused_logs += 1
            else:
                stats = render_log(log, config, clips_dir, dense[log_id])
        except LogFormatError as exc:
            # Files read lazily while rendering (the map, sweeps' folder) can still be bad: skip the log.
            skipped.add(f"log could not be rendered: {exc}", log_id=log_id)
            say(f"{log_id}: skipped: {exc}")
            continue
        report.render_s += time.perf_counter() - t0
        t1 = time.perf_counter()
        new_rows = _clip_rows(log, dense[log_id], log_rows, stats, folder, splits[log_id].value, config,
                              skipped, seen)
        clip_rows.extend(new_rows)
        report.table_s += time.perf_counter() - t1
        entry = stats.to_dict()
        entry["clips"] = len(new_rows)
        entry["clips_with_camera"] = int(sum(r["has_camera"] for r in new_rows))
        entry["split"] = splits[log_id].value
        report.logs[log_id] = entry
        extra = ""
        if stats.corrupt_sweeps:
            extra += f", {len(stats.corrupt_sweeps)} corrupt sweep(s) skipped"
        if stats.corrupt_camera_frames:
            extra += f", {len(stats.corrupt_camera_frames)} corrupt camera file(s) skipped"
        say(f"{log_id}: {len(new_rows)} clips, {stats.frames} frames, bev={stats.bev_source}, "
            f"camera frames={stats.camera_frames}{extra}")

    if config.previews and clip_rows:
        from encoders.clips.preview import write_preview

        t2 = time.perf_counter()
        for clip in clip_rows:
            rel = f"{PREVIEWS_DIR}/{preview_file_name(clip['clip_id'])}"
            write_preview(clips_dir, clip, clips_dir / rel, config)
            clip["preview_path"] = rel
        report.preview_s = time.perf_counter() - t2

    if not clip_rows:
        # Nothing to publish: keep whatever an earlier run wrote rather than replace it with an empty table.
        reasons = "; ".join(f"{item.get('log_id') or item.get('clip') or '?'}: {item['reason']}"
                            for item in skipped.items[:5])
        raise ClipsInputError(f"no clip could be made from {len(log_dirs)} log(s); {reasons or 'no captions'}")
    write_clip_table(clips_dir, clip_rows)
    manifest = {
        "format_version": FORMAT_VERSION,
        "frames_per_clip": config.frames_per_clip,
        "camera": {
            "name": config.camera.camera_name,
            "height_px": config.camera.height_px,
            "width_px": config.camera.width_px,
            "channels": 4,
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
        "num_clips": len(clip_rows),
    }
    atomic_write_text(clips_dir / MANIFEST_FILE, json.dumps(manifest, indent=2, default=str))
    report.num_clips = len(clip_rows)
    report.skipped = skipped.items
    return report


def _clip_rows(
    log: Log, dense: DenseTracks, rows: list[CaptionRow], stats: LogRenderStats, folder: Path, split: str,
    config: ClipsConfig, skipped: Skipped, seen: set[str],
) -> list[dict[str, Any]]:
    frame_ts = dense.timestamps_ns
    track_index = {str(t): i for i, t in enumerate(dense.track_ids)}
    counts = np.load(folder / CAMERA_PIXEL_COUNTS_FILE, mmap_mode="r")
    cam = config.camera
    appearance = log.metadata.appearance
    time_of_day = str(appearance.get("time_of_day", "unknown"))
    weather = str(appearance.get("weather", "unknown"))
    out: list[dict[str, Any]] = []
    for row in rows:
        if row.clip_id in seen:
            skipped.add("duplicate clip_id", clip=row.clip_id, row=row.row)
            continue
        window = window_frames(frame_ts, row.start_ns, row.end_ns, config.window_tolerance_ns)
        if window is None:
            lo, hi = (int(frame_ts[0]), int(frame_ts[-1])) if frame_ts.shape[0] else (0, 0)
            skipped.add(f"window {row.start_ns}..{row.end_ns} outside the log's time range {lo}..{hi}",
                        clip=row.clip_id, row=row.row)
            continue
        seen.add(row.clip_id)
        indices = sample_frame_indices(window[0], window[1], config.frames_per_clip)
        k = track_index[row.track_id]
        visible = np.asarray(counts[indices, k]) >= cam.min_mask_px if counts.shape[0] else np.zeros(1, bool)
        has_camera = bool(stats.camera_frames > 0 and visible.mean() >= cam.min_visible_fraction)
        out.append(
            {
                "clip_id": row.clip_id,
                "log_id": row.log_id,
                "track_id": row.track_id,
                "category": row.category,
                "start_ns": row.start_ns,
                "end_ns": row.end_ns,
                "caption": row.caption,
                "canonical_caption": row.canonical_caption,
                "paraphrases": row.paraphrases,
                "tags": row.tags,
                "host_tags": row.host_tags,
                "split": split,
                "has_camera": has_camera,
                "bev_source": stats.bev_source,
                "time_of_day": time_of_day,
                "weather": weather,
                "frame_indices": indices.tolist(),
                "preview_path": None,
                **row.behavior,
            }
        )
    return out
