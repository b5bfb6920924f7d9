"""Systematic resampling: unbiasedness, low variance, round-off edge cases; weights; ESS."""

from __future__ import annotations

import numpy as np
import pytest

from chpf.tracking.resampling import (
    effective_sample_size,
    normalise_weights,
    systematic_resample,
)


def test_systematic_resampling_is_unbiased():
    w = np.array([0.5, 0.05, 0.2, 0.0, 0.125, 0.125])
    n, runs = 7, 4000
    counts = np.zeros_like(w)
    for seed in range(runs):
        idx = systematic_resample(w, n, np.random.default_rng(seed))
        c = np.bincount(idx, minlength=w.size)
        # low variance: every count is floor or ceil of n w_i
        assert np.all(c >= np.floor(n * w) - 1e-9) and np.all(c <= np.ceil(n * w) + 1e-9)
        counts += c
    np.testing.assert_allclose(counts / runs, n * w, atol=0.03)
    assert counts[3] == 0  # zero weight never drawn


def test_round_off_guard_on_the_last_cumulative_sum():
    # cumulative sum ends at 0.9999999 instead of 1: positions near 1 must stay in range
    w = np.full(10, 0.09999999)
    for seed in range(200):
        idx = systematic_resample(w, 10, np.random.default_rng(seed))
        assert idx.min() >= 0 and idx.max() <= 9
        assert np.array_equal(np.sort(idx), np.arange(10))
    # one weight 1, rest 0, wherever the 1 is
    for k in (0, 4, 9):
        w = np.zeros(10)
        w[k] = 1.0
        idx = systematic_resample(w, 50, np.random.default_rng(k))
        assert np.all(idx == k)


class _MaxRng:
    """A generator whose uniform draw is the largest double below 1 (worst case)."""

    def random(self):
        return np.nextafter(1.0, 0.0)


def test_worst_case_offset_with_short_cumsum():
    w = np.array([0.3, 0.3, 0.3999999])  # sums to 0.9999999
    idx = systematic_resample(w, 3, _MaxRng())
    assert idx.max() == 2
    assert systematic_resample(w, 0, _MaxRng()).shape == (0,)


def test_normalise_weights_and_ess():
    np.testing.assert_allclose(normalise_weights(np.array([1.0, 3.0])), [0.25, 0.75])
    np.testing.assert_allclose(normalise_weights(np.array([1.0, np.nan, -2.0])), [1, 0, 0])
    assert normalise_weights(np.zeros(4)) is None
    assert normalise_weights(np.full(4, np.nan)) is None
    assert effective_sample_size(np.full(50, 1 / 50)) == pytest.approx(50.0)
    assert effective_sample_size(np.eye(5)[2]) == 1.0
