"""``docs/reference/configuration.md``: every key of every config file, from the config dataclasses.

Each top-level config is a frozen dataclass (:mod:`scenesearch_base.config`); nested configs appear as dotted
keys, as a YAML file nests them. A key's text is its entry in the ``Attributes:`` section of its
class's docstring; its upper bound comes from the class's ``upper_bounds``.
"""

from __future__ import annotations

import dataclasses
import enum
import importlib
import json
import types
import typing
from pathlib import Path
from typing import Any

from retrieval.docs_reference.markdown import GENERATED, attribute_docs, cell, code, docstring_blocks, page, table

#: (module, class, the file and the commands that read it), in pipeline order.
CONFIGS: tuple[tuple[str, str, str], ...] = (
    ("scenes.sim.config", "SimulationConfig", "`scenesearch simulate --config FILE`"),
    ("scenes.sensorsim.config", "SensorConfig",
     "`scenesearch simulate --sensor-config FILE`, `scenesearch render-sensors --config FILE`"),
    ("captioning.config", "CaptioningConfig",
     "`scenesearch caption --config FILE` (annotated defaults: `captioning/captioning.yaml`)"),
    ("scenes.tracking.config", "TrackerConfig", "`scenesearch track --config FILE`"),
    ("encoders.clips.config", "ClipsConfig", "`scenesearch clips --config FILE`"),
    ("encoders.train_config", "TrainConfig",
     "a recipe (`scenesearch train --preset NAME`, `--config FILE`, `--set KEY=VALUE`; presets in "
     "`encoders/presets/`); the run keeps it in `config.json` and the whole recipe in `recipe.yaml`"),
    ("encoders.tagging.config", "TagTrainConfig",
     "a recipe's `tagging:` keys (`--set tagging.KEY=VALUE`); a run that answers tag queries keeps it in "
     "`tagging.json`"),
    ("indexes.factory", "AutoConfig", "the choice of FAISS index (Python: `indexes`)"),
)


def _type(hint: Any) -> str:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is typing.Literal:
        return " / ".join(str(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join("null" if a is type(None) else _type(a) for a in args)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type(args[0])}"
        return "[" + ", ".join(_type(a) for a in args) + "]"
    if origin in (dict, typing.Mapping):
        return f"map of {_type(args[0])} to {_type(args[1])}"
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return " / ".join(str(m.value) for m in hint)
    if hint is Path:
        return "path"
    return getattr(hint, "__name__", str(hint))


def _value(value: Any) -> str:
    if isinstance(value, enum.Enum):
        value = value.value
    if isinstance(value, Path):
        value = str(value)
    if isinstance(value, bool) or value is None:
        return json.dumps(value)
    if isinstance(value, str):
        return value
    if isinstance(value, tuple | list | dict):
        return json.dumps(_plain(value))
    return repr(value)


def _plain(value: Any) -> Any:
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    return value


def _nested(hint: Any) -> type | None:
    """The dataclass a field holds (also inside ``X | None``), else None."""
    candidates = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
    for candidate in candidates:
        if isinstance(candidate, type) and dataclasses.is_dataclass(candidate):
            return candidate
    return None


def _rows(instance: Any, prefix: str = "") -> list[list[str]]:
    cls = type(instance)
    hints = typing.get_type_hints(cls)
    docs = attribute_docs(cls)
    bounds = getattr(cls, "upper_bounds", {})
    rows = []
    for f in dataclasses.fields(cls):
        value = getattr(instance, f.name)
        nested = _nested(hints[f.name])
        if nested is not None and dataclasses.is_dataclass(value):
            summary = docs.get(f.name) or docstring_blocks(nested)[0]
            rows.append([code(prefix + f.name), f"`{nested.__name__}`: the keys below", "", "", summary])
            rows += _rows(value, prefix + f.name + ".")
            continue
        bound = bounds.get(f.name)
        rows.append([code(prefix + f.name), cell(_type(hints[f.name])), code(_value(value)),
                     "" if bound is None else f"{bound:.15g}", docs.get(f.name, "")])
    return rows


def markdown() -> str:
    """The page (Markdown)."""
    lines = ["# Configuration files", "", GENERATED, "",
             "A config file is YAML: the keys below, nested as the dots say (`model.camera.widths` is "
             "`model: {camera: {widths: ...}}`). A missing key keeps its default; an unknown key, a value of "
             "the wrong type or one above its upper bound is refused with the file and the dotted key. "
             "Command-line options override file values.", ""]
    for _, class_name, readers in CONFIGS:
        lines += [f"- [`{class_name}`](#{class_name.lower()}): {readers}"]
    lines.append("")
    for module_name, class_name, readers in CONFIGS:
        cls = getattr(importlib.import_module(module_name), class_name)
        summary, _ = docstring_blocks(cls)
        lines += [f"## {class_name}", "", f"`{module_name}.{class_name}`. Read by {readers}.", ""]
        if summary:
            lines += [summary, ""]
        lines += [*table(["key", "type", "default", "upper bound", "meaning"], _rows(cls())), ""]
    return page(lines)
