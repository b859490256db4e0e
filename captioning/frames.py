"""The config's durations in frames of one log: every window and run of the rules is set in seconds
(:mod:`captioning.config`) and converted here, at the log's own frame rate, so that one config means
the same at 10 Hz (AV2, KITTI, WOMD) as at 2 Hz (nuScenes, a tracker run at 2 Hz).

The frame interval of a log is the median step of its frame grid, i.e. of its annotation timestamps
(a dropped sweep, or a few LiDAR sweeps without annotations in the grid, do not change it). A
duration of ``s`` seconds is ``round(s / interval)`` frames, never fewer than a minimum that keeps
each rule defined:

- Savitzky–Golay windows (``smoothing.window_s``, ``behavior.window_s``, ``behavior.accel_window_s``)
  take the odd frame count nearest to ``s / interval``, at least 3, and their polynomial order is
  lowered to ``window − 2`` where it is higher: a polynomial through as many samples as it has
  coefficients interpolates the jitter instead of smoothing it, and its slope at a run's end is
  noisier than a plain difference. At 2 Hz the 0.9 s default is 3 frames with a straight line: the
  central difference inside a run and the slope over its three end frames at its ends. Runs shorter
  than the window use plain differences (:mod:`captioning.smoothing`), so two frames still give a
  derivative.
- flicker suppression (``smoothing.min_run_s``): at least 1 frame (1 turns it off; at 2 Hz one frame
  already lasts the 0.5 s default).
- bridged gaps (``smoothing.max_gap_s``): at least 0 frames (0 bridges nothing; at 2 Hz the 0.3 s
  default bridges one missed frame); a gap's missed frames are counted in time as well
  (:func:`captioning.neighbors.bridge_gaps`).
- runs for own-behaviour tags (``behavior.min_run_s``): at least 2 frames (a derivative needs two).
- host segments (``segments.min_s`` / ``max_s``): at least 1 frame, and the maximum at least twice
  the minimum after rounding (splitting a long run never yields a part below the minimum).

A log with a single frame has no interval; every count is then its minimum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from captioning.config import CaptioningConfig
from captioning.smoothing import seconds_since_first
from scenes.geometry import FloatArray


def frame_interval_s(t_s: FloatArray) -> float:
    """The median step between (T,) increasing sample times in seconds; NaN with fewer than two."""
    t = np.asarray(t_s, dtype=np.float64)
    if t.size < 2:
        return math.nan
    return float(np.median(np.diff(t)))


def frames_at(seconds: float, interval_s: float, minimum: int) -> int:
    """``seconds`` as a whole number of frames ``interval_s`` apart (nearest, halves up), at least ``minimum``.

    Without a usable interval (NaN, infinite or not positive: a single-frame log) it is ``minimum``.
    """
    if not (math.isfinite(interval_s) and interval_s > 0):
        return minimum
    return max(minimum, math.floor(seconds / interval_s + 0.5))


def savgol_frames(seconds: float, interval_s: float, polyorder: int) -> tuple[int, int]:
    """A Savitzky–Golay window of ``seconds`` and the polynomial order it takes: the odd frame count
    nearest to ``seconds / interval_s`` (an even quotient goes up), at least 3, and ``polyorder``
    lowered to at most that count − 2 (see the module docstring)."""
    frames = 3
    if math.isfinite(interval_s) and interval_s > 0:
        frames = max(frames, 2 * math.floor(seconds / interval_s / 2) + 1)
    return frames, max(1, min(polyorder, frames - 2))


@dataclass(frozen=True)
class FrameCounts:
    """The durations of a :class:`~captioning.config.CaptioningConfig` in frames of one log.

    Attributes:
        interval_s: the log's frame interval (:func:`frame_interval_s`); NaN for a single frame.
        window: ``smoothing.window_s``, odd (host, neighbour and position derivatives).
        polyorder: ``smoothing.polyorder``, at most ``window − 2``.
        min_run: ``smoothing.min_run_s`` (flicker suppression; 1 = off).
        max_gap: ``smoothing.max_gap_s``, in missed frames bridged.
        segment_min: ``segments.min_s`` (shortest host segment; fewest tagged frames of a neighbour caption).
        segment_max: ``segments.max_s``, at least twice ``segment_min``.
        behavior_window: ``behavior.window_s``, odd (the objects' own speed and lateral offset).
        behavior_polyorder: ``behavior.polyorder``, at most ``behavior_window − 2``.
        accel_window: ``behavior.accel_window_s``, odd (the rate of change of the speed).
        accel_polyorder: ``behavior.polyorder``, at most ``accel_window − 2``.
        behavior_min_run: ``behavior.min_run_s`` (shortest run with own-behaviour tags), at least 2.
    """

    interval_s: float
    window: int
    polyorder: int
    min_run: int
    max_gap: int
    segment_min: int
    segment_max: int
    behavior_window: int
    behavior_polyorder: int
    accel_window: int
    accel_polyorder: int
    behavior_min_run: int

    @staticmethod
    def of(config: CaptioningConfig, interval_s: float) -> FrameCounts:
        """The counts at a frame interval (see the module docstring for the rounding and minimums)."""
        s, g, b = config.smoothing, config.segments, config.behavior
        segment_min = frames_at(g.min_s, interval_s, 1)
        window, polyorder = savgol_frames(s.window_s, interval_s, s.polyorder)
        behavior_window, behavior_polyorder = savgol_frames(b.window_s, interval_s, b.polyorder)
        accel_window, accel_polyorder = savgol_frames(b.accel_window_s, interval_s, b.polyorder)
        return FrameCounts(
            interval_s=interval_s,
            window=window,
            polyorder=polyorder,
            min_run=frames_at(s.min_run_s, interval_s, 1),
            max_gap=frames_at(s.max_gap_s, interval_s, 0),
            segment_min=segment_min,
            segment_max=max(frames_at(g.max_s, interval_s, 1), 2 * segment_min),
            behavior_window=behavior_window,
            behavior_polyorder=behavior_polyorder,
            accel_window=accel_window,
            accel_polyorder=accel_polyorder,
            behavior_min_run=frames_at(b.min_run_s, interval_s, 2),
        )

    @staticmethod
    def of_log(config: CaptioningConfig, timestamps_ns: NDArray[np.integer]) -> FrameCounts:
        """The counts at the frame rate of a log with (T,) annotation timestamps."""
        return FrameCounts.of(config, frame_interval_s(seconds_since_first(np.asarray(timestamps_ns, np.int64))))

    def describe(self) -> str:
        """The frame rate in words, for messages (``10 Hz``; ``one frame`` without an interval)."""
        if not (math.isfinite(self.interval_s) and self.interval_s > 0):
            return "one frame"
        return f"{1.0 / self.interval_s:.3g} Hz"
