"""Search keeps to the moments the query's scenario program selects, and says when it cannot."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from retrieval_fakes import HashTextEncoder

from retrieval.captions_search import CaptionSearch
from retrieval.cli import main
from retrieval.scenario_search import SCENARIOS_DIR, ScenarioStore, log_folders_of
from scenarios.cache import encode
from tests.scenarios.synthetic import car, cyclist, make_features
from tests.scenes.av2_fixtures import DEV_LOGS, require

Y = 50.0


def _moments(rows: list[tuple[str, str, int, int]]) -> pa.Table:
    return pa.table({"clip_id": [f"synthetic:{t}:{a}" for t, _, a, _ in rows], "log_id": ["synthetic"] * len(rows),
                     "track_id": [t for t, _, _, _ in rows], "start_ns": [a for _, _, a, _ in rows],
                     "end_ns": [b for _, _, _, b in rows]})


@pytest.fixture
def store(tmp_path: Path) -> tuple[ScenarioStore, np.ndarray]:
    beside = np.zeros(30, bool)
    beside[5:11] = True
    path = np.stack([np.zeros(30), np.where(beside, Y - 3, Y - 80)], axis=1)  # the cyclist is beside at 0.5–1 s
    turning = np.zeros(30, bool)
    turning[20:25] = True
    x = make_features([car((0, Y), id="car"), cyclist(path, id="bike")], frames=30)
    ego_flags = x.flags.copy()
    ego_flags[-1, 20:25] |= 1 << 4  # the ego turns left at 2–2.5 s ("left_turn" is bit 4)
    x = type(x)(**{**x.__dict__, "flags": ego_flags})
    folder = tmp_path / SCENARIOS_DIR
    folder.mkdir()
    (folder / "synthetic.features").write_bytes(encode(x, "s"))
    return ScenarioStore(folder), x.timestamps_ns


def test_the_program_selects_the_windows_where_it_holds(store: tuple[ScenarioStore, np.ndarray]) -> None:
    scenarios, ts = store
    moments = _moments([("car", "", int(ts[0]), int(ts[15])), ("car", "", int(ts[15]), int(ts[29])),
                        ("bike", "", int(ts[0]), int(ts[29]))])
    match = scenarios.match("vehicle with a bicycle to its right", moments)
    assert match.fallback is None and match.compiled is not None
    assert match.clip_ids == (f"synthetic:car:{ts[0]}",)
    assert match.referred[f"synthetic:car:{ts[0]}"] == ("car",) and match.related[f"synthetic:car:{ts[0]}"] == ("bike",)
    ego = scenarios.match("we turn left", moments)  # the ego's own moments have no clip: those of its log do
    assert set(ego.clip_ids) == {f"synthetic:car:{ts[15]}", f"synthetic:bike:{ts[0]}"}
    assert ego.to_dict()["program"] == "turning(ego, direction=left)"


def test_a_sequence_selects_the_windows_where_it_happens(tmp_path: Path) -> None:
    """"Drives off": the window that holds the car setting off, not those that hold only its stop or
    only its driving after it, although the program selects the car in both."""
    speed = np.where(np.arange(30) < 12, 0.0, 5.0)  # stopped for 1.2 s, then moving
    x = make_features([car((0, Y), id="car", speed=speed)], frames=30)
    folder = tmp_path / SCENARIOS_DIR
    folder.mkdir()
    (folder / "synthetic.features").write_bytes(encode(x, "s"))
    ts = x.timestamps_ns
    moments = _moments([("car", "", int(ts[0]), int(ts[8])), ("car", "", int(ts[8]), int(ts[16])),
                        ("car", "", int(ts[16]), int(ts[29]))])
    match = ScenarioStore(folder).match("a car that drives off", moments)
    assert match.compiled is not None and match.compiled.text == "then(stopped(car), moving(car), within_s=4)"
    assert match.clip_ids == (f"synthetic:car:{ts[8]}",)


def test_the_store_keeps_features_within_its_budget_and_answers_the_same(
        store: tuple[ScenarioStore, np.ndarray], monkeypatch: pytest.MonkeyPatch) -> None:
    """A query over a fleet's logs reads every log's features: the least recently used go past the
    budget, and are read again when asked for, to the same answer."""
    import retrieval.scenario_search as scenario_search

    scenarios, ts = store
    moments = _moments([("car", "", int(ts[0]), int(ts[15])), ("bike", "", int(ts[0]), int(ts[29]))])
    kept = scenarios.match("vehicle with a bicycle to its right", moments)
    one_log = scenarios.features("synthetic").nbytes  # type: ignore[union-attr]
    assert scenarios._features.total == one_log and scenarios.features("absent") is None
    monkeypatch.setattr(scenario_search, "FEATURES_KEPT_BYTES", one_log - 1)  # no log fits
    small = ScenarioStore(scenarios.folder)
    for _ in range(2):
        assert small.match("vehicle with a bicycle to its right", moments) == kept
        assert small._features.total == 0
    assert small.features("absent") is None and "absent" in small._features  # known to have none: kept


def test_the_search_says_why_it_ranks_every_moment(store: tuple[ScenarioStore, np.ndarray], tmp_path: Path) -> None:
    scenarios, ts = store
    moments = _moments([("car", "", int(ts[15]), int(ts[29]))])
    none = scenarios.match("vehicle with a bicycle to its right", moments)
    assert none.fallback == "the program selects none of the indexed moments" and not none.clip_ids
    words = scenarios.match("purple elephants", moments)
    assert words.compiled is None and "words not understood: purple, elephants" in str(words.fallback)
    bare = ScenarioStore(tmp_path / "none").match("vehicle", moments)
    assert "holds no scenario features" in str(bare.fallback)


def test_a_caption_index_answers_programs_on_its_logs(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("retrieval.captions_search.SentenceEncoder", HashTextEncoder)
    log = tmp_path / "logs" / require(DEV_LOGS["7fab2350"]).name
    log.parent.mkdir()
    log.symlink_to(DEV_LOGS["7fab2350"], target_is_directory=True)
    assert main(["caption", str(log), "--out", str(tmp_path / "captions")]) == 0
    assert json.loads((tmp_path / "captions" / "logs.json").read_text()) == {log.name: str(log.resolve())}
    CaptionSearch.build(tmp_path / "captions", tmp_path / "index", encoder=HashTextEncoder())
    index = CaptionSearch.open(tmp_path / "index", encoder=HashTextEncoder())
    results, match = index.search_scenario("vehicle with a pedestrian to its right", k=5)
    assert match.fallback is None and len(results) == 5
    assert all(match.referred[r.clip_id] for r in results)
    assert all(r.category in ("car", "truck", "bus") for r in results)
    plain = index.search("vehicle with a pedestrian to its right", k=50)
    assert {r.clip_id for r in plain} != {r.clip_id for r in results}
    capsys.readouterr()
    assert main(["search", str(tmp_path / "index"), "stopped(vehicle)", "-k", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["scenario"]["program"] == "stopped(vehicle)" and out["scenario"]["fallback"] is None
    assert all(r["referred_tracks"] and r["program_selects"] for r in out["results"])
    # A short answer: all the program selects, then the closest others, said to be outside it.
    _, short = index.search_scenario("vehicle with a pedestrian to its right", k=1, fill=False)
    k = len(short.clip_ids) + 3
    results, match = index.search_scenario("vehicle with a pedestrian to its right", k=k)
    assert len(results) == k and [r.rank for r in results] == list(range(1, k + 1))
    assert {r.clip_id for r in results[:-3]} == set(match.clip_ids) and len(match.filled) == 3
    assert [r.clip_id for r in results[-3:]] == list(match.filled)
    assert not any(match.selects(c) for c in match.filled) and all(match.selects(c) for c in match.clip_ids)
    assert [r.clip_id for r in results[-3:]] == [r.clip_id for r in plain if r.clip_id not in match.clip_ids][:3]
    unfilled, _ = index.search_scenario("vehicle with a pedestrian to its right", k=k, fill=False)
    assert [r.clip_id for r in unfilled] == [r.clip_id for r in results[:-3]]
    assert main(["search", str(tmp_path / "index"), "vehicle with a pedestrian to its right", "-k", str(k),
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [r["program_selects"] for r in out["results"]] == [True] * (k - 3) + [False] * 3
    assert out["scenario"]["filled"] == 3
    assert main(["search", str(tmp_path / "index"), "vehicle with a pedestrian to its right", "-k", str(k)]) == 0
    assert "the last 3 result(s) are the search's next best" in capsys.readouterr().out


@pytest.mark.parametrize("kind", ["log_left_out", "folder_gone"])
def test_a_log_without_scenario_features_is_reported_when_indexed(
        kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """``logs.json`` that leaves out a captioned log, or names a folder that is gone: the index says which
    log's moments scenario queries cannot select (exit 1), rather than leaving them out in silence."""
    monkeypatch.setattr("retrieval.captions_search.SentenceEncoder", HashTextEncoder)
    log = tmp_path / "logs" / require(DEV_LOGS["7fab2350"]).name
    log.parent.mkdir()
    log.symlink_to(DEV_LOGS["7fab2350"], target_is_directory=True)
    assert main(["caption", str(log), "--out", str(tmp_path / "captions")]) == 0
    listed = {"other-log": str(log.resolve())} if kind == "log_left_out" else {log.name: str(tmp_path / "gone")}
    (tmp_path / "captions" / "logs.json").write_text(json.dumps(listed))
    capsys.readouterr()
    assert main(["index", "--captions", str(tmp_path / "captions"), "--out", str(tmp_path / "index")]) == 1
    out = capsys.readouterr().out
    why = ("its folder is not recorded (no entry in the log list" if kind == "log_left_out"
           else f"its folder {tmp_path / 'gone'} cannot be read")
    assert f"note: no scenario features for log {log.name}: {why}" in out
    assert "1 log(s) without scenario features" in out


