"""Resampling schemes (unbiasedness, low variance, round-off edge cases); log-weights; ESS."""

from __future__ import annotations

import numpy as np
import pytest

from chpf.errors import ConfigError
from chpf.tracking.resampling import (
    RESAMPLERS,
    Weights,
    multinomial_resample,
    resampler,
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


def test_weights_normalise_and_ess():
    np.testing.assert_allclose(Weights.from_weights(np.array([1.0, 3.0])).W, [0.25, 0.75])
    np.testing.assert_allclose(Weights.from_weights(np.array([1.0, np.nan, -2.0])).W, [1, 0, 0])
    assert Weights.from_weights(np.zeros(4)).W is None
    assert Weights.from_weights(np.full(4, np.nan)).W is None
    assert Weights.uniform(50).ess == pytest.approx(50.0)
    assert Weights.from_weights(np.eye(5)[2]).ess == 1.0


def test_weights_from_log_weights():
    # W = (1, 2, 4, 1) / 8 -> ESS = 1 / sum W^2 = 64 / 22
    w = Weights(np.log([1.0, 2.0, 4.0, 1.0]) + 1000.0)  # a large shift must not overflow
    np.testing.assert_allclose(w.W, [0.125, 0.25, 0.5, 0.125])
    assert w.ess == pytest.approx(64.0 / 22.0) and not w.collapsed
    # NaN and +inf log-weights weigh nothing; all -inf is a collapse
    w = Weights(np.array([np.nan, 0.0, np.inf, -np.inf]))
    np.testing.assert_array_equal(w.W, [0.0, 1.0, 0.0, 0.0])
    collapsed = Weights(np.full(3, -np.inf))
    assert collapsed.collapsed and collapsed.W is None and collapsed.ess == 0.0
    assert Weights(np.full(3, np.nan)).collapsed


def test_tempered_weights_are_the_normalised_power():
    raw = np.random.default_rng(0).random(200) * np.exp(np.random.default_rng(1).normal(0, 5, 200))
    raw[::7] = 0.0
    for beta in (0.2, 0.5, 1.0):
        power = np.power(raw, beta)
        np.testing.assert_allclose(
            Weights.from_weights(raw).tempered(beta).W, power / power.sum(), rtol=1e-12, atol=0
        )


def test_multinomial_resampling_is_unbiased_and_selectable():
    w = np.array([0.5, 0.05, 0.2, 0.0, 0.125, 0.125])
    counts = np.zeros_like(w)
    for seed in range(2000):
        counts += np.bincount(multinomial_resample(w, 8, np.random.default_rng(seed)), minlength=6)
    np.testing.assert_allclose(counts / 2000, 8 * w, atol=0.1)
    assert counts[3] == 0
    assert multinomial_resample(w, 0, np.random.default_rng(0)).shape == (0,)
    assert resampler("multinomial") is multinomial_resample
    assert RESAMPLERS["systematic"] is systematic_resample
    with pytest.raises(ConfigError, match=r"resampling.*'stratified'"):
        resampler("stratified")
