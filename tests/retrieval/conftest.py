"""Fixtures of the retrieval tests; the stand-ins themselves live in ``retrieval_fakes.py``."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from retrieval_fakes import FakeEmbedder, HashTextEncoder, make_clips_dir, make_run_dir


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    from retrieval.embedding import model_hash
    from retrieval.scenesearch import SceneSearch

    root = tmp_path_factory.mktemp("retrieval")
    clips = make_clips_dir(root / "clips")
    run = make_run_dir(root / "run")
    embedder = FakeEmbedder(model_hash(run))
    index_dir = root / "index"
    lines: list[str] = []
    search = SceneSearch.build(run, clips, index_dir, embedder=embedder, text_encoder=HashTextEncoder(),
                               progress=lines.append)
    return {"root": root, "clips": clips, "run": run, "index": index_dir, "embedder": embedder,
            "search": search, "progress": lines}
