"""Reading and writing configs: frozen dataclasses are the schema, YAML files their serialised instances.

Every stage's config goes through these functions, so every config file fails the same way. The
config dataclasses inherit :class:`YamlConfig`, which offers them as methods::

    >>> config = ClipsConfig.from_yaml("clips.yaml")   # missing keys keep their defaults
    >>> config.to_yaml("clips.yaml")                    # atomic; round-trips exactly

A value is checked against the field's type hint (``bool``, ``int``, ``float``, ``str``, ``Path``, a
``str`` Enum, ``Literal[...]``, ``tuple[...]``, ``dict[str, ...]``, ``X | None`` and nested config
dataclasses), and an error names the file, the dotted key and the type expected::

    clips.yaml: key 'bev.num_sweeps': expected an integer, got 'two'
    train.yaml: unknown keys model.camera.widht, epoch (known at model.camera: temporal, widths)

Checks that relate several fields stay in each dataclass's ``__post_init__``; a ``ValueError`` raised
there is reported with the file name in front.

**Plausibility bounds.** A size-like field (frames, pixels, cells, items, epochs) declares its upper
bound in the class's ``upper_bounds``, so that an absurd value is refused when the config is made,
before anything is allocated for it (``frames_per_clip: 1000000000`` would otherwise ask for gigabytes
before any check)::

    clips.yaml: key 'frames_per_clip': 1000000000 is above its upper bound 256

:meth:`YamlConfig.__post_init__` checks them; a subclass with checks of its own calls it first.
"""

from __future__ import annotations

import dataclasses
import enum
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, Self, TypeVar

import yaml

from scenesearch_base.atomic import atomic_write_text

T = TypeVar("T")
E = TypeVar("E", bound=enum.Enum)


class ConfigError(ValueError):
    """A config file or mapping is unreadable, holds unknown keys, or a value of the wrong type."""


class YamlConfig:
    """Base of the config dataclasses: this module's functions as methods, raising the stage's error.

    A stage sets ``config_error`` to its own :class:`ConfigError` subclass, so that its callers can
    catch one exception type for every bad config of that stage.
    """

    config_error: ClassVar[type[ConfigError]] = ConfigError
    #: Field name → the largest value it may take (see the module docstring).
    upper_bounds: ClassVar[Mapping[str, float]] = {}

    def __post_init__(self) -> None:
        """Refuse a value above its field's upper bound, naming the key and the bound."""
        check_upper_bounds(self, self.upper_bounds, self.config_error)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, source: str = "<dict>") -> Self:
        return from_dict(cls, data, source=source, error=cls.config_error)

    @classmethod
    def from_yaml(cls, path: Path | str) -> Self:
        return from_yaml(cls, path, error=cls.config_error)

    @classmethod
    def from_yaml_text(cls, text: str, source: str = "<text>") -> Self:
        return from_yaml_text(cls, text, source=source, error=cls.config_error)

    def to_dict(self) -> dict[str, Any]:
        return to_dict(self)

    def to_yaml(self, path: Path | str) -> None:
        to_yaml(self, path)

    def to_yaml_text(self) -> str:
        return to_yaml_text(self)


def check_upper_bounds(config: Any, bounds: Mapping[str, float], error: type[ValueError] = ConfigError) -> None:
    """Refuse each field of ``config`` named in ``bounds`` whose value is above its bound.

    A tuple's elements are each checked (e.g. layer widths).

    Raises:
        error: ``key 'NAME': VALUE is above its upper bound BOUND`` for each field out of bounds.
    """
    problems = []
    for name, bound in bounds.items():
        value = getattr(config, name)
        values = value if isinstance(value, tuple) else (value,)
        if any(isinstance(v, int | float) and not isinstance(v, bool) and v > bound for v in values):
            problems.append(f"key '{name}': {value} is above its upper bound {bound:.15g}")
    if problems:
        raise error("; ".join(problems))


def check_positive(owner: str, /, *, error: type[ValueError] = ValueError, **values: float) -> None:
    """Refuse the first of ``values`` that is not > 0 (NaN included), naming the field as ``owner.<name>``.

    The per-field checks of a config's ``__post_init__`` share these helpers, so that every stage words a
    bad value alike; ``error`` is the stage's exception.

    Raises:
        error: ``OWNER.NAME must be > 0, got VALUE``.
    """
    for name, value in values.items():
        if not value > 0:
            raise error(f"{owner}.{name} must be > 0, got {value}")


def check_at_least(owner: str, minimum: float, /, *, error: type[ValueError] = ValueError, **values: float) -> None:
    """Refuse the first of ``values`` below ``minimum``, naming the field as ``owner.<name>``.

    Raises:
        error: ``OWNER.NAME must be >= MINIMUM, got VALUE``.
    """
    for name, value in values.items():
        if value < minimum:
            raise error(f"{owner}.{name} must be >= {minimum}, got {value}")


