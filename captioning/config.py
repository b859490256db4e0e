"""Thresholds and options of the captioning rules: one frozen dataclass, loadable from YAML.

The YAML file mirrors the nesting (every key optional, defaults below)::

    host:      {stationary_speed_mps: 0.5, accel_mps2: 0.5, yaw_rate_rps: 0.1}
    neighbor:  {stationary_speed_mps: 0.5, stationary_quantile: 0.8, host_lane_half_width_m: 1.85,
                relative_speed_mps: 1.0, oncoming_min_deg: 150.0, lateral_deg: [60.0, 120.0]}
    smoothing: {window_frames: 9, polyorder: 2, min_run_frames: 5, max_gap_frames: 3}
    segments:  {min_frames: 8, max_frames: 300}
    windows:   {strategy: host_segments, length_s: 5.0, stride_s: 2.5}
    text:      {num_paraphrases: 3, seed: 0}
    rules:     behavior          # or: paper (the paper's rules only, seed-exact captions)
    behavior:  {window_frames: 15, stopped_speed_mps: 0.4, braking_decel_mps2: 0.8, ...}
    map:       {resolution_m: 0.5, margin_m: 10.0, arm_gap_deg: 30.0, junction_approach_m: 20.0}

Reading and writing go through :mod:`common.config` (``CaptioningConfig.from_yaml(path)``,
``to_yaml(path)``): unknown keys (all listed), values of the wrong type, contradicting thresholds and
sizes above their upper bounds (windows, counts; each part's docstring lists them) raise
:class:`~captioning.errors.ConfigError`. :data:`DEFAULT_CONFIG_PATH` is the annotated default
file, equal to ``CaptioningConfig()``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import ClassVar

from captioning.errors import ConfigError
from common.config import YamlConfig

#: The annotated default configuration shipped with the package.
DEFAULT_CONFIG_PATH = Path(__file__).with_name("captioning.yaml")


class CaptioningYamlConfig(YamlConfig):
    """Base of the captioning config dataclasses: every bad value or file raises :class:`ConfigError`."""

    config_error = ConfigError


class RuleSet(StrEnum):
    """Which rules caption a log."""

    #: The paper's rules only: moving neighbours, lane and relative motion (today's captions byte for byte).
    PAPER = "paper"
    #: Also each object's own behaviour and map context, and stationary objects.
    BEHAVIOR = "behavior"


class WindowStrategy(StrEnum):
    """How neighbour captions are cut in time."""

    #: One window per host segment, as in the paper.
    HOST_SEGMENTS = "host_segments"
    #: Fixed-length windows every ``stride_s``.
    SLIDING = "sliding"


@dataclass(frozen=True)
class HostConfig(CaptioningYamlConfig):
    """Host (ego) motion and direction thresholds (paper eqs. 1, 2).

    Attributes:
        stationary_speed_mps: T_v. 0.5 m/s sits well above the speed noise of smoothed AV2/ORB-SLAM
            poses (a few cm/s) and below any deliberate creeping.
        accel_mps2: T_a. 0.5 m/s² is a quarter of a comfortable braking or acceleration (about 2 m/s²),
            so gentle speed changes count while pose jitter after smoothing (≈0.1 m/s²) does not.
        yaw_rate_rps: T_ω. 0.1 rad/s (≈6°/s): a 90° turn takes 3–6 s (0.25–0.5 rad/s); lane keeping on
            curved roads and lane changes stay mostly below it.
    """

    stationary_speed_mps: float = 0.5
    accel_mps2: float = 0.5
    yaw_rate_rps: float = 0.1


@dataclass(frozen=True)
class NeighborConfig(CaptioningYamlConfig):
    """Neighbour stationarity, lane and motion thresholds (paper eqs. 3–7).

    Attributes:
        stationary_speed_mps: T_s. A track is stationary when its host-compensated speed along each
            axis stays below this; 0.5 m/s is above box-centre jitter of human labels and trackers
            (±0.1 m per frame, ≈0.2 m/s after smoothing) and below a slow walk (≈1 m/s).
        stationary_quantile: the robust statistic of eq. 3: a track is stationary when this quantile
            of its per-frame absolute speed along each axis is below T_s. 0.8 ignores the worst 20 %
            of frames (tracker glitches) yet keeps a car that moves for a fifth of its track.
        host_lane_half_width_m: T_h, half of a 3.7 m lane.
        relative_speed_mps: T_m. 1 m/s: a follower's distance fluctuates by less than that while
            "keeping its distance"; a real approach is faster.
        oncoming_min_deg: φ_on; headings beyond ±150° count as oncoming.
        lateral_deg: (φ_ll, φ_lu); headings between them count as lateral (crossing).
    """

    stationary_speed_mps: float = 0.5
    stationary_quantile: float = 0.8
    host_lane_half_width_m: float = 1.85
    relative_speed_mps: float = 1.0
    oncoming_min_deg: float = 150.0
    lateral_deg: tuple[float, float] = (60.0, 120.0)


@dataclass(frozen=True)
class SmoothingConfig(CaptioningYamlConfig):
    """Derivatives and flicker suppression.

    Attributes:
        window_frames: Savitzky–Golay window (odd). 9 frames = 0.9 s at 10 Hz: long enough to average
            out box jitter, short enough to keep a 2 s braking manoeuvre.
        polyorder: Savitzky–Golay polynomial order (< window_frames).
        min_run_frames: per-frame tags holding for fewer frames are replaced by their neighbours'
            (0.5 s at 10 Hz); 1 turns suppression off.
        max_gap_frames: a track's gaps of at most this many frames (missed detections) are bridged
            by linear interpolation in time before differentiating and suppressing flicker, so a
            tracker's occasional miss does not cut a track into short, noisy runs; tags are still
            reported on observed frames only. 3 frames (0.3 s) covers typical misses and occlusions
            by a passing object; 0 differentiates each contiguous run on its own.

    Upper bounds: ``window_frames`` 1001, ``min_run_frames`` and ``max_gap_frames`` 100000.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"window_frames": 1001, "min_run_frames": 100_000,
                                                   "max_gap_frames": 100_000}

    window_frames: int = 9
    polyorder: int = 2
    min_run_frames: int = 5
    max_gap_frames: int = 3


