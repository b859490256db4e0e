"""Thresholds and options of the captioning rules: one frozen dataclass, loadable from YAML.

The YAML file mirrors the nesting (every key optional, defaults below)::

    host:      {stationary_speed_mps: 0.5, accel_mps2: 0.5, yaw_rate_rps: 0.1}
    neighbor:  {stationary_speed_mps: 0.5, stationary_quantile: 0.8, host_lane_half_width_m: 1.85,
                relative_speed_mps: 1.0, oncoming_min_deg: 150.0, lateral_deg: [60.0, 120.0]}
    smoothing: {window_s: 0.9, polyorder: 2, min_run_s: 0.5, max_gap_s: 0.3}
    segments:  {min_s: 0.8, max_s: 30.0}
    windows:   {strategy: host_segments, length_s: 5.0, stride_s: 2.5}
    text:      {num_paraphrases: 3, seed: 0}
    rules:     behavior          # or: paper (the paper's rules only, seed-exact captions)
    behavior:  {window_s: 0.9, accel_window_s: 0.5, min_run_s: 0.5, stopped_speed_mps: 0.4, ...}
    map:       {resolution_m: 0.5, margin_m: 10.0, arm_gap_deg: 30.0, junction_approach_m: 20.0}

Reading and writing go through :mod:`scenesearch_base.config` (``CaptioningConfig.from_yaml(path)``,
``to_yaml(path)``): unknown keys (all listed), values of the wrong type, contradicting thresholds and
sizes above their upper bounds (windows, counts; each part's docstring lists them) raise
:class:`~captioning.errors.ConfigError`. :data:`DEFAULT_CONFIG_PATH` is the annotated default
file, equal to ``CaptioningConfig()``.

**Durations are in seconds.** Every window and run of the rules (keys ending in ``_s``) is converted
to frames at each log's own frame rate (:mod:`captioning.frames`), so that one config means the same
at 10 Hz and at 2 Hz. Files with the frame-count keys these replace (``smoothing.window_frames``,
``segments.min_frames``, …) are refused, naming each key and its replacement.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any, ClassVar, Self

import yaml

from captioning.errors import ConfigError
from captioning.renamed_keys import refuse_renamed_keys
from scenesearch_base.config import YamlConfig

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
    """Derivatives and flicker suppression, in seconds (frames at each log's rate: :mod:`captioning.frames`).

    Attributes:
        window_s: Savitzky–Golay window of the host's and the tracks' derivatives. 0.9 s (9 frames at
            10 Hz): long enough to average out box jitter, short enough to keep a 2 s braking
            manoeuvre. In frames it is the nearest odd count, at least 3: 3 at 2 Hz, where the
            derivative is the central difference.
        polyorder: Savitzky–Golay polynomial order; lowered to the window's frames − 2 where the
            window is shorter (a polynomial through every sample of its window interpolates the jitter).
        min_run_s: per-frame tags holding for less than this are replaced by their neighbours'
            (0.5 s: 5 frames at 10 Hz; at 2 Hz a single frame lasts as long, so nothing is
            replaced); 0 turns suppression off.
        max_gap_s: a track's gaps of at most this long in missed frames (missed detections) are
            bridged by linear interpolation in time before differentiating and suppressing flicker, so
            a tracker's occasional miss does not cut a track into short, noisy runs; tags are still
            reported on observed frames only. 0.3 s (3 frames at 10 Hz, 1 at 2 Hz) covers typical
            misses and occlusions by a passing object; 0 differentiates each contiguous run on its own.

    Upper bounds: ``window_s`` 100, ``min_run_s`` and ``max_gap_s`` 10000 (seconds), ``polyorder`` 20.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"window_s": 100.0, "min_run_s": 10_000.0,
                                                   "max_gap_s": 10_000.0, "polyorder": 20}

    window_s: float = 0.9
    polyorder: int = 2
    min_run_s: float = 0.5
    max_gap_s: float = 0.3


