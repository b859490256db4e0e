"""Base of the scenes configs (simulator, sensors, tracker): YAML through :mod:`scenesearch_base.config`."""

from __future__ import annotations

from scenes.errors import ConfigError
from scenesearch_base.config import YamlConfig


class ScenesConfig(YamlConfig):
    """A frozen config dataclass of :mod:`scenes`; every bad file or value raises :class:`ConfigError`."""

    config_error = ConfigError


def check_positive(owner: str, **values: float) -> None:
    """Raise ``ValueError`` naming ``owner.<name>`` for the first value that is not > 0."""
    for name, value in values.items():
        if not value > 0:
            raise ValueError(f"{owner}.{name} must be > 0, got {value}")


def check_at_least(owner: str, minimum: float, **values: float) -> None:
    """Raise ``ValueError`` naming ``owner.<name>`` for the first value below ``minimum``."""
    for name, value in values.items():
        if value < minimum:
            raise ValueError(f"{owner}.{name} must be >= {minimum}, got {value}")
