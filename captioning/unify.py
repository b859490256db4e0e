"""Unified tag sequences (eq. 8), host segments and caption windows."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from captioning.config import CaptioningConfig, WindowStrategy
from captioning.frames import FrameCounts
from captioning.smoothing import IntArray
from captioning.tags import NO_TAG


def collapse(tags: Sequence[str]) -> list[str]:
    """Eq. 8: keep ``c_i`` where ``c_i ≠ c_{i+1}`` (and the last), i.e. one entry per run, in order."""
    return [tag for i, tag in enumerate(tags) if i + 1 == len(tags) or tag != tags[i + 1]]


def collapse_codes(codes: IntArray) -> IntArray:
    """Eq. 8 on integer codes: (N,) → (M,) one code per run."""
    codes = np.asarray(codes)
    if codes.size == 0:
        return codes.astype(np.int64)
    keep = np.ones(codes.shape[0], dtype=bool)
    keep[:-1] = codes[:-1] != codes[1:]
    return codes[keep].astype(np.int64)


@dataclass(frozen=True)
class Segment:
    """A run of frames ``start``..``end`` (inclusive indices into the frame grid).

    Attributes:
        start: first frame index.
        end: last frame index (inclusive).
        code: the host tag code of the run (−1 for windows not tied to one tag).
    """

    start: int
    end: int
    code: int = NO_TAG

    @property
    def num_frames(self) -> int:
        return self.end - self.start + 1


def host_segments(host_codes: IntArray, min_frames: int, max_frames: int) -> list[Segment]:
    """Runs of one host tag lasting ``min_frames``..``max_frames`` frames.

    Shorter runs are dropped; a longer run is split into ``ceil(n / max_frames)`` parts of equal
    length (± 1 frame), each at least ``max_frames / 2 ≥ min_frames`` long.

    Args:
        host_codes: (T,) unified host tag codes, :data:`NO_TAG` where untagged.
    """
    codes = np.asarray(host_codes)
    t = codes.shape[0]
    if t == 0:
        return []
    change = np.flatnonzero(codes[1:] != codes[:-1]) + 1
    starts = np.r_[0, change]
    ends = np.r_[change - 1, t - 1]
    out: list[Segment] = []
    for s, e in zip(starts.tolist(), ends.tolist()):
        code = int(codes[s])
        n = e - s + 1
        if code == NO_TAG or n < min_frames:
            continue
        parts = -(-n // max_frames)
        bounds = s + (np.arange(parts + 1) * n) // parts
        out.extend(Segment(int(a), int(b) - 1, code) for a, b in zip(bounds[:-1], bounds[1:]))
    return out


def sliding_windows(timestamps_ns: IntArray, length_s: float, stride_s: float) -> list[Segment]:
    """Windows of ``length_s`` every ``stride_s`` over the frame grid (by timestamps).

    Args:
        timestamps_ns: (T,) frame timestamps.
    """
    ts = np.asarray(timestamps_ns, dtype=np.int64)
    if ts.size == 0:
        return []
    length_ns, stride_ns = round(length_s * 1e9), round(stride_s * 1e9)
    begins = np.arange(int(ts[0]), int(ts[-1]) + 1, stride_ns, dtype=np.int64)
    out: list[Segment] = []
    for begin in begins.tolist():
        s = int(np.searchsorted(ts, begin, side="left"))
        e = int(np.searchsorted(ts, begin + length_ns, side="left")) - 1
        if e >= s:
            out.append(Segment(s, e))
        if begin + length_ns > ts[-1]:
            break
    return out


def caption_windows(
    timestamps_ns: IntArray, host_code: IntArray, config: CaptioningConfig
) -> tuple[list[Segment], list[Segment]]:
    """Host segments and the neighbour windows of the configured strategy.

    Segments last ``segments.min_s``..``max_s`` in frames at the log's frame rate
    (:class:`~captioning.frames.FrameCounts`); sliding windows need as many frames as the shortest segment.

    Args:
        timestamps_ns: (T,) frame timestamps.
        host_code: (T,) unified host codes.

    Returns:
        (host segments, neighbour windows).
    """
    frames = FrameCounts.of_log(config, timestamps_ns)
    segments = host_segments(host_code, frames.segment_min, frames.segment_max)
    if config.windows.strategy == WindowStrategy.HOST_SEGMENTS:
        return segments, segments
    windows = sliding_windows(timestamps_ns, config.windows.length_s, config.windows.stride_s)
    return segments, [w for w in windows if w.num_frames >= frames.segment_min]
