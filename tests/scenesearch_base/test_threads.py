"""Idle OpenMP threads spin briefly: the setting reaches this process before torch loads, the processes
it starts, and Ray's workers; a value the user set is kept."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from scenesearch_base.threads import SPIN_COUNT, SPIN_VARIABLE, shorten_thread_spin, thread_spin_env

#: Shortens the spin, then imports torch; prints whether it took effect and what a child process sees.
_CHILD = """
import os, subprocess, sys
from scenesearch_base.threads import shorten_thread_spin
took = shorten_thread_spin()
import torch
child = subprocess.run([sys.executable, "-c", "import os; print(os.environ.get('GOMP_SPINCOUNT'))"],
                       capture_output=True, text=True, check=True).stdout.strip()
print(took, child)
"""


def _run_child(env_spin: str | None) -> list[str]:
    env = {k: v for k, v in os.environ.items() if k != SPIN_VARIABLE}
    if env_spin is not None:
        env[SPIN_VARIABLE] = env_spin
    return subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True, check=True,
                          env=env).stdout.split()


def test_before_torch_the_short_spin_takes_effect_and_reaches_started_processes() -> None:
    assert _run_child(None) == ["True", str(SPIN_COUNT)]


def test_a_spin_the_user_set_is_kept() -> None:
    assert _run_child("5000") == ["True", "5000"]


def test_after_torch_it_says_this_process_keeps_its_spin(monkeypatch: pytest.MonkeyPatch) -> None:
    import torch  # noqa: F401  (loaded: libgomp read its setting already)

    monkeypatch.delenv(SPIN_VARIABLE, raising=False)
    assert shorten_thread_spin() is False
    assert os.environ[SPIN_VARIABLE] == str(SPIN_COUNT)  # processes started from now on still get it


def test_ray_workers_get_the_spin_with_the_malloc_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    from scenesearch_base.ray_cluster import _worker_env

    monkeypatch.setenv(SPIN_VARIABLE, "7000")
    env_vars = _worker_env()["env_vars"]
    assert env_vars[SPIN_VARIABLE] == "7000" == thread_spin_env()[SPIN_VARIABLE] and "GLIBC_TUNABLES" in env_vars
