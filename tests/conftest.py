"""Fixtures shared by test folders: one Ray runtime for the tests that need one, none for those that must have none."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

#: The session's local runtime: 2 CPUs, quiet.
_LOCAL = {"num_cpus": 2, "include_dashboard": False, "log_to_driver": False, "configure_logging": False}


@pytest.fixture(scope="session")
def ray_local() -> Iterator[None]:
    """A local Ray runtime with 2 CPUs, started once (a few seconds) and shut down at the end.

    :mod:`scenesearch_base.ray_cluster` reuses a runtime this process started, so ``Execution(workers=2)``
    runs on this one; ``Execution(workers=1)`` keeps to one task at a time on it.
    """
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'scenesearch[scale]')")
    ray.init(**_LOCAL)
    try:
        yield
    finally:
        ray.shutdown()


@pytest.fixture
def ray_stopped() -> Iterator[None]:
    """No Ray runtime in this process during the test: one that ``ray_local`` started is stopped, and
    started again afterwards. :mod:`scenesearch_base.ray_cluster` reuses a running runtime (or refuses an address
    it is not on), so a test of joining a cluster would otherwise depend on which tests ran before it."""
    try:
        import ray
    except ImportError:
        yield
        return
    running = ray.is_initialized()
    if running:
        ray.shutdown()
    try:
        yield
    finally:
        if running and not ray.is_initialized():
            ray.init(**_LOCAL)


@pytest.fixture(autouse=True)
def private_cache_home(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Keep what commands remember between runs (the last search's short ids) out of the user's ~/.cache."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("cache_home")))
