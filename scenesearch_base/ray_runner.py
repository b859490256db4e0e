"""Run one task per item (one log, usually): serially in this process, or on Ray.

>>> report = run_tasks(caption_one, log_dirs, Execution(workers=2), labels=[str(p) for p in log_dirs])
>>> [o.value for o in report.outcomes if o.status is TaskStatus.DONE]    # input order, whatever finished first

:class:`~scenesearch_base.ray_cluster.Execution` says where the tasks run: ``Execution()`` in this process,
one after the other; ``Execution(workers=N)`` on a Ray runtime started here with N CPUs (one task
per CPU); and ``Execution(address="HOST:PORT" | "auto")`` on an existing Ray cluster (``ray start
--head`` on its head node). A runtime already started in this process (``ray.init``) is reused and
left running. Ray is imported only when a task runs on it, so this module works without Ray installed.

Every item gets an :class:`Outcome`, in input order: ``done`` (with the task's value), ``skipped``
(the task raised :class:`TaskSkipped` or one of the ``skip_on`` errors: bad input, which another
attempt would not fix), or ``failed`` (any other error, or the worker process died on every
attempt). A worker that dies (killed, out of memory, a crash in native code) is a *system* failure:
Ray runs the task again on another worker up to ``max_retries`` times; an exception raised by the
task itself is not retried. One item's failure never stops the others.

A task's value travels back to the driver (pickled), so tasks return what the driver needs to
assemble and publish the outputs in input order, and write nothing the driver publishes itself.

On Ray, consecutive items share one Ray task where items are small: a task costs a few ms of
scheduling and messaging whatever it does, as much as captioning a short log. By default the chunk
size adapts, as joblib's ``batch_size="auto"`` does: the first items run one per task, and later
chunks hold as many items as take about ``TARGET_TASK_S`` by the mean time an item has taken so far,
capped so that the items left still spread over every worker. Each item keeps its own outcome. A
chunk whose worker dies on every attempt runs again one item per task (with its own retries), so
that only the item that kills its worker fails; the same holds for a chunk whose values cannot travel back.
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import Any, Generic, TypeVar

from scenesearch_base.ray_cluster import Execution, cluster_cpus, import_ray, one_line, ray_runtime

R = TypeVar("R")


class TaskStatus(StrEnum):
    """What became of one item."""

    DONE = "done"
    SKIPPED = "skipped"
    FAILED = "failed"


class TaskSkipped(Exception):
    """Raised by a task: its item is skipped for the reason given (bad input; not retried)."""

@dataclass(frozen=True)
class Outcome(Generic[R]):
    """One item's result: ``value`` when done, ``reason`` when skipped or failed."""

    label: str
    status: TaskStatus
    value: R | None = None
    reason: str = ""


@dataclass(frozen=True)
class RunReport(Generic[R]):
    """Every item's outcome, in input order."""

    outcomes: list[Outcome[R]]
    wall_s: float = 0.0
    execution: str = "serial"
    noun: str = "item"

    def with_status(self, status: TaskStatus) -> list[Outcome[R]]:
        return [o for o in self.outcomes if o.status is status]

    @property
    def values(self) -> list[R]:
        """The values of the items done, in input order."""
        return [o.value for o in self.outcomes if o.status is TaskStatus.DONE]  # type: ignore[misc]

    def problems(self) -> list[str]:
        """One line per item skipped or failed: ``skipped LABEL: reason``."""
        return [f"{o.status.value} {self.noun} {o.label}: {o.reason}" for o in self.outcomes
                if o.status is not TaskStatus.DONE]

    def summary(self) -> str:
        """``3 of 5 logs done, 1 skipped, 1 failed in 2.1 s (Ray, 2 local worker(s))``."""
        n = len(self.outcomes)
        done, skipped, failed = (len(self.with_status(s)) for s in TaskStatus)
        return (f"{done} of {n} {self.noun}s done, {skipped} skipped, {failed} failed in {self.wall_s:.1f} s "
                f"({self.execution})")


def _run_one(fn: Callable[..., Any], item: Any, context: Any, has_context: bool, label: str,
             skip_on: tuple[type[BaseException], ...]) -> Outcome[Any]:
    """Run one task and turn what it raised into an outcome (here or in a Ray worker)."""
    skippable: tuple[type[BaseException], ...] = (TaskSkipped, *skip_on)
    try:
        value = fn(item, context) if has_context else fn(item)
    except skippable as exc:
        return Outcome(label, TaskStatus.SKIPPED, reason=one_line(exc))
    except Exception as exc:
        return Outcome(label, TaskStatus.FAILED, reason=f"{type(exc).__name__}: {one_line(exc)}")
    return Outcome(label, TaskStatus.DONE, value)