def check_fraction(owner: str, /, *, error: type[ValueError] = ValueError, **values: float) -> None:
    """Refuse the first of ``values`` outside [0, 1] (a probability or a share), naming ``owner.<name>``.

    Raises:
        error: ``OWNER.NAME must be in [0, 1], got VALUE``.
    """
    for name, value in values.items():
        if not 0.0 <= value <= 1.0:
            raise error(f"{owner}.{name} must be in [0, 1], got {value}")


def parse_choice(choices: type[E], value: object, what: str, valid: str, /, *,
                 error: type[ValueError] = ValueError) -> E:
    """The member of the Enum ``choices`` whose value is ``value`` (a member is returned as it is).

    Every vocabulary read from a flag, a file or a query (metrics, network kinds, tagging regions) is
    refused with the same words, listing what it accepts; ``error`` is the stage's exception.

    Raises:
        error: ``unknown WHAT VALUE; VALID: A, B, C`` (the values of ``choices``, in their order).
    """
    try:
        return choices(value)
    except ValueError:
        raise error(f"unknown {what} {value!r}; {valid}: {', '.join(str(c.value) for c in choices)}") from None


def with_option(config: T, option: str, **changes: Any) -> T:
    """``dataclasses.replace(config, **changes)`` for a command-line ``option``; a value the config
    refuses is reported as the option's (``--frames-per-clip 1000000000: key 'frames_per_clip': …``)."""
    try:
        return dataclasses.replace(config, **changes)  # type: ignore[type-var]
    except ValueError as exc:
        raise type(exc)(f"{option} {', '.join(str(v) for v in changes.values())}: {exc}") from None


def check_flag_bound(option: str, value: float, bound: float) -> None:
    """Refuse a command-line flag's ``value`` above ``bound`` before anything is allocated for it, naming
    the flag (``--batch-size 100000: above its upper bound 4096``)."""
    if value > bound:
        raise ValueError(f"{option} {value}: above its upper bound {bound:g}")


# --- writing ----------------------------------------------------------------------------------------


def to_dict(config: Any) -> dict[str, Any]:
    """The plain nested dict of a config dataclass: enums as their values, tuples as lists, paths as str."""
    if not dataclasses.is_dataclass(config) or isinstance(config, type):
        raise TypeError(f"to_dict needs a dataclass instance, got {type(config).__name__}")
    plain = _to_plain(config)
    assert isinstance(plain, dict)
    return plain


def _to_plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _to_plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Mapping):
        return {k: _to_plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_to_plain(v) for v in value]
    return value


def to_yaml_text(config: Any) -> str:
    """YAML text of ``config``, keys in field order (the order a reader of the file expects)."""
    return str(yaml.safe_dump(to_dict(config), sort_keys=False))


def to_yaml(config: Any, path: Path | str) -> None:
    """Write ``config`` to ``path`` as YAML, atomically."""
    atomic_write_text(path, to_yaml_text(config))


# --- reading ----------------------------------------------------------------------------------------


def from_yaml(cls: type[T], path: Path | str, error: type[ConfigError] = ConfigError) -> T:
    """Load the config dataclass ``cls`` from the YAML file ``path``; raises ``error`` naming file and key."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read config ({exc})") from None
    return from_yaml_text(cls, text, source=str(path), error=error)


def from_yaml_text(cls: type[T], text: str, source: str = "<text>", error: type[ConfigError] = ConfigError) -> T:
    """Like :func:`from_yaml` for YAML already in memory (``source`` names it in errors)."""
    return from_dict(cls, read_yaml_text(text, source, error), source=source, error=error)


class _UniqueKeyLoader(yaml.SafeLoader):
    """A safe loader that refuses a key given twice in one mapping (PyYAML keeps the last silently, so
    ``lr: 0.001`` then ``lr: 0.5`` would train at 0.5 without a word)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} appears twice in one mapping (which one is meant?)", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def read_yaml_text(text: str, source: str = "<text>", error: type[ConfigError] = ConfigError) -> Any:
    """The data of a YAML text; a syntax error or a key given twice raises ``error`` naming ``source``, the line
    and the column."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" (line {where.line + 1}, column {where.column + 1})" if where is not None else ""
        problem = getattr(exc, "problem", None) or exc
        raise error(f"{source}: not valid YAML{line}: {problem}") from None


def from_dict(
    cls: type[T], data: Mapping[str, Any] | None, source: str = "<dict>", error: type[ConfigError] = ConfigError
) -> T:
    """Build the config dataclass ``cls`` from nested plain data; missing keys keep their defaults.

    Raises:
        ``error`` (a :class:`ConfigError`): the top level is not a mapping, keys are unknown (all of
        them are listed, dotted), or a value does not fit its field's type.
    """
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise error(f"{source}: expected a mapping at the top level, got {_kind(data)}")
    unknown = unknown_keys(cls, data)
    if unknown:
        raise error(f"{source}: unknown keys {', '.join(path for path, _ in unknown)} ({_known_hint(unknown)})")
    return _build(cls, data, "", source, error)


def unknown_keys(cls: type, data: Mapping[str, Any], prefix: str = "") -> list[tuple[str, type]]:
    """(dotted path, dataclass) of every key of ``data`` that the nested dataclass ``cls`` lacks."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    found = [(f"{prefix}{key}", cls) for key in data if key not in names]
    for key, value in data.items():
        if key in names and isinstance(value, Mapping):
            sub = _dataclass_of(hints[key])
            if sub is not None:
                found += unknown_keys(sub, value, f"{prefix}{key}.")
    return found


