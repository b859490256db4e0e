"""What a scenario program answers in one log: which objects it refers to, at which frames, and the
objects they relate to, with everything the scenario-mining submission records of each object."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class LogAnswer:
    """One description's answer in one log, on the log's frame grid (K tracks × F frames).

    Attributes:
        log_id: the log.
        description: the description (or program text) answered.
        timestamps_ns: (F,) the log's annotation timestamps, increasing.
        track_ids: (K,) track ids (str).
        categories: (K,) each object's dataset label where the log has AV2's (``REGULAR_VEHICLE``,
            ``EGO_VEHICLE``), else its public category (``car``).
        valid: (K, F) whether the track is observed at the frame.
        referred: (K, F) float32 score in [0, 1] of each object being referred to at each frame; 0
            where not referred (or not observed).
        related: (K, F) bool, the objects a referred object relates to at that frame (the bicycle
            of "vehicle with a bicycle to its right"), where not referred themselves.
        center_city_xyz_m: (K, F, 3) box centres in the city frame, NaN where not observed.
        size_lwh_m: (K, F, 3) box sizes.
        yaw_city_rad: (K, F) headings in the city frame.
        velocity_city_mps: (K, F, 3) velocities in the city frame.
        ego_city_xyz_m: (F, 3) the ego's position in the city frame.
    """

    log_id: str
    description: str
    timestamps_ns: NDArray[np.int64]
    track_ids: NDArray[np.str_]
    categories: NDArray[np.str_]
    valid: NDArray[np.bool_]
    referred: NDArray[np.float32]
    related: NDArray[np.bool_]
    center_city_xyz_m: NDArray[np.float64]
    size_lwh_m: NDArray[np.float64]
    yaw_city_rad: NDArray[np.float64]
    velocity_city_mps: NDArray[np.float64]
    ego_city_xyz_m: NDArray[np.float64]

    @property
    def referred_mask(self) -> NDArray[np.bool_]:
        """(K, F) where an object is referred to."""
        return self.referred > 0
