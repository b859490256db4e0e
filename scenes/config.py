"""Base of the scenes configs (simulator, sensors, tracker): YAML through :mod:`scenesearch_base.config`."""

from __future__ import annotations

from scenes.errors import ConfigError
from scenesearch_base.config import YamlConfig


class ScenesConfig(YamlConfig):
    """A frozen config dataclass of :mod:`scenes`; every bad file or value raises :class:`ConfigError`."""

    config_error = ConfigError

