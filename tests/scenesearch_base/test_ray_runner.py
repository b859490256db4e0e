"""One task per item, serially or on Ray: order, skips, failures, retries after a worker died,
items chunked into shared Ray tasks, and a clear error for a cluster address that does not answer."""

from __future__ import annotations

import socket
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

import ray_tasks

from scenesearch_base.ray_cluster import ClusterError, Execution, check_reachable, ray_runtime, split_address
from scenesearch_base.ray_runner import ChunkSizer, TaskSkipped, TaskStatus, run_tasks


def _square(x: int) -> int:
    if x == 3:
        raise TaskSkipped("three is skipped")
    if x == 4:
        raise ValueError("four is bad input")
    if x == 5:
        raise RuntimeError("five is a bug")
    return x * x


def test_serial_run_keeps_order_and_reports_every_item() -> None:
    report = run_tasks(_square, [1, 2, 3, 4, 5, 6], labels=list("abcdef"), skip_on=(ValueError,))
    assert [o.status for o in report.outcomes] == [TaskStatus.DONE] * 2 + [TaskStatus.SKIPPED] * 2 + [
        TaskStatus.FAILED, TaskStatus.DONE]
    assert report.values == [1, 4, 36]
    assert report.problems() == ["skipped log c: three is skipped", "skipped log d: four is bad input",
                                 "failed log e: RuntimeError: five is a bug"]
    assert report.summary().startswith("3 of 6 logs done, 2 skipped, 1 failed in ")
    assert report.execution == "serial"


def test_execution_from_flags_and_bad_values() -> None:
    class Args:
        workers, ray_address = 3, None

    assert Execution.from_args(Args()) == Execution(workers=3)
    assert Execution(workers=2).on_ray and not Execution().on_ray
    with pytest.raises(ValueError, match=r"--workers must lie in \[1, 4096\], got 0"):
        Execution(workers=0)
    with pytest.raises(ValueError, match="labels"):
        run_tasks(_square, [1, 2], labels=["a"])


@pytest.mark.parametrize(("address", "expected"), [
    ("10.0.0.5:6380", ("10.0.0.5", 6380)), ("head", ("head", 6379)), ("ray://head", ("head", 10001)),
    ("ray://head:1234", ("head", 1234)), ("[::1]:7000", ("::1", 7000)),
])
def test_addresses_are_parsed(address: str, expected: tuple[str, int]) -> None:
    assert split_address(address) == expected


def test_bad_addresses_are_named() -> None:
    with pytest.raises(ClusterError, match="port 'x' is not a number"):
        split_address("head:x")
    with pytest.raises(ClusterError, match="expected HOST:PORT"):
        split_address("http://head:6379")


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.usefixtures("ray_stopped")
def test_an_unreachable_address_is_a_clear_error_within_seconds() -> None:
    port = _closed_port()
    start = time.perf_counter()
    with pytest.raises(ClusterError, match=rf"cannot reach a Ray cluster at 127.0.0.1:{port}.*ray start --head"):
        run_tasks(_square, [1], Execution(address=f"127.0.0.1:{port}", connect_timeout_s=2))
    assert time.perf_counter() - start < 5
    # A routable address where nothing answers: bounded by the connect timeout, not Ray's minute.
    start = time.perf_counter()
    with pytest.raises(ClusterError, match="cannot reach"):
        check_reachable("192.0.2.1:6379", timeout_s=1.0)  # TEST-NET-1: never routed
    assert time.perf_counter() - start < 4


