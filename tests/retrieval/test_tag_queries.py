"""Tag queries from the Python API, the CLI and the HTTP API, on a tiny trained tagging model."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from fastapi import FastAPI
from fastapi.testclient import TestClient

from encoders.tagging.attributes import TagError
from encoders.tagging.scene_tags import compose, pool_values, region_masks, sigmoid
from retrieval.cli import main
from retrieval.service.tags_api import register_tag_routes, register_tags_unavailable
from retrieval.tagging import TagSearch, find, spans_of, tag_log
from tests.encoders.tagging_fixtures import build_tagging_fixture


@pytest.fixture(scope="module")
def fx(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    torch.manual_seed(0)
    root = tmp_path_factory.mktemp("tag_queries")
    out = build_tagging_fixture(root, num_frames=10, steps=2)
    nomap = root / "logs" / "nomap_0"
    shutil.copytree(out["logs"][0], nomap)
    shutil.rmtree(nomap / "map")
    out["nomap"] = nomap
    out["search"] = TagSearch(out["run"], cache_dir=root / "cache")
    return out


def test_series_is_the_model_tag_tensor_pooled_over_the_region(fx: dict[str, Any]) -> None:
    search: TagSearch = fx["search"]
    log = fx["logs"][0]
    ts, values = search.series(log, "parked", "front")
    assert ts.shape == values.shape == (10,) and np.all(np.diff(ts) > 0)
    # Recompute from the model's tensors: sigmoid, front mask, max.
    fr = search.frames(log)
    v = search.tagger.tag_frames(fr.bev_lidar, fr.bev_map)[:, search.tagger.names.index("parked")]
    front = region_masks(search.grid)["front"]  # type: ignore[index]
    np.testing.assert_allclose(values, pool_values(sigmoid(v), front, "max"), rtol=1e-5)
    # A composition is formed per cell, then pooled.
    _, both = search.series(log, "parked & four_way", "front")
    p = search.values(log, "parked")
    q = search.values(log, "four_way")
    np.testing.assert_allclose(both, pool_values(compose([p, q], "and"), front, "max"), rtol=1e-5)
    # Densities are sums in m² (cells of 1 m at r = 2).
    _, dens = search.series(log, "vehicle_density", "full")
    np.testing.assert_allclose(dens, search.values(log, "vehicle_density").sum(axis=(1, 2)), rtol=1e-4)
    # The functional API gives the same.
    np.testing.assert_allclose(tag_log(fx["run"], log, "parked", "front", cache_dir=search.cache_dir)[1], values,
                               rtol=1e-5)


def test_tag_values_are_kept_within_their_budget_and_computed_again_alike(fx: dict[str, Any],
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    import retrieval.tagging as tagging

    log = fx["logs"][0]
    kept = fx["search"].values_many(log, ["parked", "four_way"])
    monkeypatch.setattr(tagging, "VALUES_KEPT_BYTES", kept[0].nbytes)  # one attribute's values fit
    small = TagSearch(fx["run"], cache_dir=fx["search"].cache_dir)
    for _ in range(2):
        again = small.values_many(log, ["parked", "four_way", "parked"])
        assert small._values.total <= kept[0].nbytes and len(small._values) == 1
        for got, want in zip(again, [*kept, kept[0]]):
            np.testing.assert_array_equal(got, want)


def test_find_ranks_spans_by_score(fx: dict[str, Any]) -> None:
    search: TagSearch = fx["search"]
    spans = search.find(fx["logs"], "parked | braking", "full", threshold=0.0, min_duration_s=0.0)
    assert len(spans) == 3 and all(s.frames == 10 for s in spans)  # threshold 0: every log is one span
    assert [s.score for s in spans] == sorted((s.score for s in spans), reverse=True)
    assert search.find(fx["logs"], "parked", "full", threshold=1.01) == []
    assert find(fx["run"], fx["logs"][:1], "stopped & four_way", "front", threshold=0.0, min_duration_s=0.0,
                cache_dir=search.cache_dir)[0].log_id == "tagged_0"
    ts = np.arange(6) * 100_000_000
    assert spans_of(np.array([0, 1, 1, 0, 1, 1.0]), ts, 0.5, 0.1) == [(1, 2), (4, 5)]
    assert spans_of(np.array([0, 1, 1, 0, 1, 1.0]), ts, 0.5, 0.15) == []


def test_bad_queries_fail_with_the_valid_options(fx: dict[str, Any]) -> None:
    search: TagSearch = fx["search"]
    log = fx["logs"][0]
    with pytest.raises(TagError, match="valid attributes: vehicle_density"):
        search.series(log, "flying", "front")
    with pytest.raises(TagError, match="valid regions: full, front"):
        search.series(log, "parked", "left")
    with pytest.raises(TagError, match="twice"):
        search.find([log], "blocked_by & blocked_by", "front")
    # A log without a map: map regions fail clearly, ego-relative regions work.
    with pytest.raises(TagError, match="nomap_0.*needs the log's map"):
        search.series(fx["nomap"], "parked", "intersection")
    _, values = search.series(fx["nomap"], "parked", "front")
    assert values.shape == (10,)


def test_cli_tag_find_and_eval_tags(fx: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cache = str(fx["search"].cache_dir)
    assert main(["tag", str(fx["run"]), str(fx["logs"][1]), "--attribute", "stopped & four_way", "--region", "front",
                 "--json", "--cache", cache, "--plot", str(tmp_path / "p.png")]) == 0
    out = capsys.readouterr().out
    data = json.loads(out.splitlines()[0])
    assert len(data["values"]) == 10 and (tmp_path / "p.png").stat().st_size > 0
    assert main(["find", str(fx["run"]), *map(str, fx["logs"]), "--tag", "parked | braking", "--region", "full",
                 "--threshold", "0", "--min-duration-s", "0", "--json", "--cache", cache]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(rows) == 3 and {"log_id", "start_ns", "end_ns", "score"} <= set(rows[0])
    assert main(["tag", str(fx["run"]), str(fx["logs"][1]), "--attribute", "flying", "--cache", cache]) == 2
    assert "valid attributes" in capsys.readouterr().err
    assert main(["eval-tags", str(fx["run"]), str(fx["clips"]), "--out", str(tmp_path / "ev")]) == 0
    tags = json.loads((tmp_path / "ev" / "tags.json").read_text())
    assert tags["by_region"]["blocked_by"]["front"]["metric"] == "F1"
    assert set(tags["inputs"]) == {"none", "both"} and tags["inputs"]["none"]["vehicle_speed"]["metric"] == "L1"


def test_http_tag_routes(fx: dict[str, Any]) -> None:
    app = FastAPI()
    register_tag_routes(app, fx["search"], [*fx["logs"], fx["nomap"]])
    client = TestClient(app)
    vocab = client.get("/api/tags/vocabulary").json()
    assert {"name": "four_way", "kind": "discrete"} in vocab["attributes"] and "crosswalk" in vocab["regions"]
    r = client.get("/api/tags/series", params={"log_id": "tagged_2", "tag": "parked", "region": "front"})
    assert r.status_code == 200 and len(r.json()["values"]) == 10
    r = client.get("/api/tags/find", params={"tag": "parked | braking", "region": "full", "threshold": 0,
                                             "min_duration_s": 0, "k": 2})
    assert r.status_code == 200 and len(r.json()["results"]) == 2
    assert client.get("/api/tags/series", params={"log_id": "nope", "tag": "parked"}).status_code == 404
    r = client.get("/api/tags/find", params={"tag": "parked & parked"})
    assert r.status_code == 422 and "twice" in r.json()["detail"]
    r = client.get("/api/tags/series", params={"log_id": "nomap_0", "tag": "parked", "region": "crosswalk"})
    assert r.status_code == 422 and "map" in r.json()["detail"]


def test_tag_routes_of_a_service_without_tag_queries_say_what_starts_them() -> None:
    app = FastAPI()
    register_tags_unavailable(app, "the service was started without --logs")
    client = TestClient(app)
    for path in ("/api/tags/vocabulary", "/api/tags/find?tag=stopped", "/api/tags/series?log_id=a&tag=b"):
        response = client.get(path)
        assert response.status_code == 404
        assert response.json()["detail"] == "tag queries are not served: the service was started without --logs"

