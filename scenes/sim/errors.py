"""Errors of the city simulator."""

from __future__ import annotations

from scenes.errors import ScenesError


class SimulationError(ScenesError):
    """SUMO (netgenerate or the simulation) failed; the message carries SUMO's own words."""
