"""Configuration of the city simulator: frozen dataclasses that round-trip YAML."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import yaml


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
        try:
            return NetworkKind(value)
        except ValueError:
            choices = ", ".join(k.value for k in NetworkKind)
            raise ValueError(f"unknown network kind {value!r} (choose one of: {choices})") from None


@dataclass(frozen=True)
class TrackerNoiseConfig:
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
    """

    center_std_m: float = 0.15
    yaw_std_rad: float = 0.03
    miss_probability: float = 0.05
    id_switch_rate_per_s: float = 0.01
    max_range_m: float = 70.0
    occlusion_fraction: float = 0.8
    occlusion_rays: int = 16

    def __post_init__(self) -> None:
        for name in ("center_std_m", "yaw_std_rad", "id_switch_rate_per_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"TrackerNoiseConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.miss_probability <= 1.0:
            raise ValueError(f"TrackerNoiseConfig.miss_probability must be in [0, 1], got {self.miss_probability}")
        if not 0.0 < self.occlusion_fraction <= 1.0:
            raise ValueError(
                f"TrackerNoiseConfig.occlusion_fraction must be in (0, 1], got {self.occlusion_fraction}"
            )
        if self.max_range_m <= 0:
            raise ValueError(f"TrackerNoiseConfig.max_range_m must be > 0, got {self.max_range_m}")
        if self.occlusion_rays < 2:
            raise ValueError(f"TrackerNoiseConfig.occlusion_rays must be >= 2, got {self.occlusion_rays}")


@dataclass(frozen=True)
class SimulationConfig:
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
        tracker_noise: apply :class:`TrackerNoiseConfig` to the written annotations (labels stay exact).
        noise: the noise model used when ``tracker_noise`` is set.
        sensors: whether sensor data (LiDAR, cameras) is rendered after the tracks; recorded for the
            sensor stage, which runs on the written logs.
        cache_dir: folder for generated networks (default: the system temp folder).
    """

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
    tracker_noise: bool = False
    noise: TrackerNoiseConfig = field(default_factory=TrackerNoiseConfig)
    sensors: bool = True
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "network", NetworkKind.parse(self.network))
        if isinstance(self.noise, dict):
            object.__setattr__(self, "noise", TrackerNoiseConfig(**self.noise))
        if self.logs < 1:
            raise ValueError(f"SimulationConfig.logs must be >= 1, got {self.logs}")
        for name in ("duration_s", "step_s", "range_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SimulationConfig.{name} must be > 0, got {getattr(self, name)}")
        for name in ("warmup_s", "vehicles_per_s_per_km", "pedestrians_per_s_per_km", "parked_vehicles"):
            if getattr(self, name) < 0:
                raise ValueError(f"SimulationConfig.{name} must be >= 0, got {getattr(self, name)}")
        if self.egos_per_run < 1:
            raise ValueError(f"SimulationConfig.egos_per_run must be >= 1, got {self.egos_per_run}")
        if self.duration_s < 2 * self.step_s:
            raise ValueError(f"SimulationConfig.duration_s must span at least two steps, got {self.duration_s}")

    @property
    def num_windows(self) -> int:
        """Windows each ego drives through."""
        return -(-self.logs // self.egos_per_run)

    @property
    def num_egos(self) -> int:
        return min(self.logs, self.egos_per_run)

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["network"] = self.network.value
        return data

    @staticmethod
    def from_dict(data: dict[str, Any]) -> SimulationConfig:
        known = {f.name for f in dataclasses.fields(SimulationConfig)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"SimulationConfig: unknown keys {unknown}")
        values = dict(data)
        if "noise" in values and isinstance(values["noise"], dict):
            noise_known = {f.name for f in dataclasses.fields(TrackerNoiseConfig)}
            noise_unknown = sorted(set(values["noise"]) - noise_known)
            if noise_unknown:
                raise ValueError(f"SimulationConfig.noise: unknown keys {noise_unknown}")
            values["noise"] = TrackerNoiseConfig(**values["noise"])
        return SimulationConfig(**values)

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=True)

    @staticmethod
    def from_yaml(text: str) -> SimulationConfig:
        data = yaml.safe_load(text) or {}
        if not isinstance(data, dict):
            raise ValueError("SimulationConfig YAML must be a mapping")
        return SimulationConfig.from_dict(data)
