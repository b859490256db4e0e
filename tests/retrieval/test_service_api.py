"""The HTTP API with FastAPI's test client, over an index built with stand-in models."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient
from PIL import Image
from retrieval_fakes import FakeEmbedder, HashTextEncoder, caption_of, make_clips_dir, make_run_dir

from retrieval.embedding import model_hash
from retrieval.scenesearch import SceneSearch
from retrieval.service import ServiceLimits, create_app


def _write_gif(path: Path, colour: tuple[int, int, int]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = [Image.new("RGB", (32, 16), tuple(min(255, c + 20 * i) for c in colour)) for i in range(3)]
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=100, loop=0)


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("service")
    clips = make_clips_dir(root / "clips")
    table = pq.read_table(clips / "clips.parquet")
    rows = table.to_pylist()
    for row in rows[:-1]:
        _write_gif(clips / row["preview_path"], (40, 80, 120))
    # A hostile row: its preview path climbs out of the clips folder, to a file that exists.
    secret = root / "secret.gif"
    _write_gif(secret, (255, 0, 0))
    rows[-1]["preview_path"] = "../secret.gif"
    pq.write_table(pa.Table.from_pylist(rows, schema=table.schema), clips / "clips.parquet")
    run = make_run_dir(root / "run")
    search = SceneSearch.build(run, clips, root / "index", embedder=FakeEmbedder(model_hash(run)),
                               text_encoder=HashTextEncoder())
    client = TestClient(create_app(search, ServiceLimits(max_k=20, max_query_chars=200)))
    return {"client": client, "rows": rows, "search": search}


def test_health_and_openapi(served: dict[str, Any]) -> None:
    client = served["client"]
    health = client.get("/health").json()
    assert health["status"] == "ok" and health["clips"] == len(served["rows"])
    schema = client.get("/openapi.json").json()
    assert {"/api/search", "/api/export", "/health"} <= set(schema["paths"])


def test_search_returns_the_clips_of_the_caption(served: dict[str, Any]) -> None:
    query = caption_of(["left:approach", "left:cut_in"])
    body = served["client"].get("/api/search", params={"q": query, "k": 5}).json()
    assert len(body["results"]) == 5
    top = body["results"][0]
    assert top["caption"] == query
    assert top["preview_url"] == f"/api/clips/{top['clip_id']}/preview"
    assert [r["rank"] for r in body["results"]] == [1, 2, 3, 4, 5]
    assert all(a["score"] >= b["score"] for a, b in zip(body["results"], body["results"][1:]))


def test_filters_restrict_results(served: dict[str, Any]) -> None:
    client = served["client"]
    body = client.get("/api/search", params={"q": "keeps its distance ahead", "k": 10,
                                             "filter": ["category=truck", "time_of_day=night"]}).json()
    assert body["results"] and all(r["category"] == "truck" for r in body["results"])
    logs_at_night = {r["log_id"] for r in served["rows"] if r["time_of_day"] == "night"}
    assert {r["log_id"] for r in body["results"]} <= logs_at_night
    tagged = client.get("/api/search", params={"q": "overtakes", "filter": "tags contains 'right:overtake'"}).json()
    assert tagged["results"] and all("right:overtake" in r["tags"] for r in tagged["results"])


def test_hybrid_mode(served: dict[str, Any]) -> None:
    client = served["client"]
    body = client.get("/api/search", params={"q": "overtakes on the right", "mode": "hybrid", "k": 5}).json()
    assert body["mode"] == "hybrid" and body["view"] == "fused" and len(body["results"]) == 5
    assert body["results"][0]["caption"] == "overtakes on the right"
    assert body["hybrid_weight"] == served["search"].hybrid.weight
    model_only = client.get("/api/search", params={"q": "overtakes on the right", "mode": "hybrid", "weight": 0,
                                                   "k": 6}).json()
    plain = client.get("/api/search", params={"q": "overtakes on the right", "k": 6}).json()
    assert [r["clip_id"] for r in model_only["results"]] == [r["clip_id"] for r in plain["results"]]
    assert "hybrid" in client.get("/api/fields").json()["modes"]


def test_caption_mode_needs_no_model(served: dict[str, Any]) -> None:
    body = served["client"].get("/api/search", params={"q": "overtakes on the right", "mode": "captions",
                                                       "k": 3}).json()
    assert body["mode"] == "captions" and body["results"][0]["caption"] == "overtakes on the right"


def test_similar_excludes_the_query_clip(served: dict[str, Any]) -> None:
    clip_id = served["rows"][0]["clip_id"]
    body = served["client"].get(f"/api/similar/{clip_id}", params={"k": 4}).json()
    ids = [r["clip_id"] for r in body["results"]]
    assert len(ids) == 4 and clip_id not in ids
    assert body["results"][0]["caption"] == served["rows"][0]["caption"]


def test_similar_from_other_moments(served: dict[str, Any]) -> None:
    row = served["rows"][5]
    same_time = {r["clip_id"] for r in served["rows"] if r["log_id"] == row["log_id"]
                 and r["start_ns"] < row["end_ns"] and r["end_ns"] > row["start_ns"]}
    in_its_log = {"k": 20, "filter": f"log_id={row['log_id']}"}
    everywhere = served["client"].get(f"/api/similar/{row['clip_id']}", params=in_its_log).json()
    assert same_time - {row["clip_id"]} <= {r["clip_id"] for r in everywhere["results"]}
    body = served["client"].get(f"/api/similar/{row['clip_id']}", params=in_its_log | {"other_moments": "true"}).json()
    ids = {r["clip_id"] for r in body["results"]}
    assert body["other_moments"] is True and len(ids) == 14 - len(same_time) and not ids & same_time


def test_clip_metadata_and_timeline(served: dict[str, Any]) -> None:
    row = next(r for r in served["rows"] if len(r["tags"]) == 2)
    body = served["client"].get(f"/api/clips/{row['clip_id']}").json()
    assert body["tags"] == row["tags"]
    assert [s["tag"] for s in body["timeline"]] == row["tags"]
    assert body["timeline"][-1]["end_s"] == pytest.approx((row["end_ns"] - row["start_ns"]) / 1e9, abs=0.01)
    assert body["metadata"]["time_of_day"] == row["time_of_day"]


def test_preview_is_served_as_gif(served: dict[str, Any]) -> None:
    clip_id = served["rows"][0]["clip_id"]
    response = served["client"].get(f"/api/clips/{clip_id}/preview")
    assert response.status_code == 200 and response.headers["content-type"] == "image/gif"
    assert response.content[:6] in (b"GIF89a", b"GIF87a")


@pytest.mark.parametrize(
    "path",
    [
        "/api/clips/..%2F..%2Fsecret.gif/preview",
        "/api/clips/%2E%2E/%2E%2E/secret.gif/preview",
        "/api/clips/..%2F..%2F..%2Fetc%2Fpasswd",
        "/api/similar/..%2F..%2Fetc%2Fpasswd",
        "/api/clips/%2Fetc%2Fpasswd/preview",
    ],
)
def test_path_traversal_in_ids_is_404(served: dict[str, Any], path: str) -> None:
    response = served["client"].get(path)
    assert response.status_code == 404, response.text
    assert "root:" not in response.text


def test_a_preview_path_outside_the_clips_folder_is_never_served(served: dict[str, Any]) -> None:
    hostile = served["rows"][-1]["clip_id"]
    response = served["client"].get(f"/api/clips/{hostile}/preview")
    assert response.status_code == 404
    assert "missing" in response.json()["detail"]


def test_export_by_ids_and_by_query(served: dict[str, Any]) -> None:
    client = served["client"]
    ids = [r["clip_id"] for r in served["rows"][:3]]
    body = client.get("/api/export", params={"ids": ",".join(ids)}).json()
    x = np.asarray(body["embeddings"])
    assert body["clip_ids"] == ids and x.shape == (3, body["dim"])
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1.0, atol=1e-4)
    _, xb = served["search"].embeddings("fused")
    assert np.abs(xb - x[0]).max(axis=1).min() < 1e-5  # the exported vector is the indexed one
    by_query = client.get("/api/export", params={"q": "stops ahead of the host", "k": 4}).json()
    assert len(by_query["clip_ids"]) == 4


@pytest.mark.parametrize(
    ("params", "status", "needle"),
    [
        ({"q": ""}, 422, "empty"),
        ({"q": "   "}, 422, "empty"),
        ({"q": "car", "k": 0}, 422, "k must be"),
        ({"q": "car", "k": 21}, 422, "k must be"),
        ({"q": "car", "k": "many"}, 422, ""),
        ({"q": "x" * 201}, 413, "limit"),
        ({"q": "car", "filter": "colour=red"}, 422, "valid fields"),
        ({"q": "car", "view": "lidar"}, 422, "lidar"),
        ({"q": "car", "mode": "guess"}, 422, "parameter 'mode'"),
        ({"q": "car", "weight": 0.5}, 422, "add mode=hybrid"),
        ({"q": "car", "mode": "hybrid", "weight": 1.5}, 422, "in [0, 1]"),
        ({"q": "car", "mode": "hybrid", "weight": "nan"}, 422, "in [0, 1]"),
    ],
)
def test_bad_parameters_get_clear_errors(served: dict[str, Any], params: dict[str, Any], status: int,
                                         needle: str) -> None:
    response = served["client"].get("/api/search", params=params)
    assert response.status_code == status, response.text
    assert needle in str(response.json()["detail"])


def test_k_is_checked_once_with_the_service_limit(served: dict[str, Any]) -> None:
    client, clip_id = served["client"], served["rows"][0]["clip_id"]
    endpoints = [("/api/search", {"q": "a car"}), ("/api/search", {"q": "a car", "mode": "captions"}),
                 (f"/api/similar/{clip_id}", {}), ("/api/export", {"q": "a car"})]
    for path, params in endpoints:
        ok = client.get(path, params={**params, "k": 20}).json()
        assert len(ok.get("results", ok.get("clip_ids"))) == 20
        response = client.get(path, params={**params, "k": 21})
        assert response.status_code == 422
        assert response.json()["detail"] == "k must be an integer in 1 … 20, got k=21"


def test_unknown_ids_are_404(served: dict[str, Any]) -> None:
    client = served["client"]
    assert client.get("/api/clips/nope:1:2").status_code == 404
    assert client.get("/api/similar/nope:1:2").status_code == 404
    assert client.get("/api/export", params={"ids": "nope:1:2"}).status_code == 404
    assert client.get("/api/export").status_code == 422


def test_page_and_static_files(served: dict[str, Any]) -> None:
    client = served["client"]
    page = client.get("/")
    assert page.status_code == 200 and 'id="search-form"' in page.text
    script = client.get("/static/app.js").text
    # No network fetches beyond this server: every URL the page uses is relative to it.
    assert "http://" not in script and "https://" not in script and "http" not in page.text.replace(
        'http-equiv', '')
    fields = client.get("/api/fields").json()
    assert {v["value"]: v["count"] for v in fields["menus"]["category"]["values"]} == {
        c: sum(r["category"] == c for r in served["rows"]) for c in ("car", "truck", "pedestrian")}
    steps = {v["value"]: v["label"] for v in fields["menus"]["tags"]["values"]}
    assert steps["left:approach"] == "left lane · approaches"  # readable names, not raw tag strings
    assert fields["summary"]["clips"] == len(served["rows"]) and fields["examples"]
