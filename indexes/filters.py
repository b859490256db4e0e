"""A small filter language over clip metadata, compiled to a boolean row mask with pyarrow.

String form — clauses joined by ``and``::

    category in {car, truck} and log_id == "abc" and tags contains "left:approach"
    start_ns >= 1700000000000000000 and end_ns < 1700000005000000000
    time_of_day == night and appearance != occluded

Operators: ``==``, ``!=``, ``<``, ``<=``, ``>``, ``>=``, ``in``, ``not in``, ``contains``.
Values are bare words or numbers, quoted strings (``"…"`` or ``'…'``), or sets ``{a, b}`` / ``[a, b]``.
``contains`` tests membership in a list column (``tags``) or a substring of a text column.

Dict form — one entry per field, all must hold::

    {"category": ["car", "truck"]}            # in
    {"log_id": "abc"}                         # == (contains for a list column)
    {"start_ns": {">=": 10, "<": 20}}         # operators by name
    {"tags": {"contains": "left:approach"}}

Values are converted to the column's type (so ``start_ns >= 12`` compares integers); a value that
does not convert, an operator that does not suit the column, or an unknown field raises
:class:`indexes.errors.FilterError` naming the field (and, for unknown fields, the valid ones).
Rows where the field is null never match.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from indexes.errors import FilterError
from scenesearch_base import arrow_numpy


class Op(str, Enum):
    """Comparison operators; the values are the operators' spelling in filter strings."""

    EQ = "=="
    NE = "!="
    LT = "<"
    LE = "<="
    GT = ">"
    GE = ">="
    IN = "in"
    NOT_IN = "not in"
    CONTAINS = "contains"


@dataclass(frozen=True)
class Condition:
    """One clause: ``field op value``; ``value`` is a tuple for ``in`` / ``not in``."""

    field: str
    op: Op
    value: Any


FilterSpec = str | Mapping[str, Any] | Sequence[Condition] | None

_TOKEN = re.compile(
    r"""\s*(?:
        (?P<str>"(?:[^"\\]|\\.)*"|'(?:[^'\\]|\\.)*')
      | (?P<op>==|!=|<=|>=|<|>)
      | (?P<punct>[{}\[\](),])
      | (?P<word>[^\s{}\[\](),"'=!<>]+)
    )""",
    re.VERBOSE,
)


def parse(expression: str) -> list[Condition]:
    """Parse a filter string into conditions (all of which must hold).

    Raises:
        FilterError: a syntax error, naming the position.
    """
    tokens = _tokenize(expression)
    conditions: list[Condition] = []
    pos = 0

    def expect_value(at: int) -> tuple[Any, int]:
        if at >= len(tokens):
            raise FilterError("a value is missing at the end", expression)
        kind, text = tokens[at]
        if kind in ("str", "word"):
            return _literal(kind, text), at + 1
        raise FilterError(f"expected a value, found {text!r}", expression)

    while pos < len(tokens):
        kind, field = tokens[pos]
        if kind != "word":
            raise FilterError(f"expected a field name, found {field!r}", expression)
        pos += 1
        if pos >= len(tokens):
            raise FilterError(f"an operator is missing after {field!r}", expression, field)
        kind, text = tokens[pos]
        if kind == "op":
            op = Op(text)
            pos += 1
        elif kind == "word" and text.lower() == "not" and pos + 1 < len(tokens) and tokens[pos + 1][1].lower() == "in":
            op = Op.NOT_IN
            pos += 2
        elif kind == "word" and text.lower() in ("in", "contains"):
            op = Op(text.lower())
            pos += 1
        else:
            raise FilterError(f"unknown operator {text!r}; use one of {[o.value for o in Op]}", expression, field)
        if op in (Op.IN, Op.NOT_IN):
            values, pos = _parse_set(tokens, pos, expression, field)
            conditions.append(Condition(field, op, tuple(values)))
        else:
            value, pos = expect_value(pos)
            conditions.append(Condition(field, op, value))
        if pos < len(tokens):
            kind, text = tokens[pos]
            if kind != "word" or text.lower() != "and":
                raise FilterError(f"expected 'and' between clauses, found {text!r}", expression)
            pos += 1
            if pos >= len(tokens):
                raise FilterError("a clause is missing after 'and'", expression)
    return conditions


