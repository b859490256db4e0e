"""The embedded default data: a SUMO-driven city simulator writing AV2-layout logs.

>>> from scenes.sim import SimulationConfig, simulate
>>> log_dirs = simulate(SimulationConfig(logs=8, duration_s=25, seed=0), "demo_logs")

Modules, in the order data flows: :mod:`~scenes.sim.network` (netgenerate, cached),
:mod:`~scenes.sim.netparse` (read the network), :mod:`~scenes.sim.map_export` (AV2 map, junction
kinds), :mod:`~scenes.sim.demand` (seeded traffic), :mod:`~scenes.sim.runner` (libsumo at 10 Hz),
:mod:`~scenes.sim.props` (street furniture and standing people, which SUMO does not have),
:mod:`~scenes.sim.labels` (behaviour labels), :mod:`~scenes.sim.noise` (detector and tracker
noise), :mod:`~scenes.sim.appearance`, and :mod:`~scenes.sim.pipeline` (writes the logs).
SUMO itself is imported only when a simulation runs.
"""

from scenes.sim.config import NetworkKind, SimulationConfig, TrackerNoiseConfig
from scenes.sim.errors import SimulationError
from scenes.sim.noise import apply_tracker_noise
from scenes.sim.pipeline import PostLogHook, SimulationResult, simulate, simulate_tracks_and_map

__all__ = [
    "NetworkKind",
    "PostLogHook",
    "SimulationConfig",
    "SimulationError",
    "SimulationResult",
    "TrackerNoiseConfig",
    "apply_tracker_noise",
    "simulate",
    "simulate_tracks_and_map",
]