def _run_chunk(fn: Callable[..., Any], items: Sequence[Any], context: Any, has_context: bool,
               labels: Sequence[str], skip_on: tuple[type[BaseException], ...]) -> tuple[list[Outcome[Any]], float]:
    """Run consecutive items in one Ray task → (their outcomes, the seconds they took together)."""
    start = time.perf_counter()
    outcomes = [_run_one(fn, item, context, has_context, label, skip_on) for item, label in zip(items, labels)]
    return outcomes, time.perf_counter() - start


#: Seconds of work one Ray task aims at when items are chunked: its fixed cost (a few ms) stays a
#: few percent, and a chunk is still short enough for an even share of the work between workers.
TARGET_TASK_S = 0.2


@dataclass
class ChunkSizer:
    """How many items the next Ray task takes, from the mean time an item has taken so far.

    ``fixed`` sets the size once for all (1: one item per task). Otherwise the first items run one
    per task (nothing is known of them yet), and then a chunk holds about ``target_s`` of work, at
    most a ``1 / (2 · parallelism)`` share of the items left, so that the last chunks still spread
    over every worker (a single worker takes all that is left).
    """

    parallelism: int
    fixed: int | None = None
    target_s: float = TARGET_TASK_S
    items_timed: int = 0
    seconds: float = 0.0

    def observe(self, items: int, seconds: float) -> None:
        self.items_timed += items
        self.seconds += seconds

    def size(self, remaining: int) -> int:
        if self.fixed is not None:
            return max(1, min(self.fixed, remaining))
        if self.items_timed == 0:
            return 1
        per_item_s = self.seconds / self.items_timed
        wanted = int(self.target_s / per_item_s) if per_item_s > 0 else remaining
        share = remaining if self.parallelism <= 1 else math.ceil(remaining / (2 * self.parallelism))
        return max(1, min(wanted, share, remaining))


def run_tasks(
    fn: Callable[..., R],
    items: Sequence[Any],
    execution: Execution | None = None,
    *,
    labels: Sequence[str] | None = None,
    context: Any = None,
    skip_on: tuple[type[BaseException], ...] = (),
    noun: str = "log",
    num_cpus: float = 1.0,
    items_per_task: int | None = None,
    consume: Callable[[R], Any] | None = None,
) -> RunReport[R]:
    """Run ``fn(item)`` (``fn(item, context)`` when a context is given) for every item.

    Args:
        fn: the task; on Ray it must be importable or picklable by cloudpickle (a module-level
            function is both), and so must its items, context and value.
        items: one per task.
        execution: where to run (default: serially, here).
        labels: how the report names each item (default: ``str(item)``).
        context: what every task shares (a config, a map), sent to the cluster once.
        skip_on: errors that mean bad input: the item is skipped with the error's message.
        noun: what an item is, for the progress bar and the report.
        num_cpus: CPUs one task reserves on Ray.
        items_per_task: consecutive items one Ray task runs (default: adapted to how long items
            take, see :class:`ChunkSizer`; 1: one task per item).
        consume: receives each value, in the items' order, as soon as every earlier item has ended
            (on Ray, values that come early wait for them, and no item is sent more than
            :data:`CONSUME_AHEAD_ITEMS` past the first one not yet consumed, so that a slow item never
            lets the values behind it pile up); the report keeps what it returns in the value's place,
            so that a run over many items need not hold every value. What it raises ends the run.

    Raises:
        ClusterError: Ray is not installed, or its cluster cannot be reached.
    """
    execution = execution or Execution()
    names = [str(x) for x in (labels if labels is not None else items)]
    if len(names) != len(items):
        raise ValueError(f"{len(names)} labels for {len(items)} items")
    if items_per_task is not None and items_per_task < 1:
        raise ValueError(f"items_per_task must be at least 1, not {items_per_task}")
    start = time.perf_counter()
    has_context = context is not None
    ordered = _InOrder(len(items), consume)
    with _progress(len(items), noun, execution.progress) as advance:
        if not execution.on_ray or not items:  # nothing to run: no runtime to start
            for i, (item, name) in enumerate(zip(items, names)):
                ordered.put(i, _run_one(fn, item, context, has_context, name, skip_on))
                advance()
        else:
            _run_on_ray(fn, items, names, execution, context, has_context, skip_on, num_cpus, items_per_task,
                        advance, ordered)
    return RunReport(ordered.outcomes(), time.perf_counter() - start, execution.describe(), noun)


#: With a consumer, how far past the first item not yet consumed a Ray run sends items: the most
#: values it holds while an earlier item runs on (a log's captions or clip rows, each).
CONSUME_AHEAD_ITEMS = 256


