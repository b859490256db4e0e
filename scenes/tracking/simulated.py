"""Per-frame detections simulated from ground-truth boxes, for testing detections → tracks → captions.

Reuses the simulator's tracker-noise model (:func:`scenes.sim.noise.apply_tracker_noise`: range,
occlusion, misses, centre and yaw jitter), then drops track ids, adds false positives, and gives
every box a detector-like score: true boxes score high, false positives low, with overlap, so a
score threshold trades misses against false positives as with a real detector.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scenes.categories import Category
from scenes.sim.config import TrackerNoiseConfig
from scenes.sim.noise import apply_tracker_noise
from scenes.tracking.detections import Detections
from scenes.tracks import Annotations, EgoTrajectory

#: Sizes (l, w, h) of false-positive boxes per category: the typical object of that class.
_FALSE_POSITIVE_SIZES = {Category.CAR: (4.4, 1.8, 1.5), Category.PEDESTRIAN: (0.6, 0.6, 1.7),
                         Category.CYCLIST: (1.8, 0.6, 1.7)}


@dataclass(frozen=True)
class DetectorNoiseConfig:
    """Noise of a simulated detector beyond the tracker-noise model.

    Attributes:
        tracker_noise: range, occlusion, misses and jitter (id switches do not apply: detections
            carry no ids).
        false_positives_per_frame: mean number of spurious boxes per frame (Poisson).
        true_score_beta: Beta(a, b) of the scores of real objects.
        false_score_beta: Beta(a, b) of the scores of false positives.
        size_std_m: jitter of detected box sizes.
    """

    tracker_noise: TrackerNoiseConfig = field(default_factory=TrackerNoiseConfig)
    false_positives_per_frame: float = 0.5
    true_score_beta: tuple[float, float] = (8.0, 2.0)
    false_score_beta: tuple[float, float] = (2.0, 4.0)
    size_std_m: float = 0.1

    def __post_init__(self) -> None:
        if self.false_positives_per_frame < 0:
            raise ValueError(f"false_positives_per_frame must be >= 0, got {self.false_positives_per_frame}")
        if min(*self.true_score_beta, *self.false_score_beta) <= 0:
            raise ValueError("Beta parameters of the scores must be positive")
        if self.size_std_m < 0:
            raise ValueError(f"size_std_m must be >= 0, got {self.size_std_m}")


def simulate_detections(
    annotations: Annotations, ego: EgoTrajectory, config: DetectorNoiseConfig, rng: np.random.Generator
) -> Detections:
    """Detections a LiDAR detector would report for ``annotations``.

    Args:
        annotations: ground-truth boxes (ego frame).
        ego: the log's ``city_SE3_ego``.
        config: the detector's noise.
        rng: the source of randomness; the same state gives the same detections.

    Returns:
        Detections without ids, ordered by timestamp; the source line of a detection is its row.
    """
    seen = apply_tracker_noise(annotations.without_ego(), ego, config.tracker_noise, rng)
    n = len(seen)
    size = seen.size_lwh_m * np.exp(rng.normal(0.0, config.size_std_m / 3.0, size=(n, 3)))
    true = Detections(
        timestamp_ns=seen.timestamp_ns,
        category=np.array([c.value for c in seen.public_category], dtype=np.str_),
        score=rng.beta(*config.true_score_beta, size=n),
        center_xyz_m=seen.center_xyz_m,
        size_lwh_m=size,
        yaw_rad=seen.yaw_rad,
        source_line=np.zeros(n, np.int64),
    )
    frames = annotations.timestamps_ns
    counts = rng.poisson(config.false_positives_per_frame, size=frames.size)
    m = int(counts.sum())
    categories = rng.choice(list(_FALSE_POSITIVE_SIZES), size=m, p=[0.6, 0.3, 0.1])
    radius = config.tracker_noise.max_range_m * np.sqrt(rng.random(m))  # uniform over the disc
    angle = rng.uniform(-np.pi, np.pi, m)
    sizes = np.array([_FALSE_POSITIVE_SIZES[Category(c)] for c in categories]).reshape(m, 3)
    false = Detections(
        timestamp_ns=np.repeat(frames, counts),
        category=np.array([Category(c).value for c in categories], dtype=np.str_),
        score=rng.beta(*config.false_score_beta, size=m),
        center_xyz_m=np.stack([radius * np.cos(angle), radius * np.sin(angle), sizes[:, 2] / 2], axis=1),
        size_lwh_m=sizes,
        yaw_rad=rng.uniform(-np.pi, np.pi, m),
        source_line=np.zeros(m, np.int64),
    )
    out = Detections.concatenate([true, false])
    return Detections(out.timestamp_ns, out.category, out.score, out.center_xyz_m, out.size_lwh_m, out.yaw_rad,
                      np.arange(1, len(out) + 1, dtype=np.int64))


DETECTIONS_FILENAME = "detections.parquet"


def write_simulated_detections(log_dir: Path, config: DetectorNoiseConfig | None = None, seed: int = 0,
                               log_id: str | None = None) -> Path:
    """Simulate detections from a log's annotations and write ``<log_dir>/detections.parquet``.

    The generator is seeded from ``seed`` and the log's id (default: the folder's name; give it for
    a log being written under a temporary name), so each log of a run gets its own, reproducible
    detections.
    """
    from scenes import av2_io
    from scenes.tracking.detections import write_detections_table

    log_dir = Path(log_dir)
    annotations = av2_io.read_annotations(log_dir / av2_io.ANNOTATIONS_FILENAME)
    ego = av2_io.read_ego_poses(log_dir / av2_io.POSES_FILENAME)
    digest = hashlib.sha256(f"{seed}/{log_id or log_dir.name}/detections".encode()).digest()
    rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
    detections = simulate_detections(annotations, ego, config or DetectorNoiseConfig(), rng)
    path = log_dir / DETECTIONS_FILENAME
    write_detections_table(path, detections)
    return path