def test_an_unreadable_log_list_is_refused_naming_it(tmp_path: Path) -> None:
    (tmp_path / "logs.json").write_text('{"a": "/logs/a", "b": ')  # cut off mid-file
    with pytest.raises(ValueError, match=r"logs.json: unreadable \(Expecting value"):
        log_folders_of(tmp_path)
    (tmp_path / "logs.json").write_text('["/logs/a"]')
    with pytest.raises(ValueError, match="logs.json: expected an object of log id → folder, got list"):
        log_folders_of(tmp_path)



def test_what_several_logs_cannot_answer_is_said_once_naming_them(tmp_path: Path) -> None:
    folder = tmp_path / SCENARIOS_DIR
    folder.mkdir()
    x = make_features([car((0, Y), id="car")], frames=10)
    x = type(x)(**{**x.__dict__, "has_map": False})  # map predicates have no answer
    names = [f"log{i}" for i in range(5)]
    for name in names:
        (folder / f"{name}.features").write_bytes(encode(type(x)(**{**x.__dict__, "log_id": name}), "s"))
    ts = x.timestamps_ns
    moments = pa.table({"clip_id": [f"{n}:car:{ts[0]}" for n in names], "log_id": names, "track_id": ["car"] * 5,
                        "start_ns": [int(ts[0])] * 5, "end_ns": [int(ts[-1])] * 5})
    match = ScenarioStore(folder).match("a car at the crosswalk", moments)
    assert match.notes == ("log0, log1, log2 and 2 more logs: 'at_crosswalk' needs a map, and the log has none: "
                           "no answer there (not 'false')",)
