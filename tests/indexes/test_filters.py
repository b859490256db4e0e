import numpy as np
import pyarrow as pa
import pytest

from indexes.errors import FilterError
from indexes.filters import Condition, Op, check, compile_mask, conditions_of, parse


@pytest.fixture
def table() -> pa.Table:
    return pa.table({
        "id": pa.array([0, 1, 2, 3, 4], pa.int64()),
        "clip_id": ["a", "b", "c", "d", "e"],
        "category": ["car", "truck", "pedestrian", "car", None],
        "log_id": ["log1", "log1", "log2", "log2", "log3"],
        "start_ns": pa.array([10, 20, 30, 40, 50], pa.int64()),
        "speed_mps": [1.5, 10.0, 0.5, 7.25, 3.0],
        "night": [True, False, False, True, False],
        "tags": [["left:approach", "host:stop"], ["right:overtake"], [], ["left:approach"], None],
    })


def rows(table: pa.Table, spec: object) -> list[int]:
    return np.flatnonzero(compile_mask(table, spec)).tolist()  # type: ignore[arg-type]


def test_parse_the_documented_forms() -> None:
    assert parse('category in {car, truck} and log_id == "abc" and tags contains "left:approach"') == [
        Condition("category", Op.IN, ("car", "truck")),
        Condition("log_id", Op.EQ, "abc"),
        Condition("tags", Op.CONTAINS, "left:approach"),
    ]
    assert parse("start_ns >= 123 AND start_ns<200")[1] == Condition("start_ns", Op.LT, "200")
    assert parse("category not in [car]")[0].op is Op.NOT_IN


@pytest.mark.parametrize(("spec", "expected"), [
    ("category in {car, truck}", [0, 1, 3]),
    ("category == car and log_id == log2", [3]),
    ("log_id != log1", [2, 3, 4]),
    ('tags contains "left:approach"', [0, 3]),
    ("tags contains host:stop", [0]),
    ("start_ns >= 20 and start_ns < 50", [1, 2, 3]),
    ("speed_mps > 2.5", [1, 3, 4]),
    ("night == true", [0, 3]),
    ("category not in {car}", [1, 2]),  # null never matches
    ("log_id contains 2", [2, 3]),
    ('clip_id == "c"', [2]),
    ("category in {bicycle}", []),
    ({"category": ["car", "truck"]}, [0, 1, 3]),
    ({"log_id": "log1", "start_ns": {">": 10}}, [1]),
    ({"tags": "left:approach"}, [0, 3]),
    ({"tags": {"contains": "right:overtake"}}, [1]),
    ([Condition("start_ns", Op.LE, 20)], [0, 1]),
    (None, [0, 1, 2, 3, 4]),
])
def test_filters_select_matching_rows(table: pa.Table, spec: object, expected: list[int]) -> None:
    assert rows(table, spec) == expected


def test_unknown_field_lists_valid_fields(table: pa.Table) -> None:
    with pytest.raises(FilterError, match=r"field 'colour'.*valid fields: category, clip_id") as info:
        compile_mask(table, "colour == red")
    assert info.value.field == "colour"


@pytest.mark.parametrize(("spec", "pattern"), [
    ("start_ns >= soon", "field 'start_ns'.*not an integer"),
    ("speed_mps < fast", "not a number"),
    ("night == maybe", "true or false"),
    ("tags > 3", "only 'contains'"),
    ("start_ns contains 3", "'contains' needs"),
])
def test_values_of_the_wrong_type(table: pa.Table, spec: str, pattern: str) -> None:
    with pytest.raises(FilterError, match=pattern):
        compile_mask(table, spec)
    # The schema alone gives the same error, before any row is read.
    with pytest.raises(FilterError, match=pattern):
        check(parse(spec), table.schema, spec)


def test_check_against_the_schema_passes_what_compiles(table: pa.Table) -> None:
    dictionary = table.set_column(2, "category", pa.array(table.column("category").to_pylist()).dictionary_encode())
    for spec in ("category in {car, truck} and tags contains host:stop", "start_ns >= 20 and night == true"):
        check(parse(spec), dictionary.schema, spec)
    with pytest.raises(FilterError, match=r"filter 'colour == red', field 'colour': unknown field"):
        check(parse("colour == red"), table.schema, "colour == red")


@pytest.mark.parametrize("spec", [
    "category", "category ~ car", "category in {car", "category == car or log_id == x",
    "== car", "category == car and", "category in", 'log_id == "unterminated',
])
def test_syntax_errors(spec: str) -> None:
    with pytest.raises(FilterError):
        parse(spec)


def test_dict_with_unknown_operator() -> None:
    with pytest.raises(FilterError, match="unknown operator"):
        conditions_of({"start_ns": {"~": 3}})
