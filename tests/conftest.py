"""Fixtures shared by test folders: one Ray runtime for every test of a session that needs one."""

from __future__ import annotations

from collections.abc import Iterator

import pytest


@pytest.fixture(scope="session")
def ray_local() -> Iterator[None]:
    """A local Ray runtime with 2 CPUs, started once (a few seconds) and shut down at the end.

    :mod:`common.ray_cluster` reuses a runtime this process started, so ``Execution(workers=2)``
    runs on this one; ``Execution(workers=1)`` keeps to one task at a time on it.
    """
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'scenesearch[scale]')")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        yield
    finally:
        ray.shutdown()
