"""Time over a log's frames, as (K, F) masks on the log's own timestamps: runs of consecutive frames,
where they begin, what follows or precedes what within so many seconds. Durations are seconds, so a
program means the same at 10 Hz and at 2 Hz."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Mask = NDArray[np.bool_]


def runs_lasting(mask: Mask, time_s: NDArray[np.float64], seconds: float) -> Mask:
    """(K, F) frames of runs of ``mask`` (consecutive frames per object) that last at least ``seconds``.

    A run lasts from its first frame's time to its last's plus one frame interval (a single frame at
    10 Hz lasts 0.1 s).
    """
    if mask.shape[1] == 0:
        return mask
    dt = float(np.median(np.diff(time_s))) if time_s.shape[0] > 1 else 0.0
    t = np.broadcast_to(time_s, mask.shape)
    ends = mask & ~np.pad(mask, ((0, 0), (0, 1)))[:, 1:]
    start_t = np.maximum.accumulate(np.where(onsets(mask), t, -np.inf), axis=1)
    end_t = np.flip(np.minimum.accumulate(np.flip(np.where(ends, t, np.inf), axis=1), axis=1), axis=1)
    return mask & (end_t - start_t + dt >= seconds - 1e-6)


def onsets(mask: Mask) -> Mask:
    """(K, F) the first frame of each run of ``mask`` (consecutive frames per row)."""
    return mask & ~np.pad(mask, ((0, 0), (1, 0)))[:, :-1]


def runs_holding(mask: Mask, marks: Mask) -> Mask:
    """(K, F) the runs of ``mask`` (consecutive frames per row) that hold a frame of ``marks``."""
    run = np.cumsum(onsets(mask), axis=1)  # (K, F) each frame's run number in its row (1, 2, ...)
    keys = np.arange(mask.shape[0])[:, None] * (mask.shape[1] + 1) + run
    return mask & np.isin(keys, keys[marks & mask])


def followed_within(mask: Mask, later: Mask, time_s: NDArray[np.float64], within_s: float) -> Mask:
    """(K, F) frames of ``mask`` that a frame of ``later`` follows within ``within_s`` (after it, not at the
    same frame) on the same row; ``later`` (K, F) or (F,) for every row."""
    if mask.shape[1] == 0:
        return mask
    t = np.broadcast_to(time_s, mask.shape)
    upcoming = np.flip(np.minimum.accumulate(np.flip(np.where(later, time_s, np.inf), axis=-1), axis=-1), axis=-1)
    next_after = np.broadcast_to(np.concatenate([upcoming[..., 1:], np.full((*upcoming.shape[:-1], 1), np.inf)],
                                                axis=-1), mask.shape)
    return mask & (next_after - t <= within_s)


def preceded_within(mask: Mask, earlier: Mask, time_s: NDArray[np.float64], within_s: float) -> Mask:
    """(K, F) frames of ``mask`` that a frame of ``earlier`` precedes by at most ``within_s`` (before it, not
    at the same frame) on the same row; ``earlier`` (K, F) or (F,) for every row."""
    if mask.shape[1] == 0:
        return mask
    t = np.broadcast_to(time_s, mask.shape)
    past = np.maximum.accumulate(np.where(earlier, time_s, -np.inf), axis=-1)
    before = np.broadcast_to(np.concatenate([np.full((*past.shape[:-1], 1), -np.inf), past[..., :-1]], axis=-1),
                             mask.shape)
    return mask & (t - before <= within_s)


def reached_in_order(steps: list[Mask], within_s: list[float], time_s: NDArray[np.float64]) -> list[Mask]:
    """(K, F) for each step of a chain on the same object, its frames that the steps before it reach in
    order: a frame of each earlier step, each within ``within_s[j]`` (between ``steps[j]`` and
    ``steps[j + 1]``) before the next, not at the same frame."""
    reached = [steps[0]]
    for step, gap_s in zip(steps[1:], within_s, strict=True):
        reached.append(preceded_within(step, reached[-1], time_s, gap_s))
    return reached


def chained(steps: list[Mask], within_s: list[float], time_s: NDArray[np.float64]) -> Mask:
    """(K, F) frames of a chain of steps on the same object: a frame of ``steps[i]`` is kept where the steps
    before it reach it in order (:func:`reached_in_order`) and the steps after it follow it so. "Stops,
    then turns, then accelerates" keeps no acceleration that comes before the turn."""
    reached = reached_in_order(steps, within_s, time_s)
    kept = [reached[-1]]  # frames of step i on a whole chain, from the last step back
    for frames, gap_s in zip(reached[-2::-1], within_s[::-1], strict=True):
        kept.append(followed_within(frames, kept[-1], time_s, gap_s))
    return np.logical_or.reduce(kept)
