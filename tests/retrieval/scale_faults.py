"""Fault injection for the scale tests: a caption task that kills its Ray worker. It runs in the
workers, so it is sent by value (the workers cannot import the tests)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any


def dying_on(real: Callable[..., Any], marker_dir: str, dies_once: str, dies_always: str) -> Callable[..., Any]:
    """``real`` (one log's task), except that the log named ``dies_once`` kills its worker on the
    first attempt (a marker file says it was tried) and ``dies_always`` on every attempt."""

    def task(log_dir: Any, context: Any) -> Any:
        name = Path(str(log_dir)).name
        marker = Path(marker_dir) / f"{name}.tried"
        if name == dies_always or (name == dies_once and not marker.exists()):
            marker.write_text("tried")
            os._exit(1)
        return real(log_dir, context)

    return task


def dying_actor(base: type, marker_dir: str) -> type:
    """``base`` (the embedding actor), except that its first block kills its process (a marker file
    says it was tried): Ray Data starts the actor anew and gives it the block again."""

    class DyingActor(base):  # type: ignore[misc, valid-type]
        def __call__(self, block: dict[str, Any]) -> Any:
            marker = Path(marker_dir) / "embed.tried"
            if not marker.exists():
                marker.write_text("tried")
                os._exit(1)
            return super().__call__(block)

    return DyingActor