def test_auto_without_a_cluster_says_how_to_start_one(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr("tempfile.gettempdir", lambda: str(tmp_path))
    with pytest.raises(ClusterError, match=r"auto: no Ray cluster runs on this machine.*ray start --head"):
        check_reachable("auto")


@pytest.mark.usefixtures("ray_stopped")
def test_a_listener_that_is_not_a_ray_head_is_refused_quickly() -> None:
    pytest.importorskip("ray")
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    port = server.getsockname()[1]

    def answer() -> None:  # an HTTP server, say: it answers, but not in Ray's protocol
        for _ in range(20):
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.sendall(b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\n\r\n")
            conn.close()

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    start = time.perf_counter()
    try:
        with pytest.raises(ClusterError, match=f"127.0.0.1:{port}"), \
                ray_runtime(Execution(address=f"127.0.0.1:{port}", connect_timeout_s=2)):
            pass
    finally:
        server.close()
    assert time.perf_counter() - start < 8


@pytest.mark.usefixtures("ray_local")
def test_on_ray_order_retries_and_failures(tmp_path: Path) -> None:
    import ray

    ray.cloudpickle.register_pickle_by_value(ray_tasks)
    items = ["a", "dies-once", "bad", "dies-always", "bug", "b"]
    report = run_tasks(ray_tasks.crashing, items, Execution(workers=2, max_retries=1), context=str(tmp_path),
                       skip_on=(ValueError,))
    by_label = {o.label: o for o in report.outcomes}
    assert [o.label for o in report.outcomes] == items
    # The worker that died on the first attempt was replaced and the task ran again.
    assert by_label["dies-once"].status is TaskStatus.DONE and (tmp_path / "dies-once.tried").exists()
    assert by_label["dies-always"].status is TaskStatus.FAILED
    assert "worker died on each of 2 attempt(s)" in by_label["dies-always"].reason
    assert (tmp_path / "attempts").read_text() == "xx"
    assert by_label["bad"].status is TaskStatus.SKIPPED and by_label["bad"].reason == "bad input: no such frame"
    assert by_label["bug"].status is TaskStatus.FAILED and by_label["bug"].reason == "KeyError: 'oops'"
    assert by_label["a"].value.startswith("a:") and by_label["b"].value.startswith("b:")  # type: ignore[union-attr]
    assert "Ray, 2 local worker(s)" in report.summary()


def test_chunk_sizes_follow_item_time_and_leave_work_for_every_worker() -> None:
    sizer = ChunkSizer(parallelism=2, target_s=0.2)
    assert sizer.size(100) == 1  # nothing known yet: one item per task
    sizer.observe(items=2, seconds=0.02)  # 10 ms an item: 20 items make a task of 0.2 s
    assert sizer.size(100) == 20
    assert sizer.size(24) == 6  # a quarter of what is left: both workers still get work at the end
    assert sizer.size(1) == 1
    sizer.observe(items=1, seconds=1.0)  # slow items: back to one per task
    assert sizer.size(100) == 1
    alone = ChunkSizer(parallelism=1, target_s=0.2)
    alone.observe(items=1, seconds=0.01)
    assert alone.size(7) == 7  # a single worker takes all that is left when it is short
    fixed = ChunkSizer(parallelism=2, fixed=3)
    assert [fixed.size(n) for n in (10, 2)] == [3, 2]


def test_items_per_task_must_be_positive() -> None:
    with pytest.raises(ValueError, match="items_per_task"):
        run_tasks(_square, [1], items_per_task=0)


@pytest.mark.usefixtures("ray_local")
def test_chunked_tasks_keep_each_item_outcome_and_isolate_a_worker_killer(tmp_path: Path) -> None:
    import ray

    ray.cloudpickle.register_pickle_by_value(ray_tasks)
    items = ["a", "b", "dies-always", "bad", "c", "d", "bug"]
    report = run_tasks(ray_tasks.crashing, items, Execution(workers=2, max_retries=1), context=str(tmp_path),
                       skip_on=(ValueError,), items_per_task=3)
    by_label = {o.label: o for o in report.outcomes}
    assert [o.label for o in report.outcomes] == items
    # Its chunk died twice (one retry), then it ran alone twice: its chunk-mates were run again alone and are done.
    assert by_label["dies-always"].status is TaskStatus.FAILED
    assert (tmp_path / "attempts").read_text() == "xxxx"
    assert [by_label[x].status for x in ("a", "b", "c", "d")] == [TaskStatus.DONE] * 4
    assert by_label["bad"].status is TaskStatus.SKIPPED and by_label["bug"].status is TaskStatus.FAILED
    # Chunk-mates ran in one process: a chunk is one task.
    pid = {x: by_label[x].value.split(":")[1] for x in ("c", "d")}  # type: ignore[union-attr]
    assert pid["c"] == pid["d"]


@pytest.mark.usefixtures("ray_local")
def test_adaptive_chunks_give_the_serial_results() -> None:
    items = list(range(40))
    serial = run_tasks(_square, items)
    on_ray = run_tasks(_square, items, Execution(workers=2))
    assert on_ray.outcomes == serial.outcomes


@pytest.mark.usefixtures("ray_local")
def test_a_running_runtime_is_not_taken_for_another_cluster() -> None:
    import ray

    gcs = ray.get_runtime_context().gcs_address
    host, port = split_address(gcs)
    for same in (gcs, f"127.0.0.1:{port}", "auto", None):  # its own address, this machine, any cluster
        with ray_runtime(Execution(address=same, workers=1)) as at_once:
            assert at_once == 1
    with pytest.raises(ClusterError, match=f"already runs on the Ray runtime at {gcs}, not on that cluster"), \
            ray_runtime(Execution(address=f"{host}:{port + 1}")):
        pass
    assert ray.is_initialized()  # refused, not stopped: the runtime stays for the rest of the session


def _consumer(seen: list[int]) -> Callable[[int], str]:
    def consume(value: int) -> str:
        seen.append(value)
        return f"kept {value}"
    return consume


def test_values_reach_the_consumer_in_the_items_order_and_the_report_keeps_what_it_returns() -> None:
    seen: list[int] = []
    report = run_tasks(_square, [2, 3, 1], consume=_consumer(seen))
    assert seen == [4, 1]  # the skipped item never reaches it
    assert report.values == ["kept 4", "kept 1"] and report.with_status(TaskStatus.SKIPPED)[0].label == "3"


@pytest.mark.usefixtures("ray_local")
def test_on_ray_values_that_end_early_wait_for_the_earlier_items() -> None:
    import ray

    ray.cloudpickle.register_pickle_by_value(ray_tasks)
    seen: list[int] = []
    report = run_tasks(ray_tasks.slow_first, list(range(8)), Execution(workers=2), items_per_task=1,
                       consume=_consumer(seen))
    assert seen == list(range(8)) and report.values == [f"kept {i}" for i in range(8)]


@pytest.mark.usefixtures("ray_local")
def test_on_ray_a_slow_item_holds_back_at_most_the_items_allowed_ahead(monkeypatch: pytest.MonkeyPatch) -> None:
    """Items are sent at most ``CONSUME_AHEAD_ITEMS`` past the first one not consumed: the values that
    wait for a slow item stay that few, and every item still runs."""
    import ray

    from scenesearch_base import ray_runner

    ray.cloudpickle.register_pickle_by_value(ray_tasks)
    monkeypatch.setattr(ray_runner, "CONSUME_AHEAD_ITEMS", 2)
    ahead: list[int] = []
    put = ray_runner._InOrder.put

    def watched(self: ray_runner._InOrder, i: int, outcome: ray_runner.Outcome[int]) -> None:
        ahead.append(i - self._next)
        put(self, i, outcome)

    monkeypatch.setattr(ray_runner._InOrder, "put", watched)
    seen: list[int] = []
    run_tasks(ray_tasks.slow_zero, list(range(12)), Execution(workers=2), items_per_task=1, consume=_consumer(seen))
    assert seen == list(range(12)) and max(ahead) == 1  # item 1 ends while item 0 runs; item 2 waits to be sent
    monkeypatch.setattr(ray_runner, "CONSUME_AHEAD_ITEMS", 256)
    ahead.clear()
    run_tasks(ray_tasks.slow_zero, list(range(12)), Execution(workers=2), items_per_task=1, consume=_consumer([]))
    assert max(ahead) > 1  # without the limit, the later items end while item 0 still runs


def test_what_the_consumer_raises_ends_the_run() -> None:
    def refusing(value: int) -> None:
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        run_tasks(_square, [1, 2], consume=refusing)
