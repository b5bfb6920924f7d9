"""Importance weights as log-weights, and the resampling schemes (small pure functions)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from chpf.errors import ConfigError


class Weights:
    """Importance weights of N particles kept as log-weights ``lw`` (N,).

    NaN and +inf log-weights count as -inf (a weight of 0). All -inf is a *collapse*: no
    particle carries any weight, ``W`` is None and ``ess`` is 0.
    """

    def __init__(self, lw: np.ndarray) -> None:
        lw = np.asarray(lw, dtype=np.float64).reshape(-1)
        self.lw = np.where(np.isnan(lw) | (lw == np.inf), -np.inf, lw)
        self.collapsed = not np.isfinite(self.lw).any()
        self.W = None if self.collapsed else _normalised(self.lw)
        self.ess = 0.0 if self.W is None else float(1.0 / np.sum(self.W * self.W))

    @classmethod
    def from_weights(cls, w: np.ndarray) -> Weights:
        """From raw importance weights (N,): log w, with zero, negative and NaN weights -> -inf."""
        w = np.asarray(w, dtype=np.float64).reshape(-1)
        with np.errstate(divide="ignore"):
            return cls(np.log(np.where(np.isfinite(w) & (w > 0.0), w, 0.0)))

    @classmethod
    def uniform(cls, n: int) -> Weights:
        """Equal weights 1/n for n particles."""
        return cls(np.zeros(n))

    def tempered(self, beta: float) -> Weights:
        """The weights raised to beta > 0 (annealing): log-weights beta * lw."""
        return Weights(beta * self.lw)


def _normalised(lw: np.ndarray) -> np.ndarray:
    """exp(lw) / sum(exp(lw)) (N,), shifted by the maximum so that nothing overflows."""
    w = np.exp(lw - lw.max())
    return w / w.sum()


Resampler = Callable[[np.ndarray, int, np.random.Generator], np.ndarray]


def _inverse_cdf(w: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Indices (n,) int64 of the positions (n,) in [0, 1) in the cumulative sum of w (N,).

    The last cumulative sum is forced to exactly 1 so that round-off (e.g. a sum of 0.9999999)
    can never send a position past the end; zero-weight particles are never drawn.
    """
    w = np.asarray(w, dtype=np.float64).reshape(-1)
    cum = np.cumsum(w)
    cum /= cum[-1]
    cum[-1] = 1.0
    idx = np.searchsorted(cum, positions, side="right")
    return np.minimum(idx, w.shape[0] - 1).astype(np.int64)


def systematic_resample(w: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Draw n indices (n,) int64 from normalised weights w (N,) by systematic resampling.

    One uniform offset u ~ U(0, 1/n); positions (u + j/n) are located in the cumulative sum.
    Index i is drawn floor(n w_i) or ceil(n w_i) times (expected count n w_i).
    """
    if n <= 0:
        return np.zeros(0, dtype=np.int64)
    return _inverse_cdf(w, (rng.random() + np.arange(n)) / n)


def multinomial_resample(w: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Draw n indices (n,) int64 from normalised weights w (N,) independently (n uniforms)."""
    if n <= 0:
        return np.zeros(0, dtype=np.int64)
    return _inverse_cdf(w, rng.random(n))


RESAMPLERS: dict[str, Resampler] = {
    "systematic": systematic_resample,
    "multinomial": multinomial_resample,
}


def resampler(name: str) -> Resampler:
    """The resampling scheme called ``name`` (a key of RESAMPLERS); ConfigError otherwise."""
    if name not in RESAMPLERS:
        raise ConfigError(f"resampling: one of {sorted(RESAMPLERS)}, got {name!r}")
    return RESAMPLERS[name]