@dataclass(frozen=True)
class SegmentsConfig(CaptioningYamlConfig):
    """Host segments: runs of one host tag, ``min_s``..``max_s`` long (paper: 8..300 frames at 10 Hz).

    Attributes:
        min_s: runs shorter than this are dropped (0.8 s: 8 frames at 10 Hz, 2 at 2 Hz); a neighbour
            caption needs its track tagged in at least as many frames of the window.
        max_s: longer runs are split into equal parts (30 s: 300 frames at 10 Hz), which is why it
            must be at least twice ``min_s`` (no part may fall below the minimum; in frames the
            maximum is kept at least twice the minimum after rounding).

    Upper bounds: ``min_s`` 5000, ``max_s`` 10000 (seconds; almost three hours).
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"min_s": 5_000.0, "max_s": 10_000.0}

    min_s: float = 0.8
    max_s: float = 30.0


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
        window_s: Savitzky–Golay window of the objects' own speed, heading rate and smoothed
            position (for the map lookup). 0.9 s (9 frames at 10 Hz), as ``smoothing.window_s``, so
            the speed is the neighbour tags' derivative: box jitter of a tracker (±0.15 m) becomes
            ≈0.1–0.2 m/s of speed noise, below ``stopped_speed_mps``, while a 2 s braking keeps most of
            its peak. In frames the nearest odd count, at least 3.
        polyorder: its polynomial order (and that of ``accel_window_s``), lowered to a window's frames
            − 2 where the window is shorter.
        accel_window_s: Savitzky–Golay window of the rate of change of the smoothed speed; short,
            because the speed is smoothed already (0.5 s: 5 frames at 10 Hz; at least 3 frames).
        min_run_s: a track needs a run of observed (or bridged) frames lasting at least this for
            own-behaviour tags (0.5 s: 5 frames at 10 Hz, 2 at 2 Hz; never fewer than 2 frames, as a
            derivative needs two); shorter runs are untagged (null) and the track is reported.
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

    Upper bounds: ``window_s`` and ``accel_window_s`` 100, ``min_run_s`` 10000 (seconds), ``polyorder`` 20.
    """

    upper_bounds: ClassVar[Mapping[str, float]] = {"window_s": 100.0, "accel_window_s": 100.0,
                                                   "min_run_s": 10_000.0, "polyorder": 20}

    window_s: float = 0.9
    polyorder: int = 2
    accel_window_s: float = 0.5
    min_run_s: float = 0.5
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

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, source: str = "<dict>") -> Self:
        """As :meth:`YamlConfig.from_dict`; a frame-count key of an older file is refused naming its
        replacement (:mod:`captioning.renamed_keys`)."""
        refuse_renamed_keys(data, source)
        return super().from_dict(data, source)

    @classmethod
    def from_yaml_text(cls, text: str, source: str = "<text>") -> Self:
        """As :meth:`YamlConfig.from_yaml_text`, refusing frame-count keys as :meth:`from_dict` does."""
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError:
            data = None  # the reader below reports it, with line and column
        refuse_renamed_keys(data, source)
        return super().from_yaml_text(text, source)

    @classmethod
    def from_yaml(cls, path: Path | str) -> Self:
        """As :meth:`YamlConfig.from_yaml`, refusing frame-count keys as :meth:`from_dict` does."""
        try:
            text = Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            return super().from_yaml(path)  # reports why the file cannot be read
        return cls.from_yaml_text(text, source=str(path))

    def validate(self) -> None:
        """Raise :class:`ConfigError` listing every contradiction."""
        problems: list[str] = []
        s, g, b = self.smoothing, self.segments, self.behavior
        non_negative = {
            "host.stationary_speed_mps": self.host.stationary_speed_mps,
            "host.accel_mps2": self.host.accel_mps2,
            "host.yaw_rate_rps": self.host.yaw_rate_rps,
            "neighbor.stationary_speed_mps": self.neighbor.stationary_speed_mps,
            "neighbor.host_lane_half_width_m": self.neighbor.host_lane_half_width_m,
            "neighbor.relative_speed_mps": self.neighbor.relative_speed_mps,
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
        positive_s = {
            "smoothing.window_s": s.window_s,
            "segments.min_s": g.min_s,
            "behavior.window_s": b.window_s,
            "behavior.accel_window_s": b.accel_window_s,
        }
        for key, value in positive_s.items():
            if not math.isfinite(value) or value <= 0:
                problems.append(f"{key} must be a finite number of seconds > 0, got {value}")
        at_least_zero_s = {
            "smoothing.min_run_s": s.min_run_s,
            "smoothing.max_gap_s": s.max_gap_s,
            "behavior.min_run_s": b.min_run_s,
        }
        for key, value in at_least_zero_s.items():
            if not math.isfinite(value) or value < 0:
                problems.append(f"{key} must be a finite number of seconds >= 0, got {value}")
        for key, order in (("smoothing.polyorder", s.polyorder), ("behavior.polyorder", b.polyorder)):
            if order < 1:
                problems.append(f"{key} must be >= 1, got {order}")
        if g.min_s > g.max_s:
            problems.append(f"segments.min_s ({g.min_s}) exceeds segments.max_s ({g.max_s})")
        elif not g.max_s >= 2 * g.min_s:
            problems.append(
                f"segments.max_s ({g.max_s}) must be at least twice segments.min_s ({g.min_s}) "
                "so that splitting a long run never yields a part shorter than the minimum"
            )
        w = self.windows
        if not isinstance(w.strategy, WindowStrategy):
            problems.append(f"windows.strategy must be one of {[v.value for v in WindowStrategy]}, got {w.strategy!r}")
        if not (w.length_s > 0 and w.stride_s > 0):
            problems.append(f"windows.length_s and windows.stride_s must be > 0, got {w.length_s}, {w.stride_s}")
        elif w.stride_s > w.length_s:  # windows would leave gaps that no caption covers
            problems.append(f"windows.stride_s ({w.stride_s}) exceeds windows.length_s ({w.length_s})")
        if not isinstance(self.rules, RuleSet):
            problems.append(f"rules must be one of {[v.value for v in RuleSet]}, got {self.rules!r}")
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
        if self.text.num_paraphrases < 0:
            problems.append(f"text.num_paraphrases must be >= 0, got {self.text.num_paraphrases}")
        if problems:
            raise ConfigError("invalid captioning config: " + "; ".join(problems))
