"""Weight normalisation, effective sample size and systematic (low-variance) resampling."""

from __future__ import annotations

import numpy as np


def normalise_weights(w: np.ndarray) -> np.ndarray | None:
    """Weights (N,) -> normalised weights (N,) float64 summing to 1, or None when unusable.

    Negative and non-finite entries count as 0; None when nothing positive remains (all
    zero or NaN), which the filters treat as a total loss (full reinvigoration).
    """
    w = np.asarray(w, dtype=np.float64).reshape(-1)
    w = np.where(np.isfinite(w) & (w > 0.0), w, 0.0)
    total = w.sum()
    if not np.isfinite(total) or total <= 0.0:
        return None
    return w / total


def effective_sample_size(w: np.ndarray) -> float:
    """ESS = 1 / sum(w_i^2) of normalised weights (N,); in [1, N]."""
    w = np.asarray(w, dtype=np.float64)
    return float(1.0 / np.sum(w * w))


def systematic_resample(w: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Draw n indices (n,) int64 from normalised weights w (N,) by systematic resampling.

    One uniform offset u ~ U(0, 1/n); positions (u + j/n) are located in the cumulative sum.
    Index i is drawn floor(n w_i) or ceil(n w_i) times (expected count n w_i). The last
    cumulative sum is forced to exactly 1 so that round-off (e.g. a sum of 0.9999999) can
    never send a position past the end; zero-weight particles are never drawn.
    """
    if n <= 0:
        return np.zeros(0, dtype=np.int64)
    w = np.asarray(w, dtype=np.float64).reshape(-1)
    cum = np.cumsum(w)
    cum /= cum[-1]
    cum[-1] = 1.0  # round-off guard: positions are < 1, so searchsorted stays in range
    positions = (rng.random() + np.arange(n)) / n
    idx = np.searchsorted(cum, positions, side="right")
    return np.minimum(idx, w.shape[0] - 1).astype(np.int64)
