"""Tracker parameters, one frozen dataclass, serialised as YAML by :mod:`scenesearch_base.config`."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from scenes.config import ScenesConfig
from scenesearch_base.config import check_at_least, check_fraction, check_positive


class Association(str, Enum):
    """How a predicted track and a detection are scored for matching."""

    #: Planar distance between box centres (metres); robust for small objects (pedestrians).
    DISTANCE = "distance"
    #: 1 − bird's-eye-view IoU of the rotated boxes; stricter for large, well-localised vehicles.
    BEV_IOU = "bev_iou"


def _default_gates() -> dict[str, float]:
    # Centre-distance gates per public category, in metres: about one box length for vehicles at
    # 10 Hz (a car at 15 m/s moves 1.5 m per frame, and the filter predicts most of it), less for
    # pedestrians, whose neighbours in a crowd are often 1 m apart.
    return {"car": 2.5, "truck": 3.0, "bus": 3.5, "motorcycle": 2.0, "cyclist": 1.5, "pedestrian": 1.0, "other": 1.5}


@dataclass(frozen=True)
class TrackerConfig(ScenesConfig):
    """Parameters of :class:`~scenes.tracking.tracker.Tracker`.

    Attributes:
        association: matching score, ``distance`` (default) or ``bev_iou``.
        distance_gate_m: per public category, the largest centre distance of a match.
        min_bev_iou: with ``bev_iou``, the smallest IoU of a match.
        min_hits: matches before a track is reported (AB3DMOT uses 3 at 10 Hz: suppresses
            one-frame false positives at the cost of 0.2 s of latency at birth).
        max_age: missed frames before a track dies (2 at 10 Hz bridges single missed detections).
        score_threshold: detections scoring below this are ignored (scores are in [0, 1]; 0.5 treats
            the score as a probability; PointRCNN on the development KITTI sequences does best near 0.9).
        position_noise_m: measurement noise std of the box centre.
        yaw_noise_rad: measurement noise std of the yaw.
        size_noise_m: measurement noise std of the box size.
        accel_noise_mps2: process noise of the constant-velocity model (random acceleration).
        initial_velocity_std_mps: prior std of a new track's velocity (unknown at birth).
        per_category: associate only detections and tracks of the same public category.
        heading_min_speed_mps: once a confirmed track moves at least this fast, its heading is
            turned to agree with its velocity (detectors confuse front and back; cars drive forwards).
        fill_gaps: report boxes for frames a confirmed track missed (at most ``max_age`` in a row),
            interpolated between the frames before and after the gap; logs are tracked offline, so
            the future is known.
    """

    association: Association = Association.DISTANCE
    distance_gate_m: dict[str, float] = field(default_factory=_default_gates)
    min_bev_iou: float = 0.1
    min_hits: int = 3
    max_age: int = 2
    score_threshold: float = 0.5
    position_noise_m: float = 0.3
    yaw_noise_rad: float = 0.2
    size_noise_m: float = 0.2
    accel_noise_mps2: float = 3.0
    initial_velocity_std_mps: float = 10.0
    per_category: bool = True
    heading_min_speed_mps: float = 2.0
    fill_gaps: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "association", Association(self.association))
        check_at_least("TrackerConfig", 1, min_hits=self.min_hits)
        check_at_least("TrackerConfig", 0, max_age=self.max_age)
        check_fraction("TrackerConfig", score_threshold=self.score_threshold)
        if not 0.0 < self.min_bev_iou <= 1.0:
            raise ValueError(f"TrackerConfig.min_bev_iou must be in (0, 1], got {self.min_bev_iou}")
        check_positive("TrackerConfig", position_noise_m=self.position_noise_m, yaw_noise_rad=self.yaw_noise_rad,
                       size_noise_m=self.size_noise_m, accel_noise_mps2=self.accel_noise_mps2,
                       initial_velocity_std_mps=self.initial_velocity_std_mps)
        for category, gate in self.distance_gate_m.items():
            if not gate > 0:
                raise ValueError(f"TrackerConfig.distance_gate_m[{category!r}] must be > 0, got {gate}")

    def gate_m(self, category: str) -> float:
        return float(self.distance_gate_m.get(category, self.distance_gate_m.get("other", 1.5)))