def _tokenize(expression: str) -> list[tuple[str, str]]:
    tokens: list[tuple[str, str]] = []
    pos = 0
    text = expression.rstrip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None or m.end() == pos:
            raise FilterError(f"cannot read the text at position {pos}: {text[pos:pos + 20]!r}", expression)
        kind = m.lastgroup
        assert kind is not None
        tokens.append((kind, m.group(kind)))
        pos = m.end()
    return tokens


def _parse_set(tokens: list[tuple[str, str]], pos: int, expression: str, field: str) -> tuple[list[Any], int]:
    if pos >= len(tokens) or tokens[pos][1] not in ("{", "[", "("):
        # A single bare value is accepted as a one-element set.
        if pos < len(tokens) and tokens[pos][0] in ("str", "word"):
            return [_literal(*tokens[pos])], pos + 1
        raise FilterError("expected a set of values such as {a, b}", expression, field)
    close = {"{": "}", "[": "]", "(": ")"}[tokens[pos][1]]
    pos += 1
    values: list[Any] = []
    while True:
        if pos >= len(tokens):
            raise FilterError(f"the set is not closed with {close!r}", expression, field)
        kind, text = tokens[pos]
        if text == close and kind == "punct":
            return values, pos + 1
        if kind == "punct" and text == ",":
            pos += 1
            continue
        if kind not in ("str", "word"):
            raise FilterError(f"unexpected {text!r} in a set", expression, field)
        values.append(_literal(kind, text))
        pos += 1


def _literal(kind: str, text: str) -> Any:
    """A quoted string stays a string; a bare word stays text and is converted per column later."""
    if kind == "str":
        return re.sub(r"\\(.)", r"\1", text[1:-1])
    return _Bare(text)


class _Bare(str):
    """An unquoted value: converted to the column's type (number, bool, …) at compile time."""


def conditions_of(spec: FilterSpec) -> list[Condition]:
    """Normalise any accepted filter form to a list of conditions."""
    if spec is None:
        return []
    if isinstance(spec, str):
        return parse(spec)
    if isinstance(spec, Mapping):
        out: list[Condition] = []
        for field, value in spec.items():
            if isinstance(value, Mapping):
                for op_name, v in value.items():
                    try:
                        op = Op(str(op_name).lower())
                    except ValueError:
                        raise FilterError(f"unknown operator {op_name!r}; use one of {[o.value for o in Op]}",
                                          None, str(field)) from None
                    out.append(Condition(str(field), op, tuple(v) if op in (Op.IN, Op.NOT_IN) else v))
            elif isinstance(value, list | tuple | set | frozenset):
                out.append(Condition(str(field), Op.IN, tuple(value)))
            else:
                out.append(Condition(str(field), Op.EQ, value))
        return out
    conditions = list(spec)
    if not all(isinstance(c, Condition) for c in conditions):
        raise FilterError(f"expected a string, a dict or Conditions, got {type(spec).__name__}")
    return conditions


def compile_mask(table: pa.Table, spec: FilterSpec) -> np.ndarray:
    """(N,) bool mask of the rows of ``table`` that satisfy every condition of ``spec``."""
    return _mask(table, conditions_of(spec), spec if isinstance(spec, str) else None)


def check(conditions: Sequence[Condition], schema: pa.Schema, expression: str | None = None) -> None:
    """Raise the :class:`FilterError` that :func:`compile_mask` would raise on a table of ``schema``
    (unknown field, an operator the field does not take, a value of the wrong type), reading no rows.

    ``expression`` is the filter string the conditions were parsed from, named in the error.
    """
    _mask(pa.Table.from_batches([], schema=schema), conditions, expression)  # no chunks: no conversion runs


