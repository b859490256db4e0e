"""Configuration of the city simulator: frozen dataclasses, serialised as YAML by :mod:`scenesearch_base.config`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import ClassVar

import numpy as np

from scenes.config import ScenesConfig
from scenesearch_base.config import check_at_least, check_fraction, check_positive, parse_choice

#: Simulation steps in one log, at most (an hour at 100 Hz): the steps of a log are held in memory.
MAX_STEPS_PER_LOG = 360_000


class NetworkKind(StrEnum):
    """Road network layouts ``netgenerate`` builds for the simulated city."""

    #: A 5 × 4 grid: 4-way junctions inside, 3-way junctions on the border and where roads are removed.
    GRID = "grid"
    #: Rings and radial arms: a multi-way centre, 4-way ring crossings and 3-way outer junctions.
    SPIDER = "spider"
    #: A random planar network with junctions of varied degree.
    RANDOM = "random"

    @staticmethod
    def parse(value: str | NetworkKind) -> NetworkKind:
        return parse_choice(NetworkKind, value, "network kind", "choose one of")


@dataclass(frozen=True)
class TrackerNoiseConfig(ScenesConfig):
    """What a real LiDAR detector and tracker do to perfect boxes.

    Attributes:
        center_std_m: standard deviation of the box centre jitter in x and y.
        yaw_std_rad: standard deviation of the heading jitter.
        miss_probability: chance that a visible box is missed in a frame.
        id_switch_rate_per_s: expected id switches per track-second; after one, the track continues
            under a new id.
        max_range_m: boxes whose centre is farther from the ego are not detected.
        occlusion_fraction: a box is dropped when at least this fraction of its angular extent, seen
            from the ego, is hidden behind nearer boxes.
        occlusion_rays: rays sampled across each box's angular extent for the occlusion test.

    Upper bounds: ``occlusion_rays`` 1024.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"occlusion_rays": 1024}

    center_std_m: float = 0.15
    yaw_std_rad: float = 0.03
    miss_probability: float = 0.05
    id_switch_rate_per_s: float = 0.01
    max_range_m: float = 70.0
    occlusion_fraction: float = 0.8
    occlusion_rays: int = 16

    def __post_init__(self) -> None:
        super().__post_init__()
        check_at_least("TrackerNoiseConfig", 0, center_std_m=self.center_std_m, yaw_std_rad=self.yaw_std_rad,
                       id_switch_rate_per_s=self.id_switch_rate_per_s)
        check_fraction("TrackerNoiseConfig", miss_probability=self.miss_probability)
        if not 0.0 < self.occlusion_fraction <= 1.0:
            raise ValueError(
                f"TrackerNoiseConfig.occlusion_fraction must be in (0, 1], got {self.occlusion_fraction}"
            )
        check_positive("TrackerNoiseConfig", max_range_m=self.max_range_m)
        check_at_least("TrackerNoiseConfig", 2, occlusion_rays=self.occlusion_rays)