def _known_hint(unknown: list[tuple[str, type]]) -> str:
    parts = []
    for path, cls in unknown:
        where = path.rpartition(".")[0] or "top level"
        known = ", ".join(f.name for f in dataclasses.fields(cls))
        part = f"known at {where}: {known}"
        if part not in parts:
            parts.append(part)
    return "; ".join(parts)


def _build(cls: type[T], data: Mapping[str, Any], prefix: str, source: str, error: type[ConfigError]) -> T:
    hints = typing.get_type_hints(cls)
    values = {key: _convert(hints[key], value, f"{prefix}{key}", source, error) for key, value in data.items()}
    try:
        return cls(**values)
    except ConfigError as exc:
        message = str(exc).replace("key '", f"key '{prefix}")  # a nested config's keys named from the top
        raise error(f"{source}: {message}") from None
    except (TypeError, ValueError) as exc:
        where = f"key '{prefix.rstrip('.')}': " if prefix else ""
        raise error(f"{source}: {where}{exc}") from None


def _convert(hint: Any, value: Any, key: str, source: str, error: type[ConfigError]) -> Any:
    def wrong() -> ConfigError:
        return error(f"{source}: key '{key}': expected {_describe(hint)}, got {value!r}")

    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is Any or hint is object:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        for arg in (a for a in args if a is not type(None)):
            try:
                return _convert(arg, value, key, source, error)
            except ConfigError:
                continue
        raise wrong()
    if origin is typing.Literal:
        if value not in args:
            raise wrong()
        return value
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, Mapping):
            raise wrong()
        return _build(typing.cast(type, hint), value, f"{key}.", source, error)
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        try:
            return hint(value)
        except ValueError:
            raise wrong() from None
    if hint is bool:
        if not isinstance(value, bool):
            raise wrong()
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise wrong()
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise wrong()
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise wrong()
        return value
    if hint is Path:
        if not isinstance(value, str | Path):
            raise wrong()
        return Path(value)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise wrong()
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{key}[{i}]", source, error) for i, v in enumerate(value))
        if args and len(args) != len(value):
            raise wrong()
        return tuple(_convert(a, v, f"{key}[{i}]", source, error) for i, (a, v) in enumerate(zip(args, value)))
    if origin is list:
        if not isinstance(value, list | tuple):
            raise wrong()
        item = args[0] if args else Any
        return [_convert(item, v, f"{key}[{i}]", source, error) for i, v in enumerate(value)]
    if origin in (dict, Mapping):
        if not isinstance(value, Mapping):
            raise wrong()
        item = args[1] if len(args) == 2 else Any
        return {k: _convert(item, v, f"{key}.{k}", source, error) for k, v in value.items()}
    return value


def _dataclass_of(hint: Any) -> type | None:
    """The config dataclass a field holds, looking through ``X | None``."""
    if dataclasses.is_dataclass(hint):
        return typing.cast(type, hint)
    for arg in typing.get_args(hint):
        if dataclasses.is_dataclass(arg):
            return typing.cast(type, arg)
    return None


def _describe(hint: Any) -> str:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in args)
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_describe(args[0])}"
        return f"a list of {len(args)} values"
    if origin is list:
        return f"a list of {_describe(args[0]) if args else 'values'}"
    if origin in (dict, Mapping):
        return "a mapping"
    if dataclasses.is_dataclass(hint):
        return "a mapping"
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return "one of " + ", ".join(repr(m.value) for m in hint)
    names = {bool: "true or false", int: "an integer", float: "a number", str: "a string", Path: "a path"}
    return names.get(hint, getattr(hint, "__name__", str(hint)))


def _kind(value: object) -> str:
    return "nothing" if value is None else type(value).__name__