def _mask(table: pa.Table, conditions: Sequence[Condition], expression: str | None) -> np.ndarray:
    mask = np.ones(table.num_rows, dtype=bool)
    for cond in conditions:
        if cond.field not in table.column_names:
            raise FilterError(f"unknown field; valid fields: {', '.join(sorted(table.column_names))}",
                              expression, cond.field)
        column = table.column(cond.field)
        result = _condition_mask(column, cond, expression)
        mask &= result
    return mask


def _condition_mask(column: pa.ChunkedArray, cond: Condition, expression: str | None) -> np.ndarray:
    typ = column.type
    is_list = pa.types.is_list(typ) or pa.types.is_large_list(typ)
    if is_list:
        if cond.op not in (Op.CONTAINS, Op.EQ):
            raise FilterError(f"list field supports only 'contains', not {cond.op.value!r}", expression, cond.field)
        value = _convert(cond.value, typ.value_type, cond.field, expression)
        flat = pc.list_flatten(column)
        parents = arrow_numpy.to_numpy(pc.list_parent_indices(column))
        hit = arrow_numpy.mask(pc.equal(flat, value))
        mask = np.zeros(len(column), dtype=bool)
        mask[parents[hit]] = True
        return mask
    if cond.op is Op.CONTAINS:
        if not arrow_numpy.is_string(typ):
            raise FilterError(f"'contains' needs a list or text field, this one is {typ}", expression, cond.field)
        result = pc.match_substring(column, str(cond.value))
    elif cond.op in (Op.IN, Op.NOT_IN):
        value_type = typ.value_type if pa.types.is_dictionary(typ) else typ
        values = _values_array([_convert(v, typ, cond.field, expression) for v in cond.value], value_type)
        result = pc.is_in(column, value_set=values)
        if cond.op is Op.NOT_IN:
            result = pc.and_(pc.invert(result), pc.is_valid(column))
    else:
        value = _convert(cond.value, typ, cond.field, expression)
        fn = {Op.EQ: pc.equal, Op.NE: pc.not_equal, Op.LT: pc.less, Op.LE: pc.less_equal,
              Op.GT: pc.greater, Op.GE: pc.greater_equal}[cond.op]
        try:
            result = fn(column, value)
        except (pa.ArrowNotImplementedError, pa.ArrowInvalid) as exc:
            raise FilterError(f"cannot compare a {typ} field with {cond.op.value!r}: {exc}",
                              expression, cond.field) from None
    return arrow_numpy.mask(result)


def _values_array(values: Sequence[pa.Scalar], value_type: pa.DataType) -> pa.Array:
    """The set of an ``in`` condition: strings from their text, other types through ``pa.array``."""
    if arrow_numpy.is_string(value_type):
        return arrow_numpy.strings([v.as_py() for v in values]).cast(value_type)
    return pa.array([v.as_py() for v in values], type=value_type)


def _convert(value: Any, typ: pa.DataType, field: str, expression: str | None) -> pa.Scalar:
    """``value`` as a scalar of the column's type; bare words become numbers / bools as needed."""
    v: Any = value
    if isinstance(value, str):
        text = str(value)
        if pa.types.is_integer(typ) or pa.types.is_timestamp(typ) or pa.types.is_duration(typ):
            try:
                v = int(text.replace("_", ""))
            except ValueError:
                raise FilterError(f"{text!r} is not an integer", expression, field) from None
        elif pa.types.is_floating(typ):
            try:
                v = float(text)
            except ValueError:
                raise FilterError(f"{text!r} is not a number", expression, field) from None
        elif pa.types.is_boolean(typ):
            if text.lower() not in ("true", "false"):
                raise FilterError(f"{text!r} is not true or false", expression, field) from None
            v = text.lower() == "true"
        elif pa.types.is_dictionary(typ):
            return arrow_numpy.scalar(text, typ.value_type)
        else:
            v = text
    try:
        return arrow_numpy.scalar(v, typ.value_type if pa.types.is_dictionary(typ) else typ)
    except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError, TypeError, ValueError) as exc:
        raise FilterError(f"value {value!r} does not fit the field's type {typ}: {exc}", expression, field) from None