@dataclass(frozen=True)
class SimulationConfig(ScenesConfig):
    """One simulator run: ``logs`` windows of ``duration_s`` cut from the drives of the egos.

    Attributes:
        logs: number of logs to write.
        duration_s: length of each log.
        seed: seeds the network's randomness, the demand, SUMO and the appearance; same seed,
            same bytes.
        network: road network layout.
        warmup_s: simulated time before the first window, so that the city is busy.
        egos_per_run: egos driving at once; log ``i`` follows ego ``i % egos_per_run`` in window
            ``i // egos_per_run``.
        step_s: simulation step and annotation period (0.1 s = 10 Hz).
        range_m: objects farther from the ego than this are not annotated.
        vehicles_per_s_per_km: mean rate of vehicle trips starting, per km of road (each direction
            counted), so that every layout is about as busy.
        pedestrians_per_s_per_km: mean rate of pedestrian walks starting, per km of road.
        parked_vehicles: vehicles parked at the roadside for the whole run.
        furniture_per_km: mean groups of street furniture (cones, bollards, barrels, signs; category
            ``other``) per km of sidewalk, placed at the curb (:mod:`scenes.sim.props`).
        standing_pedestrians_per_km: mean groups of people standing still per km of sidewalk.
        tracker_noise: apply :class:`TrackerNoiseConfig` to the written annotations (labels stay exact).
        noise: the noise model used when ``tracker_noise`` is set.
        sensors: whether sensor data (LiDAR, cameras) is rendered after the tracks; recorded for the
            sensor stage, which runs on the written logs.
        map_less_share: share of the logs written without their vector map (``map/``), as track-only
            real logs come (KITTI tracking has no map): their captions then come from the rules'
            map-less fallback and their BEV clips have empty map channels, so a model trained on a mix
            knows both kinds. Their sensors are still rendered from the map, and their behaviour labels
            and junctions (simulator truth, for tag targets) are kept. Which logs: a seeded draw.
        jitter_share: share of the logs whose boxes scatter from frame to frame as real labels do
            (:func:`scenes.sim.noise.jitter_boxes` with ``noise``'s centre and heading noise, nothing
            else): a standing car's speed through the rules then reads 0.1–0.4 m/s, as on KITTI, instead of
            the simulator's exact 0. Captions follow the jittered boxes; behaviour labels stay exact.
            Which logs: a seeded draw, apart from the map-less one. Ignored with ``tracker_noise``.
        cache_dir: folder for generated networks (default: the system temp folder).

    Upper bounds: ``logs`` 100000, ``duration_s`` and ``warmup_s`` 3600, ``egos_per_run`` 256,
    ``vehicles_per_s_per_km`` and ``pedestrians_per_s_per_km`` 10, ``parked_vehicles`` 10000,
    ``furniture_per_km`` and ``standing_pedestrians_per_km`` 1000, and :data:`MAX_STEPS_PER_LOG` steps of
    ``step_s`` in a log.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {
        "logs": 100_000, "duration_s": 3600, "warmup_s": 3600, "egos_per_run": 256, "vehicles_per_s_per_km": 10,
        "pedestrians_per_s_per_km": 10, "parked_vehicles": 10_000, "furniture_per_km": 1000,
        "standing_pedestrians_per_km": 1000}

    logs: int = 8
    duration_s: float = 25.0
    seed: int = 0
    network: NetworkKind = NetworkKind.GRID
    warmup_s: float = 60.0
    egos_per_run: int = 4
    step_s: float = 0.1
    range_m: float = 80.0
    vehicles_per_s_per_km: float = 0.17
    pedestrians_per_s_per_km: float = 0.06
    parked_vehicles: int = 30
    furniture_per_km: float = 1.5
    standing_pedestrians_per_km: float = 1.0
    tracker_noise: bool = False
    noise: TrackerNoiseConfig = field(default_factory=TrackerNoiseConfig)
    sensors: bool = True
    map_less_share: float = 0.0
    jitter_share: float = 0.0
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "network", NetworkKind.parse(self.network))
        check_at_least("SimulationConfig", 1, logs=self.logs)
        check_positive("SimulationConfig", duration_s=self.duration_s, step_s=self.step_s, range_m=self.range_m)
        check_at_least("SimulationConfig", 0, warmup_s=self.warmup_s, vehicles_per_s_per_km=self.vehicles_per_s_per_km,
                       pedestrians_per_s_per_km=self.pedestrians_per_s_per_km, parked_vehicles=self.parked_vehicles,
                       furniture_per_km=self.furniture_per_km,
                       standing_pedestrians_per_km=self.standing_pedestrians_per_km)
        check_at_least("SimulationConfig", 1, egos_per_run=self.egos_per_run)
        for name, share in (("map_less_share", self.map_less_share), ("jitter_share", self.jitter_share)):
            if not 0.0 <= share <= 1.0:
                raise ValueError(f"SimulationConfig.{name} must lie in [0, 1], got {share}")
        if self.duration_s < 2 * self.step_s:
            raise ValueError(f"SimulationConfig.duration_s must span at least two steps, got {self.duration_s}")
        if self.duration_s / self.step_s > MAX_STEPS_PER_LOG:
            raise self.config_error(f"key 'step_s': {self.duration_s:g} s in steps of {self.step_s:g} s are "
                                    f"{self.duration_s / self.step_s:.0f} steps a log, above the upper bound "
                                    f"{MAX_STEPS_PER_LOG}")

    @property
    def num_windows(self) -> int:
        """Windows each ego drives through."""
        return -(-self.logs // self.egos_per_run)

    def map_less_logs(self) -> frozenset[int]:
        """Indices of the logs written without their map (``round(map_less_share * logs)`` of them)."""
        return self._drawn_logs(self.map_less_share, 0x3A9)

    def jittered_logs(self) -> frozenset[int]:
        """Indices of the logs whose boxes carry label jitter (``round(jitter_share * logs)`` of them;
        none with ``tracker_noise``, whose own jitter every log then has)."""
        return frozenset() if self.tracker_noise else self._drawn_logs(self.jitter_share, 0x717)

    def _drawn_logs(self, share: float, salt: int) -> frozenset[int]:
        count = round(share * self.logs)
        order = np.random.default_rng([self.seed, salt]).permutation(self.logs)
        return frozenset(int(i) for i in order[:count])

    @property
    def num_egos(self) -> int:
        return min(self.logs, self.egos_per_run)
