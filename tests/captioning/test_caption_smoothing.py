"""Savitzky–Golay derivatives per contiguous run, and flicker suppression."""

from __future__ import annotations

import numpy as np
import pytest

from captioning.smoothing import frame_derivative, run_bounds, suppress_flicker, time_derivative
from captioning.tags import NO_TAG


def test_quadratic_derivative_is_exact_everywhere_including_run_ends() -> None:
    t = np.arange(30, dtype=float)
    x = 0.5 * t**2 - 3 * t + 2
    d = frame_derivative(x[None, :, None], np.ones((1, 30), bool), 9, 2)[0, :, 0]
    np.testing.assert_allclose(d, t - 3, atol=1e-9)


def test_gap_splits_runs_and_short_runs_use_finite_differences() -> None:
    valid = np.array([[True] * 12 + [False] + [True] * 3 + [False] + [True]])
    x = np.where(valid, np.arange(18.0) ** 2, np.nan)
    d = frame_derivative(x[..., None], valid, 9, 2)[0, :, 0]
    np.testing.assert_allclose(d[:12], 2 * np.arange(12.0), atol=1e-9)  # long run: exact SG
    assert np.isnan(d[12]) and np.isnan(d[16]) and np.isnan(d[17])  # gaps and a single-frame run
    np.testing.assert_allclose(d[13:16], [14**2 - 13**2, (15**2 - 13**2) / 2, 15**2 - 14**2])


def test_run_bounds() -> None:
    start, end = run_bounds(np.array([[False, True, True, False, True]]))
    assert start[0, [1, 2, 4]].tolist() == [1, 1, 4]
    assert end[0, [1, 2, 4]].tolist() == [2, 2, 4]


def test_uneven_timestamps_give_true_speed() -> None:
    ts_ns = np.cumsum(np.r_[0, np.full(10, 100_000_000), 200_000_000, np.full(10, 100_000_000)])
    t_s = ts_ns * 1e-9
    x = 7.0 * t_s  # constant 7 m/s despite a dropped frame
    d = time_derivative(x[None, :, None], np.ones((1, t_s.size), bool), t_s, 9, 2)
    np.testing.assert_allclose(d[0, :, 0], 7.0, rtol=1e-9)


@pytest.mark.parametrize(
    ("codes", "min_run", "expected"),
    [
        ([0, 0, 0, 1, 0, 0, 0], 2, [0, 0, 0, 0, 0, 0, 0]),  # a one-frame flicker
        ([1, 0, 0, 0, 0], 3, [0, 0, 0, 0, 0]),  # short run at the start takes the next tag
        ([0, 0, 0, 2, 2, 1, 1, 1], 3, [0, 0, 0, 0, 0, 1, 1, 1]),  # takes the previous long run's tag
        ([0, 1, 0, 1], 3, [0, 1, 0, 1]),  # nothing long to take from: unchanged
        ([0, 0, 0, NO_TAG, 1, 0, 0, 0], 2, [0, 0, 0, NO_TAG, 0, 0, 0, 0]),  # untagged frames stay untagged
        ([0, 1, 0], 1, [0, 1, 0]),  # 1 turns suppression off
    ],
)
def test_suppress_flicker(codes: list[int], min_run: int, expected: list[int]) -> None:
    assert suppress_flicker(np.array([codes]), min_run)[0].tolist() == expected


def test_suppress_flicker_keeps_rows_apart() -> None:
    codes = np.array([[0, 0, 0, 1], [2, 2, 2, 2]])
    assert suppress_flicker(codes, 2).tolist() == [[0, 0, 0, 0], [2, 2, 2, 2]]


def test_quantile_below_matches_numpy_quantile() -> None:
    from captioning.neighbors import quantile_below

    rng = np.random.default_rng(5)
    values = rng.exponential(0.5, (300, 23))
    values[rng.random(values.shape) < 0.3] = np.nan
    values[0] = np.nan  # no samples
    for q in (0.5, 0.8, 1.0):
        for threshold in (0.2, 0.5, 0.9):
            got = quantile_below(values, q, threshold)
            want = [bool(np.isfinite(r).any()) and np.quantile(r[np.isfinite(r)], q) < threshold for r in values]
            assert got.tolist() == want
