"""Configuration of clip rendering: frozen dataclasses, serialised as YAML by :mod:`scenesearch_base.config`.

>>> config = ClipsConfig.from_yaml(Path("clips.yaml"))     # every field optional
>>> config.to_yaml(Path("clips.yaml"))                        # round-trips exactly
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import ClassVar

import scenesearch_base.config
from scenesearch_base.config import YamlConfig

#: Cells along each side of the BEV grid, and height bins, at most: beyond them a log's arrays stop fitting.
MAX_GRID_CELLS = 2048
MAX_HEIGHT_BINS = 64


class BevSource(StrEnum):
    """Where a log's BEV occupancy comes from."""

    LIDAR = "lidar"  # real or simulated sweeps, motion-compensated
    BOXES = "boxes"  # rendered from the annotated cuboids (logs without sweeps)


class BevSourceChoice(StrEnum):
    """Which BEV source to use for a log: ``auto`` picks LiDAR when sweeps cover enough frames."""

    AUTO = "auto"
    LIDAR = "lidar"
    BOXES = "boxes"


class Split(StrEnum):
    TRAIN = "train"
    VAL = "val"
    TEST = "test"


class ClipsConfigError(scenesearch_base.config.ConfigError):
    """A clips configuration file or value is invalid; names the file and the field."""


class ClipsYamlConfig(YamlConfig):
    """Base of the clips configs: every bad value or file raises :class:`ClipsConfigError`."""

    config_error = ClipsConfigError


@dataclass(frozen=True)
class CameraClipConfig(ClipsYamlConfig):
    """The camera view.

    Attributes:
        camera_name: camera folder under ``sensors/cameras``.
        width_px, height_px: size of the stored frames: 64 × 32, the recommended model's (larger frames
            did not lift the camera view on the quality benchmark; the object's crop, stored beside
            each frame at this size from the full-resolution image, keeps small objects visible).
        frame_tolerance_ns: a frame uses the camera image nearest in time within this tolerance.
        min_mask_px: an object counts as visible in a frame with at least this many mask pixels
            at the camera's full resolution.
        min_visible_fraction: a clip has a camera view when the object is visible in at least this
            fraction of its sampled frames.
        highlight_rgb: overlay colour of the object of interest.
        highlight_alpha: overlay opacity over the object.
        dim_factor: brightness kept outside the object.

    Upper bounds: ``width_px`` and ``height_px`` 4096.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"width_px": 4096, "height_px": 4096}

    camera_name: str = "ring_front_center"
    width_px: int = 64
    height_px: int = 32
    frame_tolerance_ns: int = 60_000_000
    min_mask_px: int = 20
    min_visible_fraction: float = 0.25
    highlight_rgb: tuple[int, int, int] = (255, 0, 255)
    highlight_alpha: float = 0.5
    dim_factor: float = 0.7


@dataclass(frozen=True)
class BevClipConfig(ClipsYamlConfig):
    """The LiDAR bird's-eye view, a grid in each frame's ego frame.

    Attributes:
        x_min_m, x_max_m, y_min_m, y_max_m, resolution_m: the grid; row 0 is ``x_max_m`` (forward
            at the top), column 0 is ``y_max_m`` (left on the left). 1.25 m cells (64 × 32): the
            recommended model's.
        z_bins_m: edges of the height bins (ego frame, z up); one occupancy channel per bin.
        num_sweeps: sweeps aggregated per frame (the current one and the previous ones),
            corrected for ego motion.
        sweep_tolerance_ns: a frame uses the sweep nearest in time within this tolerance.
        density_saturation_points: points per cell that map to the full value 255 (log scale).
        source: ``auto`` (LiDAR when sweeps cover ``lidar_min_coverage`` of the frames), ``lidar``
            or ``boxes``.
        lidar_min_coverage: see ``source``.

    Upper bounds: ``num_sweeps`` 50, ``density_saturation_points`` 65535, 64 height bins and
    2048 cells along each side of the grid (checked by :class:`ClipsConfig`).
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"num_sweeps": 50, "density_saturation_points": 65535}

    x_min_m: float = -20.0
    x_max_m: float = 60.0
    y_min_m: float = -20.0
    y_max_m: float = 20.0
    resolution_m: float = 1.25
    z_bins_m: tuple[float, ...] = (-0.5, 0.3, 1.0, 2.0, 4.0)
    num_sweeps: int = 3
    sweep_tolerance_ns: int = 60_000_000
    density_saturation_points: int = 16
    source: BevSourceChoice = BevSourceChoice.AUTO
    lidar_min_coverage: float = 0.9


