"""What the service says about results, pages and the index: paging through every result, "more like this"
without the query's own track, the time of a moment in its log, filters with counts, readable tags,
weak-result warnings, suggested phrasings, the embedding map and offline API docs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient
from retrieval_fakes import FakeEmbedder, HashTextEncoder, caption_of, make_clips_dir, make_run_dir

from retrieval.embedding import model_hash
from retrieval.records import LogSpan, SearchResult, TimeInLog, read_log_spans, time_in_log
from retrieval.scenario_search import ScenarioMatch
from retrieval.scenesearch import SceneSearch
from retrieval.service import ServiceLimits, create_app
from retrieval.service.explain import best_threshold, calibrate, matching_tags, object_sentence, suggestion, tag_label
from retrieval.service.results import ResultContext

MAX_K = 10


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("explain")
    clips = make_clips_dir(root / "clips", n_logs=5, clips_per_log=10)
    rows = pq.read_table(clips / "clips.parquet").to_pylist()
    # The first clip's object again, later in its log: the same track in another window.
    first = rows[0]
    later = [dict(first, clip_id=f"{first['log_id']}:{first['track_id']}:{first['start_ns'] + d}",
                  start_ns=first["start_ns"] + d, end_ns=first["end_ns"] + d) for d in (30_000_000_000, 40_000_000_000)]
    rows += later
    for i, row in enumerate(rows):
        row["braking"] = i % 4 == 0
        row["at_intersection"] = i % 5 == 0
    pq.write_table(pa.Table.from_pylist(rows), clips / "clips.parquet")
    run = make_run_dir(root / "run")
    search = SceneSearch.build(run, clips, root / "index", embedder=FakeEmbedder(model_hash(run)),
                               text_encoder=HashTextEncoder())
    client = TestClient(create_app(search, ServiceLimits(max_k=MAX_K)))
    return {"client": client, "rows": rows, "search": search, "same_track": [first["clip_id"]] + [r["clip_id"]
                                                                                                   for r in later]}


def test_search_pages_through_every_result_max_k_at_a_time(served: dict[str, Any]) -> None:
    client, n = served["client"], len(served["rows"])
    for mode in ("model", "captions", "hybrid"):
        seen, offset, ranks = [], 0, []
        while offset is not None:
            body = client.get("/api/search", params={"q": "keeps its distance ahead", "k": MAX_K, "offset": offset,
                                                     "mode": mode, "program": "false"}).json()
            assert body["total"] == n and len(body["results"]) <= MAX_K
            seen += [r["clip_id"] for r in body["results"]]
            ranks += [r["rank"] for r in body["results"]]
            offset = body["next_offset"]
        assert len(seen) == n and len(set(seen)) == n, mode  # every moment once, past max_k
        assert ranks == list(range(1, n + 1))
    past = client.get("/api/search", params={"q": "stops", "k": 5, "offset": n + 3}).json()
    assert past["results"] == [] and past["next_offset"] is None


def test_a_page_is_the_slice_of_the_whole_ranking(served: dict[str, Any]) -> None:
    client = served["client"]
    params = {"q": caption_of(["left:approach", "left:cut_in"]), "filter": "category=car"}
    first = client.get("/api/search", params=params | {"k": 6}).json()
    second = client.get("/api/search", params=params | {"k": 3, "offset": 3}).json()
    assert [r["clip_id"] for r in second["results"]] == [r["clip_id"] for r in first["results"][3:6]]
    assert first["total"] == sum(r["category"] == "car" for r in served["rows"])
    assert client.get("/api/search", params={"q": "car", "offset": -1}).status_code == 422


def test_more_like_this_leaves_out_the_query_track_unless_asked(served: dict[str, Any]) -> None:
    client, own = served["client"], served["same_track"]
    body = client.get(f"/api/similar/{own[0]}", params={"k": MAX_K}).json()
    assert not {r["clip_id"] for r in body["results"]} & set(own)
    assert body["query"]["clip_id"] == own[0] and "score" not in body["query"]  # the clip the page pins
    assert body["same_track"] is False and body["next_offset"] == MAX_K
    kept = client.get(f"/api/similar/{own[0]}", params={"k": MAX_K, "same_track": "true"}).json()
    assert set(own[1:]) <= {r["clip_id"] for r in kept["results"]}  # the same caption: the closest clips
    assert own[0] not in {r["clip_id"] for r in kept["results"]}
    page2 = client.get(f"/api/similar/{own[0]}", params={"k": 5, "offset": 5}).json()
    assert [r["clip_id"] for r in page2["results"]] == [r["clip_id"] for r in body["results"][5:10]]


def test_results_say_when_the_moment_happens_in_its_log(served: dict[str, Any]) -> None:
    body = served["client"].get("/api/search", params={"q": "overtakes on the right", "k": 3}).json()
    rows = {r["clip_id"]: r for r in served["rows"]}
    for r in body["results"]:
        log = [x for x in served["rows"] if x["log_id"] == r["log_id"]]
        first = min(x["start_ns"] for x in log)  # no rendered frames here: the log's moments span it
        t = r["time_in_log"]
        assert t["start_s"] == pytest.approx((rows[r["clip_id"]]["start_ns"] - first) / 1e9)
        assert t["text"].endswith(" s") and "–" in t["text"] and " of " in t["text"]


def test_time_in_log_reads_as_the_issue_shows() -> None:
    result = SearchResult(1, "l:t:1", "l", "t", "car", 12_400_000_000, 15_900_000_000, "", (), 0.5, None, "fused")
    assert str(time_in_log(result, LogSpan(0, 20_000_000_000))) == "12.4–15.9 s of 20 s"
    assert str(TimeInLog(1.0, 2.0, 19.6)) == "1.0–2.0 s of 19.6 s"


def test_log_spans_come_from_the_rendered_frames(tmp_path: Path) -> None:
    folder = tmp_path / "logs" / "log-a"
    folder.mkdir(parents=True)
    pq.write_table(pa.table({"frame_index": [0, 1, 2], "timestamp_ns": [5, 7, 9]}), folder / "frames.parquet")
    assert read_log_spans(tmp_path, ["log-a", "log-b"]) == {"log-a": LogSpan(5, 9)}


def test_fields_have_counts_switches_and_readable_names(served: dict[str, Any]) -> None:
    fields = served["client"].get("/api/fields").json()
    rows = served["rows"]
    switches = {s["field"]: s for s in fields["switches"]}
    assert switches["braking"]["count"] == sum(r["braking"] for r in rows)
    assert switches["braking"]["kind"] == "action" and switches["at_intersection"]["kind"] == "place"
    weather = {v["value"]: v["count"] for v in fields["menus"]["weather"]["values"]}
    assert weather == {w: sum(r["weather"] == w for r in rows) for w in {r["weather"] for r in rows}}
    logs = fields["menus"]["log_id"]["values"]
    assert logs[0]["label"].startswith("log 1 · ")
    assert {v["value"] for v in fields["menus"]["split"]["values"]} == {"train", "val", "test"}
    assert fields["summary"] == {"clips": len(rows), "logs": 5, "categories": {
        c: sum(r["category"] == c for r in rows) for c in ("car", "pedestrian", "truck")},
        "splits": {s: sum(r["split"] == s for r in rows) for s in ("test", "train", "val")}}
    assert set(fields["score_scales"]) == {"model", "captions", "hybrid", "similar"}
    # A switch filters as the page sends it.
    body = served["client"].get("/api/search", params={"q": "a car", "filter": "braking=true", "k": MAX_K}).json()
    assert body["results"] and all(rows_by_id(served)[r["clip_id"]]["braking"] for r in body["results"])


def rows_by_id(served: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {r["clip_id"]: r for r in served["rows"]}


def test_results_explain_what_matched(served: dict[str, Any]) -> None:
    body = served["client"].get("/api/search", params={"q": "a car in the left lane approaches", "k": 3}).json()
    top = body["results"][0]
    assert top["object_sentence"] == object_sentence(top["caption"])
    assert top["tag_labels"] == [tag_label(t) for t in top["tags"]]
    assert "left:approach" in top["matched_tags"]
    assert body["score_scale"].startswith("cosine")
    hybrid = served["client"].get("/api/search", params={"q": "stops", "mode": "hybrid", "k": 1}).json()
    assert "standard deviations" in hybrid["score_scale"]


def test_weak_best_scores_are_flagged_by_the_validation_calibration(served: dict[str, Any]) -> None:
    client = served["client"]
    strong = client.get("/api/search", params={"q": caption_of(["host:constant", "host:stop"]), "k": 3}).json()
    assert strong["confidence"]["weak"] is False and "validation" in strong["confidence"]["basis"]
    weak = client.get("/api/search", params={"q": "zebra umbrella quantum", "k": 3, "program": "false"}).json()
    assert weak["confidence"]["weak"] is True
    assert weak["confidence"]["best"] < weak["confidence"]["threshold"] <= strong["confidence"]["best"]


def test_calibration_separates_matched_from_unmatched_best_scores() -> None:
    assert best_threshold(np.array([0.8, 0.9, 0.85]), np.array([0.5, 0.6, 0.7])) == pytest.approx(0.75)
    assert best_threshold(np.array([0.8, 0.9]), np.array([0.5, 0.85])) == pytest.approx(0.65)  # ties: the lowest
    rows = [{"clip_id": f"c{i}", "caption": f"The ego vehicle is cruising. A car does {i % 3}.",
             "split": "val" if i < 3 else "train"} for i in range(9)]

    def rank(query: str, k: int, conditions: list[Any]) -> list[SearchResult]:
        inside = conditions[0].op.value == "in"
        score = 0.9 if inside else 0.4
        return [SearchResult(1, "x", "l", "t", "car", 0, 1, query, (), score, None, "fused")]

    cal = calibrate("model", rows, rank)
    assert cal is not None and cal.queries == 3 and 0.4 < cal.threshold < 0.9
    assert cal.judge(0.3)["weak"] and not cal.judge(0.95)["weak"]
    assert calibrate("model", [dict(r, split="train") for r in rows], rank) is None  # no validation clips


def test_unused_words_get_a_phrasing_the_index_knows() -> None:
    top = SearchResult(1, "x", "l", "t", "car", 0, 1,
                       "The ego vehicle is cruising straight. A car in the left lane moves into the ego lane.",
                       (), 0.5, None, "fused")
    encode = HashTextEncoder()
    out = suggestion("a car cuts in from the left", ["cuts"], lambda q: [top], encode)
    assert out is not None and out["unused_words"] == ["cuts"]
    assert out["phrasing"] == "A car in the left lane moves into the ego lane"
    assert suggestion("a car", [], lambda q: [top], encode) is None


def test_tags_in_words() -> None:
    assert tag_label("left:approach") == "left lane · approaches"
    assert tag_label("host:approach:left_turn:at_intersection") == "ego lane · approaches · left turn · at the " \
                                                                   "intersection"
    assert tag_label("cruising:heading_straight") == "ego cruising · straight"
    assert matching_tags("a car turning left", ["host:approach:left_turn", "right:away"]) == ["host:approach:left_turn"]


def test_scenario_results_preview_marks_the_other_tracks(served: dict[str, Any]) -> None:
    search: SceneSearch = served["search"]
    record = search.get(served["rows"][0]["clip_id"])
    match = ScenarioMatch("q", None, (record.clip_id,), {record.clip_id: (record.track_id, "t099")},
                          {record.clip_id: ("t050",)})
    out = ResultContext(search).result_json(record, match, "q")
    assert out["referred_tracks"] == [record.track_id, "t099"] and out["related_tracks"] == ["t050"]
    assert out["preview_url"].endswith("/preview?referred=t099&related=t050")
    # Without rendered arrays for the clip the stored preview is served instead of a drawing.
    assert ResultContext(search).preview(record.clip_id, ["t099"], ["t050"]) is None


def test_embedding_map_has_every_clip_coloured_by_action(served: dict[str, Any]) -> None:
    body = served["client"].get("/api/map").json()
    assert len(body["points"]) == len(body["clip_ids"]) == len(served["rows"])
    xy = np.asarray([p[:2] for p in body["points"]])
    assert xy.min() >= 0 and xy.max() <= 1
    assert "braking" in body["actions"] and sum(body["action_counts"]) == len(served["rows"])
    assert served["client"].get("/api/map", params={"view": "lidar"}).status_code == 422


def test_api_docs_load_nothing_from_the_network(served: dict[str, Any]) -> None:
    client = served["client"]
    for path in ("/docs", "/redoc"):
        page = client.get(path)
        assert page.status_code == 200 and "https://" not in page.text and "http://" not in page.text
    from retrieval.service.docs_pages import docs_assets_dir

    if docs_assets_dir() is None:
        pytest.skip("fastapi-offline is not installed: /docs says how to get its assets")
    assert client.get("/docs-assets/swagger-ui-bundle.js").status_code == 200
    assert client.get("/docs-assets/redoc.standalone.js").status_code == 200


def test_a_short_scenario_answer_goes_on_with_the_next_best(served: dict[str, Any],
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """A program that selects 3 moments answers those first, then the search's next best, each said to be
    outside it; the pages end there."""
    search, client = served["search"], served["client"]
    chosen = tuple(r["clip_id"] for r in served["rows"][:3])
    monkeypatch.setattr(search.scenarios, "match", lambda query, table: ScenarioMatch(query, None, chosen))
    body = client.get("/api/search", params={"q": "keeps its distance ahead", "k": 8}).json()
    assert [r["program_selects"] for r in body["results"]] == [True] * 3 + [False] * 5
    assert {r["clip_id"] for r in body["results"][:3]} == set(chosen)
    assert [r["rank"] for r in body["results"]] == list(range(1, 9))
    assert body["scenario"]["filled"] == 5 and body["total"] == 8 and body["next_offset"] is None
    plain = client.get("/api/search", params={"q": "keeps its distance ahead", "k": 8, "program": "false"}).json()
    others = [r["clip_id"] for r in plain["results"] if r["clip_id"] not in chosen]
    assert [r["clip_id"] for r in body["results"][3:]] == others[:5]
    two = client.get("/api/search", params={"q": "keeps its distance ahead", "k": 2}).json()  # no fill: 3 selected
    assert [r["program_selects"] for r in two["results"]] == [True, True] and two["next_offset"] == 2
