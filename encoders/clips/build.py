"""``scenesearch clips``: captions + logs → rendered per-log arrays, a clip table and previews.

>>> report = build_clips([Path("logs/a"), Path("logs/b")], Path("captions"), Path("clips"), ClipsConfig())
>>> report.num_clips, report.skipped

Each log is one task (:func:`clip_log`: open the log, check its captions' tracks, render its arrays
into ``CLIPS_DIR/logs/<log_id>/``, cut its clip rows, write its previews), run serially or on Ray
(:mod:`scenesearch_base.ray_runner`). The driver assigns the splits and writes ``clips.parquet`` and
``manifest.json`` from the tasks' results in a fixed order, so any number of workers gives the same
files. Logs, captions and the clips folder may be ``pyarrow.fs`` URIs (:mod:`scenesearch_base.storage`): a
task stages its log locally and uploads its rendered folder and previews.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from captioning.pipeline import CAPTIONS_FILENAME, FRAME_TAGS_FILENAME
from encoders.clips.build_report import ClipsReport, log_line, manifest, missing_error
from encoders.clips.config import ClipsConfig
from encoders.clips.frame_tags import LogFrameTags, LogFrameTagsRef, empty_clip_columns, frame_tags_of
from encoders.clips.layout import (
    CAMERA_PIXEL_COUNTS_FILE,
    CLIPS_FOLDER,
    LOGS_DIR,
    MANIFEST_FILE,
    PREVIEWS_DIR,
    RENDER_FILE,
    load_rendered_array,
    preview_file_name,
    rendered_log_dir,
)
from encoders.clips.render import render_log
from encoders.clips.render_stats import LogRenderStats, read_render_stats, render_fingerprint, reuse_problem
from encoders.clips.splits import assign_splits
from encoders.clips.table import (
    CaptionRow,
    ClipsInputError,
    ClipTableSpool,
    LogCaptionRows,
    Skipped,
    captions_by_log,
    sample_frame_indices,
    window_frames,
)
from encoders.clips.views import open_log_arrays
from scenes.errors import LogFormatError
from scenes.log import Log
from scenes.tracks import DenseTracks
from scenesearch_base.atomic import atomic_write_text
from scenesearch_base.folders import claim_folder, mark_folder
from scenesearch_base.ray_cluster import Execution
from scenesearch_base.ray_runner import TaskSkipped, TaskStatus, run_tasks
from scenesearch_base.storage import (
    Location,
    copy_to_local,
    distinct_by_name,
    is_uri,
    join,
    name_of,
    parent,
    read_bytes,
    staged_input,
    staged_output,
)


@dataclass(frozen=True)
class ClipsTaskContext:
    """What every log's task shares: where the clips go and how they are made."""

    clips_dir: Location
    config: ClipsConfig
    reuse: bool = True
    #: Only check the captions' tracks against the log (a strict run that will stop anyway).
    check_only: bool = False


@dataclass
class LogClips:
    """What :func:`clip_log` made of one log: clip rows (without their split; emptied once the driver
    has spooled them) and what it skipped."""

    log_id: str
    rows: list[dict[str, Any]] = field(default_factory=list)
    num_clips: int = 0
    clips_with_camera: int = 0
    stats: dict[str, Any] | None = None
    skipped: list[dict[str, Any]] = field(default_factory=list)
    missing_tracks: dict[str, int] = field(default_factory=dict)
    render_s: float = 0.0
    table_s: float = 0.0
    preview_s: float = 0.0
    reused: bool = False
    #: Why an earlier rendering of the log could not be reused (a file changed or missing), or None.
    rerendered: str | None = None


def clip_log(job: tuple[Location, LogCaptionRows | None, LogFrameTags | LogFrameTagsRef | None],
             ctx: ClipsTaskContext) -> LogClips:
    """One log's task: ``job`` is (its folder, its caption rows (or None), its per-frame tags from
    ``frame_tags.parquet``, or where to read them there, or None).

    Raises:
        TaskSkipped: the log cannot be opened.
    """
    log_dir, captions, frame_tags = job
    rows = captions.load() if captions is not None else ()
    frame_tags = frame_tags.load() if isinstance(frame_tags, LogFrameTagsRef) else frame_tags
    log_id, config = name_of(log_dir), ctx.config
    with staged_input(log_dir) as local_log:
        try:
            log = Log.open(local_log)
        except LogFormatError as exc:
            raise TaskSkipped(f"log could not be opened: {exc}") from None
        dense = log.dense_tracks()
        tracks = {str(t) for t in dense.track_ids}
        out = LogClips(log_id)
        for row in rows:
            if row.track_id not in tracks:
                out.missing_tracks.setdefault(row.track_id, row.row)
        if ctx.check_only or (out.missing_tracks and config.strict):
            return out
        kept = [row for row in rows if row.track_id in tracks]
        if not kept:
            out.skipped.append({"log_id": log_id, "reason": "no neighbour captions for this log"})
            return out
        with _local_clips(ctx.clips_dir, log_id, config, ctx.reuse) as clips_dir:
            _render_and_cut(log, dense, kept, clips_dir, ctx, out, frame_tags)
    return out


