"""Previews of clips built without stored ones: drawn from the rendered frames by the service and the
report when shown, and refused where those frames are not at hand."""

from __future__ import annotations

import io
import shutil
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient
from PIL import Image
from retrieval_fakes import FakeEmbedder, HashTextEncoder, make_run_dir

from encoders.clips.build import build_clips
from encoders.clips.config import BevClipConfig, CameraClipConfig, ClipsConfig
from encoders.clips.layout import read_clip_table, rendered_log_dir
from retrieval.embedding import model_hash
from retrieval.report import draw_preview, preview_html
from retrieval.scenesearch import SceneSearch
from retrieval.service import ServiceLimits, create_app
from tests.encoders.clip_fixtures import synthetic_captions, write_synthetic_log

CONFIG = ClipsConfig(frames_per_clip=8, camera=CameraClipConfig(width_px=64, height_px=32),
                     bev=BevClipConfig(resolution_m=1.25))


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("previews")
    logs = [write_synthetic_log(root / "logs", name, num_frames=40) for name in ("drawn", "gone")]
    (root / "captions").mkdir()
    pq.write_table(synthetic_captions(logs), root / "captions" / "captions.parquet")
    assert not CONFIG.previews  # previews are drawn when shown unless asked for at build time
    build_clips(logs, root / "captions", root / "clips", CONFIG)
    rows = read_clip_table(root / "clips").to_pylist()
    assert rows and all(r["preview_path"] is None for r in rows)
    run = make_run_dir(root / "run")
    search = SceneSearch.build(run, root / "clips", root / "index", embedder=FakeEmbedder(model_hash(run)),
                               text_encoder=HashTextEncoder())
    shutil.rmtree(rendered_log_dir(root / "clips", "gone"))  # a log whose frames are no longer at hand
    client = TestClient(create_app(search, ServiceLimits(max_k=20)))
    return {"client": client, "rows": rows, "search": search, "root": root}


def _result(served: dict[str, Any], log_id: str) -> dict[str, Any]:
    body = served["client"].get("/api/search", params={"q": "a car", "k": 20}).json()
    return next(r for r in body["results"] if r["log_id"] == log_id)


def test_the_service_draws_a_preview_that_was_not_stored(served: dict[str, Any]) -> None:
    result = _result(served, "drawn")
    plain = f"/api/clips/{result['clip_id']}/preview"
    assert result["preview_url"].startswith(plain)  # the query's program marks the other cars it refers to
    for url in (plain, result["preview_url"]):
        response = served["client"].get(url)
        assert response.status_code == 200 and response.headers["content-type"] == "image/gif"
        with Image.open(io.BytesIO(response.content)) as gif:
            assert gif.n_frames == CONFIG.frames_per_clip
        assert served["client"].get(url).content == response.content  # kept: the same bytes
    assert served["client"].get(plain).content != served["client"].get(result["preview_url"]).content


def test_without_rendered_frames_there_is_no_preview_to_show(served: dict[str, Any]) -> None:
    result = _result(served, "gone")
    assert result["preview_url"] is None
    response = served["client"].get(f"/api/clips/{result['clip_id']}/preview")
    assert response.status_code == 404 and "rendered frames" in response.json()["detail"]


def test_the_report_draws_its_previews_beside_the_page(served: dict[str, Any], tmp_path: Path) -> None:
    search, clips = served["search"], served["root"] / "clips"
    results = [r for r in search.search_text("a car", k=20) if r.log_id == "drawn"][:2]
    html = preview_html(results[0], tmp_path, clips)
    drawn = sorted((tmp_path / "previews").iterdir())
    assert len(drawn) == 1 and f"src='previews/{drawn[0].name}'" in html
    with Image.open(drawn[0]) as gif:
        assert gif.n_frames == CONFIG.frames_per_clip
    assert "no preview" in preview_html(results[1], tmp_path)  # nothing stored, no clips folder to draw from
    gone = next(r for r in search.search_text("a car", k=20) if r.log_id == "gone")
    assert "no preview" in preview_html(gone, tmp_path, clips)


def test_report_drawings_with_marks_are_kept_apart_and_a_bad_clip_is_skipped(served: dict[str, Any],
                                                                          tmp_path: Path) -> None:
    from dataclasses import replace

    search, clips = served["search"], served["root"] / "clips"
    result = next(r for r in search.search_text("a car", k=20) if r.log_id == "drawn")
    plain = draw_preview(result, tmp_path, clips)
    marked = draw_preview(result, tmp_path, clips, referred=["parked"])
    assert plain is not None and marked is not None and plain != marked
    assert plain.read_bytes() != marked.read_bytes()
    assert draw_preview(result, tmp_path, clips) == plain  # drawn once, then reused
    unknown = replace(result, clip_id="drawn:nobody:0")  # its log's frames are there, the clip is not
    assert draw_preview(unknown, tmp_path, clips) is None
    assert "no preview" in preview_html(unknown, tmp_path, clips)
