"""The index/search/similar/export/eval commands, with the stand-in model swapped in."""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from retrieval_fakes import FakeEmbedder, HashTextEncoder, caption_of

import retrieval.embedding as embedding
import retrieval.scenesearch as scenesearch
from encoders.model_card import MODEL_CARD_FILE
from retrieval.cli import main


@pytest.fixture(autouse=True)
def own_cache(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """The commands remember their last search in the user's cache folder: a folder of the test's own."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


@pytest.fixture
def stand_in(monkeypatch: pytest.MonkeyPatch, built: dict[str, Any]) -> dict[str, Any]:
    """Commands load the stand-in model and the hashing sentence encoder instead of the real ones."""
    monkeypatch.setattr(scenesearch, "ModelEmbedder",
                        lambda run_dir, expected_model_id=None: FakeEmbedder(embedding.model_hash(run_dir)))
    real = embedding.ModelEmbedder

    def checked(run_dir: Path, **options: Any) -> FakeEmbedder:
        real(run_dir, **options)  # the options are checked as the real one checks them (it loads nothing yet)
        return FakeEmbedder(embedding.model_hash(run_dir))

    monkeypatch.setattr(embedding, "ModelEmbedder", checked)
    monkeypatch.setattr("retrieval.captions_search.SentenceEncoder", HashTextEncoder)
    monkeypatch.setattr("retrieval.evaluation.ModelEmbedder",
                        lambda run_dir: FakeEmbedder(embedding.model_hash(run_dir)))
    return built


def test_index_command(stand_in: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "index"
    assert main(["index", str(stand_in["run"]), str(stand_in["clips"]), "--out", str(out), "--device", "cpu",
                 "--batch-size", "16", "--num-workers", "1"]) == 0
    printed = capsys.readouterr().out
    assert "view fused" in printed and f"wrote {out}" in printed
    assert json.loads((out / "manifest.json").read_text())["counts"]["fused"] == 84
    assert "hybrid weight" in printed and "chosen on 14 val clips" in printed
    given = tmp_path / "given"
    assert main(["index", str(stand_in["run"]), str(stand_in["clips"]), "--out", str(given),
                 "--hybrid-weight", "0.9"]) == 0
    assert "hybrid weight 0.9 (rule captions' share), given when the index was built" in capsys.readouterr().out
    recorded = json.loads((given / "manifest.json").read_text())["hybrid"]
    assert recorded["weight"] == 0.9 and recorded["given"] is True and recorded["curve"] == []
    assert main(["index", str(stand_in["run"]), str(stand_in["clips"]), "--out", str(tmp_path / "bad"),
                 "--hybrid-weight", "2"]) == 2
    assert "in [0, 1]" in capsys.readouterr().err and not (tmp_path / "bad").exists()


def test_search_table_and_json(stand_in: dict[str, Any], capsys: pytest.CaptureFixture[str]) -> None:
    query = caption_of(["left:approach", "left:cut_in"])
    assert main(["search", str(stand_in["index"]), query, "-k", "3", "--filter", "category=car", "--no-program"]) == 0
    table = capsys.readouterr().out
    assert table.splitlines()[0].split()[:4] == ["#", "id", "score", "category"]
    assert sum(1 for line in table.splitlines() if line[:1].isdigit()) == 3  # one line of fields per result
    assert main(["search", str(stand_in["index"]), query, "-k", "3", "--filter", "category=car"]) == 0
    said = capsys.readouterr().out.splitlines()
    assert said[0].startswith("program: ")
    assert "ranking every moment: this index holds no scenario features (build it again to answer scenario programs)" \
        in " ".join(line.strip() for line in said)  # wrapped to the terminal
    assert said[-len(table.strip().splitlines()):] == table.strip().splitlines()  # no features: the same ranking
    assert main(["search", str(stand_in["index"]), query, "-k", "4", "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["query"] == query and len(payload["results"]) == 4
    assert all(r["caption"] == query for r in payload["results"])
    assert main(["search", str(stand_in["index"]), "stops ahead of the host", "--captions", "--json", "-k", "2"]) == 0
    assert all(r["view"] == "captions" for r in json.loads(capsys.readouterr().out)["results"])


def test_search_hybrid(stand_in: dict[str, Any], capsys: pytest.CaptureFixture[str]) -> None:
    index, query = str(stand_in["index"]), caption_of(["left:approach", "left:cut_in"])
    assert main(["search", index, query, "--hybrid", "--json", "-k", "3"]) == 0
    payload = json.loads(capsys.readouterr().out)
    recorded = json.loads((stand_in["index"] / "manifest.json").read_text())["hybrid"]["weight"]
    assert payload["hybrid_weight"] == recorded and len(payload["results"]) == 3
    assert payload["results"][0]["caption"] == query
    # The weight's ends: the model alone ranks as plain search does.
    assert main(["search", index, query, "--hybrid", "--weight", "0", "--json", "-k", "5"]) == 0
    mixed = [r["clip_id"] for r in json.loads(capsys.readouterr().out)["results"]]
    assert main(["search", index, query, "--json", "-k", "5"]) == 0
    assert mixed == [r["clip_id"] for r in json.loads(capsys.readouterr().out)["results"]]
    for args, message in ((["--weight", "0.5"], "add --hybrid"), (["--hybrid", "--weight", "1.5"], "in [0, 1]")):
        assert main(["search", index, query, *args]) == 2
        assert message in capsys.readouterr().err


@pytest.mark.parametrize(("argv", "message"), [
    (["search", "{index}", "  "], "the query is empty"),
    (["search", "{index}", "a car", "-k", "0"], "k must be an integer in 1"),
    (["search", "{index}", "a car", "--filter", "colour=red"], "valid fields: clip_id, log_id"),
    (["similar", "{index}", "no:such:clip"], "unknown clip id 'no:such:clip'"),
    (["export", "{index}", "--out", "x.csv"], "use .parquet or .npy"),
    (["eval", "{run}", "{clips}", "--split", "dev"], "unknown split 'dev'"),
    (["index", "{run}", "{clips}", "--out", "{index}_x", "--device", "gpu"], "must be 'auto', 'cpu' or 'cuda[:i]'"),
    (["index", "{run}", "{clips}", "--out", "{index}_x", "--batch-size", "0"], "--batch-size 0: must be at least 1"),
])
def test_bad_input_exits_2(stand_in: dict[str, Any], capsys: pytest.CaptureFixture[str], argv: list[str],
                           message: str) -> None:
    args = [a.format(index=stand_in["index"], run=stand_in["run"], clips=stand_in["clips"]) for a in argv]
    assert main(args) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(("argv", "message"), [
    (["search", "{index}", "a car approaches " * 6200], "argument QUERY is 105400 characters; the limit is 500"),
    (["search", "{index}", "a car\x00 approaches"], "argument QUERY holds the control character U+0000"),
    (["search", "{index}", "a car\udcff"], "argument QUERY is not valid UTF-8: byte 0xff at character 5"),
    (["search", "{index}", "a car", "--captions", "--filter", "category=car\x07"],
     "--filter holds the control character U+0007"),
    (["similar", "{index}", "x" * 600], "argument CLIP_ID is 600 characters; the limit is 500"),
], ids=["long-query", "nul", "not-utf8", "filter-control", "long-clip-id"])
def test_the_cli_takes_the_query_check_of_the_api_and_the_service(
        stand_in: dict[str, Any], capsys: pytest.CaptureFixture[str], argv: list[str], message: str) -> None:
    args = [a.replace("{index}", str(stand_in["index"])) for a in argv]
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.startswith(f"scenesearch {argv[0]}: error: {message}") and err.count("\n") == 1, err


def test_similar_and_export(stand_in: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    clip_id = str(pq.read_table(stand_in["clips"] / "clips.parquet").column("clip_id")[5])
    assert main(["similar", str(stand_in["index"]), clip_id, "-k", "3", "--json"]) == 0
    results = json.loads(capsys.readouterr().out)["results"]
    assert len(results) == 3 and clip_id not in {r["clip_id"] for r in results}
    # Its log's clips at the same time (windows 1.5 s long, a second apart: the one before and after) left out.
    assert main(["similar", str(stand_in["index"]), clip_id, "-k", "83", "--other-moments", "--json"]) == 0
    others = {r["clip_id"] for r in json.loads(capsys.readouterr().out)["results"]}
    log_id, _, start = clip_id.split(":")
    assert len(others) == 81 and not any(c.startswith(log_id) and abs(int(c.split(":")[2]) - int(start)) <= 1e9
                                         for c in others)
    assert main(["similar", str(stand_in["index"]), clip_id, "--view", "bev"]) == 0
    assert capsys.readouterr().out.startswith(f"query: {clip_id.split(':')[0][:8]}/")
    out = tmp_path / "emb.parquet"
    assert main(["export", str(stand_in["index"]), "--out", str(out)]) == 0
    assert pq.read_table(out).num_rows == 84
    assert main(["export", str(stand_in["index"]), "--out", str(tmp_path / "emb.npy")]) == 0
    assert (tmp_path / "emb.json").is_file()
    # A file written inside the index would change it under its manifest; a .npy holds one view.
    assert main(["export", str(stand_in["index"]), "--out", str(stand_in["index"] / "emb.parquet")]) == 2
    assert not (stand_in["index"] / "emb.parquet").exists()
    assert main(["export", str(stand_in["index"]), "--out", str(tmp_path / "two.npy"), "--view", "camera",
                 "--view", "bev"]) == 2
    assert "a .npy file holds one view" in capsys.readouterr().err and not (tmp_path / "two.npy").exists()


def test_eval_command(stand_in: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "metrics.json"
    assert main(["eval", str(stand_in["run"]), str(stand_in["clips"]), "--out", str(out)]) == 0
    metrics = json.loads(out.read_text())
    reused = tmp_path / "metrics_reused.json"
    assert main(["eval", str(stand_in["run"]), str(stand_in["clips"]), "--out", str(reused),
                 "--index", str(stand_in["index"])]) == 0
    # The index holds the same model's embeddings: the figures are the same.
    assert json.loads(reused.read_text())["text_to_clip"] == metrics["text_to_clip"]
    assert metrics["split"] == "test" and "baselines" in metrics
    assert "text→clip R@1" in capsys.readouterr().out


def test_eval_writes_its_figures_into_the_model_card(stand_in: dict[str, Any], tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(stand_in["run"], run)
    card = run / MODEL_CARD_FILE
    before = card.read_text() if card.is_file() else ""
    out = tmp_path / "metrics.json"
    assert main(["eval", str(run), str(stand_in["clips"]), "--out", str(out)]) == 0
    assert (card.read_text() if card.is_file() else "") == before  # only when asked
    for _ in range(2):  # evaluated again: the section is replaced, not added twice
        assert main(["eval", str(run), str(stand_in["clips"]), "--out", str(out), "--model-card"]) == 0
    text = card.read_text()
    assert text.startswith(before.rstrip("\n"))
    heading = f"## Evaluation: split test of `{Path(stand_in['clips']).resolve()}`"
    assert text.count(heading) == 1 and text.count("## Evaluation") == 1
    section = text[text.index(heading):]
    assert "| figure | model | camera only | bev only | bag of frames | random | rule captions |" in section
    r1 = json.loads(out.read_text())["text_to_clip"]["R@1"]
    assert f"| text→clip R@1 | {r1:.3f} |" in section


def test_caption_only_index(stand_in: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Logs with tracks but no sensors: index the rule captions alone and search them."""
    captions = tmp_path / "captions"
    captions.mkdir()
    table = pq.read_table(stand_in["clips"] / "clips.parquet").drop_columns(["clip_id", "preview_path"])
    pq.write_table(table, captions / "captions.parquet")
    out = tmp_path / "caption_index"
    assert main(["index", "--captions", str(captions), "--out", str(out)]) == 0
    assert "84 captions" in capsys.readouterr().out
    assert main(["search", str(out), "stops ahead of the host", "-k", "3", "--filter", "category=car", "--json"]) == 0
    results = json.loads(capsys.readouterr().out)["results"]
    assert len(results) == 3 and all(r["category"] == "car" and "stops ahead" in r["caption"] for r in results)
    assert main(["search", str(out), "stops ahead of the host", "--hybrid"]) == 2
    assert "hybrid search needs the model's clip embeddings" in capsys.readouterr().err
    assert main(["index", str(stand_in["run"]), "--out", str(out)]) == 2
    assert "give RUN_DIR and CLIPS_DIR" in capsys.readouterr().err
    assert main(["index", "--captions", str(captions), "--out", str(out), "--hybrid-weight", "1"]) == 2
    assert "a caption index has no model embeddings" in capsys.readouterr().err


def test_the_output_fits_100_columns(stand_in: dict[str, Any], monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("COLUMNS", "100")
    index, query = str(stand_in["index"]), caption_of(["left:approach", "left:cut_in"]) + " " + "very " * 40 + "late"
    for argv in (["search", index, query], ["search", index, query, "--captions", "-k", "20"],
                 ["search", index, query, "--no-program", "--hybrid"], ["similar", index, "#3"]):
        assert main(argv) == 0, capsys.readouterr().err
        out = capsys.readouterr().out
        assert max(len(line) for line in out.splitlines()) <= 100, argv
        assert not re.search(r"log\d+:", out)  # short ids, never the long clip ids


def test_short_ids_round_trip_through_similar(stand_in: dict[str, Any], capsys: pytest.CaptureFixture[str]) -> None:
    index = str(stand_in["index"])
    assert main(["search", index, caption_of(["left:approach"]), "-k", "5", "--json"]) == 0
    found = json.loads(capsys.readouterr().out)["results"]
    for named, rank in (("#2", 2), (found[2]["short_id"], 3), (found[3]["clip_id"], 4)):
        assert main(["similar", index, named, "--json", "-k", "2"]) == 0
        assert json.loads(capsys.readouterr().out)["clip_id"] == found[rank - 1]["clip_id"]
    # `similar` remembers its own results: #1 is now its best match.
    assert main(["similar", index, "#1", "--json", "-k", "2"]) == 0
    assert main(["similar", index, found[0]["clip_id"], "-k", "2"]) == 0
    table = capsys.readouterr().out
    assert f"query: {found[0]['short_id']}" in table
    for named, message in (("#6", "has 2 result(s): #1 … #2"), ("log0/t000@0.0s", "names 6 logs: log00, log01"),
                           ("log00/t000@9.9s", "its moments: log00/t000@0.0s"), ("nope", "unknown clip id 'nope'")):
        assert main(["similar", index, named]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err


def test_libraries_stay_quiet_unless_verbose(stand_in: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    from retrieval.cli import QUIET_LIBRARIES

    for name in QUIET_LIBRARIES:
        monkeypatch.delenv(name, raising=False)
    assert main(["search", str(stand_in["index"]), "a car", "--verbose", "--json"]) == 0
    assert not any(name in os.environ for name in QUIET_LIBRARIES)
    assert main(["--verbose", "similar", str(stand_in["index"]), "#1", "--json"]) == 0
    assert not any(name in os.environ for name in QUIET_LIBRARIES)
    assert main(["search", str(stand_in["index"]), "a car", "--json"]) == 0
    assert {name: os.environ[name] for name in QUIET_LIBRARIES} == QUIET_LIBRARIES
