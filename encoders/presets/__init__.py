"""Training recipes: a complete configuration of a model and its training, one small file per recipe.

``encoders/presets/<name>.yaml`` holds a :class:`~encoders.train_config.TrainConfig` (model architecture,
losses, training schedule) and, under ``tagging:``, the :class:`~encoders.tagging.config.TagTrainConfig`
of the attribute-tagging head trained with it. ``recommended`` is the model the documentation measures;
``tiny`` is the smallest that runs every part (tests, smoke runs).

``scenesearch train`` starts from a recipe (``--preset NAME`` or ``--config FILE``) and overrides any of
its keys with ``--set key=value`` (dotted keys, ``tagging.`` for the tagging head's); the run folder
records the recipe it trained, resolved (``recipe.yaml``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from encoders.config import ConfigError
from encoders.tagging.config import TagTrainConfig
from encoders.train_config import TrainConfig
from scenesearch_base.atomic import atomic_write_text
from scenesearch_base.config import read_yaml_text, to_dict

PRESETS_DIR = Path(__file__).parent
#: The file a run folder records its resolved recipe in.
RECIPE_FILE = "recipe.yaml"


def preset_names() -> list[str]:
    """The recipes shipped with the package."""
    return sorted(p.stem for p in PRESETS_DIR.glob("*.yaml"))


@dataclass(frozen=True)
class Recipe:
    """A complete training configuration.

    Attributes:
        name: the preset's name, or the file it was read from.
        train: the model and its training.
        tagging: the attribute-tagging head trained jointly (when the clips hold tag targets).
    """

    name: str
    train: TrainConfig
    tagging: TagTrainConfig

    def to_dict(self) -> dict[str, Any]:
        return {"preset": self.name, **to_dict(self.train), "tagging": to_dict(self.tagging)}

    def to_yaml(self, path: Path | str) -> None:
        """Write the resolved recipe (a file :func:`read_recipe` reads back)."""
        atomic_write_text(path, yaml.safe_dump(self.to_dict(), sort_keys=False))


def _from_mapping(data: object, name: str, source: str) -> Recipe:
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a recipe is a mapping of TrainConfig keys (and 'tagging:'), got {data!r}")
    data = dict(data)
    data.pop("preset", None)
    tagging = data.pop("tagging", None) or {}
    return Recipe(name, TrainConfig.from_dict(data, source=source),
                  TagTrainConfig.from_dict(tagging, source=f"{source}, key 'tagging'"))


def read_recipe(path: Path | str) -> Recipe:
    """The recipe in a YAML file (a preset's layout).

    Raises:
        ConfigError: the file is missing, not YAML, or holds an unknown key or a bad value (named).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: recipe file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the recipe ({exc})") from None
    data = read_yaml_text(text, str(path), ConfigError)
    preset = data.get("preset") if isinstance(data, dict) else None
    return _from_mapping(data, str(preset or path), str(path))


def preset(name: str) -> Recipe:
    """The preset ``name`` (:func:`preset_names`).

    Raises:
        ConfigError: no preset of that name.
    """
    path = PRESETS_DIR / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(f"unknown preset {name!r} (presets: {', '.join(preset_names())})")
    return _from_mapping(read_yaml_text(path.read_text(encoding="utf-8"), str(path), ConfigError), name, str(path))


def run_recipe(run_dir: Path) -> Recipe | None:
    """The recipe a run folder trained: its ``recipe.yaml``, or else (a run the Python API started) the
    configurations its checkpoint holds; None when the folder holds neither.

    Raises:
        ConfigError: the recipe or checkpoint's configuration does not read (named).
    """
    if (run_dir / RECIPE_FILE).is_file():
        return read_recipe(run_dir / RECIPE_FILE)
    path = run_dir / "checkpoints" / "last.pt"
    if not path.is_file():
        return None
    from encoders.checkpoints import read_checkpoint

    checkpoint = read_checkpoint(path)
    saved_tagging = checkpoint.tagging["config"] if checkpoint.tagging is not None else {}
    return Recipe(str(run_dir), TrainConfig.from_run_dict(checkpoint.config, source=str(path)),
                  TagTrainConfig.from_dict(saved_tagging, source=f"{path}, tagging config"))


def with_settings(recipe: Recipe, settings: Sequence[str]) -> Recipe:
    """``recipe`` with ``key=value`` settings applied (``--set``): dotted keys into the train config, or into
    the tagging head's under ``tagging.``; values read as YAML (``true``, ``3``, ``[reverse]``).

    Raises:
        ConfigError: a setting without ``=``, an unknown key, or a value the key does not take (named).
    """
    data = recipe.to_dict()
    for setting in settings:
        key, sep, text = setting.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set {setting!r}: write KEY=VALUE, e.g. epochs=3 or model.time_slots=0")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ConfigError(f"--set {setting!r}: the value is not YAML ({exc})") from None
        node = data
        parts = key.strip().split(".")
        for part in parts[:-1]:
            child = node.get(part)
            if not isinstance(child, dict):
                raise ConfigError(f"--set {setting!r}: unknown key {key.strip()!r} ({part!r} holds no keys)")
            node = child
        if parts[-1] not in node:
            raise ConfigError(f"--set {setting!r}: unknown key {key.strip()!r}")
        node[parts[-1]] = value
    return _from_mapping(data, recipe.name, "--set")
