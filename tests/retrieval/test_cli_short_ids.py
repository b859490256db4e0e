"""Short ids (``#N`` and ``LOG/TRACK@SECONDSs``), the table that fits the terminal, and quiet model loading."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pytest

from retrieval.records import LogSpan, SearchResult, time_in_log
from retrieval.result_table import format_table
from retrieval.short_ids import MAX_REMEMBERED, ShortIdError, ShortIds, last_search, remember

LOG_A = "5620d013-d98a-5f82-8df8-e7b651f7d6b7"
LOG_B = "5620d013-ffff-5f82-8df8-e7b651f7d6b7"  # shares its first 8 characters with LOG_A
LOG_C = "ecea1f9d-59bc-57c4-b802-6f887e7469c0"
T0 = 1_700_000_060_000_000_000


def _moments() -> tuple[ShortIds, list[str]]:
    rows = [(LOG_A, "7a35f449-b158-562a-bfd9-98f08561f31e", 2.0), (LOG_A, "7a35f449-b158-562a-bfd9-98f08561f31e", 4.5),
            (LOG_A, "9b41ac9f-0000-562a-bfd9-98f08561f31e", 0.0), (LOG_B, "7a35f449-b158-562a-bfd9-98f08561f31e", 0.0),
            (LOG_C, "ego", 0.0), (LOG_C, "ego-2", 3.0), (LOG_C, "12", 1.0), (LOG_C, "123", 1.0)]
    starts = [T0 + int(s * 1e9) for _, _, s in rows]
    clip_ids = [f"{lg}:{tr}:{st}" for (lg, tr, _), st in zip(rows, starts)]
    return ShortIds(_table(clip_ids, [r[0] for r in rows], [r[1] for r in rows], starts)), clip_ids


def _table(clip_ids: list[str], logs: list[str], tracks: list[str], starts: list[int]) -> pa.Table:
    """Index metadata: moments 1.5 s long."""
    return pa.table({"clip_id": clip_ids, "log_id": logs, "track_id": tracks, "start_ns": pa.array(starts, pa.int64()),
                     "end_ns": pa.array([s + 1_500_000_000 for s in starts], pa.int64())})


def _parts(clip_id: str) -> tuple[str, str, int]:
    log_id, track_id, start = clip_id.split(":")
    return log_id, track_id, int(start)


def test_readable_ids_round_trip_and_lengthen_shared_prefixes(tmp_path: Path) -> None:
    short, clip_ids = _moments()
    ids = {c: short.readable(*_parts(c)) for c in clip_ids}
    assert ids[f"{LOG_A}:7a35f449-b158-562a-bfd9-98f08561f31e:{T0 + 4_500_000_000}"] \
        == "5620d013-d/7a35f449@4.5s"  # the log's 8 characters name two logs: one more each
    assert ids[f"{LOG_C}:12:{T0 + 1_000_000_000}"] == "ecea1f9d/12@1.0s"
    assert len(set(ids.values())) == len(ids)
    for clip_id, readable in ids.items():
        assert short.resolve(readable, tmp_path) == clip_id
        assert short.resolve(clip_id, tmp_path) == clip_id
    # A whole id wins over a longer one it begins ("12" and "123"); a shorter prefix works where it names one.
    assert short.resolve("ecea/123@1.0s", tmp_path) == f"{LOG_C}:123:{T0 + 1_000_000_000}"
    assert short.resolve("5620d013-f/7a@0s", tmp_path) == f"{LOG_B}:7a35f449-b158-562a-bfd9-98f08561f31e:{T0}"


@pytest.mark.parametrize(("text", "named"), [
    ("5620d013/7a35f449@2.0s", [LOG_A, LOG_B]),  # the log prefix names two logs
    ("5620d013-d/9@2.0s", ["5620d013-d/9b41ac9f@0.0s"]),  # one track, not at 2.0 s: its moments listed
    ("5620d013-d/7a35f449@3.0s", ["5620d013-d/7a35f449@2.0s", "5620d013-d/7a35f449@4.5s"]),
    ("ecea1f9d/eg@0.0s", ["ego", "ego-2"]),  # the track prefix names two tracks
    ("ffff/ego@0.0s", ["5620d013-d", "ecea1f9d"]),  # no such log: the logs are listed
    ("log:track:1", ["LOG/TRACK@SECONDSs"]),  # not indexed, not a short id: how to name a clip
])
def test_unknown_or_ambiguous_short_ids_are_refused_naming_candidates(tmp_path: Path, text: str,
                                                                      named: list[str]) -> None:
    with pytest.raises(ShortIdError) as caught:
        _moments()[0].resolve(text, tmp_path)
    assert all(n in str(caught.value) for n in named), str(caught.value)


def test_ranks_of_the_last_search_are_remembered_per_index(tmp_path: Path) -> None:
    state = tmp_path / "cache" / "last_search.json"
    short, clips = _moments()
    with pytest.raises(ShortIdError, match="no search of .* is remembered"):
        short.resolve("#1", tmp_path / "index", state)
    remember(tmp_path / "index", "a car", clips[:3], state)
    remember(tmp_path / "other", "a bus", clips[3:], state)
    assert short.resolve("#2", tmp_path / "index", state) == clips[1]
    assert short.resolve(" #2 ", tmp_path / "other", state) == clips[4]
    with pytest.raises(ShortIdError, match=r"#4: the last search of .* \('a car'\) has 3 result\(s\): #1 … #3"):
        short.resolve("#4", tmp_path / "index", state)
    remember(tmp_path / "index", "gone", ["log:track:1"], state)
    with pytest.raises(ShortIdError, match="no longer in"):
        short.resolve("#1", tmp_path / "index", state)
    for i in range(MAX_REMEMBERED + 3):
        remember(tmp_path / f"index{i}", "q", clips[:1], state)
    assert len(json.loads(state.read_text())["searches"]) == MAX_REMEMBERED
    assert last_search(tmp_path / "other", state) is None and last_search(tmp_path / "index40", state) is None
    state.write_text("not json")  # a damaged state file is as good as none
    assert last_search(tmp_path / "index34", state) is None


def test_the_time_in_an_id_counts_from_the_logs_first_frame_where_known() -> None:
    starts = [T0 + 5_000_000_000, T0 + 7_000_000_000]
    table = _table(["a:t:1", "a:t:2"], ["a", "a"], ["t", "t"], starts)
    plain = ShortIds(table)
    framed = ShortIds(table, read_spans=lambda logs: {"a": LogSpan(T0, T0 + 20 * 10**9)})
    assert [plain.readable("a", "t", s) for s in starts] == ["a/t@0.0s", "a/t@2.0s"]  # from the first moment
    assert [framed.readable("a", "t", s) for s in starts] == ["a/t@5.0s", "a/t@7.0s"]  # from the first frame
    assert framed.resolve("a/t@7s", "index") == "a:t:2"


def _result(rank: int, caption: str, category: str = "car") -> SearchResult:
    start = T0 + rank * 1_000_000_000
    return SearchResult(rank, f"{LOG_A}:track-{rank:04d}-b158-562a-bfd9-98f08561f31e:{start}", LOG_A,
                        f"track-{rank:04d}-b158-562a-bfd9-98f08561f31e", category, start, start + 3_500_000_000,
                        caption, ("left:approach",), 0.5 + rank / 100, None, "fused")


@pytest.mark.parametrize("width", [56, 80, 100, 140])
def test_the_table_fits_the_width_and_shows_the_whole_caption_object_first(width: int) -> None:
    caption = ("The ego vehicle is decelerating while turning left at the intersection. A pedestrian in the "
               "crosswalk on the right approaches, then stops, then moves away from the ego lane.")
    results = [_result(r, caption, "pedestrian") for r in range(1, 11)]
    spans = {LOG_A: LogSpan(T0, T0 + 20 * 10**9)}
    table = format_table(results, width, spans=spans)
    assert max(len(line) for line in table.splitlines()) <= width
    first = table.splitlines()[3:]
    text = " ".join(line.strip() for line in first[1:first.index(next(ln for ln in first[1:] if ln[:1].isdigit()))])
    when = str(time_in_log(results[0], spans[LOG_A]))
    narrow = width < 70  # the time opens the caption's lines where the fields do not fit on one
    assert text == (f"{when}: " if narrow else "") + (
        "A pedestrian in the crosswalk on the right approaches, then stops, then moves away from the ego lane. "
        "The ego vehicle is decelerating while turning left at the intersection.")
    assert (when in first[0]) is not narrow
    assert LOG_A not in table  # the long ids are never printed


def test_the_table_of_no_results() -> None:
    assert format_table([], 100) == "(no results)"


def _stderr_of(code: str) -> str:
    from retrieval.cli import QUIET_LIBRARIES

    # A CLI test earlier in this process may have set the switches in its environment.
    env = {k: v for k, v in os.environ.items() if k not in QUIET_LIBRARIES}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).parents[2], env=env)
    assert done.returncode == 0, done.stderr
    return done.stderr


def test_no_progress_bar_of_the_model_loading_libraries_unless_verbose() -> None:
    """transformers draws its "Loading weights" bar through its logging's tqdm: silenced by the CLI's
    switches before transformers is imported, and after."""
    bar = "from transformers.utils.logging import tqdm\nfor _ in tqdm(range(3), desc='Loading weights'): pass\n"
    quiet = "from retrieval.cli import _quiet_libraries\n_quiet_libraries()\n"
    assert "Loading weights" in _stderr_of(bar)  # what --verbose leaves on
    assert "Loading weights" not in _stderr_of(quiet + bar)
    assert "Loading weights" not in _stderr_of("import transformers\n" + quiet + bar)