@dataclass(frozen=True)
class SplitConfig(ClipsYamlConfig):
    """Splits by log: a seeded hash of the log id picks train / val / test.

    Attributes:
        train_only: ids of logs that always train, whatever their hash: extra training data (e.g.
            cheap simulated logs beside the logs to evaluate on) that must never reach val or test.
            The other logs split as they would without them.
        val_only: ids of logs that always validate: more logs to choose thresholds and calibrations on
            (a validation split of one or two hashed logs may hold no frame of a rare tag) without
            moving a hashed log, so the train and test splits stay as they were.
        test_only: ids of logs that are always held out for test (e.g. the logs a team reports on).
    """

    seed: int = 0
    train_fraction: float = 0.7
    val_fraction: float = 0.15
    train_only: tuple[str, ...] = ()
    val_only: tuple[str, ...] = ()
    test_only: tuple[str, ...] = ()

    def forced(self) -> dict[str, Split]:
        """``{log_id: split}`` of the logs whose split is given rather than hashed."""
        return {log_id: split for split, ids in ((Split.TRAIN, self.train_only), (Split.VAL, self.val_only),
                                                 (Split.TEST, self.test_only)) for log_id in ids}


@dataclass(frozen=True)
class ClipsConfig(ClipsYamlConfig):
    """Everything ``scenesearch clips`` needs.

    Attributes:
        frames_per_clip: T, frames sampled uniformly over each caption window (12: the recommended
            model's).
        window_tolerance_ns: a caption window may start/end this far outside the log's frames.
        strict: captions naming logs or tracks that are not given raise an error; when false
            they are skipped and reported.
        previews: also write an animated preview of every clip at build time. Off by default: a
            preview is drawn from the rendered frames when it is shown (the page, the demo's report),
            which costs a fleet's ingest nothing; stored ones are for viewing the folder without them.
        preview_fps: frame rate of the previews.

    Upper bounds: ``frames_per_clip`` 256, ``preview_fps`` 60, ``window_tolerance_ns`` 10 s.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"frames_per_clip": 256, "preview_fps": 60,
                                                   "window_tolerance_ns": 10_000_000_000}

    frames_per_clip: int = 12
    window_tolerance_ns: int = 50_000_000
    strict: bool = True
    previews: bool = False
    preview_fps: float = 5.0
    camera: CameraClipConfig = field(default_factory=CameraClipConfig)
    bev: BevClipConfig = field(default_factory=BevClipConfig)
    split: SplitConfig = field(default_factory=SplitConfig)

    def __post_init__(self) -> None:
        super().__post_init__()
        problems = []
        if self.frames_per_clip < 1:
            problems.append("frames_per_clip must be ≥ 1")
        if self.camera.width_px < 8 or self.camera.height_px < 8:
            problems.append("camera.width_px and camera.height_px must be ≥ 8")
        b = self.bev
        if b.resolution_m <= 0 or b.x_max_m <= b.x_min_m or b.y_max_m <= b.y_min_m:
            problems.append("bev grid needs resolution_m > 0, x_max_m > x_min_m, y_max_m > y_min_m")
        elif max(b.x_max_m - b.x_min_m, b.y_max_m - b.y_min_m) / b.resolution_m > MAX_GRID_CELLS:
            problems.append(f"bev grid of {(b.x_max_m - b.x_min_m) / b.resolution_m:g} × "
                            f"{(b.y_max_m - b.y_min_m) / b.resolution_m:g} cells: at most {MAX_GRID_CELLS} along a "
                            "side (raise bev.resolution_m or shrink the extent)")
        if len(b.z_bins_m) < 2 or any(hi <= lo for lo, hi in zip(b.z_bins_m[:-1], b.z_bins_m[1:])):
            problems.append("bev.z_bins_m must be ≥ 2 increasing edges")
        elif len(b.z_bins_m) > MAX_HEIGHT_BINS + 1:
            problems.append(f"bev.z_bins_m holds {len(b.z_bins_m)} edges: at most {MAX_HEIGHT_BINS} height bins")
        if b.num_sweeps < 1:
            problems.append("bev.num_sweeps must be ≥ 1")
        s = self.split
        if not (s.train_fraction > 0 and s.val_fraction >= 0 and s.train_fraction + s.val_fraction <= 1):
            problems.append("split fractions must be positive and sum to ≤ 1")
        named = Counter([*s.train_only, *s.val_only, *s.test_only])
        if any(n > 1 for n in named.values()):
            twice = sorted(log_id for log_id, n in named.items() if n > 1)
            problems.append(f"split: log(s) {', '.join(twice[:3])} named more than once in train_only / val_only / "
                            f"test_only (a log has one split)")
        if problems:
            raise ClipsConfigError("; ".join(problems))
