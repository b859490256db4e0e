"""Derivatives along time and flicker suppression on (K tracks, T frames) arrays.

Derivatives
-----------
Positions and headings are differentiated with a Savitzky–Golay filter (polynomial of order
``polyorder`` fitted by least squares over ``window_frames`` frames, an odd count: the config's
``window_s`` at the log's frame rate, :mod:`captioning.frames`), separately on each contiguous run of
observed frames, so that a gap in a track never mixes two runs:

- a frame whose centred window fits inside its run uses the centred window;
- near a run's ends the window is shifted to lie inside the run and the fitted polynomial is
  differentiated at the frame's own position (scipy's ``mode="interp"``);
- runs shorter than the window use plain finite differences (central inside, one-sided at the ends),
  so that at a low frame rate (2 Hz: a 3-frame window) a two-frame run still has a derivative;
- single-frame runs have no derivative (NaN): such frames are left untagged.

The filter works per frame index; timestamps are differentiated the same way and
``dx/dt = (dx/di) / (dt/di)``, which is exact for even sampling and degrades gracefully when frames
are unevenly spaced (e.g. a dropped sweep).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from captioning.tags import NO_TAG
from scenes.geometry import FloatArray

# The array types of the captioning stage, imported from here by its modules (FloatArray is the scenes' own).
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


@lru_cache(maxsize=32)
def savgol_derivative_coefficients(window_frames: int, polyorder: int) -> FloatArray:
    """(W, W) row ``o``: weights of the window's W values giving the first derivative (per frame) of
    the least-squares polynomial at window position ``o``."""
    return savgol_coefficients(window_frames, polyorder, 1)


@lru_cache(maxsize=32)
def savgol_coefficients(window_frames: int, polyorder: int, order: int) -> FloatArray:
    """(W, W) row ``o``: weights of the window's W values giving the least-squares polynomial's value
    (``order`` 0) or first derivative per frame (``order`` 1) at window position ``o``."""
    w = window_frames
    u = np.arange(w, dtype=np.float64) - (w - 1) / 2.0  # centred for conditioning
    vander = u[:, None] ** np.arange(polyorder + 1)[None, :]  # (W, P+1)
    pinv = np.linalg.pinv(vander)  # (P+1, W)
    powers = np.arange(polyorder + 1)
    if order == 0:
        dvec = vander
    else:
        # d/du of sum_k a_k u^k at u_o is sum_k k a_k u_o^(k-1)
        dvec = np.where(powers[None, :] > 0, powers[None, :] * u[:, None] ** np.maximum(powers[None, :] - 1, 0), 0.0)
    coeffs = dvec @ pinv  # (W, W)
    coeffs.setflags(write=False)
    return coeffs


def run_bounds(valid: BoolArray) -> tuple[IntArray, IntArray]:
    """First and last frame of the contiguous observed run holding each frame.

    Args:
        valid: (K, T) observed mask.

    Returns:
        (K, T) run start and (K, T) run end (inclusive); meaningless where ``valid`` is false.
    """
    k, t = valid.shape
    frame = np.broadcast_to(np.arange(t), (k, t))
    starts = valid & ~np.pad(valid, ((0, 0), (1, 0)))[:, :-1]
    ends = valid & ~np.pad(valid, ((0, 0), (0, 1)))[:, 1:]
    run_start = np.maximum.accumulate(np.where(starts, frame, -1), axis=1)
    run_end = np.minimum.accumulate(np.where(ends, frame, t)[:, ::-1], axis=1)[:, ::-1]
    return run_start.astype(np.int64), run_end.astype(np.int64)


def frame_derivative(
    values: FloatArray, valid: BoolArray, window_frames: int, polyorder: int, order: int = 1,
    runs: tuple[IntArray, IntArray] | None = None,
) -> FloatArray:
    """Derivative per frame index of each channel, per contiguous run (see module docstring).

    Args:
        values: (K, T, C) samples; entries where ``valid`` is false are ignored.
        valid: (K, T) observed mask.
        order: 1 for the derivative; 0 for the smoothed values themselves (runs shorter than the
            window keep their samples).
        runs: :func:`run_bounds` of ``valid``, when known already.

    Returns:
        (K, T, C) derivatives; NaN where not observed or (order 1) in a single-frame run.
    """
    k, t, c = values.shape
    if k == 0 or t == 0:
        return np.full((k, t, c), np.nan)
    # A window longer than the grid fits no run: the smallest odd count above T gives the same result.
    w = min(window_frames, t + 1 if t % 2 == 0 else t + 2)
    half = w // 2
    sg_coeffs = savgol_coefficients(w, polyorder, order)
    # Unobserved samples get weight 0, but 0 × NaN is NaN: zero them unless all are finite already.
    flat3 = values if np.isfinite(values).all() else np.where(valid[..., None], values, 0.0)
    run_start, run_end = run_bounds(valid) if runs is None else runs
    frame = np.arange(t)[None, :]
    # Bulk: frames whose centred window lies inside their run, as one correlation over the grid.
    interior = valid & (frame - half >= run_start) & (frame + half <= run_end)
    if interior.any():
        # out[i] = sum_j centred[j] * x[i + j - half]: a correlation along time, done in C.
        from scipy.ndimage import correlate1d  # imported here: a cost a search's start-up never needs
        out = correlate1d(flat3, sg_coeffs[half], axis=1, mode="constant", cval=0.0)
        out[~interior] = np.nan
    else:
        out = np.full((k, t, c), np.nan)
    # Remainder: frames near a run's ends and short runs, gathered one window per frame.
    rows, cols = np.nonzero(valid & ~interior)
    a = run_start[rows, cols]
    b = run_end[rows, cols]
    n = b - a + 1
    keep = n >= (2 if order == 1 else 1)
    rows, cols, a, b, n = rows[keep], cols[keep], a[keep], b[keep], n[keep]
    if rows.size == 0:
        return out
    sg = n >= w
    fd_rows = np.zeros((3, w))
    if order == 1:
        start = np.where(sg, np.clip(cols - half, a, b - w + 1), np.where(cols == a, cols, cols - 1))
        fd_rows[0, :2] = (-1.0, 1.0)  # forward difference at a run's start
        fd_rows[1, :3] = (-0.5, 0.0, 0.5)  # central difference inside
        fd_rows[2, :2] = (-1.0, 1.0)  # backward difference at a run's end (window starts one frame before)
        fd_kind = np.where(cols == a, 0, np.where(cols == b, 2, 1))
    else:
        start = np.where(sg, np.clip(cols - half, a, b - w + 1), cols)
        fd_rows[0, 0] = 1.0  # a short run keeps its samples
        fd_kind = np.zeros_like(cols)
    coeffs = np.where(sg[:, None], sg_coeffs[np.clip(cols - start, 0, w - 1)], fd_rows[fd_kind])  # (N, W)
    flat = flat3.reshape(k * t, c)
    idx = np.minimum((rows * t + start)[:, None] + np.arange(w)[None, :], k * t - 1)  # (N, W)
    acc_edge = coeffs[:, :1] * flat[idx[:, 0]]
    for j in range(1, w):
        acc_edge += coeffs[:, j : j + 1] * flat[idx[:, j]]
    out[rows, cols] = acc_edge
    return out


def seconds_since_first(timestamps_ns: IntArray) -> FloatArray:
    """(T,) seconds since the first of (T,) timestamps (float64 keeps µs precision over days)."""
    ts = np.asarray(timestamps_ns, dtype=np.int64)
    return ((ts - (ts[0] if ts.size else 0)) * 1e-9).astype(np.float64)


def time_derivative(
    values: FloatArray, valid: BoolArray, t_s: FloatArray, window_frames: int, polyorder: int,
    runs: tuple[IntArray, IntArray] | None = None,
) -> FloatArray:
    """Derivative per second: ``(dx/di) / (dt/di)``.

    Args:
        values: (K, T, C) samples.
        valid: (K, T) observed mask.
        t_s: (T,) or (K, T) time of each sample in seconds (rows may have their own clocks).
        runs: :func:`run_bounds` of ``valid``, when known already.

    Returns:
        (K, T, C) derivatives per second; NaN where untaggable.
    """
    k, t, c = values.shape
    if k == 0 or t == 0:
        return np.full((k, t, c), np.nan)
    clock = np.broadcast_to(np.asarray(t_s, dtype=np.float64).reshape(-1, t)[..., None], (k, t, 1))
    stacked = np.concatenate([values, clock], axis=2)
    d = frame_derivative(stacked, valid, window_frames, polyorder, runs=runs)
    return d[..., :-1] / d[..., -1:]


def suppress_flicker(codes: IntArray, min_run_frames: int) -> IntArray:
    """Replace runs of a tag shorter than ``min_run_frames`` (the config's ``min_run_s`` at the log's
    frame rate) by the neighbouring tag.

    A short run takes the tag of the frame before it (the end of the previous long run); at a
    track's start or after a gap it takes the tag after it; when a whole observed stretch consists
    of short runs it is left as it was. Untagged frames (:data:`NO_TAG`) never change and split runs.

    Args:
        codes: (K, T) tag codes, :data:`NO_TAG` where untagged.

    Returns:
        (K, T) codes.
    """
    codes = np.asarray(codes, dtype=np.int64)
    k, t = codes.shape
    if min_run_frames <= 1 or k == 0 or t == 0:
        return codes.copy()
    # Work on runs, not frames: (R,) run starts, lengths, tags and rows.
    flat = codes.ravel()
    change = np.empty(k * t, dtype=bool)
    change[0] = True
    np.not_equal(flat[1:], flat[:-1], out=change[1:])
    change[::t] = True  # a run never spans two tracks
    starts = np.flatnonzero(change)
    lengths = np.diff(np.r_[starts, k * t])
    tags = flat[starts]
    row = starts // t
    hole = (lengths < min_run_frames) & (tags != NO_TAG)
    if not hole.any():
        return codes.copy()
    r = starts.shape[0]
    index = np.arange(r)
    prev = np.maximum.accumulate(np.where(hole, -1, index))
    nxt = np.minimum.accumulate(np.where(hole, r, index)[::-1])[::-1]
    prev_c, next_c = np.clip(prev, 0, r - 1), np.clip(nxt, 0, r - 1)
    prev_tag = np.where((prev >= 0) & (row[prev_c] == row), tags[prev_c], NO_TAG)
    next_tag = np.where((nxt < r) & (row[next_c] == row), tags[next_c], NO_TAG)
    fill = np.where(prev_tag != NO_TAG, prev_tag, np.where(next_tag != NO_TAG, next_tag, tags))
    return np.repeat(np.where(hole, fill, tags), lengths).reshape(k, t)