@contextlib.contextmanager
def _local_clips(clips_dir: Location, log_id: str, config: ClipsConfig, reuse: bool) -> Iterator[Path]:
    """A local clips folder for one log's task: ``clips_dir`` itself, or for a URI a scratch folder
    (holding the log's earlier rendering when it may be reused) uploaded when the task is done."""
    if not is_uri(clips_dir):
        yield Path(clips_dir)
        return
    with staged_output(clips_dir) as scratch:
        remote = join(clips_dir, LOGS_DIR, log_id)
        with contextlib.suppress(FileNotFoundError, ValueError):
            if reuse and json.loads(read_bytes(join(remote, RENDER_FILE))).get("fingerprint") == \
                    render_fingerprint(config):
                copy_to_local(str(remote), rendered_log_dir(scratch, log_id))
        yield scratch


def _render_and_cut(log: Log, dense: DenseTracks, rows: Sequence[CaptionRow], clips_dir: Path, ctx: ClipsTaskContext,
                    out: LogClips, frame_tags: LogFrameTags | None) -> None:
    config, skipped = ctx.config, Skipped(out.skipped)
    folder = rendered_log_dir(clips_dir, log.log_id)
    t0 = time.perf_counter()
    try:
        problem = reuse_problem(folder, config, dense) if ctx.reuse else None
        if ctx.reuse and problem is None:
            stats, out.reused = read_render_stats(folder), True
        else:
            if problem is not None and folder.is_dir():
                out.rerendered = problem  # said in the log's line: a damaged rendering is never reused
            stats = render_log(log, config, clips_dir, dense)
    except LogFormatError as exc:
        # Files read lazily while rendering (the map, sweeps' folder) can still be bad: skip the log.
        skipped.add(f"log could not be rendered: {exc}", log_id=log.log_id)
        return
    out.render_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    out.rows = _clip_rows(log, dense, rows, stats, folder, config, skipped, frame_tags)
    out.num_clips, out.clips_with_camera = len(out.rows), sum(bool(r["has_camera"]) for r in out.rows)
    out.table_s = time.perf_counter() - t1
    out.stats = stats.to_dict()
    if config.previews and out.rows:
        from encoders.clips.preview import write_preview

        t2 = time.perf_counter()
        arrays = open_log_arrays(clips_dir, log.log_id)
        for clip in out.rows:
            rel = f"{PREVIEWS_DIR}/{preview_file_name(clip['clip_id'])}"
            write_preview(clips_dir, clip, clips_dir / rel, config, arrays)
            clip["preview_path"] = rel
        out.preview_s = time.perf_counter() - t2