@dataclass(frozen=True)
class SegmentsConfig(CaptioningYamlConfig):
    """Host segments: runs of one host tag, ``min_frames``..``max_frames`` long (paper: 8..300).

    Runs shorter than ``min_frames`` are dropped; longer than ``max_frames`` are split into equal parts,
    which is why ``max_frames`` must be at least twice ``min_frames`` (no part may fall below the minimum).

    Upper bounds: ``min_frames`` 50000, ``max_frames`` 100000 (almost three hours at 10 Hz).
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"min_frames": 50_000, "max_frames": 100_000}

    min_frames: int = 8
    max_frames: int = 300


@dataclass(frozen=True)
class WindowsConfig(CaptioningYamlConfig):
    """Neighbour caption windows.

    Attributes:
        strategy: ``host_segments`` (paper) or ``sliding``.
        length_s: sliding window length.
        stride_s: sliding window step.

    Upper bounds: ``length_s`` and ``stride_s`` 3600.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"length_s": 3600, "stride_s": 3600}

    strategy: WindowStrategy = WindowStrategy.HOST_SEGMENTS
    length_s: float = 5.0
    stride_s: float = 2.5


@dataclass(frozen=True)
class TextConfig(CaptioningYamlConfig):
    """Caption text.

    Attributes:
        num_paraphrases: seeded paraphrase variants per caption (besides the canonical one).
        seed: base seed of the paraphrase choice.

    Upper bounds: ``num_paraphrases`` 100.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"num_paraphrases": 100}

    num_paraphrases: int = 3
    seed: int = 0


@dataclass(frozen=True)
class BehaviorConfig(CaptioningYamlConfig):
    """Each object's own behaviour (:mod:`captioning.behavior`); the vocabulary is that of the
    simulator's behaviour labels (:class:`scenes.behavior.BehaviorLabel`).

    Attributes:
        window_frames: Savitzky–Golay window (odd) of the objects' own speed, acceleration and
            lateral offset. 15 frames = 1.5 s at 10 Hz: box jitter of a tracker (±0.15 m) becomes
            ≈0.1 m/s of speed noise, well below ``stopped_speed_mps``, while a 2 s braking keeps
            most of its peak.
        polyorder: its polynomial order (< window_frames).
        accel_window_frames: Savitzky–Golay window (odd) of the rate of change of the smoothed speed;
            short, because the speed is smoothed already.
        min_run_frames: a track needs a run of at least this many observed (or bridged) frames for
            own-behaviour tags; shorter runs are untagged (null) and the track is reported.
        stopped_speed_mps: below this smoothed speed an object stands still (stopped or parked).
            The labels' 0.2 m/s is within the speed noise of tracked boxes; 0.4 m/s is above it.
        braking_decel_mps2: a moving vehicle brakes when its speed falls at least this fast (1 m/s²,
            half a comfortable braking, as in the simulator's labels).
        parked_off_lane_fraction: a vehicle standing still is parked when at least this share of
            its standing run lies off the travel lanes (and outside intersections).
        parked_curb_min_s: ... or when it stands at least this long at the curb (in a lane without a
            neighbour on that side, ``parked_curb_offset_m`` or more from the centre towards the curb).
        parked_curb_offset_m: see ``parked_curb_min_s``.
        parked_no_map_min_s: without a map, a vehicle standing still over its whole track, observed
            at least this long, is parked (nothing else tells the curb from a queue).
        turn_min_deg: a vehicle turns left / right through an intersection when its heading changes by
            at least this much between entering and leaving it (or, without a map, over a run of yaw
            rate above ``turn_yaw_rate_rps``). Junction connections that are not turns change it by
            less than 20°; the mildest turns of a grid by 45° or more.
        turn_yaw_rate_rps: yaw rate of a turn without a map (≈6°/s, as the host's T_ω).
        lane_change_offset_m: a lane change is a run of frames whose (smoothed) offset from the lane
            centre exceeds this, during which the lane changes to its left or right neighbour; the
            labels' 0.05 m is within box jitter, 0.25 m clears it.
        blocked_speed_mps: a vehicle slower than this ...
        blocked_gap_m: ... with a leader at most this far ahead, bumper to bumper, is blocked by it.
        braking_for_min_gap_m: a braking vehicle brakes for a leader within
            max(``braking_for_min_gap_m``, ``braking_for_headway_s`` × speed) that is slower or braking.
        braking_for_headway_s: see ``braking_for_min_gap_m``.
        leader_half_width_m: the leader's centre lies at most this far to either side of the
            follower's heading line (half a lane).
        leader_max_heading_deg: and heads within this angle of the follower (crossing traffic is no leader).
        ego_front_m: the ego's front bumper ahead of its origin (rear axle), for the ego as a leader.
        ego_rear_m: its rear bumper behind the origin.

    Upper bounds: ``window_frames`` and ``accel_window_frames`` 1001, ``min_run_frames`` 100000.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"window_frames": 1001, "accel_window_frames": 1001,
                                                   "min_run_frames": 100_000}

    window_frames: int = 9
    polyorder: int = 2
    accel_window_frames: int = 5
    min_run_frames: int = 5
    stopped_speed_mps: float = 0.4
    braking_decel_mps2: float = 1.0
    parked_off_lane_fraction: float = 0.5
    parked_curb_min_s: float = 30.0
    parked_curb_offset_m: float = 0.5
    parked_no_map_min_s: float = 10.0
    turn_min_deg: float = 30.0
    turn_yaw_rate_rps: float = 0.1
    lane_change_offset_m: float = 0.25
    blocked_speed_mps: float = 0.5
    blocked_gap_m: float = 10.0
    braking_for_min_gap_m: float = 15.0
    braking_for_headway_s: float = 3.0
    leader_half_width_m: float = 1.6
    leader_max_heading_deg: float = 45.0
    ego_front_m: float = 3.6
    ego_rear_m: float = 1.0


@dataclass(frozen=True)
class MapConfig(CaptioningYamlConfig):
    """How the map is read for context (:mod:`captioning.map_context`).

    Attributes:
        resolution_m: cell size of the city-frame rasters. 0.5 m: a lane is six cells wide, and only
            which lane a point is in comes from the raster (its offset from the centre line is exact).
        margin_m: the rasters cover the tracks' extent plus this margin (a box front reaches a few
            metres beyond its centre).
        arm_gap_deg: lanes leaving a junction in directions at least this far apart belong to
            different roads (roads of a junction meet at 45° or more; lanes of one road are parallel).
        junction_approach_m: an object on a lane entering a junction, at most this far from the
            lane's end, is at that junction (its kind applies), as in the simulator's labels.

    Upper bounds: ``margin_m`` 1000 (the rasters grow with the square of their extent).
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"margin_m": 1000}

    resolution_m: float = 0.5
    margin_m: float = 10.0
    arm_gap_deg: float = 30.0
    junction_approach_m: float = 20.0


@dataclass(frozen=True)
class CaptioningConfig(CaptioningYamlConfig):
    """All thresholds of the rules. See each part's docstring for the defaults' reasons.

    Attributes:
        rules: ``behavior`` (default) adds each object's own behaviour and map context to the tags
            and captions and captions stationary objects too; ``paper`` keeps to the paper's rules
            (moving neighbours, lane and relative motion) and gives exactly the captions and frame
            tags of the paper's rules alone.
    """

    rules: RuleSet = RuleSet.BEHAVIOR
    host: HostConfig = field(default_factory=HostConfig)
    neighbor: NeighborConfig = field(default_factory=NeighborConfig)
    smoothing: SmoothingConfig = field(default_factory=SmoothingConfig)
    segments: SegmentsConfig = field(default_factory=SegmentsConfig)
    windows: WindowsConfig = field(default_factory=WindowsConfig)
    text: TextConfig = field(default_factory=TextConfig)
    behavior: BehaviorConfig = field(default_factory=BehaviorConfig)
    map: MapConfig = field(default_factory=MapConfig)

    def __post_init__(self) -> None:
        super().__post_init__()
        self.validate()

    def validate(self) -> None:
        """Raise :class:`ConfigError` listing every contradiction."""
        problems: list[str] = []
        non_negative = {
            "host.stationary_speed_mps": self.host.stationary_speed_mps,
            "host.accel_mps2": self.host.accel_mps2,
            "host.yaw_rate_rps": self.host.yaw_rate_rps,
            "neighbor.stationary_speed_mps": self.neighbor.stationary_speed_mps,
            "neighbor.host_lane_half_width_m": self.neighbor.host_lane_half_width_m,
            "neighbor.relative_speed_mps": self.neighbor.relative_speed_mps,
        }
        for key, value in non_negative.items():
            if not math.isfinite(value) or value < 0:
                problems.append(f"{key} must be a finite number >= 0, got {value}")
        lo, hi = self.neighbor.lateral_deg
        on = self.neighbor.oncoming_min_deg
        if not (0 <= lo < hi <= 180):
            problems.append(f"neighbor.lateral_deg must satisfy 0 <= lower < upper <= 180, got [{lo}, {hi}]")
        if not (hi <= on <= 180):
            problems.append(
                f"neighbor.oncoming_min_deg ({on}) must lie in [lateral_deg upper ({hi}), 180] "
                "so that the lanes do not overlap"
            )
        if not (0 < self.neighbor.stationary_quantile <= 1):
            problems.append(f"neighbor.stationary_quantile must lie in (0, 1], got {self.neighbor.stationary_quantile}")
        s = self.smoothing
        if s.window_frames < 3 or s.window_frames % 2 == 0:
            problems.append(f"smoothing.window_frames must be odd and >= 3, got {s.window_frames}")
        if not (1 <= s.polyorder < s.window_frames):
            problems.append(f"smoothing.polyorder must lie in [1, window_frames), got {s.polyorder}")
        if s.max_gap_frames < 0:
            problems.append(f"smoothing.max_gap_frames must be >= 0, got {s.max_gap_frames}")
        if s.min_run_frames < 1:
            problems.append(f"smoothing.min_run_frames must be >= 1, got {s.min_run_frames}")
        g = self.segments
        if g.min_frames < 1:
            problems.append(f"segments.min_frames must be >= 1, got {g.min_frames}")
        if g.min_frames > g.max_frames:
            problems.append(f"segments.min_frames ({g.min_frames}) exceeds segments.max_frames ({g.max_frames})")
        elif g.max_frames < 2 * g.min_frames:
            problems.append(
                f"segments.max_frames ({g.max_frames}) must be at least twice segments.min_frames ({g.min_frames}) "
                "so that splitting a long run never yields a part shorter than the minimum"
            )
        w = self.windows
        if not isinstance(w.strategy, WindowStrategy):
            problems.append(f"windows.strategy must be one of {[v.value for v in WindowStrategy]}, got {w.strategy!r}")
        if not (w.length_s > 0 and w.stride_s > 0):
            problems.append(f"windows.length_s and windows.stride_s must be > 0, got {w.length_s}, {w.stride_s}")
        if not isinstance(self.rules, RuleSet):
            problems.append(f"rules must be one of {[v.value for v in RuleSet]}, got {self.rules!r}")
        b = self.behavior
        if b.window_frames < 3 or b.window_frames % 2 == 0:
            problems.append(f"behavior.window_frames must be odd and >= 3, got {b.window_frames}")
        if b.accel_window_frames < 3 or b.accel_window_frames % 2 == 0:
            problems.append(f"behavior.accel_window_frames must be odd and >= 3, got {b.accel_window_frames}")
        if not (1 <= b.polyorder < b.window_frames):
            problems.append(f"behavior.polyorder must lie in [1, window_frames), got {b.polyorder}")
        if b.min_run_frames < 2:
            problems.append(
                f"behavior.min_run_frames must be >= 2 (a derivative needs two frames), got {b.min_run_frames}"
            )
        if not (0 < b.parked_off_lane_fraction <= 1):
            problems.append(f"behavior.parked_off_lane_fraction must lie in (0, 1], got {b.parked_off_lane_fraction}")
        positive = {
            "behavior.stopped_speed_mps": b.stopped_speed_mps,
            "behavior.braking_decel_mps2": b.braking_decel_mps2,
            "behavior.turn_min_deg": b.turn_min_deg,
            "behavior.lane_change_offset_m": b.lane_change_offset_m,
            "behavior.leader_half_width_m": b.leader_half_width_m,
            "behavior.leader_max_heading_deg": b.leader_max_heading_deg,
            "map.resolution_m": self.map.resolution_m,
            "map.arm_gap_deg": self.map.arm_gap_deg,
        }
        for key, value in positive.items():
            if not math.isfinite(value) or value <= 0:
                problems.append(f"{key} must be a finite number > 0, got {value}")
        at_least_zero = {
            "behavior.parked_curb_min_s": b.parked_curb_min_s,
            "behavior.parked_curb_offset_m": b.parked_curb_offset_m,
            "behavior.parked_no_map_min_s": b.parked_no_map_min_s,
            "behavior.turn_yaw_rate_rps": b.turn_yaw_rate_rps,
            "behavior.blocked_speed_mps": b.blocked_speed_mps,
            "behavior.blocked_gap_m": b.blocked_gap_m,
            "behavior.braking_for_min_gap_m": b.braking_for_min_gap_m,
            "behavior.braking_for_headway_s": b.braking_for_headway_s,
            "behavior.ego_front_m": b.ego_front_m,
            "behavior.ego_rear_m": b.ego_rear_m,
            "map.margin_m": self.map.margin_m,
            "map.junction_approach_m": self.map.junction_approach_m,
        }
        for key, value in at_least_zero.items():
            if not math.isfinite(value) or value < 0:
                problems.append(f"{key} must be a finite number >= 0, got {value}")
        if self.text.num_paraphrases < 0:
            problems.append(f"text.num_paraphrases must be >= 0, got {self.text.num_paraphrases}")
        if problems:
            raise ConfigError("invalid captioning config: " + "; ".join(problems))
