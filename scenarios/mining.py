"""Scenario mining: descriptions compiled once, answered on every log from its cached features.

>>> run = mine([Path("logs/a"), Path("logs/b")], ["vehicle with a bicycle to its right"], cache_dir=Path("feat"))
>>> write_submission(run.answers, "predictions.pkl")

Each log is one task (:func:`mine_log`: features from the cache or built, then every program),
serially or on Ray (:mod:`scenesearch_base.ray_runner`); answers keep the logs' order, then the descriptions'.
A log that cannot be read is skipped with its reason; a description that names nothing is refused
before any log is read. A log given twice (the same folder, or two of one log id) is answered once and
the repeat reported.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from captioning.config import CaptioningConfig
from scenarios.answer import LogAnswer
from scenarios.cache import cached_features, claim_cache
from scenarios.compiler import Compiled, compile_description
from scenarios.evaluate import answer, grouped_notes
from scenes.errors import ScenesError
from scenesearch_base.ray_cluster import Execution
from scenesearch_base.ray_runner import TaskStatus, run_tasks
from scenesearch_base.storage import distinct_by_name


@dataclass(frozen=True)
class MiningContext:
    """What every log's task shares."""

    compiled: tuple[Compiled, ...]
    cache_dir: Path | None
    config: CaptioningConfig


@dataclass
class LogMining:
    """One log's answers (one per description, in order) and the notes of what it could not answer."""

    log_id: str
    answers: list[LogAnswer]
    notes: list[str]
    cached: bool
    seconds: float


@dataclass
class MiningRun:
    """A mining run over many logs.

    Attributes:
        compiled: each description as compiled, in order.
        answers: one per (log, description), logs in order.
        notes: what some logs could not answer (a map, recorded weather), once per reason, naming the logs.
        skipped: log → why it was skipped.
        cached: logs whose features came from the cache.
        seconds: wall time of the run.
    """

    compiled: list[Compiled]
    answers: list[LogAnswer] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    cached: int = 0
    seconds: float = 0.0


def compile_all(descriptions: Sequence[str]) -> list[Compiled]:
    """Each description compiled (programs in the program syntax are read as such).

    Raises:
        DescriptionError: a description names nothing (the message names it and its unknown words).
    """
    return [compile_description(text) for text in descriptions]


def mine_log(log_dir: Path, ctx: MiningContext) -> LogMining:
    """One log's task: its features (cached or built), then each program's answer."""
    start = time.perf_counter()
    features, cached = cached_features(log_dir, ctx.cache_dir, ctx.config)
    answers, notes = [], []
    for compiled in ctx.compiled:
        result, said = answer(compiled.program, features, compiled.description)
        answers.append(result)
        notes += [n for n in said if n not in notes]
    return LogMining(features.log_id, answers, notes, cached, time.perf_counter() - start)


def mine(log_dirs: Sequence[Path], descriptions: Sequence[str], cache_dir: Path | None = None,
         config: CaptioningConfig | None = None, execution: Execution | None = None) -> MiningRun:
    """Answer every description on every log (see the module docstring).

    Args:
        log_dirs: log folders (AV2 layout).
        descriptions: descriptions, or programs in the program syntax.
        cache_dir: where per-log features are kept between runs (None: built each time, kept nowhere).
        config: the captioning rules' thresholds the features are built with.
        execution: where the logs' tasks run (default: serially).

    Raises:
        DescriptionError: a description names nothing.
        FolderClaimError: ``cache_dir`` is a folder of something else.
    """
    start = time.perf_counter()
    compiled = compile_all(descriptions)
    if cache_dir is not None:
        claim_cache(cache_dir, list(log_dirs))
    given, repeated = distinct_by_name(list(log_dirs))
    dirs = [Path(d) for d in given.values()]
    ctx = MiningContext(tuple(compiled), cache_dir, config or CaptioningConfig())
    report = run_tasks(mine_log, dirs, execution, labels=[str(d) for d in dirs], context=ctx,
                       skip_on=(ScenesError, ValueError, OSError))
    run = MiningRun(compiled, skipped=dict(repeated))
    said: list[tuple[str, str]] = []
    for log_dir, outcome in zip(dirs, report.outcomes):
        if outcome.status is TaskStatus.DONE and outcome.value is not None:
            run.answers += outcome.value.answers
            said += [(outcome.value.log_id, note) for note in outcome.value.notes]
            run.cached += int(outcome.value.cached)
        else:
            run.skipped[str(log_dir)] = outcome.reason
    run.notes = list(grouped_notes(said))
    run.seconds = time.perf_counter() - start
    return run