def build_clips(
    log_dirs: Sequence[Location],
    captions_dir: Location,
    clips_dir: Location,
    config: ClipsConfig,
    progress: Callable[[str], None] | None = None,
    reuse: bool = True,
    execution: Execution | None = None,
) -> ClipsReport:
    """Render every log once, then write ``clips.parquet``, ``manifest.json`` and previews.

    Args:
        log_dirs: log folders (AV2 layout), local or URIs.
        captions_dir: folder holding ``captions.parquet`` (or the file itself).
        clips_dir: output folder.
        config: rendering and sampling options.
        progress: called with one line per log.
        reuse: keep a log's rendered arrays when they were made with an equivalent config.
        execution: where the logs' tasks run (default: serially, here).

    Raises:
        ClipsInputError: captions name logs that are not given or tracks not in their log (with
            ``config.strict``), a caption row is malformed, or no clip could be made.
        FolderClaimError: ``clips_dir`` is neither new, empty nor a clips folder, or is one of the
            inputs, lies inside one or holds one (:mod:`scenesearch_base.folders`).
    """
    say = progress or (lambda _line: None)
    claim_folder(clips_dir, CLIPS_FOLDER, [*log_dirs, captions_dir])
    if not is_uri(clips_dir):  # marked first: a run killed half way leaves a folder of its kind
        mark_folder(clips_dir, CLIPS_FOLDER, CLIPS_FOLDER.entries)
    captions_path: Location = captions_dir
    captions_folder = parent(captions_dir)
    if (not str(captions_dir).endswith(".parquet")) if is_uri(captions_dir) else Path(captions_dir).is_dir():
        captions_path, captions_folder = join(captions_dir, CAPTIONS_FILENAME), captions_dir
    with staged_input(captions_path) as local_captions:
        # A local file is read again by each log's task, for its own rows; a staged copy goes with this block.
        captions = captions_by_log(local_captions, refer=not is_uri(captions_path))
    report = ClipsReport(clips_dir=clips_dir)
    skipped = Skipped()

    given, repeated = distinct_by_name(log_dirs)
    for label, reason in repeated.items():
        skipped.add(reason, log_id=name_of(label), log_dir=label)
    try:
        frame_tags = frame_tags_of(join(captions_folder, FRAME_TAGS_FILENAME), list(given))
    except ValueError as exc:
        raise ClipsInputError(str(exc)) from None
    missing_logs = {lid: rows.first_row for lid, rows in captions.items() if lid not in given}
    ctx = ClipsTaskContext(clips_dir, config, reuse, check_only=bool(missing_logs) and config.strict)
    jobs = [(log_dir, captions.get(log_id), frame_tags.get(log_id)) for log_id, log_dir in given.items()]
    with staged_output(clips_dir) as out, ClipTableSpool(Path(out)) as table:

        def spooled(res: LogClips) -> LogClips:
            """Each log's rows go to the table's spool as its task ends: the driver never holds them all."""
            table.add(res.log_id, res.rows)
            res.rows = []
            return res

        run = run_tasks(clip_log, jobs, execution, labels=list(given), context=ctx, noun="log", consume=spooled)
        results: dict[str, LogClips] = {}
        for log_id, outcome in zip(given, run.outcomes):
            if outcome.status is TaskStatus.DONE and outcome.value is not None:
                results[log_id] = outcome.value
            elif outcome.status is TaskStatus.SKIPPED:
                skipped.add(outcome.reason, log_id=log_id)
                for row in captions[log_id].load() if log_id in captions else ():
                    skipped.add("log could not be opened", clip=row.clip_id)
            else:
                report.failed[log_id] = outcome.reason
                skipped.add(f"log failed: {outcome.reason}", log_id=log_id)
        missing_tracks = {(lid, tid): r for lid, res in results.items() for tid, r in res.missing_tracks.items()}
        if config.strict and (missing_logs or missing_tracks):
            raise missing_error(captions_path, missing_logs, missing_tracks)
        for lid, r in missing_logs.items():
            skipped.add("log not given", log_id=lid, row=r)
        for (lid, tid), r in missing_tracks.items():
            skipped.add("track not in log", log_id=lid, track_id=tid, row=r)

        splits = {log_id: split.value for log_id, split in assign_splits(results, config.split).items()}
        order = [lid for lid in captions if lid in results] + [lid for lid in results if lid not in captions]
        for log_id in order:
            res = results[log_id]
            skipped.items.extend(res.skipped)
            if res.stats is None:
                for item in res.skipped:
                    if item.get("log_id") == log_id and "could not be rendered" in item["reason"]:
                        say(f"{log_id}: skipped: {item['reason'].removeprefix('log could not be rendered: ')}")
                continue
            report.render_s += res.render_s
            report.table_s += res.table_s
            report.preview_s += res.preview_s
            report.reused_logs += int(res.reused)
            log_dir = given[log_id]
            report.logs[log_id] = {**res.stats, "clips": res.num_clips, "clips_with_camera": res.clips_with_camera,
                                   "split": splits[log_id],
                                   "log_dir": str(log_dir) if is_uri(log_dir) else str(Path(log_dir).resolve())}
            say(log_line(log_id, res.num_clips, res.stats, res.rerendered, res.reused))
        for log_id, reason in report.failed.items():
            say(f"{log_id}: failed: {reason}")

        if not table.num_rows:
            # Nothing to publish: keep whatever an earlier run wrote rather than replace it with an empty table.
            reasons = "; ".join(f"{item.get('log_id') or item.get('clip') or '?'}: {item['reason']}"
                                for item in skipped.items[:5])
            raise ClipsInputError(f"no clip could be made from {len(log_dirs)} log(s); {reasons or 'no captions'}")
        report.num_clips = table.num_rows
        mark_folder(out, CLIPS_FOLDER, CLIPS_FOLDER.entries)
        table.publish(order, splits)
        atomic_write_text(Path(out) / MANIFEST_FILE, json.dumps(manifest(config, report, skipped), indent=2,
                                                                default=str))
    report.skipped = skipped.items
    return report


def _clip_rows(
    log: Log, dense: DenseTracks, rows: Sequence[CaptionRow], stats: LogRenderStats, folder: Path,
    config: ClipsConfig, skipped: Skipped, frame_tags: LogFrameTags | None = None,
) -> list[dict[str, Any]]:
    """The log's clip rows (``split`` is set by the driver, which knows every log)."""
    frame_ts = dense.timestamps_ns
    track_index = {str(t): i for i, t in enumerate(dense.track_ids)}
    counts = load_rendered_array(folder, CAMERA_PIXEL_COUNTS_FILE)
    cam = config.camera
    appearance = log.metadata.appearance
    time_of_day = str(appearance.get("time_of_day", "unknown"))
    weather = str(appearance.get("weather", "unknown"))
    seen: set[str] = set()
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
                "split": None,
                "has_camera": has_camera,
                "bev_source": stats.bev_source,
                "time_of_day": time_of_day,
                "weather": weather,
                "frame_indices": indices.tolist(),
                "preview_path": None,
                **(frame_tags.clip_columns(row.track_id, frame_ts[indices]) if frame_tags is not None
                   else empty_clip_columns(len(indices))),
                **row.behavior,
            }
        )
    return out
