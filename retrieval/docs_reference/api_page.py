"""``docs/reference/python-api.md``: the public classes and functions, from their signatures and docstrings."""

from __future__ import annotations

import importlib
import inspect
from typing import Any

from retrieval.docs_reference.markdown import GENERATED, docstring_blocks, fence, page, rst_to_markdown

#: (section, [(import path shown to users, module, name)]).
API: tuple[tuple[str, tuple[tuple[str, str, str], ...]], ...] = (
    ("Search an index", (
        ("from retrieval import SceneSearch", "retrieval.scenesearch", "SceneSearch"),
        ("from retrieval import SearchResult", "retrieval.records", "SearchResult"),
        ("from retrieval import CaptionSearch", "retrieval.captions_search", "CaptionSearch"),
    )),
    ("Scenario queries", (
        ("from scenarios.mining import mine", "scenarios.mining", "mine"),
        ("from scenarios.compiler import compile_description", "scenarios.compiler", "compile_description"),
    )),
    ("Logs, captions and models", (
        ("from scenes.log import Log", "scenes.log", "Log"),
        ("from captioning import caption_log", "captioning.pipeline", "caption_log"),
        ("from encoders.inference import load_model", "encoders.inference", "load_model"),
    )),
    ("Indexes beyond memory", (
        ("from indexes import build_on_disk", "indexes.ondisk", "build_on_disk"),
    )),
)


def _annotation(value: Any) -> str:
    return value if isinstance(value, str) else inspect.formatannotation(value)


def _signature(obj: Any, name: str) -> str:
    """``name(a: int, b: str = 'x') -> T``; ``self`` and ``cls`` left out, annotations unquoted."""
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):
        return name
    params = []
    for i, param in enumerate(signature.parameters.values()):
        if i == 0 and param.name in ("self", "cls"):
            continue
        text = param.name
        if param.kind is param.VAR_POSITIONAL:
            text = "*" + text
        elif param.kind is param.VAR_KEYWORD:
            text = "**" + text
        if param.annotation is not param.empty:
            text += f": {_annotation(param.annotation)}"
        if param.default is not param.empty:
            text += f" = {param.default!r}"
        params.append(text)
    returned = signature.return_annotation
    returns = "" if returned is signature.empty else f" -> {_annotation(returned)}"
    return f"{name}({', '.join(params)}){returns}"


def _members(cls: type) -> list[tuple[str, Any]]:
    """Public methods and properties defined by ``cls`` itself, in source order."""
    out: list[tuple[str, Any]] = []
    for name, value in vars(cls).items():
        if name.startswith("_"):
            continue
        if isinstance(value, classmethod | staticmethod):
            out.append((name, value.__func__))
        elif (isinstance(value, property) and value.fget is not None) or inspect.isfunction(value):
            out.append((name, value))
    return out


def _entry(name: str, obj: Any, level: int) -> list[str]:
    if isinstance(obj, property):  # documented by its getter, without a call
        summary, rest = docstring_blocks(obj.fget)
        lines = [f"{'#' * level} `{name}` (property)", ""]
    else:
        summary, rest = docstring_blocks(obj)
        lines = [f"{'#' * level} `{name}`", "", *fence(_signature(obj, name), "python"), ""]
    if summary:
        lines += [summary, ""]
    if rest:
        lines += [*rst_to_markdown(rest), ""]
    return lines


def markdown() -> str:
    """The page (Markdown)."""
    lines = ["# Python API", "", GENERATED, "",
             "The command line is a thin layer over these; everything it does can be done from Python.", ""]
    for section, entries in API:
        lines += [f"## {section}", ""]
        for import_line, module_name, name in entries:
            obj = getattr(importlib.import_module(module_name), name)
            lines += [f"### `{name}`", "", f"`{import_line}`", ""]
            summary, rest = docstring_blocks(obj)
            if summary:
                lines += [summary, ""]
            if rest:
                lines += [*rst_to_markdown(rest), ""]
            if inspect.isclass(obj):
                for member_name, member in _members(obj):
                    lines += _entry(f"{name}.{member_name}", member, 4)
            else:
                lines += [*fence(_signature(obj, name), "python"), ""]
    return page(lines)
