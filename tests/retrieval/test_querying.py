"""One check of a query's k and filters, whatever form the filter takes and whoever asks."""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pyarrow as pa
import pytest

from indexes.clip_index import ClipIndex
from indexes.filters import Condition, Op
from indexes.metadata import MetadataStore
from retrieval.errors import FilterSyntaxError, InvalidKError
from retrieval.querying import (
    MAX_K,
    MAX_QUERY_CHARS,
    Query,
    QueryTextError,
    QueryTooLongError,
    build_query,
    check_k,
    check_query,
    hits_to_results,
    parse_cli_filters,
)

ROWS = [{"clip_id": f"c{i}", "category": ["car", "truck", "pedestrian"][i % 3], "start_ns": 10 * i,
         "tags": [["left:approach"], ["host:stop"], []][i % 3]} for i in range(6)]


@pytest.fixture(scope="module")
def metadata() -> MetadataStore:
    return MetadataStore.from_rows(pa.Table.from_pylist(ROWS), np.arange(len(ROWS)))


@pytest.mark.parametrize("k", [0, -1, MAX_K + 1, 2.5, True, "3", None])
def test_k_outside_1_to_max_k_names_the_parameter(metadata: MetadataStore, k: Any) -> None:
    with pytest.raises(InvalidKError, match=rf"^k must be an integer in 1 … {MAX_K}, got k={k!r}$"):
        build_query(k, None, metadata, len(metadata))


def test_k_is_capped_by_what_the_search_can_return(metadata: MetadataStore) -> None:
    assert build_query(50, None, metadata, 5) == Query(5, None)
    assert build_query(np.int64(2), None, metadata, 5) == Query(2, None)
    assert build_query(3, None, metadata, 0).k == 0
    with pytest.raises(InvalidKError, match="in 1 … 20, got k=21"):
        build_query(21, None, metadata, 5, max_k=20)
    assert check_k(7, max_k=20) == 7


@pytest.mark.parametrize("spec", [{"colour": "red"}, "colour == red", [Condition("colour", Op.EQ, "red")],
                                  {"id": 3}, "id == 3"])
def test_unknown_fields_get_one_message_in_every_form(metadata: MetadataStore, spec: Any) -> None:
    field = "colour" if "colour" in str(spec) else "id"
    with pytest.raises(FilterSyntaxError,
                       match=rf"^unknown filter field '{field}'; valid fields: clip_id, category, start_ns, tags$"):
        build_query(3, spec, metadata, len(metadata))


@pytest.mark.parametrize(("spec", "needle"), [
    ("start_ns >= soon", r"filter 'start_ns >= soon', field 'start_ns': 'soon' is not an integer"),
    ({"start_ns": {"~": 3}}, "unknown operator"),
    ("tags > 3", "only 'contains'"),
    ("category ==", "a value is missing"),
])
def test_unreadable_filters_are_caught_before_any_search(metadata: MetadataStore, spec: Any, needle: str) -> None:
    with pytest.raises(FilterSyntaxError, match=rf"{needle}.*; valid fields: clip_id, category"):
        build_query(3, spec, metadata, len(metadata))


def test_filters_become_conditions_once(metadata: MetadataStore) -> None:
    query = build_query(3, "category in {car, truck} and start_ns >= 10", metadata, len(metadata))
    assert query.filters == (Condition("category", Op.IN, ("car", "truck")), Condition("start_ns", Op.GE, "10"))
    assert build_query(3, parse_cli_filters(["category=car,truck"]), metadata, 6).filters == (
        Condition("category", Op.IN, ("car", "truck")),)
    with pytest.raises(FilterSyntaxError, match="expected FIELD=VALUE"):
        parse_cli_filters(["category="])