class _InOrder:
    """Outcomes as they end, each value handed to ``consume`` in the items' order (see :func:`run_tasks`)."""

    def __init__(self, n: int, consume: Callable[[Any], Any] | None) -> None:
        self._outcomes: list[Outcome[Any] | None] = [None] * n
        self._next = 0
        self._consume = consume

    def limit(self, n: int) -> int:
        """How many items may be sent so far: all of them without a consumer."""
        return n if self._consume is None else min(n, self._next + CONSUME_AHEAD_ITEMS)

    def put(self, i: int, outcome: Outcome[Any]) -> None:
        self._outcomes[i] = outcome
        while self._next < len(self._outcomes) and (ended := self._outcomes[self._next]) is not None:
            if self._consume is not None and ended.status is TaskStatus.DONE:
                self._outcomes[self._next] = replace(ended, value=self._consume(ended.value))
            self._next += 1

    def outcomes(self) -> list[Outcome[Any]]:
        return [o for o in self._outcomes if o is not None]


def _run_on_ray(fn: Callable[..., Any], items: Sequence[Any], names: list[str], execution: Execution,
                context: Any, has_context: bool, skip_on: tuple[type[BaseException], ...], num_cpus: float,
                items_per_task: int | None, advance: Callable[[], None], ordered: _InOrder) -> None:
    ray = import_ray()
    with ray_runtime(execution) as parallelism:
        # Where the runtime has no more CPUs than the run's workers, Ray keeps the run to them and a
        # window twice as wide keeps each worker's next task queued. A cluster, or a runtime started
        # before, may have more: then the window alone keeps the run to its workers.
        capped = execution.workers is not None and cluster_cpus(ray) > execution.workers
        remote = ray.remote(_run_chunk).options(num_cpus=num_cpus, max_retries=execution.max_retries,
                                                retry_exceptions=False)
        fn_ref, context_ref = _shared(ray, fn), _shared(ray, context)
        sizer = ChunkSizer(parallelism, items_per_task)
        # A bounded window of tasks in flight: enough to keep every worker busy, few enough that a
        # million items do not all sit in the scheduler at once.
        window = max(1, parallelism if capped else 2 * parallelism)
        pending: dict[Any, list[int]] = {}
        alone: deque[int] = deque()  # items of chunks whose worker died: run again one per task
        submitted = 0
        while submitted < len(items) or alone or pending:
            while (submitted < ordered.limit(len(items)) or alone) and len(pending) < window:
                if alone:  # items sent before: within the limit
                    chunk = [alone.popleft()]
                else:
                    size = min(sizer.size(len(items) - submitted), ordered.limit(len(items)) - submitted)
                    chunk = list(range(submitted, submitted + size))
                    submitted += size
                ref = remote.remote(fn_ref, [items[i] for i in chunk], context_ref, has_context,
                                    [names[i] for i in chunk], skip_on)
                pending[ref] = chunk
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                chunk = pending.pop(ref)
                try:
                    done, seconds = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    if len(chunk) > 1:  # which of them kills its worker (or fails to travel): each on its own
                        alone.extend(chunk)
                        continue
                    done = [_failure(ray, exc, names[i], execution.max_retries) for i in chunk]
                else:
                    sizer.observe(len(chunk), seconds)
                for i, outcome in zip(chunk, done):
                    ordered.put(i, outcome)
                    advance()


def _shared(ray: Any, value: Any) -> Any:
    """What every task gets: small values travel inside each task (Ray inlines them; a reference
    would cost each task a fetch), large ones are put in the object store once."""
    import pickle

    try:
        small = len(ray.cloudpickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)) <= _INLINE_BYTES
    except Exception:  # not picklable here: let Ray say so when it sends the task
        small = True
    return value if small else ray.put(value)


#: Shared values up to this size travel with each task (Ray inlines arguments below 100 KiB).
_INLINE_BYTES = 64 * 1024


def _failure(ray: Any, exc: Exception, label: str, max_retries: int) -> Outcome[Any]:
    """The outcome of an item whose task did not return."""
    if isinstance(exc, ray.exceptions.RayTaskError):  # raised outside the task's own handler (unpickling)
        return Outcome(label, TaskStatus.FAILED, reason=f"{type(exc.cause).__name__}: {one_line(exc.cause)}")
    attempts = max_retries + 1
    return Outcome(label, TaskStatus.FAILED,
                   reason=f"the worker died on each of {attempts} attempt(s) ({type(exc).__name__}: "
                          f"{one_line(exc).splitlines()[0][:300]})")


@contextlib.contextmanager
def _progress(total: int, noun: str, show: bool | None) -> Iterator[Callable[[], None]]:
    enabled = sys.stderr.isatty() if show is None else show
    if not enabled or total == 0:
        yield lambda: None
        return
    from tqdm import tqdm

    with tqdm(total=total, desc=f"{noun}s", unit=noun, leave=False, file=sys.stderr) as bar:
        yield lambda: bar.update(1)

