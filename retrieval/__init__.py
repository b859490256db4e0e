"""Retrieval: the SceneSearch API, the ``scenesearch`` CLI, the HTTP service, evaluation and the demo.

>>> from retrieval import SceneSearch
>>> search = SceneSearch.open("demo_out/index")
>>> search.search_text("a car in the left lane approaches, then moves into the ego lane", k=5)

Names are imported on first use, so ``import retrieval`` (and every CLI command) stays light.
"""

from __future__ import annotations

from typing import Any

_EXPORTS = {
    "SceneSearch": "retrieval.scenesearch",
    "CaptionSearch": "retrieval.captions_search",
    "SearchResult": "retrieval.records",
    "evaluate": "retrieval.evaluation",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        import importlib

        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'retrieval' has no attribute {name!r}")