def test_hits_come_from_the_checked_query(metadata: MetadataStore) -> None:
    x = np.eye(len(ROWS), dtype=np.float32)
    index = ClipIndex.build(x, ROWS, factory="Flat")
    query = build_query(100, {"category": "car"}, index.metadata, len(index))
    results = hits_to_results(index, x[:1], query, "fused", None)
    assert [r.clip_id for r in results] == ["c0", "c3"] and [r.rank for r in results] == [1, 2]
    others = hits_to_results(index, x[:1], build_query(100, None, index.metadata, len(index) - 1), "fused", None,
                             exclude_clip="c0")
    assert len(others) == len(ROWS) - 1 and "c0" not in {r.clip_id for r in others}
    assert hits_to_results(index, x[:1], Query(0, None), "fused", None, exclude_clip="c0") == []


def test_the_camera_view_keeps_to_the_clips_the_camera_saw(metadata: MetadataStore) -> None:
    seen = MetadataStore.from_rows(pa.Table.from_pylist([r | {"has_camera": i % 2 == 0} for i, r in enumerate(ROWS)]),
                                   np.arange(len(ROWS)))
    camera = Condition("has_camera", Op.EQ, True)
    assert build_query(3, None, seen, 6, view="camera").filters == (camera,)
    assert build_query(3, {"category": "car"}, seen, 6, view="camera").filters == (
        Condition("category", Op.EQ, "car"), camera)
    assert build_query(3, None, seen, 6, view="fused").filters is None  # other views: every clip
    assert build_query(3, None, metadata, 6, view="camera").filters is None  # an index that does not record it


@pytest.mark.parametrize(("text", "error", "needle"), [
    ("x" * (MAX_QUERY_CHARS + 1), QueryTooLongError,
     f"query is {MAX_QUERY_CHARS + 1} characters; the limit is {MAX_QUERY_CHARS}"),
    ("a car\x00", QueryTextError, "query holds the control character U+0000 at character 5"),
    ("a car\x1b[2J", QueryTextError, "control character U+001B"),
    ("a car\x85", QueryTextError, "control character U+0085"),
    ("a car\x0b", QueryTextError, "control character U+000B"),
    ("a car\udcff", QueryTextError, "query is not valid UTF-8: byte 0xff at character 5"),
    ("a car\ud800", QueryTextError, "query is not valid text: lone surrogate U+D800"),
])
def test_a_query_is_short_text(text: str, error: type[Exception], needle: str) -> None:
    with pytest.raises(error, match=re.escape(needle)):
        check_query(text)


def test_ordinary_whitespace_and_any_script_pass_and_the_name_and_limit_are_the_callers() -> None:
    assert check_query(" a car\tturns\r\nleft — 左折 🚗 ") == "a car\tturns\r\nleft — 左折 🚗"
    assert check_query("x" * MAX_QUERY_CHARS) == "x" * MAX_QUERY_CHARS
    with pytest.raises(QueryTooLongError, match="^parameter 'q' is 11 characters; the limit is 10$"):
        check_query("x" * 11, "parameter 'q'", max_chars=10)


def test_every_search_of_the_api_takes_the_one_query_check(built: dict[str, Any]) -> None:
    """SceneSearch and CaptionSearch refuse what the CLI and the service refuse, before any model runs."""
    search = built["search"]
    long_query = "a car approaches " * 6200  # about 104 kB
    for call in (search.search_text, search.search_hybrid, search.search_captions, search.captions.search):
        with pytest.raises(QueryTooLongError, match=f"^query is {len(long_query)} characters; the limit is 500$"):
            call(long_query)
        with pytest.raises(QueryTextError, match="U\\+0000"):
            call("a car\x00 approaches")


def test_a_vocabulary_value_no_clip_has_is_refused_with_the_values(metadata: MetadataStore) -> None:
    """``category=tuck``: a typo, said with the values the field holds, rather than an empty answer."""
    with pytest.raises(FilterSyntaxError, match=r"filter field 'category': no clip has the value 'tuck'; its "
                                                r"values: car, pedestrian, truck"):
        build_query(5, {"category": "tuck"}, metadata, len(ROWS))
    assert build_query(5, {"category": ["tuck", "car"]}, metadata, len(ROWS)).filters  # one value is there

