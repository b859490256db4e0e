"""Captioning many log folders in one run: one task per log, serially or on Ray
(:mod:`scenesearch_base.ray_runner`), each log's captions written as they come when a writer is given
(:class:`captioning.outputs.CaptionsWriter`), so that a fleet's logs are never all in memory."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

from captioning.config import CaptioningConfig
from captioning.pipeline import LogCaptions, caption_log
from scenes.errors import ScenesError
from scenes.log import Log
from scenesearch_base.ray_cluster import Execution
from scenesearch_base.ray_runner import TaskSkipped, TaskStatus, run_tasks
from scenesearch_base.storage import distinct_by_name, staged_input


@dataclass(frozen=True)
class LogSummary:
    """What a captioned log holds, in counts (what a batch run reports of it)."""

    log_id: str
    frames: int
    tracks: int
    stationary_tracks: int
    object_frames: int
    captions: int
    skipped_tracks: dict[str, str]
    notes: list[str]

    @staticmethod
    def of(result: LogCaptions) -> LogSummary:
        return LogSummary(result.log_id, len(result.timestamps_ns), len(result.track_ids),
                          int(result.neighbors.stationary.sum()), int(result.valid.sum()), len(result.captions),
                          dict(result.skipped_tracks), list(result.notes))


@dataclass(frozen=True)
class BatchResult:
    """Captions of many logs, and what was skipped.

    Attributes:
        results: captioned logs, in input order (none when they were written as they came).
        summaries: each captioned log in counts, in input order.
        skipped_logs: log folder → reason (it cannot be read or captioned).
        failed_logs: log folder → reason (an unexpected error, or its worker died on every attempt).
    """

    results: list[LogCaptions]
    summaries: list[LogSummary]
    skipped_logs: dict[str, str]
    failed_logs: dict[str, str] = field(default_factory=dict)


def caption_log_dir(log_dir: Path | str, config: CaptioningConfig) -> LogCaptions:
    """Caption one log folder, a local path or a ``pyarrow.fs`` URI (staged locally): the task of
    :func:`caption_logs`, in this process or on a Ray worker.

    Raises:
        TaskSkipped: the log has no annotated frames.
        ScenesError, ValueError, OSError: the log cannot be read or captioned.
    """
    with staged_input(log_dir) as local:
        log = Log.open(local)
        if log.timestamps_ns.size == 0:
            raise TaskSkipped("log has no annotated frames")
        return caption_log(log, config)


def caption_logs(log_dirs: Iterable[Path | str], config: CaptioningConfig | None = None,
                 execution: Execution | None = None,
                 write: Callable[[LogCaptions], None] | None = None) -> BatchResult:
    """Caption many log folders, one task per log (serially by default, or on Ray); a log that
    cannot be read or captioned, or given twice, is skipped with its reason; results keep the input order.

    With ``write`` (:meth:`captioning.outputs.CaptionsWriter.add`), each log's captions go to it in
    the input order as soon as they are made, and only their summaries are kept: a fleet's logs are
    never all in memory."""
    given, repeated = distinct_by_name(list(log_dirs))
    dirs = list(given.values())

    def written(result: LogCaptions) -> LogSummary:
        assert write is not None
        write(result)
        return LogSummary.of(result)

    report = run_tasks(caption_log_dir, dirs, execution, labels=[str(d) for d in dirs],
                       context=config or CaptioningConfig(), skip_on=(ScenesError, ValueError, OSError),
                       consume=None if write is None else written)
    results = report.values if write is None else []
    # With a writer the report holds what ``written`` returned for each log: its summary.
    summaries = [LogSummary.of(r) for r in results] if write is None else cast(list[LogSummary], report.values)
    skipped = {o.label: o.reason for o in report.with_status(TaskStatus.SKIPPED)}
    return BatchResult(results, summaries, {**skipped, **repeated},
                       {o.label: o.reason for o in report.with_status(TaskStatus.FAILED)})
